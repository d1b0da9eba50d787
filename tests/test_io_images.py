"""Photos of more than 8 bits per pixel (radiometric thermal, multispectral) become usable 8-bit RGB."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from semcityloc.io.images import load_image


@pytest.mark.parametrize("suffix", [".png", ".tif"])
def test_a_16_bit_gradient_keeps_its_levels(tmp_path, suffix):
    ramp = np.linspace(0, 65535, 256).astype(np.uint16)[None, :].repeat(4, axis=0)
    path = tmp_path / f"ramp{suffix}"
    Image.fromarray(ramp).save(path)
    rgb = load_image(path)
    assert rgb.shape == (4, 256, 3) and rgb.dtype == np.uint8
    row = rgb[0, :, 0].astype(int)
    assert np.all(np.diff(row) >= 0), "a brighter input pixel must not come out darker"
    assert len(np.unique(row)) > 200, f"levels collapsed: {np.unique(row)[:10]}"
    assert row[0] == 0 and row[-1] == 255


def test_a_narrow_thermal_range_is_stretched_not_flattened(tmp_path):
    # A radiometric frame: values 29,000-29,400 of 65,535 (a fixed /257 would give two grey levels).
    frame = (29000 + np.arange(400, dtype=np.uint16))[None, :].repeat(3, axis=0)
    path = tmp_path / "thermal.png"
    Image.fromarray(frame).save(path)
    row = load_image(path)[1, :, 1].astype(int)
    assert row.max() - row.min() >= 250 and len(np.unique(row)) > 200


def test_a_float_frame_with_nan_is_read(tmp_path):
    frame = np.linspace(-10, 40, 64, dtype=np.float32)[None, :].repeat(2, axis=0)
    frame[0, 5] = np.nan
    path = tmp_path / "float.tif"
    Image.fromarray(frame).save(path)
    rgb = load_image(path)
    assert rgb[0, 5].tolist() == [0, 0, 0]
    assert rgb[1, -1, 0] == 255 and rgb[1, 0, 0] == 0


def test_an_8_bit_photo_is_unchanged(tmp_path):
    photo = np.random.default_rng(0).integers(0, 256, (6, 9, 3), dtype=np.uint8)
    Image.fromarray(photo).save(tmp_path / "p.png")
    np.testing.assert_array_equal(load_image(tmp_path / "p.png"), photo)
