"""The benchmark reality's "reality != map" knobs (issue 12): each does what it says, off by default.

On the generated district (80 buildings). Each knob is tested alone, with the other differences off
(``OFF``: no shift, no height change, no roof structures, trees or cars), so that the map's triangles
can be compared with the reality's one by one.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import cKDTree

from semcityloc.benchmark.building_changes import (
    NEW_CLEARANCE_M,
    NEW_HEIGHT_M,
    NEW_SIZE_M,
    RIDGE_RISE_M,
    ROOF_CHANGES,
    _oriented_box,
)
from semcityloc.benchmark.footprints import footprint_grid
from semcityloc.benchmark.queries import zenmuse_l2_camera
from semcityloc.benchmark.reality import REALISTIC_REALITY, TREES_ID, RealityParams, build_reality
from semcityloc.benchmark.terrain_relief import RELIEF_ZERO_M
from semcityloc.citymodel.generator import default_city_path
from semcityloc.citymodel.io import load_city_model
from semcityloc.classes import BUILDING_CLASSES, SemanticClass
from semcityloc.errors import BenchmarkConfigError
from semcityloc.geometry.pose import Pose
from semcityloc.render.terrain import base_points

OFF = dict(shift_xy_max_m=0.0, height_change_max_m=0.0, roof_structure_m2=0.0, tree_m2=0.0, car_m2=0.0)
MM = 1.5e-3  # the reality is rounded to the millimetre


@pytest.fixture(scope="module")
def city():
    return load_city_model(default_city_path(lod=2))


@pytest.fixture(scope="module")
def bare(city):
    """The reality with every difference off: the map's buildings and its footprint TIN."""
    return build_reality(city, None, seed=0, params=RealityParams(**OFF))


def _corners(model, mask=None):
    c = model.vertices[model.triangles].astype(np.float64)
    return c if mask is None else c[mask]


def _height(z: np.ndarray, building: np.ndarray, n: int) -> np.ndarray:
    """Top minus bottom per building of triangle heights z (T, 3)."""
    top, bottom = np.full(n, -np.inf), np.full(n, np.inf)
    np.maximum.at(top, building, z.max(1))
    np.minimum.at(bottom, building, z.min(1))
    return top - bottom


# ------------------------------------------------------------------------------------------ defaults
def test_defaults_are_the_old_reality_bit_for_bit(city):
    old = RealityParams(
        shift_xy_max_m=0.3,
        height_change_max_m=0.5,
        roof_structure_m2=80.0,
        tree_m2=300.0,
        car_m2=300.0,
        tree_height_m=(4.0, 15.0),
        car_band_m=(1.5, 15.0),
        grid_cell_m=0.5,
        margin_m=20.0,
    )
    a = build_reality(city, None, seed=0)
    b = build_reality(city, None, seed=0, params=old)
    c = build_reality(city, None, seed=0, params=dataclasses.replace(old, overhang_m=(0.0, 0.0)))
    for other in (b, c):
        for name in ("vertices", "triangles", "classes", "building_index", "lods"):
            np.testing.assert_array_equal(getattr(a.model, name), getattr(other.model, name))
        assert a.model.building_ids == other.model.building_ids
    # The model the code wrote before the knobs existed (sha256 of its arrays, seed 0).
    h = hashlib.sha256()
    for arr in (a.model.vertices, a.model.triangles, a.model.classes, a.model.building_index, a.model.lods):
        h.update(np.ascontiguousarray(arr).tobytes())
    h.update(a.terrain_height(np.array([[0.0, 0.0], [10.3, -20.7], [100.0, 50.0]])).tobytes())
    assert h.hexdigest()[:16] == "fda580a7d11afe6c"
    counts = a.counts
    assert counts["missing_buildings"] == counts["new_buildings"] == counts["roof_changes"] == 0
    assert counts["overhang_buildings"] == counts["extra_dormers"] == 0
    assert not a.building_missing.any() and not a.building_roof_change.any()
    assert not a.building_overhang_m.any()


def test_params_are_checked_and_pairs_normalised():
    p = RealityParams(overhang_m=[0.3, 1], tree_height_m=[4, 20])
    assert p.overhang_m == (0.3, 1.0) and p.tree_height_m == (4.0, 20.0)
    for bad in (
        {"missing_fraction": 1.5},
        {"roof_change_fraction": -0.1},
        {"overhang_m": (1.0, 0.3)},
        {"overhang_m": 0.5},
        {"tree_height_m": (0.0, 5.0)},
        {"terrain_relief_m": -1.0},
        {"terrain_wavelength_m": 0.0},
        {"terrain_fade_m": 50.0},  # more than margin_m: the fade could not be measured
        {"shift_xy_max_m": float("nan")},
    ):
        with pytest.raises(BenchmarkConfigError):
            RealityParams(**bad)


