"""The flight focal-length estimate kept between runs (``benchmark.focal_cache``): its key follows what
decides the estimate, and what it keeps reads back as the same estimate."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from semcityloc.benchmark import focal_cache
from semcityloc.benchmark.photo_inputs import PhotoInput
from semcityloc.datasets.photos import PhotoPrior
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import LensDistortion
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.focal import SCALES, FocalEstimate


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SEMCITYLOC_CACHE", str(tmp_path / "cache"))


def photo(tmp_path: Path, name: str = "P0.JPG", mask_bytes: bytes = b"mask") -> PhotoInput:
    (tmp_path / "masks").mkdir(exist_ok=True)
    mask = tmp_path / "masks" / f"{Path(name).stem}.png"
    mask.write_bytes(mask_bytes)
    prior = PhotoPrior(Pose.from_xyz_rpy(np.array([10.0, 20.0, 80.0]), 0.0, 40.0, 30.0), None, "test")
    camera = Camera(200.0, 200.0, 128.0, 96.0, 256, 192)
    return PhotoInput(name, tmp_path / name, camera, prior, PriorUncertainty(), mask=mask)


SETTINGS = {"city_sha256": "abc", "lod": None, "crs": None, "localizer": {"preset": "default"}}


def test_the_key_changes_with_what_decides_the_estimate(tmp_path):
    base = focal_cache.estimate_key(SETTINGS, [photo(tmp_path)])
    assert base == focal_cache.estimate_key(SETTINGS, [photo(tmp_path)])  # same inputs, same key
    changed = [
        focal_cache.estimate_key({**SETTINGS, "city_sha256": "abd"}, [photo(tmp_path)]),
        focal_cache.estimate_key({**SETTINGS, "localizer": {"preset": "fast"}}, [photo(tmp_path)]),
        focal_cache.estimate_key(SETTINGS, [photo(tmp_path, mask_bytes=b"mask2")]),  # another mask
        focal_cache.estimate_key(SETTINGS, [photo(tmp_path, name="P1.JPG")]),
        focal_cache.estimate_key(SETTINGS, [photo(tmp_path), photo(tmp_path, name="P1.JPG")]),
    ]
    p = photo(tmp_path)
    raised = p.prior.pose_world.shift_world(np.array([0.0, 0.0, 1.0]))
    changed += [
        focal_cache.estimate_key(SETTINGS, [replace(p, camera=Camera(201.0, 200.0, 128.0, 96.0, 256, 192))]),
        focal_cache.estimate_key(SETTINGS, [replace(p, distortion=LensDistortion(k1=-0.1))]),
        focal_cache.estimate_key(SETTINGS, [replace(p, uncertainty=PriorUncertainty(z_m=20.0))]),
        focal_cache.estimate_key(SETTINGS, [replace(p, prior=replace(p.prior, pose_world=raised))]),
    ]
    assert len({base, *changed}) == len(changed) + 1


def test_a_kept_estimate_reads_back_and_a_broken_file_is_no_estimate(tmp_path):
    estimate = FocalEstimate(1.0234567891, 12, SCALES, tuple(-0.01 * i for i in range(len(SCALES))))
    assert focal_cache.read_estimate("k1") is None
    focal_cache.write_estimate("k1", estimate)
    back = focal_cache.read_estimate("k1")
    assert back.scale == estimate.scale and back.images == 12 and back.scales == SCALES
    assert back.reason is None
    none = FocalEstimate(None, 3, SCALES, (), "3 oblique images; need 5")
    focal_cache.write_estimate("k2", none)
    assert focal_cache.read_estimate("k2") == none
    focal_cache.cache_file("k3").write_text('{"scale": "not a number"}')
    assert focal_cache.read_estimate("k3") is None
    focal_cache.cache_file("k4").write_text("{not json")
    assert focal_cache.read_estimate("k4") is None
