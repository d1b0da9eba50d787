"""``benchmarks/score_at_truth.py``: whose fault a miss is (the search's or the score's), on any scenario."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "score_at_truth.py"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True)


def test_summary_names_the_scenario_knobs_and_counts_the_misses():
    out = run("--queries", "3", "--workers", "1", "--set", "focal_mm=28")
    assert out.returncode == 0, out.stderr
    lines = [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]
    misses, summary = lines[:-1], lines[-1]
    assert summary["settings"] == {"focal_mm": 28} and summary["queries"] == 3
    unscored = sum("score_truth" not in m for m in misses)
    assert summary["misses"] == len(misses) == summary["scored_misses"] + unscored
    assert summary["truth_lower"] + summary["truth_higher"] == summary["scored_misses"]
    for m in misses:
        assert m["miss"] and ("err_m" not in m or m["err_m"] > 2.0 or m["err_deg"] > 2.0)


def test_a_bad_knob_is_a_clear_exit():
    out = run("--queries", "1", "--set", "focal_mm=-3")
    assert out.returncode != 0 and "focal_mm" in out.stderr and "Traceback" not in out.stderr
