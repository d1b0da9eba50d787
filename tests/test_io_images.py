"""Photos of more than 8 bits per pixel (radiometric thermal, multispectral) become usable 8-bit RGB."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from semcityloc.io.images import is_label_map, load_image, save_labels_png, save_rgb


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


def test_a_label_map_is_told_from_a_photo(tmp_path):
    """``is_label_map`` (stop 56): a palette PNG of semcityloc's classes or a grey PNG of class ids is a
    label map; a photo, a grey PNG of other values, a JPEG and bytes of no image are not."""
    save_labels_png(np.full((8, 8), 2, np.uint8), tmp_path / "map.png")
    Image.fromarray(np.array([[0, 5], [255, 3]], np.uint8), mode="L").save(tmp_path / "grey.png")
    Image.fromarray(np.array([[0, 5], [200, 3]], np.uint8), mode="L").save(tmp_path / "dark.png")
    save_rgb(np.full((8, 8, 3), 90, np.uint8), tmp_path / "photo.png")
    save_rgb(np.full((8, 8, 3), 90, np.uint8), tmp_path / "photo.jpg")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG no image")
    found = {p.name: is_label_map(p) for p in sorted(tmp_path.iterdir())}
    assert found == {
        "dark.png": False,
        "grey.png": True,
        "junk.png": False,
        "map.png": True,
        "photo.jpg": False,
        "photo.png": False,
    }