def test_realistic_reality_has_the_issue_values_and_is_deterministic(city):
    r = REALISTIC_REALITY
    assert (r.shift_xy_max_m, r.height_change_max_m, r.overhang_m) == (1.0, 2.0, (0.3, 1.0))
    assert (r.roof_change_fraction, r.missing_fraction, r.new_fraction) == (0.15, 0.03, 0.03)
    assert (r.terrain_relief_m, r.terrain_wavelength_m) == (3.0, 250.0)
    assert r.tree_height_m == (4.0, 20.0) and r.tree_facade_clearance == 0.2
    a = build_reality(city, None, seed=2, params=REALISTIC_REALITY)
    b = build_reality(city, None, seed=2, params=REALISTIC_REALITY)
    np.testing.assert_array_equal(a.model.vertices, b.model.vertices)
    assert a.counts == b.counts
    n = len(city.building_ids)
    assert a.counts["missing_buildings"] == a.counts["new_buildings"] == round(0.03 * n)
    assert a.counts["roof_changes"] == round(0.15 * (n - a.counts["missing_buildings"]))


# ------------------------------------------------------------------------------------------ model errors
def test_height_error_and_shift_stay_within_their_bounds(city):
    r = build_reality(city, None, seed=0, params=RealityParams(**{**OFF, "height_change_max_m": 2.0}))
    n_b, t = len(city.building_ids), city.num_triangles
    b = city.building_index.astype(np.int64)
    z0, z1 = _corners(city)[:, :, 2], _corners(r.model)[:t, :, 2]
    change = _height(z1, b, n_b) - _height(z0, b, n_b)
    assert np.abs(change).max() <= 2.0 + MM
    assert np.abs(change).max() > 1.5  # the range is used
    np.testing.assert_allclose(change, r.building_height_change, atol=MM)
    r = build_reality(city, None, seed=0, params=RealityParams(**{**OFF, "shift_xy_max_m": 1.0}))
    shift = np.linalg.norm(_corners(r.model)[:t, 0, :2] - _corners(city)[:, 0, :2], axis=1)
    assert shift.max() <= 1.0 + MM and shift.max() > 0.8
    np.testing.assert_allclose(shift, np.linalg.norm(r.building_shift_xy, axis=1)[b], atol=MM)


def test_normal_model_error_spread_is_half_normal_within_the_bound(city):
    params = RealityParams(**{**OFF, "shift_xy_max_m": 1.0, "height_change_max_m": 2.0})
    uni = build_reality(city, None, seed=0, params=params)
    nor = build_reality(city, None, seed=0, params=dataclasses.replace(params, model_error_spread="normal"))
    for r in (uni, nor):
        assert np.abs(r.building_height_change).max() <= 2.0 + MM
        assert np.linalg.norm(r.building_shift_xy, axis=1).max() <= 1.0 + MM
    dh = np.abs(nor.building_height_change[nor.building_height_change != 0])
    shift = np.linalg.norm(nor.building_shift_xy, axis=1)
    # |N(0, max / 3)|: mean 0.266 x max (uniform: 0.5 x max); about a third of the buildings beyond max / 3.
    assert 0.18 < dh.mean() / 2.0 < 0.36 and 0.18 < shift.mean() < 0.36
    assert 0.15 < np.mean(dh > 2.0 / 3) < 0.5
    assert np.abs(uni.building_height_change).mean() > 0.8  # uniform: mean 1 m
    with pytest.raises(BenchmarkConfigError, match="model_error_spread"):
        RealityParams(model_error_spread="gaussian")


def test_flat_roofs_can_be_left_without_overhang(city):
    r = build_reality(city, None, seed=0, params=RealityParams(**OFF, overhang_m=(0.3, 1.0)))
    p = build_reality(
        city, None, seed=0, params=RealityParams(**OFF, overhang_m=(0.3, 1.0), overhang_flat_roofs=False)
    )
    roof = city.classes == SemanticClass.ROOF
    c = _corners(city, roof)
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    flat_area = area * (np.abs(n[:, 2]) / np.maximum(2 * area, 1e-12) > np.cos(np.radians(10)))
    b = city.building_index[roof]
    share = np.bincount(b, flat_area, len(city.building_ids)) / np.maximum(
        np.bincount(b, area, len(city.building_ids)), 1e-12
    )
    flat = share > 0.5
    assert flat.any() and (~flat).any()
    assert not p.building_overhang_m[flat].any()
    sloped = ~flat & (r.building_overhang_m > 0)
    np.testing.assert_array_equal(p.building_overhang_m[sloped], r.building_overhang_m[sloped])


