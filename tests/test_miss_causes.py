"""``benchmarks/miss_causes.py``: each miss of a run sorted into its kind, with the map's agreement at the
truth read from the simulated queries' confusion."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from semcityloc.benchmark.results import REASON_UNREADABLE
from semcityloc.classes import NUM_CLASSES, SemanticClass
from semcityloc.localization.agreement import UNMAPPED_WARNING, UNSEEN_WARNING

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "miss_causes.py"
FIELDS = "query_id status view query_miou err_xyz_m err_rot_deg found_err_xyz_m found_err_rot_deg probability"


def _confusion(agree: int, disagree: int) -> list[int]:
    """Building pixels agreeing and (each way) disagreeing between the mask and the map."""
    c = np.zeros((NUM_CLASSES, NUM_CLASSES), dtype=np.int64)
    c[SemanticClass.ROOF, SemanticClass.ROOF] = agree
    c[SemanticClass.ROOF, SemanticClass.GROUND] = disagree
    c[SemanticClass.GROUND, SemanticClass.WALL] = disagree
    c[SemanticClass.GROUND, SemanticClass.GROUND] = 500
    return c.reshape(-1).tolist()


WARNED = {  # what the localizer said about the map (localization.agreement), as results.csv keeps it
    "q2": f"{UNMAPPED_WARNING} (12 % ...) | {UNSEEN_WARNING} (3 % ...)",
    "q4": f"depth map dropped: ... | {UNSEEN_WARNING} (5 % ...)",
}


BOUNDARIES = {"q3": "4.25", "q4": "nan"}  # px at the found pose; empty as in runs before stop 42


UNREADABLE = {  # results.unreadable_result, results.failed_row
    "q6": f"{REASON_UNREADABLE}: /d/masks/q6.png: truncated PNG",
    "q7": "worker died 2 times: the actor died unexpectedly",
}


def test_misses_are_sorted_by_kind_with_the_maps_agreement(tmp_path):
    rows = [  # (status, error, found error, map agreement in pixels)
        ("q0", "localized", 0.5, 0.5, 900, 50),  # hit
        ("q1", "localized", 3.0, 3.0, 900, 50),  # near: accepted, 3 m off
        ("q2", "not_localized", "", 1.0, 300, 350),  # refused-near: the map differs at the truth
        ("q3", "not_localized", "", 40.0, 300, 350),  # refused-wrong
        ("q4", "localized", 9.0, 9.0, 600, 200),  # wrong, accepted
        ("q5", "skipped", "", "", 0, 0),  # not a query: left out
        ("q6", "not_localized", "inf", "", 0, 0),  # unreadable-input: its mask could not be read
        ("q7", "failed", "inf", "", 0, 0),  # failed: its worker died on every try (results.failed_row)
    ]
    with (tmp_path / "results.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, [*FIELDS.split(), "reason", "warnings", "meta_json", "boundary_distance_px"])
        w.writeheader()
        for qid, status, err, found, agree, disagree in rows:
            w.writerow(
                dict(
                    query_id=qid, status=status, view="nadir", query_miou=85, probability=0.5,
                    err_xyz_m=err if err != "" else (found if status != "skipped" else ""),
                    err_rot_deg=0.5 if status != "skipped" else "", found_err_xyz_m=found,
                    found_err_rot_deg=0.5 if found != "" else "",
                    warnings=WARNED.get(qid, ""), boundary_distance_px=BOUNDARIES.get(qid, ""),
                    reason=UNREADABLE.get(qid, ""),
                    meta_json=json.dumps(
                        {"map_confusion": _confusion(agree, disagree), "prior_roll_err_deg": -1.5}
                    ),
                )
            )  # fmt: skip
    out = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path)], capture_output=True, text=True, check=True
    )
    lines = out.stdout.splitlines()
    summary = json.loads(lines[-1])
    assert summary["queries"] == 7
    assert summary["count"] == {
        "hit": 1, "near": 1, "refused-near": 1, "refused-wrong": 1, "wrong": 1, "unreadable-input": 1,
        "skipped": 0, "failed": 1,
    }  # fmt: skip
    assert abs(summary["median_map_building_iou"]["hit"] - 900 / 1000) < 1e-9
    assert abs(summary["median_map_building_iou"]["refused-near"] - 300 / 1000) < 1e-9
    assert summary["hits_by_map_building_iou"] == {"0-0.6": [0, 2], "0.6-0.8": [0, 1], "0.8-1.01": [1, 2]}
    assert summary["map_warned"] == [0, 2]  # q2 and q4 carried an outdated-map warning, no hit did
    assert abs(summary["median_map_building_iou"]["misses"] - (0.3 + 0.6) / 2) < 1e-9  # of 0.9, 0.3, 0.3, 0.6
    table = [line for line in lines if line.startswith("| q") and not line.startswith("| query")]
    kinds = ["near", "refused-near", "refused-wrong", "wrong", "unreadable-input", "failed"]
    assert [line.split(" | ")[2] for line in table] == kinds
    assert "1.5° / nan°" in table[0]  # the prior's roll error, unsigned; a missing pitch error says nan
    apart = ["-", "-", "4.2", "nan", "-", "-"]  # class boundaries apart
    assert [line.split(" | ")[-2] for line in table] == apart
    assert [line.split(" | ")[-1] for line in table] == [
        "- |",
        "map lacks, image lacks |",
        "- |",
        "image lacks |",
        "- |",
        "- |",
    ]
    # At 5 m the accepted 3 m pose is a hit.
    out5 = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path), "--m", "5", "--deg", "5"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    assert json.loads(out5.stdout.splitlines()[-1])["count"]["hit"] == 2


def test_a_folder_without_results_is_a_clear_exit(tmp_path):
    out = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path)], capture_output=True, text=True)
    assert out.returncode == 2 and "no results.csv" in out.stderr and "Traceback" not in out.stderr
