"""How far the search may move the camera from the prior, what of the map lies within that reach, and what a
best hypothesis left at that reach asks of the user.

The cascade's volume (``cascade.search_volume``) grows where its best cell lies on an edge, by
``SweepConfig.extension`` of its half-width at most ``max_extensions`` times: ``reached_half`` is the volume
at its largest. ``search_half`` is either search's reach along an axis (the ``legacy`` grid's is its range;
``search_half_xy`` the horizontal one); the localizer looks for buildings that far around the prior's view
before it searches (``MapLayout.buildings_in_reach``: a query with none in reach is refused,
``REASON_NO_GEOMETRY``), and a tile store loads the tiles that far around a photo's (``tiled.reach_radius``).
The volume stays above the lowest ground under that reach (``MapLayout.ground_below``: a camera under the
terrain sees a ground-only view that can outscore a low flight's true one). A best hypothesis still on an edge
at the largest extent is refused, not taken (``REASON_AT_EDGE``): its warning (``edge_warning``) names the
``--prior-sigma`` whose volume starts at twice the bound reached (``edge_sigma``), and a refused pose with a
better view beyond the reach names one the same way (``Localizer._look_beyond``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semcityloc.citymodel.ground import base_points
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES
from semcityloc.errors import parameter
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.cascade import FULL_CIRCLE_HALF_DEG, SearchVolume, search_volume
from semcityloc.localization.config import CascadeConfig, LocalizerConfig
from semcityloc.localization.result import (
    REASON_PRIOR_LOOKS_UP,
    REASON_PRIOR_TOO_HIGH,
    REASON_PRIOR_UNDERGROUND,
)

# Rays that do not meet the ground plane within this distance are cut here when the view's footprint is
# estimated for the "model geometry in the search volume" check (``MapLayout.buildings_in_reach``).
MAX_VIEW_RANGE_M = 1500.0
# How far beyond the search's reach footprints count for the ground under it (the terrain between
# footprints runs through the nearest ones).
GROUND_MARGIN_M = 20.0


def reached_half(volume: SearchVolume, config: CascadeConfig) -> dict[str, float]:
    """The half-widths per ``--prior-sigma`` key (``xy``, ``z`` m; ``yaw`` deg) of ``volume`` grown by its
    largest extension: how far from the prior the cascade may search (in yaw a turn at most:
    ``cascade.yaw_turn``)."""
    grown = 1.0 + config.sweep.max_extensions * config.sweep.extension
    yaw = min(grown * volume.half_yaw_deg, FULL_CIRCLE_HALF_DEG)  # a circle is not grown
    return {"xy": grown * volume.half_xy_m, "z": grown * volume.half_z_m, "yaw": yaw}


def search_half(prior_local: Pose, cfg: LocalizerConfig, unc: PriorUncertainty, axis: str) -> float:
    """How far (m) the search may move the camera from the prior along ``axis`` (``"xy"``: in x and in y;
    ``"z"``): the grid's range, or the cascade's volume grown by its largest extension."""
    if cfg.search == "grid":
        ranges = {"xy": lambda c: c.range_xy_m, "z": lambda c: c.range_z_m}[axis]
        pre = ranges(cfg.pre_coarse) if cfg.pre_coarse is not None else 0.0
        return (ranges(cfg.coarse) + pre) / 2
    return reached_half(search_volume(prior_local.to_xyz_rpy(), unc, cfg.cascade), cfg.cascade)[axis]


def search_half_xy(prior_local: Pose, cfg: LocalizerConfig, unc: PriorUncertainty) -> float:
    """``search_half`` in x and in y."""
    return search_half(prior_local, cfg, unc, "xy")


def _distance(metres: float) -> str:
    """A distance for a message: metres up to 10 km, then kilometres."""
    return f"{metres:.0f} m" if metres < 10_000.0 else f"{metres / 1000.0:.0f} km"


def _view_rays(camera: Camera, pose_local: Pose, centre: bool) -> np.ndarray:
    """(3, 4 or 5) local-frame directions of the view's corner rays (and its principal ray, ``centre``)."""
    uv = [[0, 0], [camera.width, 0], [camera.width, camera.height], [0, camera.height]]
    if centre:
        uv.append([camera.cx, camera.cy])
    return pose_local.R_world_from_cam @ camera.unproject(np.array(uv, dtype=np.float64)).T


