"""``benchmarks/ridge_profile.py``: the grid of turns about the pivot and its per-ring summary."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import benchmark_script
from semcityloc.geometry.pose import Pose


@pytest.fixture(scope="module")
def script():
    return benchmark_script("ridge_profile")


def test_turns_about_the_pivot_keep_the_pivot_point_and_centre_on_the_truth(script):
    truth = np.array([10.0, -5.0, 200.0, 1.0, 2.0, 30.0])
    pivot_m = 180.0
    states = script.ridge_states(truth, pivot_m, span_deg=0.5, steps=5)
    assert states.shape == (25, 6)
    np.testing.assert_allclose(states[12], truth)  # the grid's centre is the truth

    def pivot_point(s):
        pose = Pose.from_xyz_rpy(s[:3], s[3], s[4], s[5])
        return pose.center + pivot_m * np.asarray(pose.R)[2]

    # Every turn keeps the point 180 m ahead nearly in place while the camera moves metres.
    moved = np.linalg.norm(states[:, :3] - truth[:3], axis=1)
    stays = np.array([np.linalg.norm(pivot_point(s) - pivot_point(truth)) for s in states])
    assert moved.max() > 1.5 and stays.max() < 0.02 * moved.max()


def test_profile_lists_each_ring_with_its_best_and_lowest_score(script):
    distance = np.array([0.0, 0.3, 0.8, 2.0])
    scores = np.array([0.9, 0.95, 0.7, 0.5])
    lines = script.profile(scores, distance, truth_score=0.9)
    assert lines[0].startswith("  within 0.5 m: best 0.95000 (+0.05000), lowest 0.95000")
    assert lines[1].startswith("  within 1.0 m: best 0.95000 (+0.05000), lowest 0.70000 (-0.20000), 2")
    assert "lowest 0.50000" in lines[3] and len(lines) == 5


def test_an_even_grid_is_refused(script, tmp_path, capsys):
    assert script.main(["--dataset", str(tmp_path), "--steps", "4"]) == 2
    assert "odd" in capsys.readouterr().err
