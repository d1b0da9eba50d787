"""``benchmarks/pooled_draws.py``: several draws read as one, and the queries one method has right that
another misses."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "pooled_draws.py"
FIELDS = ["query_id", "index", "status", "view", "err_xyz_m", "err_rot_deg", "err_yaw_deg"]


def _run(folder: Path, method: str, seed: int, errors: list[float | None]) -> Path:
    """A benchmark output folder whose queries have these position errors (None: refused)."""
    folder.mkdir()
    (folder / "summary.json").write_text(
        json.dumps({"config": {"city": "/data/berlin.gml", "seed": seed, "method": method}})
    )
    with (folder / "results.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, FIELDS)
        w.writeheader()
        for i, err in enumerate(errors):
            status = "localized" if err is not None else "not_localized"
            e = err if err is not None else 40.0  # a refused query keeps its found pose's error
            w.writerow(
                dict(
                    query_id=f"q{i}",
                    index=i,
                    status=status,
                    view="nadir",
                    err_xyz_m=e,
                    err_rot_deg=0.5,
                    err_yaw_deg=0.1,
                )
            )
    return folder


def test_draws_pool_and_pair_by_query(tmp_path):
    runs = [
        _run(tmp_path / "a0", "semcityloc", 0, [0.5, 1.0, 2.5, None]),
        _run(tmp_path / "b0", "no-depth", 0, [0.5, 3.0, 1.5, 9.0]),
        _run(tmp_path / "a1", "semcityloc", 1, [0.5, 0.6, 0.7, 0.8]),
        _run(tmp_path / "b1", "no-depth", 1, [0.5, 0.6, 0.7, 2.5]),
    ]
    out = subprocess.run(
        [sys.executable, str(SCRIPT), *map(str, runs)], capture_output=True, text=True, check=True
    ).stdout
    lines = [json.loads(x) for x in out.splitlines() if x.startswith("{")]
    full, no_depth = lines
    assert (full["method"], full["queries"], full["draws"]) == ("semcityloc", 8, 2)
    assert full["recall_2m2deg"] == 75.0 and full["recall_3m3deg"] == 87.5  # 6 and 7 of 8
    assert full["localized"] == 7 and full["acceptance_precision"] == 100.0
    assert no_depth["recall_2m2deg"] == 62.5 and no_depth["acceptance_precision"] == 87.5  # 9 m accepted
    # at 2 m / 2 deg: q2 of seed 0 only without depth; q1 of seed 0 and q3 of seed 1 only with it
    assert no_depth["right_at_2m2deg_only_here"] == 1 and no_depth["right_at_2m2deg_only_semcityloc"] == 2
    assert "| berlin seed 0 | 4 | 50 / 75 / 75 (3, 100.0 %) | 50 / 75 / 75 (4, 75.0 %) |" in out


def test_a_folder_without_a_summary_is_named(tmp_path):
    (tmp_path / "unfinished").mkdir()
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "unfinished")], capture_output=True, text=True
    )
    assert done.returncode == 2 and "unfinished: not a finished benchmark run" in done.stderr
