"""Rotation reuse: a fan of yaws about one centre, resampled from wide views, against direct renders."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.errors import RenderError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.render import Renderer, render_yaw_fan
from semcityloc.render.rotation_reuse import _cluster_yaws
from semcityloc.render.synthetic import synthetic_city


@pytest.fixture(scope="module")
def renderer():
    return Renderer(synthetic_city(n=8, seed=1), engine="numba")


@pytest.mark.parametrize("pitch", [0.0, 30.0, 55.0])
def test_yaw_fan_agrees_with_direct_renders(renderer, pitch):
    cam = Camera.from_fov(64, 48, 60.0)
    rng = np.random.default_rng(int(pitch))
    lo, hi = renderer.model.bounds_local
    yaws = np.arange(36) * 10.0
    agreements, depth_err = [], []
    for _ in range(4):
        centre = np.array(
            [rng.uniform(lo[0], hi[0]), rng.uniform(lo[1], hi[1]), hi[2] + rng.uniform(40, 150)]
        )
        base = Pose.from_xyz_rpy(centre, rng.normal(0, 2), pitch, rng.uniform(-180, 180))
        fan = render_yaw_fan(renderer, cam, base, yaws, depth=True, allow_direct=False)
        direct = renderer.render(cam, base.rotate_world_z(yaws), depth=True)
        assert fan.labels.shape == direct.labels.shape == (36, 48, 64)
        agreements.append((fan.labels == direct.labels).mean())
        same = (fan.labels == direct.labels) & np.isfinite(direct.depth) & np.isfinite(fan.depth)
        depth_err.append(np.median(np.abs(fan.depth[same] - direct.depth[same]) / direct.depth[same]))
    assert min(agreements) >= 0.97
    assert max(depth_err) < 0.01


def test_yaw_fan_of_several_centres_is_centre_major(renderer):
    cam = Camera.from_fov(64, 48, 60.0)
    xyz = np.array([[0.0, 0.0, 150.0], [40.0, -30.0, 120.0], [-50.0, 20.0, 100.0]])
    bases = Pose.from_xyz_rpy(xyz, np.zeros(3), np.array([0.0, 30.0, 45.0]), np.array([0.0, 50.0, -70.0]))
    yaws = np.arange(12) * 30.0
    fan = render_yaw_fan(renderer, cam, bases, yaws, depth=True, allow_direct=False)
    assert fan.labels.shape == (36, 48, 64)
    for m in range(3):
        one = render_yaw_fan(renderer, cam, bases[m], yaws, depth=True, allow_direct=False)
        direct = renderer.render(cam, bases[m].rotate_world_z(yaws))
        block = fan.labels[m * 12 : (m + 1) * 12]
        assert (block == direct.labels).mean() > 0.97
        # The shared wide camera differs from the single-centre one, so allow resampling differences.
        assert (block == one.labels).mean() > 0.94


def test_yaw_fan_face_ids_and_single_yaw(renderer):
    cam = Camera.from_fov(32, 24, 50.0)
    base = Pose.from_xyz_rpy(np.array([0.0, 0.0, 150.0]), 0.0, 20.0, 0.0)
    fan = render_yaw_fan(renderer, cam, base, [0.0, 90.0], face_ids=True, allow_direct=False)[0]
    direct = renderer.render(cam, base, face_ids=True)
    assert fan.face_ids.shape == (1, 24, 32)
    # Face ids are resampled with the labels: they agree with them, and mostly with a direct render.
    hit = fan.face_ids >= 0
    np.testing.assert_array_equal(renderer.scene.classes[fan.face_ids[hit]], fan.labels[hit])
    assert (fan.labels[~hit] == 0).all()
    assert (fan.face_ids == direct.face_ids).mean() > 0.7
    assert fan.depth is None
    empty = render_yaw_fan(renderer, cam, base, [])
    assert empty.labels.shape == (0, 24, 32)


def test_yaw_fan_renders_directly_when_wide_views_do_not_pay(renderer):
    cam = Camera.from_fov(64, 48, 60.0)
    base = Pose.from_xyz_rpy(np.array([10.0, -20.0, 120.0]), 0.0, 50.0, 30.0)
    yaws = np.array([0.0, 120.0, 240.0])  # three far-apart yaws of an oblique view: no sharing
    fan = render_yaw_fan(renderer, cam, base, yaws, depth=True)
    direct = renderer.render(cam, base.rotate_world_z(yaws), depth=True)
    np.testing.assert_array_equal(fan.labels, direct.labels)
    np.testing.assert_array_equal(fan.depth, direct.depth)
    # Near nadir with many yaws one wide view serves them all, so the fan path is taken.
    nadir = Pose.from_xyz_rpy(np.array([10.0, -20.0, 120.0]), 0.0, 0.0, 30.0)
    many = np.arange(36) * 10.0
    fan = render_yaw_fan(renderer, cam, nadir, many)
    direct = renderer.render(cam, nadir.rotate_world_z(many))
    assert 0.97 <= (fan.labels == direct.labels).mean() < 1.0


@pytest.mark.parametrize("oversample", [1.0, 2.0, 3.0])
def test_wide_pixel_grid_is_aligned_with_the_target_grid(renderer, oversample):
    # One yaw per wide view: the wide view looks exactly like the target, its pixel centres fall on the
    # target's, so nearest-neighbour resampling reproduces the direct render.
    cam = Camera.from_fov(64, 48, 60.0)
    base = Pose.from_xyz_rpy(np.array([10.0, -20.0, 120.0]), 0.0, 40.0, 30.0)
    yaws = np.array([0.0, 90.0, 180.0, 270.0])
    fan = render_yaw_fan(
        renderer, cam, base, yaws, oversample=oversample, max_span_deg=10.0, allow_direct=False
    )
    direct = renderer.render(cam, base.rotate_world_z(yaws))
    assert (fan.labels == direct.labels).mean() > 0.999


def test_yaw_clusters_respect_the_span_and_wrap_around():
    yaws = np.array([350.0, 5.0, 10.0, 170.0, 185.0, -175.0])
    cluster, mids = _cluster_yaws(yaws, 30.0)
    # 350, 5, 10 (wrapping through 0) form one cluster; 170, 185, 185 (= -175) another.
    assert cluster[0] == cluster[1] == cluster[2]
    assert cluster[3] == cluster[4] == cluster[5] != cluster[0]
    assert len(mids) == 2
    for c, mid in enumerate(mids):
        off = (yaws[cluster == c] - mid + 180.0) % 360.0 - 180.0
        assert np.abs(off).max() <= 15.0 + 1e-9


def test_yaw_fan_rejects_bad_arguments(renderer):
    cam = Camera.from_fov(32, 24, 50.0)
    base = Pose.from_xyz_rpy(np.array([0.0, 0.0, 150.0]), 0.0, 20.0, 0.0)
    grid = Pose(np.broadcast_to(np.eye(3), (2, 2, 3, 3)), np.zeros((2, 2, 3)))
    with pytest.raises(ShapeError, match="1-D batch"):
        render_yaw_fan(renderer, cam, grid, [0.0])
    with pytest.raises(TypeError, match="Pose"):
        render_yaw_fan(renderer, cam, np.eye(4), [0.0])
    with pytest.raises(ShapeError, match="finite"):
        render_yaw_fan(renderer, cam, base, [np.nan])
    with pytest.raises(RenderError, match="max_span_deg"):
        render_yaw_fan(renderer, cam, base, [0.0], max_span_deg=400.0)
    with pytest.raises(RenderError, match="oversample"):
        render_yaw_fan(renderer, cam, base, [0.0], oversample=0.5)
