"""Silhouette baseline (LoD-Loc v2 style): building-vs-not-building IoU, no classes, no depth.

Why: it isolates what SemCityLoc's semantic classes and depth add. It runs the very same search as
SemCityLoc (coarse 4D cost volume, particle-filter refinement, same presets, thresholds and statuses) on
a one-class problem, by remapping classes instead of copying the localizer:

- scene: a copy of the ``RenderScene`` whose ``classes`` map wall / roof / window / door to one
  building class (``BUILDING``, stored as the wall id) and keep ground as ground;
- query: the same remapping of the label mask; background (sky, trees, cars) stays background, which
  the IoU ignores exactly as in SemCityLoc (an occluder neither confirms nor contradicts the model);
- score: the IoU of the building class alone (``class_on`` = building only), and ``no_depth=True``.

So the score is the building silhouette's IoU over the query's non-background pixels: ground pixels
count as "not building", background pixels are left out.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES, NUM_CLASSES, SemanticClass
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.map_scenes import localizer_scene
from semcityloc.localization.result import LocalizationResult
from semcityloc.render.scene import RenderScene

BUILDING = int(SemanticClass.WALL)  # the one building class, stored under the wall id


def silhouette_lut() -> np.ndarray:
    """uint8 (256,) class map: wall, roof, window, door -> ``BUILDING``; every other value unchanged."""
    lut = np.arange(256, dtype=np.uint8)
    for c in BUILDING_CLASSES:
        lut[int(c)] = BUILDING
    return lut


def silhouette_scene(scene: RenderScene) -> RenderScene:
    """A copy of ``scene`` with building classes merged into ``BUILDING`` (geometry shared, not copied)."""
    return replace(scene, classes=np.ascontiguousarray(silhouette_lut()[scene.classes]))


def silhouette_labels(semantic: np.ndarray) -> np.ndarray:
    """The query mask with building classes merged; non-integer or non-2D input is passed on unchanged
    so that the localizer's own checks raise the usual ``ShapeError``."""
    arr = np.asarray(semantic)
    if arr.ndim != 2 or arr.size == 0 or not np.issubdtype(arr.dtype, np.integer):
        return arr
    inside = (arr >= 0) & (arr < 256)
    return np.where(inside, silhouette_lut()[np.clip(arr, 0, 255)], arr)


class SilhouetteLocalizer(Localizer):
    """SemCityLoc's search on building silhouettes only (module docstring). Same API as ``Localizer``;
    the ``depth`` argument is accepted and ignored."""

    confidence_kind = "silhouette"

    def __init__(
        self, model: CityModel, config: LocalizerConfig | None = None, scene: RenderScene | None = None
    ):
        cfg = replace(config or LocalizerConfig(), no_depth=True)
        base = scene if scene is not None else localizer_scene(model, cfg)
        super().__init__(model, cfg, scene=silhouette_scene(base))
        self.class_on = np.zeros(NUM_CLASSES, dtype=bool)
        self.class_on[BUILDING] = True

    def localize(
        self,
        camera: Camera,
        prior_local: Pose,
        semantic: np.ndarray,
        depth: np.ndarray | None = None,
        config: LocalizerConfig | None = None,
        prior_uncertainty: PriorUncertainty | None = None,
    ) -> LocalizationResult:
        """``Localizer.localize`` on the building/background split of ``semantic``, without depth."""
        cfg = replace(config or self.config, no_depth=True)
        return super().localize(
            camera,
            prior_local,
            silhouette_labels(semantic),
            None,
            config=cfg,
            prior_uncertainty=prior_uncertainty,
        )
