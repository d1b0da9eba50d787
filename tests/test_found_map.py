"""``benchmark.found_map``: which map the drawings of the map at an estimate use, from what a run recorded."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.benchmark.found_map import FLAT_EAVES_MAP, FoundMaps, row_look
from semcityloc.benchmark.methods import searched_map
from semcityloc.benchmark.warmup import box_city_obj
from semcityloc.citymodel.io import load_city_model
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.map_scenes import found_on_flat_eaves
from semcityloc.localization.result import LOCALIZED, LocalizationResult
from semcityloc.render import Renderer


@pytest.fixture(scope="module")
def boxes(tmp_path_factory):
    """The box city (flat roofs only) and a renderer of it as it is."""
    path = tmp_path_factory.mktemp("boxes") / "city.obj"
    path.write_text(box_city_obj())
    model = load_city_model(path, cache=False)
    return model, Renderer(model, engine="numba")


USED, KEPT = {"gain_at_found": 0.01, "used": True}, {"gain_at_found": 0.01, "used": False}


@pytest.mark.parametrize(
    ("localizer", "look", "flat"),
    [
        ({"map_eaves_m": 0.5, "map_eaves_flat_roofs": "auto"}, USED, True),
        ({"map_eaves_m": 0.5, "map_eaves_flat_roofs": "auto"}, KEPT, False),
        ({"map_eaves_m": 0.5, "map_eaves_flat_roofs": "auto"}, None, False),  # no second look made
        ({"map_eaves_m": 0.5, "map_eaves_flat_roofs": "on"}, None, True),  # every pose found there
        ({"map_eaves_m": 0.5, "map_eaves_flat_roofs": True}, None, True),  # "on" before stop 46
        ({"map_eaves_m": 0.5, "map_eaves_flat_roofs": "off"}, USED, False),
        ({"map_eaves_m": 0.0, "map_eaves_flat_roofs": "on"}, None, False),  # no eaves: the map as it is
        (None, USED, False),  # a run from before the map's eaves
    ],
)
def test_an_estimate_is_drawn_on_the_map_the_run_says_it_was_found_on(boxes, localizer, look, flat):
    model, renderer = boxes
    config = {} if localizer is None else {"localizer": localizer}
    maps = FoundMaps.of_run(model, renderer, config)
    drawn, caption = maps.for_estimate(look)
    assert (drawn is not renderer, caption) == (flat, FLAT_EAVES_MAP if flat else None)
    if flat:
        assert maps.for_estimate(look)[0] is drawn  # built once
        assert drawn.model is model and drawn.scene.num_triangles == renderer.scene.num_triangles
        assert not np.allclose(drawn.scene.tri_xyz, renderer.scene.tri_xyz)  # the flat roofs grew


def _model_corners(scene) -> np.ndarray:
    """A render scene's model triangles (its terrain left out) in the model's order."""
    model_tri = scene.source_triangle >= 0
    order = np.argsort(scene.source_triangle[model_tri])
    return scene.corners[model_tri][order].astype(np.float64)


def test_the_flat_eaves_map_drawn_is_the_one_the_localizer_scores_on(boxes):
    """The drawing's map and ``Localizer.map_of``'s have the same triangles: one construction."""
    model, renderer = boxes
    localizer = Localizer(model, LocalizerConfig(map_eaves_m=0.5))
    result = LocalizationResult(status=LOCALIZED, search={"flat_roof_eaves": USED})
    found = localizer.map_of(result).scene
    drawn, _ = FoundMaps(model, renderer, 0.5, "auto").for_estimate(USED)
    assert found is not localizer.scene
    np.testing.assert_allclose(_model_corners(drawn.scene), _model_corners(found), atol=1e-4)


def test_what_a_row_and_a_config_say_about_the_map():
    assert row_look({"flat_roof_eaves_used": "1"}) == {"used": True}
    assert row_look({"flat_roof_eaves_used": "0"}) == {"used": False}
    assert row_look({"flat_roof_eaves_used": ""}) is None and row_look({}) is None  # no look; an old run
    assert found_on_flat_eaves("auto", USED) and not found_on_flat_eaves("auto", None)
    assert found_on_flat_eaves("on", None) and not found_on_flat_eaves("off", USED)


def test_a_renderer_draws_another_scene_only_of_its_own_kind(boxes):
    _, renderer = boxes
    with pytest.raises(TypeError, match="RenderScene"):
        renderer.with_scene("not a scene")


@pytest.fixture(scope="module")
def pitched():
    """The generated LoD2 city (pitched roofs) and a renderer of it as it is."""
    from semcityloc.citymodel.generator import default_city_path

    model = load_city_model(default_city_path(lod=2))
    return model, Renderer(model, engine="numba")


def test_every_pose_is_drawn_on_the_map_the_localizer_searched(pitched):
    """The truth, the prior and an estimate of the plain look are drawn on the model with the localizer's
    eaves on its pitched roofs: the same triangles as ``localizer_scene``, not the model as it is."""
    from semcityloc.localization.map_scenes import localizer_scene

    model, renderer = pitched
    maps = FoundMaps.of_run(model, renderer, {"method": "semcityloc", "localizer": {"map_eaves_m": 0.5}})
    searched = maps.searched()
    assert searched is not renderer and maps.searched() is searched  # built once
    assert maps.for_estimate(KEPT) == (searched, None)
    expected = localizer_scene(model, LocalizerConfig(map_eaves_m=0.5))
    np.testing.assert_allclose(_model_corners(searched.scene), _model_corners(expected), atol=1e-4)
    assert not np.allclose(_model_corners(searched.scene), _model_corners(renderer.scene), atol=1e-3)


@pytest.mark.parametrize(
    ("config", "eaves"),
    [
        ({"method": "semcityloc", "localizer": {"map_eaves_m": 0.5, "map_eaves_flat_roofs": "auto"}}, 0.5),
        ({"method": "silhouette", "localizer": {"map_eaves_m": 0.5}}, 0.5),  # the localizer's map
        ({"method": "lodloc-wireframe", "localizer": {"map_eaves_m": 0.5}}, 0.0),  # the model's own edges
        ({"method": "semcityloc", "localizer": {"map_eaves_m": 0.0}}, 0.0),
        ({"method": "semcityloc"}, 0.0),  # a run from before the map's eaves
        ({"method": "semcityloc", "localizer": {"map_eaves_m": 0.5}, "searched_map": {"eaves_m": 1.0}}, 1.0),
    ],
)
def test_which_map_a_run_searched(pitched, config, eaves):
    """From ``run.json``: its ``searched_map`` where recorded, else its method's map: the wireframe
    baseline searches the model as it is although its ``localizer`` config names eaves."""
    model, renderer = pitched
    maps = FoundMaps.of_run(model, renderer, config)
    assert maps.eaves_m == eaves
    assert (maps.searched() is renderer) == (eaves == 0.0)
    assert (maps.for_estimate(None)[0] is renderer) == (eaves == 0.0)


def test_a_run_records_the_map_its_method_searches():
    cfg = LocalizerConfig()
    assert searched_map("semcityloc", cfg) == {"eaves_m": 0.5, "flat_roofs": "auto"}
    assert searched_map("no-depth", cfg) == {"eaves_m": 0.5, "flat_roofs": "auto"}
    assert searched_map("lodloc-wireframe", cfg) == {"eaves_m": 0.0, "flat_roofs": "off"}
    assert searched_map("semcityloc", LocalizerConfig.preset("no-eaves")) == {
        "eaves_m": 0.0,
        "flat_roofs": "off",
    }
