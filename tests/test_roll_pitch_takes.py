"""``benchmarks/roll_pitch_takes.py`` and the second look's record it reads: a take rule judged on the same
runs, from both poses' errors."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import benchmark_script
from semcityloc.geometry.pose import Pose


@pytest.fixture(scope="module")
def takes():
    return benchmark_script("roll_pitch_takes")


def _row(condition, status, err, look=None):
    return {
        "variant": "base",
        "condition": condition,
        "status": status,
        "err_m": err[0],
        "err_deg": err[1],
        "roll_pitch_look": look,
    }


def test_each_rule_keeps_the_pose_it_would_have_kept(takes):
    small_gain = {"gain": 0.005, "sigmas": 2.5, "first_err": [1.0, 0.5], "second_err": [5.4, 3.0]}
    far_off = {"gain": 0.002, "sigmas": 4.0, "first_err": [6.0, 3.0], "second_err": [1.5, 1.0]}
    rows = [
        _row("hilly", "localized", (5.4, 3.0), small_gain),  # taken by stop 52's rule: its pose recorded
        _row("hilly", "localized", (1.5, 1.0), far_off),
        _row("hilly", "localized", (0.3, 0.2)),  # no look
        _row("hilly", "not_localized", (0.3, 0.2)),  # refused: never counted
    ]
    rules = takes.rules(3.0, 0.01)
    got = {name: takes.counts(rows, rule) for name, rule in rules.items()}
    any_gain, stop54, beyond, never = got.values()
    assert any_gain == (2, 2, 1)  # the small gain taken: 5.4 m off
    assert stop54 == (3, 3, 0)  # within 3 sigma 0.005 is not enough; beyond it any gain
    assert beyond == (3, 3, 0)
    assert never == (2, 2, 1)  # the far-off first pose kept
    text = takes.table(rows, rules)
    assert "| hilly (4; 2) | 2 / 2 (1) | 3 / 3 (0) | 3 / 3 (0) | 2 / 2 (1) |" in text


def test_compare_configs_writes_both_poses_errors_of_a_second_look():
    compare = benchmark_script("compare_configs")
    truth = Pose.from_state(np.array([0.0, 0.0, 80.0, 0.0, 0.0, 30.0]))
    look = {
        "departure_deg": 2.4,
        "sigmas": 2.4,
        "gain": 0.004,
        "gain_needed": 0.01,
        "moved_m": 2.0,
        "moved_deg": 1.5,
        "taken": False,
        "refused": False,
        "first_xyz_rpy_local": [1.0, 0.0, 80.0, 0.0, 0.0, 30.0],
        "second_xyz_rpy_local": [0.0, 0.0, 80.0, 2.0, 0.0, 30.0],
    }
    out = compare._look_errors(look, truth)
    assert out["first_err"] == pytest.approx([1.0, 0.0], abs=1e-9)
    assert out["second_err"][0] == pytest.approx(0.0, abs=1e-9) and out["second_err"][1] == pytest.approx(2.0)
    assert out["gain_needed"] == 0.01 and "first_xyz_rpy_local" not in out
    assert compare._look_errors(None, truth) is None


def test_bad_input_is_one_line_not_a_traceback(takes, tmp_path):
    """Stop 54 audit: a missing file, the summary lines instead of the --rows file, or an unknown variant
    gave a traceback or an empty table with exit 0."""
    rows = tmp_path / "rows.jsonl"
    rows.write_text('{"variant": "base", "status": "localized", "err_m": 1.0, "err_deg": 0.5}\n')
    with pytest.raises(SystemExit, match="cannot read it"):
        takes.main([str(tmp_path / "missing.jsonl")])
    summary = tmp_path / "summary.jsonl"
    summary.write_text('{"condition": "realistic", "variant": "base", "queries": 3}\n')
    with pytest.raises(SystemExit, match="not compare_configs.py --rows output"):
        takes.main([str(summary)])
    with pytest.raises(SystemExit, match="no rows of variant 'nosuch'.*it has: base"):
        takes.main([str(rows), "--variant", "nosuch"])
    assert takes.main([str(rows)]) == 0
