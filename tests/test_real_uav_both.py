"""Both real UAV images (thermal near-nadir 640x512, RGB oblique 2325x1742; same LoD1 model) from their GPS
priors with the localizer's DEFAULT settings: oracle labels (the model's classes at the GT pose) and the
same labels degraded by the "trained" segmentation preset; the real-data benchmark over both folders at
once; and its report with overlays on the photos. Skips when ../shared/data is absent.

Bounds per image (``BOUNDS``): the oblique image within 1 m / 1 deg. The thermal one (prior 20.7 m too
high: the first design's search returned it 6.4 m off, confidently) within 2.5 m / 1 deg: at 225 m with a
32 deg field of view a tilt and a sideways shift look alike (docs/benchmark.md, the real images), and
where along that ridge the refinement ends is its random draw: with oracle labels and the refinement's
seeds 0-7 it lands 0.4-3.7 m off with stop 22's default and 0.4-2.7 m with stop 24's (mean 1.36 m both).
An earlier 1 m bound held for seed 0 of stop 22's default only.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from conftest import shared_file
from semcityloc.benchmark.dataset_source import DatasetSpec, oracle_labels, working_camera
from semcityloc.benchmark.perception_sim import miou, simulate_segmentation
from semcityloc.benchmark.queries import STREAM_SEG
from semcityloc.benchmark.report import make_report
from semcityloc.benchmark.run import run_benchmark
from semcityloc.classes import IGNORE
from semcityloc.cli.main import main
from semcityloc.datasets.lodloc import read_lodloc
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer

FOLDERS = {"thermal": "real_uav_lodloc", "oblique": "real_uav_lodloc_oblique"}
BOUNDS = {"thermal": (2.5, 1.0), "oblique": (1.0, 1.0)}  # (metres, degrees)


@functools.lru_cache(maxsize=1)
def _both(root: str) -> dict:
    ds = read_lodloc(root)  # a folder of scenes: both images, the LoD1 model beside the thermal one
    model = ds.load_model()
    localizer = Localizer(model, LocalizerConfig())  # default settings
    return {"queries": {q.name: q for q in ds.queries}, "model": model, "loc": localizer}


@pytest.fixture
def both():
    return _both(str(shared_file(FOLDERS["thermal"]).parent))


def _query(both, which: str):
    folder = shared_file(FOLDERS[which])
    (name,) = [p.name for p in (folder / "Query_image").iterdir()]
    return both["queries"][name]


def _labels(both, q, perception: str, index: int) -> np.ndarray:
    camera = working_camera(q.camera)  # masks at any size with the photo's aspect: 1024 px for the oblique
    clean = oracle_labels(both["model"], camera, q.gt_pose_world)
    if perception == "oracle":
        return clean
    known = np.where(clean == IGNORE, 0, clean).astype(np.uint8)
    noisy = simulate_segmentation(known, "trained", np.random.default_rng([0, index, STREAM_SEG]))
    assert 80.0 < miou(noisy, known) < 99.0
    noisy[clean == IGNORE] = IGNORE
    return noisy


@pytest.mark.parametrize(
    "which, perception",
    [
        ("thermal", "oracle"),
        ("thermal", "oracle-degraded"),
        ("oblique", "oracle"),
        ("oblique", "oracle-degraded"),
    ],
)
def test_real_image_from_its_gps_prior_with_default_settings(both, which, perception):
    q, model = _query(both, which), both["model"]
    labels = _labels(both, q, perception, 0 if which == "thermal" else 1)
    result = both["loc"].localize(q.camera, model.pose_to_local(q.prior_pose_world), labels)
    assert result.localized, result.reason
    est = model.pose_to_world(result.pose_local)
    err_m, err_deg = (
        float(center_error_m(est, q.gt_pose_world)),
        float(rotation_error_deg(est, q.gt_pose_world)),
    )
    prior_m = float(center_error_m(q.prior_pose_world, q.gt_pose_world))
    print(f"{which}, {perception}: {err_m:.2f} m, {err_deg:.2f} deg (prior {prior_m:.1f} m)")
    max_m, max_deg = BOUNDS[which]
    assert err_m < max_m and err_deg < max_deg


def test_the_real_data_benchmark_runs_over_both_folders_at_once(tmp_path, capsys):
    """``semcityloc benchmark --dataset`` on the folder holding both scenes: two queries, one model, every
    output naming its perception; its report draws the model's edges over each photo."""
    data = shared_file(FOLDERS["thermal"]).parent
    out = tmp_path / "both"
    argv = ["benchmark", "--dataset", data, "--perception", "oracle-degraded", "--preset", "default"]
    assert main([str(a) for a in [*argv, "--out", out]]) == 0
    printed = capsys.readouterr().out
    assert "oracle perception degraded by the 'trained' segmentation preset" in printed
    run = json.loads((out / "run.json").read_text())
    assert run["queries"] == 2 and run["city"].endswith("UAVD4L-LoD1.obj")
    assert sorted(run["query_names"]) == ["DJI_20230513163714_0033_T.JPG", "DJI_20231018114619_0636_D.JPG"]
    summary = json.loads((out / "summary.json").read_text())
    assert (
        summary["queries"] == 2 and summary["localized"] == 2 and summary["perception"] == "oracle-degraded"
    )
    assert sorted(summary["by_view"]) == ["nadir", "oblique"]
    report = make_report([out], tmp_path / "report", overlays=2)
    figures = [p for p in report.plots if p.name.startswith("query_")]
    assert len(figures) == 2
    assert "semcityloc [oracle-degraded (trained)]" in report.markdown.read_text()


def test_both_real_images_within_their_bounds_in_the_benchmark_with_default_settings(tmp_path):
    data = shared_file(FOLDERS["thermal"]).parent
    outcome = run_benchmark(DatasetSpec(dataset=str(data), preset="default"), tmp_path / "b", progress=False)
    assert len(outcome.rows) == 2 and all(r["status"] == "localized" for r in outcome.rows)
    for r in outcome.rows:
        max_m, max_deg = BOUNDS["thermal" if r["view"] == "nadir" else "oblique"]
        assert float(r["err_xyz_m"]) < max_m and float(r["err_rot_deg"]) < max_deg, r["query_id"]