def edge_sigma(edges: list[str], volume: SearchVolume, config: CascadeConfig) -> dict[str, int]:
    """The prior sigma per ``--prior-sigma`` key of the ``edges`` (``["z-"]``) the best hypothesis stayed on
    at the volume's largest extension: the one whose volume starts at twice the bound that was reached
    (``n_sigma`` sigmas = 2 x ``reached_half``)."""
    half = reached_half(volume, config)
    axes = dict.fromkeys("xy" if e.rstrip("+-") in ("x", "y") else e.rstrip("+-") for e in edges)
    return {a: math.ceil(2.0 * half[a] / config.n_sigma) for a in axes}


def edge_warning(edges: list[str], volume: SearchVolume, config: CascadeConfig) -> str:
    """What a user should do when the best hypothesis stayed on the search volume's ``edges``: state the
    ``edge_sigma`` (``prior_uncertainty=PriorUncertainty.parse('z=8')``; the command line's ``--prior-sigma
    z=8``: ``errors.as_flags``), or correct the prior."""
    half = reached_half(volume, config)
    sigma = edge_sigma(edges, volume, config)
    asked = parameter("prior_sigma", ",".join(f"{a}={v}" for a, v in sigma.items()))
    reached = ", ".join(f"{a} +-{half[a]:.0f} {'deg' if a == 'yaw' else 'm'}" for a in sigma)
    return (
        f"the best hypothesis stayed on the search volume's {' '.join(edges)} edge at its largest extent "
        f"({reached} around the prior): the prior is further off than its stated uncertainty; run again "
        f"with {asked} or correct the prior"
    )


