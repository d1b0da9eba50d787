"""``benchmarks/refine_seeds.py``: one real query localized with several refinement seeds (a diagnosis)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "refine_seeds.py"


def test_oblique_real_image_with_two_refinement_seeds(shared):
    data = shared("real_uav_lodloc_oblique/GT_pose").parents[1]
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--dataset", str(data), "--query", "1", "--seeds", "2"],
        capture_output=True,
        text=True,
        check=True,
    )
    lines = [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]
    rows, summary = lines[:-1], lines[-1]
    assert [r["seed"] for r in rows] == [0, 1]
    for r in rows:
        assert r["status"] == "localized" and r["error_m"] < 1.0 and r["error_deg"] < 1.0
        assert abs(float(sum(v * v for v in r["error_vector_m"])) ** 0.5 - r["error_m"]) < 2e-3
        assert 0.0 < r["score_truth"] <= 1.0
    assert summary["seeds"] == 2 and summary["within_1m"] == 2


def test_missing_dataset_is_a_clear_exit(tmp_path):
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--dataset", str(tmp_path / "nope")], capture_output=True, text=True
    )
    assert out.returncode == 2 and "no such data set folder" in out.stderr
