"""The maps a localizer searches: render scenes of its city model with eaves on the roofs.

Why: a localizer does not search the model as it is. LoD2 roofs end at their walls while real ones overhang
them (``citymodel.eaves``), so it adds ``LocalizerConfig.map_eaves_m`` of eaves to the pitched roofs, to the
flat ones too with ``map_eaves_flat_roofs="on"``, and with ``"auto"`` takes a view's pose from a second map
with eaves on the flat roofs where that map fits the view better (its refinement's second look,
``refine_stage.Refiner.look_with_flat_eaves``).
The drawings of the map at a pose (``benchmark.found_map``: the report, a photo run's overlays) build their
scenes here as well, so that they show the map a pose was scored on.
"""

from __future__ import annotations

import numpy as np

from semcityloc.citymodel.eaves import with_eaves
from semcityloc.citymodel.model import CityModel
from semcityloc.localization.config import LocalizerConfig
from semcityloc.render.scene import RenderScene, build_scene, with_model_triangles


def scene_key(config: LocalizerConfig) -> tuple:
    """What of ``config`` decides its ``localizer_scene``: Localizers of configs with equal keys can share
    one scene."""
    return (config.map_eaves_m, config.map_eaves_flat_roofs == "on")


def localizer_scene(
    model: CityModel, config: LocalizerConfig, terrain_ring: np.ndarray | None = None
) -> RenderScene:
    """The render scene a ``Localizer`` with ``config`` searches: the map with ``config.map_eaves_m`` of
    eaves on its pitched roofs (``citymodel.eaves``); build it once to share among Localizers of the
    same eaves. ``terrain_ring``: a tile store's terrain border (``render.scene.build_scene``)."""
    return build_scene(
        with_eaves(model, config.map_eaves_m, config.map_eaves_flat_roofs == "on"), terrain_ring=terrain_ring
    )


def eaves_scene(scene: RenderScene, model: CityModel, eaves_m: float, flat_roofs: bool) -> RenderScene | None:
    """``scene`` (a render scene of ``model``) with its model triangles moved by ``with_eaves(model,
    eaves_m, flat_roofs)``, its terrain and classes kept: the localizer's maps drawn on another scene of the
    same model. None when no roof moves (``render.scene.with_model_triangles``)."""
    moved = with_eaves(model, eaves_m, flat_roofs=flat_roofs)
    return with_model_triangles(scene, moved.vertices[moved.triangles])


def flat_eaves_scene(scene: RenderScene, model: CityModel, eaves_m: float) -> RenderScene | None:
    """``scene`` (a render scene of ``model``: the localizer's, or a drawing's of the model as it is) with
    ``eaves_m`` of eaves on every roof, the flat ones too: the map ``Localizer.map_of`` returns for a pose
    ``map_eaves_flat_roofs="auto"`` took from its second look. One construction, so that a drawing of the
    map at such a pose (the report, the overlays) shows the map it was scored on. None when no roof moves
    (``render.scene.with_model_triangles``)."""
    return eaves_scene(scene, model, eaves_m, flat_roofs=True)


def found_on_flat_eaves(flat_roofs: str, look: dict | None) -> bool:
    """Was a pose found on the map with eaves on its flat roofs? Always with ``map_eaves_flat_roofs``
    ``"on"``, never with ``"off"``, with ``"auto"`` where the second look took it: ``look`` is the
    result's ``search["flat_roof_eaves"]`` (or a saved copy of it; None: no look was made)."""
    return {"on": True, "off": False}.get(flat_roofs, bool((look or {}).get("used")))
