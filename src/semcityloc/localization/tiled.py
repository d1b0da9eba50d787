"""Localize against a tile store: per photo, only the tiles holding buildings its search can see.

Why: a city of hundreds of tiles does not fit a render scene, and a photo sees a few hundred metres. For
each query ``TiledMethod`` computes the **reach** of its search (``reach_radius``): the horizontal distance
at which the camera's most oblique ray meets the ground (tilted further by the search's roll/pitch range,
from the highest camera the search volume allows, capped at ``camera_range_m``), plus how far the search
may move the camera (``search_reach.search_half_xy``), plus ``TERRAIN_MARGIN_M`` so that the terrain the
renderer triangulates through the building bases is the same in view as with the whole city (its border
ring is the whole city's too: ``TileStore.terrain_ring``; baselines get their part's own). The tiles
holding a building within that disc (``TileStore.tiles_within``) are merged into one model in the store's
local frame and the method is built on it; the last ``keep_models`` tile sets keep their method (and
render scene), and a query whose tiles are all in a kept set uses it (the extra tiles lie beyond its
reach), so the photos of a flight over one area build it once. Tiles come through the store's LRU
(``TileStore.cache``, a byte budget).

The queries are in the store's local frame (``TileStore.origin``), as they would be in a single file's.
Buildings farther than ``camera_range_m`` (default ``MAX_VIEW_RANGE_M``, 1.5 km: a 20 m house is about a
pixel at the search's resolutions there) are not loaded, so a camera looking at the horizon over a big
city sees less than it would with the whole city loaded.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from semcityloc.citymodel.tiles import TileStore
from semcityloc.errors import ParameterError, unknown_choice
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.cascade import search_volume
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.map_scenes import localizer_scene
from semcityloc.localization.methods import (
    LOCALIZER_METHODS,
    LocalizerMethod,
    Method,
    MethodFactory,
    QueryRecord,
)
from semcityloc.localization.result import LocalizationResult
from semcityloc.localization.search_reach import MAX_VIEW_RANGE_M, search_half_xy

# Beyond the view: the terrain TIN near the edge of the loaded buildings differs from the whole city's.
TERRAIN_MARGIN_M = 100.0
# Extra tilt (deg) for the refinement, which may leave the searched roll/pitch range a little.
TILT_MARGIN_DEG = 2.0
# A ray within this many degrees of the horizon reaches ``camera_range_m``.
HORIZON_DEG = 89.0


def reach_radius(
    camera: Camera,
    prior_local: Pose,
    config: LocalizerConfig,
    uncertainty: PriorUncertainty,
    ground_z: float,
    camera_range_m: float = MAX_VIEW_RANGE_M,
) -> float:
    """Radius (m) around the prior's x, y within which a building can appear in a view of its search
    (module docstring); ``ground_z``: the lowest ground nearby (local z)."""
    corners = np.array(
        [[0, 0], [camera.width, 0], [camera.width, camera.height], [0, camera.height]], dtype=np.float64
    )
    rays = prior_local.R_world_from_cam @ camera.unproject(corners).T  # (3, 4)
    nadir = np.degrees(np.arccos(np.clip(-rays[2] / np.linalg.norm(rays, axis=0), -1.0, 1.0)))
    volume = search_volume(prior_local.to_xyz_rpy(), uncertainty, config.cascade)
    tilt = float(nadir.max()) + volume.half_roll_pitch_deg + TILT_MARGIN_DEG
    height = max(float(prior_local.center[2]) + volume.half_z_m - ground_z, 1.0)
    if tilt >= HORIZON_DEG:
        seen = camera_range_m
    else:
        seen = min(height * math.tan(math.radians(tilt)), camera_range_m)
    return seen + search_half_xy(prior_local, config, uncertainty) + TERRAIN_MARGIN_M


class TiledMethod:
    """Method ``name`` over a tile store: the tiles in reach of each query (module docstring).

    ``factory`` builds the method on a part of the store (``benchmark.methods.method_factory(name)``, for
    any method of the benchmark's table); without it, ``name`` must be SemCityLoc or one of its ablations
    (``localization.methods.LOCALIZER_METHODS``)."""

    def __init__(
        self,
        name: str,
        store: TileStore,
        config: LocalizerConfig | None = None,
        camera_range_m: float = MAX_VIEW_RANGE_M,
        keep_models: int = 2,
        factory: MethodFactory | None = None,
    ):
        if factory is None:
            if name not in LOCALIZER_METHODS:
                raise unknown_choice("localizer method", name, LOCALIZER_METHODS)
            factory = LOCALIZER_METHODS[name].factory
        if not (math.isfinite(camera_range_m) and camera_range_m > 0):
            raise ParameterError(f"camera_range_m must be a positive number of metres, got {camera_range_m}")
        if int(keep_models) < 1:
            raise ParameterError(f"keep_models must be >= 1, got {keep_models}")
        self.name = name
        self.factory = factory
        self.store = store
        self.config = config if config is not None else LocalizerConfig.preset("default")
        self.camera_range_m = float(camera_range_m)
        self.keep_models = int(keep_models)
        self._methods: OrderedDict[tuple[int, ...], Method] = OrderedDict()
        self.last_tiles: tuple[int, ...] = ()  # the tiles the last query needed
        self.used_tiles: tuple[int, ...] = ()  # the tile set its method was built on (holds them)

    def tiles_for(self, camera: Camera, prior_local: Pose, uncertainty: PriorUncertainty) -> tuple[int, ...]:
        """The tiles a search from ``prior_local`` can see; the nearest building's tile when none is in
        reach (the localizer then says why it cannot localize, as with the whole city)."""
        xy = prior_local.center[:2]
        ground = self.store.ground_z_near(xy, self.camera_range_m)
        if ground is None:
            return self.store.tiles_near(xy)
        radius = reach_radius(camera, prior_local, self.config, uncertainty, ground, self.camera_range_m)
        return self.store.tiles_within(xy, radius) or self.store.tiles_near(xy)

    def method_for(self, tiles: tuple[int, ...]) -> Method:
        """The method built on ``tiles`` merged, or on a kept tile set that holds them all (the last
        ``keep_models`` sets are kept: a flight's next photo usually needs the same tiles or fewer)."""
        for kept in reversed(self._methods):
            if set(tiles) <= set(kept):
                self._methods.move_to_end(kept)
                self.used_tiles = kept
                return self._methods[kept]
        while len(self._methods) >= self.keep_models:
            self._methods.popitem(last=False)
        model = self.store.load(tiles)
        if self.factory is LocalizerMethod:  # the whole city's terrain border (docstring)
            scene = localizer_scene(model, self.config, terrain_ring=self.store.terrain_ring)
            method = LocalizerMethod(self.name, model, self.config, scene=scene)
        else:
            method = self.factory(self.name, model, self.config)
        self._methods[tiles] = method
        self.used_tiles = tiles
        return method

    def localize(self, q: QueryRecord) -> LocalizationResult:
        """The query localized on the tiles its search can see (``tiles_for``), loaded as needed."""
        unc = getattr(q, "prior_uncertainty", None) or self.config.prior_uncertainty
        self.last_tiles = self.tiles_for(q.camera, q.prior_pose_local, unc)
        return self.method_for(self.last_tiles).localize(q)
