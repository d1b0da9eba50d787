"""The query's block downsampling (``localization/resample.py`` kernels behind ``query.py``): the majority
label and the mean valid depth of each block, equal to the plain numpy form bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.io.images import resize_nearest
from semcityloc.localization.query import Query, downsample_depth, downsample_labels


def old_resize_last_two(a, width, height):
    """The copy ``perception/files.py`` and ``perception/torch_utils.py`` had before stop 51."""
    h, w = a.shape[-2:]
    if (h, w) == (height, width):
        return a
    rows = np.minimum(((np.arange(height) + 0.5) * h / height).astype(int), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w / width).astype(int), w - 1)
    return a[..., rows[:, None], cols[None, :]]


def old_resize_first_two(a, width, height):
    """The copy ``render/overlay.py``, ``localization/query.py`` and ``baselines/methods.py`` had."""
    a = np.asarray(a)
    h, w = a.shape[:2]
    if (h, w) == (height, width):
        return a
    rows = np.minimum(((np.arange(height) + 0.5) * h / height).astype(int), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w / width).astype(int), w - 1)
    return a[rows[:, None], cols[None, :]]


@pytest.mark.parametrize(
    ("src", "dst"),
    [
        ((6, 8), (12, 16)),
        ((6, 8), (3, 4)),
        ((7, 9), (12, 16)),
        ((97, 131), (24, 32)),
        ((5, 3), (11, 7)),
        ((480, 640), (333, 500)),
        ((50, 70), (49, 3)),
        ((4, 4), (4, 4)),
        ((1, 1), (3, 5)),
    ],
)
def test_resize_nearest_is_the_old_pixel_centre_rule(src, dst):
    """Stop 51: one ``io.images.resize_nearest`` for the five copies, the same pixels at every ratio
    (integer or not, up or down); (H, W), (H, W, C) and (C, H, W) arrays; the array itself at its own
    size."""
    rng = np.random.default_rng(sum(src) + sum(dst))
    height, width = dst
    plain = rng.integers(0, 256, size=src).astype(np.uint8)
    image = rng.integers(0, 256, size=(*src, 3)).astype(np.uint8)
    stack = rng.uniform(0.0, 1.0, size=(6, *src)).astype(np.float32)
    np.testing.assert_array_equal(
        resize_nearest(plain, width, height), old_resize_first_two(plain, width, height)
    )
    np.testing.assert_array_equal(
        resize_nearest(plain, width, height), old_resize_last_two(plain, width, height)
    )
    np.testing.assert_array_equal(
        resize_nearest(image, width, height), old_resize_first_two(image, width, height)
    )
    np.testing.assert_array_equal(
        resize_nearest(stack, width, height, channels_first=True), old_resize_last_two(stack, width, height)
    )
    assert resize_nearest(plain, width, height).shape == (height, width)
    if src == dst:
        assert resize_nearest(plain, width, height) is plain
    if height >= src[0] and width >= src[1]:  # the query's upsampling is the same rule
        depth = rng.uniform(1.0, 100.0, size=src)
        np.testing.assert_array_equal(
            downsample_labels(plain, width, height), old_resize_first_two(plain, width, height)
        )
        np.testing.assert_array_equal(
            downsample_depth(depth, width, height), old_resize_first_two(depth, width, height)
        )


def _blocks(h, w, dst_h, dst_w):
    rows = (np.arange(h) * dst_h) // h
    cols = (np.arange(w) * dst_w) // w
    return rows[:, None] * dst_w + cols[None, :]


def numpy_labels(labels, width, height):
    idx = _blocks(*labels.shape, height, width)
    hist = np.bincount((idx * 256 + labels.astype(np.int64)).ravel(), minlength=height * width * 256)
    return hist.reshape(height * width, 256).argmax(1).astype(np.uint8).reshape(height, width)


def numpy_depth(depth, width, height):
    idx = _blocks(*depth.shape, height, width).ravel()
    d = depth.ravel()
    ok = np.isfinite(d) & (d > 0)
    sums = np.bincount(idx[ok], weights=d[ok], minlength=height * width)
    counts = np.bincount(idx[ok], minlength=height * width)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan).reshape(height, width)


@pytest.mark.parametrize(("src", "dst"), [((384, 512), (48, 64)), ((97, 131), (24, 32)), ((50, 70), (49, 3))])
def test_block_downsampling_equals_the_numpy_form_bit_for_bit(src, dst):
    rng = np.random.default_rng(sum(src))
    values = np.array([0, 1, 2, 3, 5, 255], np.uint8)
    labels = rng.choice(values, size=src, p=[0.3, 0.3, 0.2, 0.1, 0.05, 0.05])
    labels[: src[0] // 3, : src[1] // 2] = 2  # a uniform region, and ties at its edge
    depth = rng.uniform(20.0, 200.0, size=src)
    depth[rng.random(src) < 0.2] = np.nan
    depth[rng.random(src) < 0.05] = -1.0
    depth[: src[0] // 4, src[1] // 2 :] = np.nan  # blocks with no valid pixel at all
    (dh, dw) = dst
    assert np.array_equal(downsample_labels(labels, dw, dh), numpy_labels(labels, dw, dh))
    got, want = downsample_depth(depth, dw, dh), numpy_depth(depth, dw, dh)
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.isnan(got).any()
    assert np.array_equal(got[~np.isnan(got)], want[~np.isnan(want)])  # bitwise, not approximately


def test_the_kernels_refuse_to_upsample():
    from semcityloc.localization.resample import majority_labels, mean_depth

    with pytest.raises(ValueError, match="only downsamples"):
        majority_labels(np.zeros((4, 4), np.uint8), 8, 2)
    with pytest.raises(ValueError, match="only downsamples"):
        mean_depth(np.ones((4, 4)), 2, 0)
    assert downsample_labels(np.eye(2, dtype=np.uint8), 4, 4).shape == (4, 4)  # the caller upsamples


def test_majority_ties_go_to_the_smaller_label_and_each_block_votes_alone():
    labels = np.array([[4, 1, 3, 3], [1, 4, 3, 0]], np.uint8)  # block 0: 4 and 1 tie; block 1: 3 wins
    assert downsample_labels(labels, 2, 1).tolist() == [[1, 3]]
    depth = np.array([[1.0, np.nan, 2.0, 0.0], [3.0, -5.0, np.inf, 4.0]])
    assert downsample_depth(depth, 2, 1).tolist() == [[2.0, 3.0]]


def test_a_query_at_the_search_resolution_keeps_the_class_shares():
    rng = np.random.default_rng(3)
    labels = np.zeros((96, 128), np.uint8)
    labels[:, 64:] = 1
    labels[rng.random(labels.shape) < 0.1] = 3  # sparse noise loses every vote
    query = Query.from_arrays(labels, np.full(labels.shape, 50.0), has_openings=False)
    small, depth = query.at(32, 24)
    assert small.shape == (32 * 24,) and set(np.unique(small)) == {0, 1}
    assert (small.reshape(24, 32)[:, 16:] == 1).all() and np.allclose(depth, 50.0)
