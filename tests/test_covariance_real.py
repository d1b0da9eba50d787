"""``benchmarks/covariance_real.py``: the pose covariance against the truth of the real UAV images."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "covariance_real.py"


def test_both_real_images_with_oracle_labels(shared):
    data = shared("real_uav_lodloc_oblique/GT_pose").parents[1]
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--dataset", str(data), "--label-seeds", "0"],
        capture_output=True,
        text=True,
        check=True,
    )
    lines = out.stdout.splitlines()
    assert len(lines) == 2 and all("oracle seed 0: localized" in line for line in lines)
    d2 = {line.split()[0]: float(re.search(r"d2 ([\d.]+)", line).group(1)) for line in lines}
    assert d2["q0001"] < 12.6  # the oblique image's truth inside the 95 % ellipsoid
    assert 0.0 < d2["q0000"] < 1e6  # the thermal one: finite; outside the 99 % one (docs/localization.md)


def test_missing_dataset_is_a_clear_exit(tmp_path):
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--dataset", str(tmp_path / "nope")], capture_output=True, text=True
    )
    assert out.returncode == 2 and "no such data set folder" in out.stderr