@dataclass(frozen=True)
class MapLayout:
    """Where a city model's buildings stand and its ground lies, as the reach's checks need them: the
    centres (x, y) of its building triangles, the median bottom of those triangles (the ground plane a
    view's footprint is cast on) and the footprints' bottom points (through which the terrain runs)."""

    building_xy: np.ndarray  # (N, 2)
    ground_z: float
    base: np.ndarray  # (M, 3)
    top_z: float  # the highest roof (-inf: no building)

    @classmethod
    def of(cls, model: CityModel) -> MapLayout:
        """The model's building centres, ground and top heights and base points (the reach's checks)."""
        building = np.isin(model.classes, BUILDING_CLASSES)
        corners = model.vertices[model.triangles[building]].astype(np.float64)
        ground_z = float(np.median(corners[:, :, 2].min(1))) if len(corners) else 0.0
        top_z = float(corners[:, :, 2].max()) if len(corners) else -math.inf
        return cls(corners.mean(1)[:, :2], ground_z, base_points(model), top_z)

    def prior_problem(
        self, camera: Camera, prior_local: Pose, cfg: LocalizerConfig, unc: PriorUncertainty
    ) -> str | None:
        """Why no camera the search may reach from this prior can see the model, or None: every reached
        height far below the model's lowest ground (a height in another datum, a sign lost), all of them more
        than ``MAX_VIEW_RANGE_M`` above its highest roof, or a view above the horizon from above every roof
        (a pitch in another convention: DJI's gimbal pitch -90 is our 0). Said as such, not as a search that
        ended on its volume's edge with a ``--prior-sigma`` to try."""
        if not len(self.building_xy):
            return None
        reach_z = search_half(prior_local, cfg, unc, "z")
        z = float(prior_local.center[2])
        floor = float(self.base[:, 2].min()) if len(self.base) else self.ground_z
        # Twice the reach: a prior somewhat under the ground is searched from the volume's floor upwards
        # (``cascade``: the floor's layer, grown through its upper edge), which can still find the camera.
        if z + 2.0 * reach_z < floor:
            return REASON_PRIOR_UNDERGROUND
        if z - reach_z > self.top_z + MAX_VIEW_RANGE_M:
            return REASON_PRIOR_TOO_HIGH
        rays = _view_rays(camera, prior_local, centre=False)
        tilt = math.radians(unc.roll_pitch_deg * cfg.cascade.n_sigma) if cfg.search == "cascade" else 0.0
        below = rays[2] / np.linalg.norm(rays, axis=0) < math.sin(tilt)  # or the search's tilt takes it there
        if z - reach_z > self.top_z and not below.any():
            return REASON_PRIOR_LOOKS_UP
        return None

    def distance_warning(self, prior_local: Pose) -> str | None:
        """How far the prior lies from the model's nearest building, when no building is in the search's
        reach: a wrong CRS or ``--offset`` (a typo's digit) puts a prior kilometres away, a prior just
        beside a tile's edge metres; the distance tells the two apart. None for a model without buildings."""
        if not len(self.building_xy):
            return None
        nearest = self.nearest_building_m(prior_local)
        lo, hi = self.building_xy.min(0), self.building_xy.max(0)
        return (
            f"the prior lies {_distance(nearest)} from the model's nearest building (the buildings span "
            f"{hi[0] - lo[0]:.0f} x {hi[1] - lo[1]:.0f} m); kilometres point at a wrong CRS or "
            f"{parameter('offset')}, or a photo of another place"
        )

    def nearest_building_m(self, prior_local: Pose) -> float:
        """The horizontal distance (m) from the prior's camera to the nearest building (inf: none)."""
        if not len(self.building_xy):
            return math.inf
        return float(np.min(np.linalg.norm(self.building_xy - prior_local.center[:2], axis=1)))

    def off_map(self, prior_local: Pose, cfg: LocalizerConfig, unc: PriorUncertainty) -> str | None:
        """``distance_warning`` when no camera the search may reach from this prior can see any building
        (None otherwise): the nearest lies farther than twice the sum of ``MAX_VIEW_RANGE_M`` and the
        search's horizontal reach. ``buildings_in_reach`` is then False whatever the camera (the footprint
        it casts ends ``MAX_VIEW_RANGE_M`` out, its box widened by the reach), as is a tile store's reach
        (``tiled.reach_radius``): the localizer would refuse it, ``REASON_NO_GEOMETRY``. ``semcityloc run``
        checks it per photo before anything is searched or drawn (``benchmark.photo_inputs``): a prior
        hundreds of kilometres off (a COLMAP quaternion in another order, a photo of another place) is
        said as such, not found by a renderer that refuses cameras that far from the model."""
        bound = 2.0 * (MAX_VIEW_RANGE_M + search_half_xy(prior_local, cfg, unc))
        if self.nearest_building_m(prior_local) <= bound:
            return None
        return self.distance_warning(prior_local)

    def buildings_in_reach(
        self, camera: Camera, prior_local: Pose, cfg: LocalizerConfig, unc: PriorUncertainty
    ) -> bool:
        """Does any building lie where the prior's view, widened by the search range, could see it? The
        view is cast from the highest camera the search reaches (a prior metres above the ground sees a
        few metres of it; the camera the search may find higher up sees more)."""
        if not len(self.building_xy):
            return False
        rays = _view_rays(camera, prior_local, centre=True)  # (3, 5)
        centre = prior_local.center.copy()
        full_circle = False
        if cfg.search == "cascade":
            volume = search_volume(prior_local.to_xyz_rpy(), unc, cfg.cascade)
            centre[2] += reached_half(volume, cfg.cascade)["z"]
            full_circle = volume.full_circle
        dz = self.ground_z - centre[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(rays[2] * dz > 0, dz / rays[2], np.inf)
        s = np.minimum(s, MAX_VIEW_RANGE_M / np.linalg.norm(rays, axis=0))
        pts = centre[:2, None] + rays[:2] * s
        if full_circle:  # every heading searched: the footprint turned about the camera, a square around it
            r = float(np.max(np.linalg.norm(pts - centre[:2, None], axis=0)))
            pts = centre[:2, None] + np.array([[-r, r], [-r, r]])
        pts = np.concatenate([pts, centre[:2, None]], axis=1)
        margin = search_half_xy(prior_local, cfg, unc) + 1.0
        lo, hi = pts.min(1) - margin, pts.max(1) + margin
        inside = np.all((self.building_xy >= lo) & (self.building_xy <= hi), axis=1)
        return bool(inside.any())

    def ground_below(self, prior_state: np.ndarray, unc: PriorUncertainty, cfg: LocalizerConfig) -> float:
        """The lowest ground (local frame, m) under the area the search may move the camera over: the
        lowest footprint bottom within the reached half-width (+ ``GROUND_MARGIN_M``) of the prior's x, y,
        else the model's lowest; -inf for a model without buildings (no floor)."""
        if not len(self.base):
            return -math.inf
        half = reached_half(search_volume(prior_state, unc, cfg.cascade), cfg.cascade)["xy"] + GROUND_MARGIN_M
        near = np.all(np.abs(self.base[:, :2] - np.asarray(prior_state[:2])) <= half, axis=1)
        return float(self.base[near, 2].min() if near.any() else self.base[:, 2].min())