# ------------------------------------------------------------------------------------------ overhangs
def test_overhangs_push_roofs_out_along_their_planes_and_leave_walls(city):
    r = build_reality(city, None, seed=0, params=RealityParams(**OFF, overhang_m=(0.3, 1.0)))
    t = city.num_triangles
    before, after = _corners(city), _corners(r.model)[:t]
    roof = city.classes == SemanticClass.ROOF
    np.testing.assert_allclose(after[~roof], before[~roof], atol=MM)  # walls and footprints stay
    o = r.building_overhang_m
    assert np.all((o == 0) | ((o >= 0.3) & (o <= 1.0)))
    assert (o > 0).sum() >= 0.9 * len(city.building_ids)
    move = np.linalg.norm((after - before)[roof][:, :, :2], axis=2)
    assert np.all(move <= 2 * o[city.building_index[roof]][:, None] + MM)  # miter cap
    # Every roof corner stays on its triangle's plane: the roof is extended, not tilted.
    c = before[roof]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    off_plane = np.abs(np.einsum("tkd,td->tk", after[roof] - c[:, :1], n))
    assert off_plane.max() <= 5e-3
    # Free-standing rectangles: the roof outline lies exactly o beyond each wall.
    ground = city.classes == SemanticClass.GROUND
    all_xy = before[np.isin(city.classes, BUILDING_CLASSES)][:, :, :2].reshape(-1, 2)
    owner = np.repeat(city.building_index[np.isin(city.classes, BUILDING_CLASSES)], 3)
    tree = cKDTree(all_xy)
    checked = 0
    for b in range(len(city.building_ids)):
        foot = np.unique(
            np.round(before[ground & (city.building_index == b)][:, :, :2].reshape(-1, 2), 3), axis=0
        )
        if len(foot) != 4 or o[b] == 0:
            continue
        centre, length, width, axis = _oriented_box(foot)
        if abs(length * width - _area(before[ground & (city.building_index == b)])) > 0.01:
            continue  # not a rectangle
        near = tree.query_ball_point(foot, 2.0)
        if any(np.any(owner[q] != b) for q in near):
            continue  # touches another building
        pts = after[roof & (city.building_index == b)][:, :, :2].reshape(-1, 2) - centre
        u = pts @ axis
        v = pts @ np.array([-axis[1], axis[0]])
        np.testing.assert_allclose(
            [u.max() - u.min(), v.max() - v.min()], [length + 2 * o[b], width + 2 * o[b]], atol=5e-3
        )
        checked += 1
    assert checked >= 5


def _area(c: np.ndarray) -> float:
    e1, e2 = c[:, 1, :2] - c[:, 0, :2], c[:, 2, :2] - c[:, 0, :2]
    return float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]).sum())


# ------------------------------------------------------------------------------------------ roof changes
def test_roof_changes_flat_to_pitched_sloped_to_flat_and_dormers(city):
    r = build_reality(city, None, seed=0, params=RealityParams(**OFF, roof_change_fraction=0.3))
    n_b = len(city.building_ids)
    change = r.building_roof_change
    assert r.counts["roof_changes"] == (change > 0).sum() == round(0.3 * n_b)
    kinds = {ROOF_CHANGES[k] for k in change[change > 0]}
    assert kinds == {"gable", "hip", "flattened", "dormers"}
    m = r.model
    structure = (m.lods == 0) & (m.building_index < n_b)  # the boxes on the roofs
    for b in range(n_b):
        old = _corners(city, city.building_index == b)
        mine = (m.building_index == b) & ~structure
        new = _corners(m, mine)
        old_roof = _corners(city, (city.building_index == b) & (city.classes == SemanticClass.ROOF))
        new_roof = _corners(m, mine & (m.classes == SemanticClass.ROOF))
        kind = ROOF_CHANGES[change[b]]
        if kind in ("none", "dormers"):
            np.testing.assert_allclose(
                np.sort(new.reshape(len(new), -1), 0), np.sort(old.reshape(len(old), -1), 0)
            )
        elif kind in ("gable", "hip"):
            eaves = old_roof[:, :, 2].max()
            assert np.ptp(old_roof[:, :, 2]) < 0.5  # it was flat
            rise = new_roof[:, :, 2].max() - eaves
            assert RIDGE_RISE_M[0] - MM <= rise <= RIDGE_RISE_M[1] + MM
            assert new_roof[:, :, 2].min() == pytest.approx(eaves, abs=MM)
            gable_ends = (
                mine
                & (m.classes == SemanticClass.WALL)
                & (m.vertices[m.triangles][:, :, 2].min(1) >= eaves - MM)
            )
            assert gable_ends.sum() == (2 if kind == "gable" else 0)
        else:  # flattened to the eaves
            eaves = old_roof[:, :, 2].min()
            assert np.ptp(old_roof[:, :, 2]) > 1.0  # it was sloped
            assert new[:, :, 2].max() == pytest.approx(eaves, abs=MM)
            assert np.ptp(new_roof[:, :, 2]) <= MM
    dormers = structure & np.isin(m.building_index, np.flatnonzero(change == ROOF_CHANGES.index("dormers")))
    assert dormers.sum() == 10 * r.counts["extra_dormers"] > 0
    assert not (structure & ~dormers).any()  # roof structures are off: every box is a dormer


