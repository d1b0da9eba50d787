"""``citymodel.eaves.with_eaves``: the localizer's map with a stated eave on its pitched roofs."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.citymodel.eaves import FLAT_NZ, area_normal, with_eaves
from semcityloc.citymodel.generator import default_city_path
from semcityloc.citymodel.io import load_city_model
from semcityloc.classes import SemanticClass
from semcityloc.errors import ParameterError
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.map_scenes import localizer_scene


@pytest.fixture(scope="module")
def city():
    return load_city_model(default_city_path(lod=2))


def _flat_share(model) -> np.ndarray:
    """Per building: the share of its roof area within 10 deg of horizontal."""
    roof = model.classes == SemanticClass.ROOF
    area, unit = area_normal(model.vertices[model.triangles[roof]].astype(np.float64))
    b = model.building_index[roof]
    n = len(model.building_ids)
    flat = np.bincount(b, area * (np.abs(unit[:, 2]) > FLAT_NZ), n)
    return flat / np.maximum(np.bincount(b, area, n), 1e-12)


def test_pitched_roofs_grow_by_the_eave_flat_roofs_and_walls_stay(city):
    out = with_eaves(city, 0.5)
    before = city.vertices[city.triangles].astype(np.float64)
    after = out.vertices[out.triangles].astype(np.float64)
    roof = city.classes == SemanticClass.ROOF
    np.testing.assert_allclose(after[~roof], before[~roof], atol=1e-4)  # walls and ground stay
    assert np.array_equal(out.classes, city.classes) and np.array_equal(out.origin, city.origin)
    assert np.array_equal(out.building_index, city.building_index) and out.crs == city.crs
    move = np.linalg.norm((after - before)[:, :, :2], axis=2).max(1)  # per triangle, horizontal
    pitched = _flat_share(city) <= 0.5
    on_pitched = roof & pitched[city.building_index]
    assert pitched.sum() >= 10 and (~pitched).sum() >= 10  # the generated city has both kinds
    assert np.all(move[roof & ~pitched[city.building_index]] < 1e-4)  # flat roofs: parapets, no eave
    grown = np.bincount(city.building_index[on_pitched], move[on_pitched] > 0.4, len(city.building_ids))
    assert (grown[pitched] > 0).mean() >= 0.8  # pitched roofs reach out (not walled in all round)
    assert move.max() <= 2 * 0.5 + 1e-4  # the miter cap
    # A pitched roof's outline now lies beyond its walls: its footprint area grew.
    for b in np.flatnonzero(pitched)[:5]:
        sel = roof & (city.building_index == b)
        span = np.ptp(after[sel][:, :, :2].reshape(-1, 2) @ [1.0, 0.3], axis=0)
        assert span > np.ptp(before[sel][:, :, :2].reshape(-1, 2) @ [1.0, 0.3], axis=0)


def test_flat_roofs_get_the_eave_only_when_asked(city):
    before = city.vertices[city.triangles].astype(np.float64)
    roof = city.classes == SemanticClass.ROOF
    flat_roof = roof & (_flat_share(city) > 0.5)[city.building_index]
    asked = with_eaves(city, 0.5, flat_roofs=True)
    move = np.linalg.norm((asked.vertices[asked.triangles] - before)[:, :, :2], axis=2).max(1)
    grown = np.bincount(city.building_index[flat_roof], move[flat_roof] > 0.4, len(city.building_ids))
    assert (grown[_flat_share(city) > 0.5] > 0).mean() >= 0.8  # flat roofs reach out too
    np.testing.assert_allclose(asked.vertices[asked.triangles][~roof], before[~roof], atol=1e-4)
    assert "flat roofs too" in asked.source
    pitched_only = with_eaves(city, 0.5)
    assert np.array_equal(
        pitched_only.vertices[pitched_only.triangles][flat_roof].astype(np.float64),
        before[flat_roof].astype(np.float32).astype(np.float64),
    )
    # The localizer's map follows its config.
    flat_scene = localizer_scene(city, LocalizerConfig(map_eaves_flat_roofs="on"))
    default_scene = localizer_scene(city, LocalizerConfig())
    assert flat_scene.num_triangles == default_scene.num_triangles
    assert not np.allclose(flat_scene.tri_xyz, default_scene.tri_xyz)


def test_no_eave_is_the_map_itself_and_the_config_checks_it(city):
    assert with_eaves(city, 0.0) is city
    assert LocalizerConfig.preset("legacy").map_eaves_m == 0.0  # the first design searched the map as is
    assert LocalizerConfig.preset("no-eaves").map_eaves_m == 0.0 and LocalizerConfig().map_eaves_m == 0.5
    for bad in (-0.1, 5.0, "0.5", True):
        with pytest.raises(ParameterError, match="map_eaves_m"):
            LocalizerConfig(map_eaves_m=bad)


def test_the_localizer_searches_the_map_with_its_eaves(city):
    cfg = LocalizerConfig(map_eaves_m=0.5)
    loc = Localizer(city, cfg)
    plain = localizer_scene(city, LocalizerConfig(map_eaves_m=0.0))
    assert loc.scene.num_triangles == plain.num_triangles
    assert not np.allclose(loc.scene.tri_xyz, plain.tri_xyz)  # the roofs moved
    assert np.allclose(localizer_scene(city, cfg).tri_xyz, loc.scene.tri_xyz)  # deterministic


def test_distinct_vertex_keys_match_numpys_unique_rows():
    from semcityloc.citymodel.eaves import _unique_rows

    rng = np.random.default_rng(5)
    key = rng.integers(-3, 3, size=(500, 4))  # many repeats, negative values
    first, inverse = _unique_rows(key)
    _, want_first, want_inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    assert np.array_equal(first, want_first) and np.array_equal(inverse, want_inverse.reshape(-1))
    assert len(_unique_rows(key[:0])[0]) == 0


def test_auto_takes_the_flat_roofs_eaves_where_the_view_shows_them_and_only_there(city):
    """``map_eaves_flat_roofs="auto"`` (the default): a view of a world whose flat roofs overhang is
    refined again on the map with eaves on its flat roofs too and takes that pose; a view of a world
    whose flat roofs end at the walls keeps the map without them. "off" and "on" never look twice."""
    from helpers import CAMERA, perturbed, view
    from semcityloc.geometry.errors import center_error_m
    from semcityloc.render import Renderer

    auto = Localizer(city)
    assert LocalizerConfig().map_eaves_flat_roofs == "auto" and auto.flat_eaves_scene is not None
    assert Localizer(city, LocalizerConfig(map_eaves_flat_roofs="off")).flat_eaves_scene is None
    assert Localizer(city, LocalizerConfig(map_eaves_flat_roofs=True)).flat_eaves_scene is None  # "on"
    true = view(city, 10.0, -20.0, 80.0, 1.0, 2.0, 30.0)
    prior = perturbed(true, np.array([3.0, -2.0, 1.0]), 0.3, -0.3, 2.0)
    for eaves_on_flat_roofs in (True, False):
        world = Renderer(with_eaves(city, 0.8, flat_roofs=eaves_on_flat_roofs), engine="numba")
        out = world.render(CAMERA, true, depth=True)
        labels, depth = out.labels[0], 0.5 * out.depth[0] + 3.0
        result = auto.localize(CAMERA, prior, labels, depth)
        look = result.search["flat_roof_eaves"]
        assert look["used"] is eaves_on_flat_roofs, look
        assert center_error_m(result.pose_local, true) < 0.5
        if not look["used"]:  # the look's gain is against the pose's score on the plain map, re-scored here
            pose = [result.pose_local]
            plain = auto.score_poses(CAMERA, labels, depth, pose)["semantic"][0]
            flat = auto._with_scene(auto.flat_eaves_scene).score_poses(CAMERA, labels, depth, pose)
            assert np.isclose(plain, result.semantic, atol=1e-9)
            assert np.isclose(look["gain_at_found"], flat["semantic"][0] - plain, atol=1e-9)
    with pytest.raises(ParameterError, match="map_eaves_flat_roofs"):
        LocalizerConfig(map_eaves_flat_roofs="sometimes")
    for bad in (float("nan"), 2.0, "0.1", True):
        with pytest.raises(ParameterError, match="flat_eaves_gate"):
            LocalizerConfig(flat_eaves_gate=bad)