# ------------------------------------------------------------------------------------------ missing / new
def test_missing_buildings_are_gone_and_ground_covers_their_footprint(city, bare):
    r = build_reality(city, None, seed=0, params=RealityParams(**OFF, missing_fraction=0.05))
    n_b = len(city.building_ids)
    gone = np.flatnonzero(r.building_missing)
    assert len(gone) == r.counts["missing_buildings"] == round(0.05 * n_b)
    assert not np.isin(r.model.building_index, gone).any()
    cam = zenmuse_l2_camera(64, 48)
    for b in gone:
        foot = _corners(city, (city.building_index == b) & (city.classes == SemanticClass.GROUND))
        area = np.cross(foot[:, 1] - foot[:, 0], foot[:, 2] - foot[:, 0])[:, 2]
        p = foot[np.argmax(np.abs(area))].mean(0)  # the centre of the footprint's largest triangle
        pose = Pose.from_xyz_rpy(p + [0.0, 0.0, 100.0], 0.0, 0.0, 0.0)
        assert r.renderer.render(cam, pose).labels[0, 24, 32] == SemanticClass.GROUND
        assert bare.renderer.render(cam, pose).labels[0, 24, 32] == SemanticClass.ROOF


def test_new_buildings_stand_on_open_ground_clear_of_the_others(city):
    params = RealityParams(
        **{**OFF, "tree_m2": 300.0, "car_m2": 300.0}, new_fraction=0.05, terrain_relief_m=3.0
    )
    r = build_reality(city, None, seed=1, params=params)
    n_b = len(city.building_ids)
    n_new = r.counts["new_buildings"]
    assert n_new == round(0.05 * n_b)
    m = r.model
    assert m.building_ids[n_b : n_b + n_new] == [f"__new_building_{k}__" for k in range(n_new)]
    old = _corners(city, np.isin(city.classes, BUILDING_CLASSES))
    lo, hi = old[:, :, :2].reshape(-1, 2).min(0) - 60, old[:, :, :2].reshape(-1, 2).max(0) + 60
    others = footprint_grid(old, np.zeros(len(old), np.int64), lo, hi, 0.25)
    dist = ndimage.distance_transform_edt(others.ids < 0) * 0.25
    for k in range(n_new):
        mine = m.building_index == n_b + k
        assert set(np.unique(m.classes[mine])) == {SemanticClass.WALL, SemanticClass.ROOF}
        c = _corners(m, mine)
        box = _oriented_box(c[:, :, :2].reshape(-1, 2))
        assert NEW_SIZE_M[0] - MM <= box[2] <= box[1] <= NEW_SIZE_M[1] + MM
        rows, cols, inside = others.cells(c[:, :, :2].reshape(-1, 2))
        assert inside.all() and dist[rows, cols].min() >= NEW_CLEARANCE_M - 0.5
        corners_xy = np.unique(np.round(c[:, :, :2].reshape(-1, 2), 3), axis=0)
        ground = r.terrain_height(corners_xy)
        assert c[:, :, 2].min() <= ground.min() - 0.2  # sunk into the terrain: no floating
        assert NEW_HEIGHT_M[0] - MM <= c[:, :, 2].max() - ground.max() <= NEW_HEIGHT_M[1] + MM
    # trees and cars keep off the new buildings
    added = _corners(m, (m.building_index >= n_b) & (m.building_index < n_b + n_new))
    new = footprint_grid(added, np.zeros(len(added), np.int64), lo, hi, 0.25)
    occ = _corners(m, m.classes == SemanticClass.BACKGROUND)
    low = occ[occ[:, :, 2].max(1) < r.terrain_height(occ[:, 0, :2]) + 1.0]  # trunks and car bodies
    rows, cols, inside = new.cells(low.mean(1)[:, :2])
    assert not (inside & (new.ids[rows, cols] >= 0)).any()


# ------------------------------------------------------------------------------------------ terrain
def test_terrain_relief_is_bounded_smooth_and_zero_at_the_footprints(city, bare):
    params = RealityParams(**{**OFF, "tree_m2": 300.0}, terrain_relief_m=3.0, terrain_wavelength_m=250.0)
    r = build_reality(city, None, seed=0, params=params)
    xs = np.arange(-350.0, 350.0, 3.0)
    p = np.stack(np.meshgrid(xs, xs), -1).reshape(-1, 2)
    relief = r.terrain_height(p) - bare.terrain_height(p)
    assert np.abs(relief).max() <= 3.0 + 1e-9
    assert np.abs(relief).max() >= 1.5  # the amplitude is used
    # Smooth: 3 m steps no steeper than the waves allow, plus the fade's ramp near the buildings.
    step = np.abs(relief - (r.terrain_height(p + [3.0, 0.0]) - bare.terrain_height(p + [3.0, 0.0])))
    waves = 3.0 * 2 * np.pi / (0.7 * 250.0)  # steepest slope of one wave of the stated amplitude
    ramp = 3.0 * 1.5 / (15.0 - RELIEF_ZERO_M)  # steepest slope of the smoothstep fade
    assert step.max() <= 3.0 * (waves + ramp)
    bc = _corners(city, np.isin(city.classes, BUILDING_CLASSES))
    grid = footprint_grid(bc, np.zeros(len(bc), np.int64), p.min(0) - 5, p.max(0) + 5, 0.5)
    dist = ndimage.distance_transform_edt(grid.ids < 0) * 0.5
    rows, cols, _ = grid.cells(p)
    far = (dist[rows, cols] > 15.0 + 12.0) & (np.abs(p).max(1) < 250)  # beyond the fade and the border
    assert far.sum() > 100 and step[far].max() <= 3.0 * waves
    foot = base_points(city)[:, :2]
    np.testing.assert_allclose(r.terrain_height(foot), bare.terrain_height(foot), atol=1e-9)
    # Trees stand on it: each trunk's bottom is 0.2 m under the relief terrain.
    n_trees = r.counts["trees"]
    trunks = _corners(r.model, r.model.building_index == r.model.building_ids.index(TREES_ID))[: 10 * n_trees]
    trunks = trunks.reshape(n_trees, 30, 3)
    centre = trunks[:, :, :2].mean(1)
    np.testing.assert_allclose(trunks[:, :, 2].min(1), r.terrain_height(centre) - 0.2, atol=MM)
    assert np.abs(r.terrain_height(centre) - bare.terrain_height(centre)).max() > 0.5


# ------------------------------------------------------------------------------------------ trees
def test_taller_trees_and_crowns_over_facades(city):
    def build(clearance):
        params = RealityParams(
            **{**OFF, "tree_m2": 200.0}, tree_height_m=(4.0, 20.0), tree_facade_clearance=clearance
        )
        return build_reality(city, None, seed=0, params=params)

    near, far = build(0.2), build(0.7)
    trees = near.model.building_index == near.model.building_ids.index(TREES_ID)
    c = _corners(near.model, trees).reshape(-1, 3)
    above = c[:, 2] - near.terrain_height(c[:, :2])
    assert above.max() <= 20.0 + MM and above.max() > 15.0
    bc = _corners(city, np.isin(city.classes, BUILDING_CLASSES))
    lo, hi = bc[:, :, :2].reshape(-1, 2).min(0) - 30, bc[:, :, :2].reshape(-1, 2).max(0) + 30
    grid = footprint_grid(bc, np.zeros(len(bc), np.int64), lo, hi, 0.5)

    def over_buildings(r):
        cc = _corners(r.model, r.model.building_index == r.model.building_ids.index(TREES_ID)).reshape(-1, 3)
        rows, cols, inside = grid.cells(cc[:, :2])
        return float((inside & (grid.ids[rows, cols] >= 0)).mean())

    assert over_buildings(near) > 2 * over_buildings(far) and over_buildings(near) > 0.02
