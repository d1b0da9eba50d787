"""Simulated benchmark queries: a UAV over a real city model, its perceived labels / depth and a prior.

Why: the paper evaluates on real DJI Zenmuse L2 images flown at ~75 m over a dense city, nadir and
oblique. We simulate that protocol on real LoD2 city models so that every change can be measured.
``QuerySimulator(map_model, config, reality_model).query(i)`` gives query ``i``; it depends on
``(config.seed, i)`` only (not on other queries, call order or thread count).

Camera: the DJI Zenmuse L2 RGB camera, f = 12.29 mm on a 4/3" sensor 17.3 x 13.0 mm at 5280 x 3956 px,
so fx = 12.29 / 17.3 x 5280 = 3751 px at full resolution. Scaled to the working width W (square
pixels, principal point at the image centre): fx = fy = 12.29 / 17.3 x W, i.e. 363.7 px at 512 x 384,
horizontal field of view 2 atan(256 / 363.7) = 70.3 deg, vertical 55.6 deg; at 75 m above flat ground a
nadir view covers about 106 x 79 m at 0.21 m per pixel.

True pose of query i (attempt k = 0, 1, ... until the view is accepted, at most ``MAX_ATTEMPTS``; each
attempt from its own generator ``default_rng([seed, i, 0, k])``):

- view: oblique or nadir from a golden-ratio sequence over the index (``view_kind``), so any run of n
  consecutive queries has n x ``oblique_fraction`` oblique views to within about 2;
- height above the ground under the camera: normal around ``nominal_height_m`` with sigma 20 % of it,
  redrawn until inside ``height_range_m``; ground height from the reality's terrain TIN;
- heading (yaw) uniform in [-180, 180); roll uniform in +-``max_roll_deg``; pitch uniform in
  ``oblique_pitch_deg`` (oblique) or +-3 deg (nadir), from nadir (``Pose.from_xyz_rpy`` convention);
- the point the optical axis meets on the ground is uniform over the x, y bounding box of the map's
  buildings; the camera stands back from it along the heading by height x tan(pitch);
- accepted when nothing of the reality is above the camera, nothing is closer than ``MIN_CLEARANCE_M``,
  and wall + roof (+ window, door) cover at least ``min_building_fraction`` of the clean labels. If no
  attempt passes, the best-covered one is returned with ``meta["accepted"] = False`` (the runner may
  skip it).

Reality: ``reality.build_reality`` (the reality model, LoD3 where the caller has it, with per-building
geometric errors, roof structures, trees and cars), built once per simulator from ``config.seed``. The
clean labels / depth are its render at the true pose; ``perception_sim`` degrades them into the query's
``labels`` (``default_rng([seed, i, 3])``) and ``depth`` (``default_rng([seed, i, 4])``).

Prior (``sample_prior``): a base translation error of norm uniform in ``prior_translation_m`` whose
direction is uniform in the horizontal plane with a smaller vertical part (direction proportional to
(cos t, sin t, u), u uniform in +-``PRIOR_Z_RATIO`` = 0.4, so |dz| <= 0.37 x the norm: GNSS-like priors are
mostly horizontal and the search's z range is narrower than its x, y range), from
``default_rng([seed, i, 1])``; plus, when ``prior_extra_m`` = (lo, hi) is set, an independent
perturbation on each of x, y, z of magnitude uniform in [lo, hi] with a random sign (the paper's bins
10-20 ... 150-200 m), from ``default_rng([seed, i, 2])`` so that every bin shares the same base errors.
Yaw error: magnitude uniform in [0, ``prior_yaw_deg``], random sign; roll and pitch errors uniform in
+-``prior_roll_pitch_deg``. Separate streams per stage mean a query's pose and prior do not change when
only the segmentation quality or the prior bin changes.

All poses are cam_from_world in the map model's LOCAL frame (world = ``map_model.origin`` + local).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from semcityloc.benchmark.depth_sim import DepthParams, simulate_depth_realistic
from semcityloc.benchmark.perception_sim import SEG_PRESETS, miou, simulate_depth, simulate_segmentation
from semcityloc.benchmark.reality import RealityParams, RealityScene, build_reality
from semcityloc.benchmark.seg_errors import (
    REALISTIC_SEG_PRESETS,
    fold_to_map_classes,
    sun_direction,
    view_truth,
)
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES, IGNORE, NUM_CLASSES
from semcityloc.errors import (
    ArgumentTypeError,
    BenchmarkConfigError,
    CameraError,
    EmptyModelError,
    QuerySimulationError,
    true_or_false,
    unknown_choice,
)
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import LensDistortion, distort_image, pinhole_canvas, undistort_image
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.perception.autolabel import auto_label
from semcityloc.perception.metrics import confusion
from semcityloc.render import Renderer

SENSOR_WIDTH_MM = 17.3  # DJI Zenmuse L2 RGB, 4/3" CMOS, 17.3 x 13.0 mm, 5280 x 3956 px
MAX_ATTEMPTS = 64
NADIR_PITCH_DEG = 3.0
HEIGHT_SIGMA_FRACTION = 0.2
PRIOR_Z_RATIO = 0.4
MIN_CLEARANCE_M = 10.0
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
STREAM_POSE, STREAM_PRIOR, STREAM_PRIOR_EXTRA, STREAM_SEG, STREAM_DEPTH = 0, 1, 2, 3, 4
STREAM_PRIOR_REALISTIC, STREAM_SUN = 6, 7  # 5 is the wireframe baseline's edge map
STREAM_LENS_MARGIN = 8  # the canvas a barrel lens needs beyond the query (``_lens_canvas``)
SEG_MODELS = ("blobs", "structured")
# The simulated query image's width and height (``QueryConfig``): 8192 holds the Zenmuse L2's full 5280 x
# 3956; a larger one is a typo that would render for hours (the renderer refuses only beyond 1e9 pixels).
QUERY_MIN_SIDE_PX, QUERY_MAX_SIDE_PX = 16, 8192


def _pair(value, name: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise BenchmarkConfigError(f"{name} must be a pair of numbers (lo, hi), got {value!r}") from exc
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise BenchmarkConfigError(f"{name} must be finite with lo <= hi, got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class QueryConfig:
    """How the benchmark's queries are simulated (module docstring)."""

    queries: int = 100
    seed: int = 0
    width: int = 512  # working resolution of the simulated query image
    height: int = 384
    height_range_m: tuple[float, float] = (40.0, 150.0)  # camera height above local ground
    nominal_height_m: float = 75.0  # heights drawn around this (clipped normal), within range
    oblique_fraction: float = 0.5  # share of oblique views; others nadir (pitch 0 +- 3 deg)
    oblique_pitch_deg: tuple[float, float] = (30.0, 60.0)  # from nadir
    max_roll_deg: float = 3.0
    min_building_fraction: float = 0.15  # keep views where wall+roof cover at least this share
    seg_quality: str = "trained"  # preset name of perception_sim
    prior_translation_m: tuple[float, float] = (5.0, 15.0)  # norm of the base prior translation error
    prior_yaw_deg: float = 8.0  # |yaw error| uniform in [0, this]
    prior_roll_pitch_deg: float = 1.0
    prior_extra_m: tuple[float, float] | None = None  # extra per-axis (x, y, z) perturbation magnitude bin
    depth: bool = True
    focal_mm: float = 12.29  # DJI Zenmuse L2 (4/3", 17.3 x 13.0 mm sensor, 5280 x 3956): fx = f/17.3*W
    # The localizer is told a focal length (1 + this) x the true one (the query is rendered with the true
    # one): EXIF intrinsics instead of a calibration (-0.024 on the real thermal image, docs/your-data.md).
    focal_error: float = 0.0
    # The camera's lens: radial distortion k1 (OpenCV model, ``geometry.distortion``; < 0 barrel). The
    # query is seen through it; ``lens_stated``: the localizer is told the lens and gets the query
    # undistorted, as a photo run does with a calibration that has it; else it takes the distorted query
    # for a pinhole image (a calibration without the lens, or EXIF focal length only).
    lens_k1: float = 0.0
    lens_stated: bool = True
    # --- knobs of the realistic scenario (``benchmark.scenario``); these defaults are the clean one ---
    scenario: str = "clean"  # the name of the bundle these values came from (recorded, not used)
    prior_height_m: float | None = None  # None: z error a part of the 3D base error; else uniform +-this
    prior_roll_pitch_sigma_deg: float | None = None  # None: uniform +-prior_roll_pitch_deg; else N(0, s)
    reality: RealityParams = field(default_factory=RealityParams)  # reality != map (reality.py)
    seg_model: str = "blobs"  # "blobs": SEG_PRESETS; "structured": REALISTIC_SEG_PRESETS + view truth
    depth_model: DepthParams | None = None  # None: near-affine depth (simulate_depth); else realistic
    score_against_map: bool = False  # also measure the labels against the map's own labels (paper's way)

    def __post_init__(self) -> None:
        def put(name, value):
            object.__setattr__(self, name, value)

        for name in ("queries", "seed", "width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise BenchmarkConfigError(f"{name} must be an integer, got {value!r}")
            put(name, int(value))
        for name in ("queries", "seed"):
            if getattr(self, name) < 0:
                raise BenchmarkConfigError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("width", "height"):
            if not QUERY_MIN_SIDE_PX <= getattr(self, name) <= QUERY_MAX_SIDE_PX:
                sides = f"[{QUERY_MIN_SIDE_PX}, {QUERY_MAX_SIDE_PX}]"
                raise BenchmarkConfigError(f"{name} must be in {sides} pixels, got {getattr(self, name)}")
        for name in ("depth", "lens_stated", "score_against_map"):
            put(name, true_or_false(getattr(self, name), name, BenchmarkConfigError))
        for name in (
            "nominal_height_m",
            "oblique_fraction",
            "max_roll_deg",
            "min_building_fraction",
            "prior_yaw_deg",
            "prior_roll_pitch_deg",
            "focal_mm",
            "focal_error",
            "lens_k1",
        ):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float, np.number))
                or not math.isfinite(value)
            ):
                raise BenchmarkConfigError(f"{name} must be a finite number, got {value!r}")
            put(name, float(value))
        lo, hi = _pair(self.height_range_m, "height_range_m")
        if lo <= 0 or not lo <= self.nominal_height_m <= hi:
            raise BenchmarkConfigError(
                f"need 0 < height_range_m[0] <= nominal_height_m <= height_range_m[1], got {(lo, hi)} and "
                f"{self.nominal_height_m}"
            )
        put("height_range_m", (lo, hi))
        pitch = _pair(self.oblique_pitch_deg, "oblique_pitch_deg")
        if pitch[0] < 0 or pitch[1] >= 85:
            raise BenchmarkConfigError(f"oblique_pitch_deg must lie in [0, 85) degrees, got {pitch}")
        put("oblique_pitch_deg", pitch)
        for name, ok, rule in (  # one check per knob, naming it alone
            ("oblique_fraction", 0 <= self.oblique_fraction <= 1, "in [0, 1]"),
            ("min_building_fraction", 0 <= self.min_building_fraction < 1, "in [0, 1)"),
            ("max_roll_deg", 0 <= self.max_roll_deg <= 45, "in [0, 45]"),
            ("prior_yaw_deg", 0 <= self.prior_yaw_deg <= 180, "in [0, 180]"),
            ("prior_roll_pitch_deg", 0 <= self.prior_roll_pitch_deg <= 45, "in [0, 45]"),
            ("focal_mm", self.focal_mm > 0, "positive"),
        ):
            if not ok:
                raise BenchmarkConfigError(f"{name} must be {rule}, got {getattr(self, name):g}")
        if not -0.5 < self.focal_error < 0.5:
            raise BenchmarkConfigError(f"focal_error must be in (-0.5, 0.5), got {self.focal_error}")
        try:
            LensDistortion(k1=self.lens_k1).check(zenmuse_l2_camera(self.width, self.height, self.focal_mm))
        except CameraError as exc:
            raise BenchmarkConfigError(
                f"lens_k1 = {self.lens_k1:g} does not fit this camera: {exc}"
            ) from None
        tr = _pair(self.prior_translation_m, "prior_translation_m")
        if tr[0] < 0:
            raise BenchmarkConfigError(f"prior_translation_m must be >= 0, got {tr}")
        put("prior_translation_m", tr)
        if self.prior_extra_m is not None:
            extra = _pair(self.prior_extra_m, "prior_extra_m")
            if extra[0] < 0:
                raise BenchmarkConfigError(f"prior_extra_m must be >= 0, got {extra}")
            put("prior_extra_m", extra)
        if self.seg_quality not in SEG_PRESETS:
            raise unknown_choice("seg_quality", self.seg_quality, SEG_PRESETS, BenchmarkConfigError)
        for name in ("prior_height_m", "prior_roll_pitch_sigma_deg"):
            value = getattr(self, name)
            if value is not None:
                if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                    raise BenchmarkConfigError(f"{name} must be a number or None, got {value!r}")
                if not (math.isfinite(value) and 0 <= value <= 500):
                    raise BenchmarkConfigError(f"{name} must be in [0, 500], got {value!r}")
                put(name, float(value))
        if self.seg_model not in SEG_MODELS:
            raise unknown_choice("seg_model", self.seg_model, SEG_MODELS, BenchmarkConfigError)
        if not isinstance(self.reality, RealityParams):
            raise BenchmarkConfigError("reality must be a RealityParams")
        if self.depth_model is not None and not isinstance(self.depth_model, DepthParams):
            raise BenchmarkConfigError("depth_model must be a DepthParams or None")

    def seg_preset(self):
        """The segmentation preset these queries use (``seg_model`` picks the table)."""
        table = SEG_PRESETS if self.seg_model == "blobs" else REALISTIC_SEG_PRESETS
        return table[self.seg_quality]


@dataclass
class BenchmarkQuery:
    """One query of a run (simulated: module docstring; or from a data set or a user's photos). Poses in
    the map model's LOCAL frame."""

    query_id: str  # "q0000", "q0001", ... (index i -> f"q{i:04d}")
    index: int
    camera: Camera  # at config.width x config.height
    true_pose_local: Pose | None  # cam_from_world, LOCAL frame of the map model; None: a user's photo
    prior_pose_local: Pose  # same frame
    labels: np.ndarray  # (H, W) uint8 simulated segmentation (SemanticClass ids; 0 = background)
    depth: np.ndarray | None  # (H, W) float32 simulated relative depth, NaN where invalid (sky)
    query_miou: float  # mIoU (%) of `labels` vs the clean labels of the reality render
    meta: dict = field(default_factory=dict)  # view, height_m, prior errors, ... (JSON-friendly)
    # How far the prior may be off, when the source knows it per query (a photo's RTK tags); None: the
    # localizer's own default. Passed on by ``benchmark.run.localize_query``.
    prior_uncertainty: PriorUncertainty | None = None


@dataclass
class SimulatedView:
    """A query with the truth it was made from: the reality's clean labels and z-depth (+inf = nothing)."""

    query: BenchmarkQuery
    clean_labels: np.ndarray  # (H, W) uint8
    true_depth: np.ndarray  # (H, W) float32


def zenmuse_l2_camera(width: int = 512, height: int = 384, focal_mm: float = 12.29) -> Camera:
    """The DJI Zenmuse L2 camera at ``width`` x ``height`` (module docstring): fx = fy = f / 17.3 mm x W."""
    f = float(focal_mm) / SENSOR_WIDTH_MM * int(width)
    return Camera(f, f, width / 2.0, height / 2.0, width, height)


def stated_camera(
    width: int = 512, height: int = 384, focal_mm: float = 12.29, focal_error: float = 0.0
) -> Camera:
    """The camera the localizer is told of (``QueryConfig.focal_error``): the true one's focal length
    times ``1 + focal_error``."""
    return zenmuse_l2_camera(width, height, focal_mm * (1.0 + focal_error))


def query_id(index: int) -> str:
    """The id of query ``index`` (``q0007``): the name of its details and estimate files and its
    ``results.csv`` key, zero-padded so that files sort in query order.
    """
    return f"q{int(index):04d}"


def view_kind(seed: int, index: int, oblique_fraction: float) -> str:
    """The view type of a query, ``"oblique"`` or ``"nadir"``: a golden-ratio (Weyl) sequence over the
    index with a phase drawn from the seed, so any run of n indices holds n x ``oblique_fraction``
    oblique views to within about 2."""
    phase = float(np.random.default_rng([int(seed), 0x71E4]).random())
    u = (phase + int(index) * GOLDEN) % 1.0
    return "oblique" if u < oblique_fraction else "nadir"


def _height(rng: np.random.Generator, cfg: QueryConfig) -> float:
    lo, hi = cfg.height_range_m
    sigma = HEIGHT_SIGMA_FRACTION * cfg.nominal_height_m
    for _ in range(100):
        h = cfg.nominal_height_m + sigma * rng.standard_normal()
        if lo <= h <= hi:
            return float(h)
    return float(np.clip(h, lo, hi))


def _realistic_prior_errors(
    base: np.ndarray, cfg: QueryConfig, rng: np.random.Generator, roll_err: float, pitch_err: float
) -> tuple[np.ndarray, float, float]:
    """GNSS/IMU as flown (``prior_height_m`` / ``prior_roll_pitch_sigma_deg`` set): the base error's
    horizontal part keeps its norm and direction, the height error is uniform in +-``prior_height_m``
    (barometric and geoid errors), roll and pitch errors are N(0, sigma) clipped to
    +-``prior_roll_pitch_deg`` (gimbal IMU). Drawn from its own stream, every draw every time."""
    dz = rng.uniform(-1.0, 1.0)
    rp = rng.standard_normal(2)
    out = base.copy()
    if cfg.prior_height_m is not None:
        horizontal = float(np.linalg.norm(base))
        angle = math.atan2(base[1], base[0])
        out = np.array([horizontal * math.cos(angle), horizontal * math.sin(angle), dz * cfg.prior_height_m])
    if cfg.prior_roll_pitch_sigma_deg is not None:
        lim = cfg.prior_roll_pitch_deg
        roll_err, pitch_err = (float(v) for v in np.clip(rp * cfg.prior_roll_pitch_sigma_deg, -lim, lim))
    return out, roll_err, pitch_err


def sample_prior(
    true_pose_local: Pose,
    cfg: QueryConfig,
    rng_base: np.random.Generator,
    rng_extra: np.random.Generator,
    rng_realistic: np.random.Generator | None = None,
) -> tuple[Pose, dict]:
    """The prior pose and its errors (module docstring). Every draw happens whatever the ranges, so the
    streams stay aligned across configurations; ``rng_realistic`` (given when ``prior_height_m`` or
    ``prior_roll_pitch_sigma_deg`` is set) draws the realistic height and roll / pitch errors."""
    r = rng_base.uniform(*cfg.prior_translation_m)
    theta = rng_base.uniform(0.0, 2 * np.pi)
    u = rng_base.uniform(-PRIOR_Z_RATIO, PRIOR_Z_RATIO)
    d = np.array([np.cos(theta), np.sin(theta), u])
    base = r * d / np.linalg.norm(d)
    yaw_err = rng_base.uniform(0.0, cfg.prior_yaw_deg) * rng_base.choice([-1.0, 1.0])
    roll_err, pitch_err = rng_base.uniform(-cfg.prior_roll_pitch_deg, cfg.prior_roll_pitch_deg, 2)
    if rng_realistic is not None:
        base, roll_err, pitch_err = _realistic_prior_errors(base, cfg, rng_realistic, roll_err, pitch_err)
    extra = np.zeros(3)
    if cfg.prior_extra_m is not None:
        extra = rng_extra.uniform(*cfg.prior_extra_m, 3) * rng_extra.choice([-1.0, 1.0], 3)
    x, y, z, roll, pitch, yaw = true_pose_local.to_xyz_rpy()
    err = base + extra
    prior = Pose.from_xyz_rpy(np.array([x, y, z]) + err, roll + roll_err, pitch + pitch_err, yaw + yaw_err)
    info = {
        "prior_err_m": float(np.linalg.norm(err)),
        "prior_err_xyz": [float(v) for v in err],
        "prior_base_err_m": float(np.linalg.norm(base)),
        "prior_extra_xyz": [float(v) for v in extra],
        "prior_yaw_err_deg": float(yaw_err),
        "prior_roll_err_deg": float(roll_err),
        "prior_pitch_err_deg": float(pitch_err),
    }
    return prior, info


class QuerySimulator:
    """Simulated queries over ``map_model`` (module docstring). Builds the reality scene once."""

    def __init__(self, map_model: CityModel, config: QueryConfig, reality_model: CityModel | None = None):
        if not isinstance(config, QueryConfig):
            raise ArgumentTypeError(
                f"config must be a QueryConfig (QueryConfig(...) or scenario.query_config(...)), got "
                f"{type(config).__name__}"
            )
        if not isinstance(map_model, CityModel):
            raise ArgumentTypeError(
                f"map_model must be a CityModel (load_city_model(path)), got {type(map_model).__name__}"
            )
        self.map_model = map_model
        self.config = config
        self.camera = zenmuse_l2_camera(config.width, config.height, config.focal_mm)  # renders the query
        self.stated_camera = stated_camera(config.width, config.height, config.focal_mm, config.focal_error)
        # A barrel lens (``lens_k1`` < 0) pulls rays from outside the query's pinhole image into the
        # photo's corners: the query is also simulated on this wider canvas around it (``_lens_canvas``).
        self.canvas = pinhole_canvas(self.camera, LensDistortion(k1=config.lens_k1))
        self.reality: RealityScene = build_reality(
            map_model, reality_model, seed=config.seed, params=config.reality
        )
        building = np.isin(map_model.classes, BUILDING_CLASSES)
        if not building.any():
            raise EmptyModelError("the map model has no walls or roofs: no query can see a building")
        xy = map_model.vertices[map_model.triangles[building]][:, :, :2].reshape(-1, 2).astype(np.float64)
        self.target_lo, self.target_hi = xy.min(0), xy.max(0)
        self._up_camera = Camera.from_fov(8, 8, 20.0)
        self.map_model = map_model
        self._map_renderer: Renderer | None = None

    def __len__(self) -> int:
        return self.config.queries

    def __iter__(self) -> Iterator[BenchmarkQuery]:
        for i in range(self.config.queries):
            yield self.query(i)

    def query(self, index: int) -> BenchmarkQuery:
        """Query ``index`` (deterministic from ``(config.seed, index)``)."""
        return self.query_with_truth(index).query

    # ------------------------------------------------------------------ internals
    def _pose(self, rng: np.random.Generator, view: str) -> tuple[Pose, dict]:
        cfg = self.config
        h = _height(rng, cfg)
        yaw = rng.uniform(-180.0, 180.0)
        roll = rng.uniform(-cfg.max_roll_deg, cfg.max_roll_deg)
        if view == "oblique":
            pitch = rng.uniform(*cfg.oblique_pitch_deg)
        else:
            pitch = rng.uniform(-NADIR_PITCH_DEG, NADIR_PITCH_DEG)
        target = rng.uniform(self.target_lo, self.target_hi)
        axis = Pose.from_xyz_rpy(np.zeros(3), roll, pitch, yaw).viewing_direction
        # Millimetre camera centre (module docstring of ``reality``: bit-identical on every machine).
        cam_xy = np.round(target - axis[:2] / max(-axis[2], 1e-6) * h, 3)
        ground = float(self.reality.terrain_height(cam_xy))
        pose = Pose.from_xyz_rpy(np.array([cam_xy[0], cam_xy[1], ground + h]), roll, pitch, yaw)
        info = {
            "height_m": float(h),
            "ground_z": ground,
            "roll_deg": float(roll),
            "pitch_deg": float(pitch),
            "yaw_deg": float(yaw),
        }
        return pose, info

    def _blocked_above(self, pose_local: Pose) -> bool:
        """Whether anything of the reality lies straight above the camera (it is inside or under it)."""
        up = Pose.from_xyz_rpy(pose_local.center, 0.0, 180.0, 0.0)
        d = self.reality.renderer.render(self._up_camera, up, depth=True).depth
        return bool(np.isfinite(d).any())

    def _segmentation(
        self,
        index: int,
        pose_local: Pose,
        clean: np.ndarray,
        meta: dict,
        camera: Camera | None = None,
        stream: tuple[int, ...] = (STREAM_SEG,),
    ) -> np.ndarray:
        """The simulated segmentation of a view (``seg_model``: random blobs, or structured errors from
        the view's truth: normals, occluders and what is behind them, cast shadows); ``camera``: what
        ``clean`` was rendered with (default the query's)."""
        cfg = self.config
        rng = np.random.default_rng([cfg.seed, index, *stream])
        if cfg.seg_model == "blobs":
            return simulate_segmentation(clean, SEG_PRESETS[cfg.seg_quality], rng)
        sun = sun_direction(np.random.default_rng([cfg.seed, index, STREAM_SUN]))
        truth = view_truth(self.reality, camera or self.camera, pose_local, sun)
        meta["shadow_fraction"] = float(truth.shadow.mean())
        return simulate_segmentation(clean, cfg.seg_preset(), rng, truth=truth)

    def _depth(
        self, index: int, true_depth: np.ndarray, clean: np.ndarray, stream: tuple[int, ...] = (STREAM_DEPTH,)
    ) -> np.ndarray | None:
        """The simulated relative depth of a view (``depth_model``; None without ``depth``)."""
        cfg = self.config
        if not cfg.depth:
            return None
        rng = np.random.default_rng([cfg.seed, index, *stream])
        if cfg.depth_model is None:
            return simulate_depth(true_depth, clean, rng)
        return simulate_depth_realistic(true_depth, rng, cfg.depth_model)

    def _lens_canvas(
        self, index: int, pose_local: Pose, labels: np.ndarray, depth: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The query's simulated labels and depth on ``canvas`` (a barrel lens; else as they are): the
        query's own in its pinhole window, unchanged, and around it a segmentation and depth of the wider
        render from their own streams (the depth scaled and shifted to agree with the query's where both
        are, as one network's output would). Why: a real wide photo shows something in its corners too;
        left unknown there, a lens left out would be easier than on a real photo."""
        if self.canvas == self.camera:
            return labels, depth
        out = self.reality.renderer.render(self.canvas, pose_local, depth=True)
        clean, true_depth = out.labels[0], out.depth[0]
        mx, my = round(self.canvas.cx - self.camera.cx), round(self.canvas.cy - self.camera.cy)
        window = (slice(my, my + self.camera.height), slice(mx, mx + self.camera.width))
        wide_labels = self._segmentation(
            index, pose_local, clean, {}, self.canvas, (STREAM_SEG, STREAM_LENS_MARGIN)
        )
        wide_labels[window] = labels
        if depth is None:
            return wide_labels, None
        wide = self._depth(index, true_depth, clean, (STREAM_DEPTH, STREAM_LENS_MARGIN)).astype(np.float64)
        both = np.isfinite(wide[window]) & np.isfinite(depth)
        if both.sum() >= 2:
            scale, shift = np.polyfit(wide[window][both], depth[both], 1)
            wide = scale * wide + shift
        wide[window] = depth
        return wide_labels, wide.astype(np.asarray(depth).dtype)

    def _through_lens(
        self, labels: np.ndarray, depth: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The query as the localizer gets it (``lens_k1``, ``lens_stated``): its ``canvas`` arrays
        (``_lens_canvas``) seen through the lens, then undistorted with the stated camera when the lens is
        stated (where that pinhole image reaches beyond a pincushion photo: IGNORE / NaN). The
        segmentation's scores (``query_miou``, the map's mIoU) are the lens-free masks'."""
        cfg = self.config
        if cfg.lens_k1 == 0.0:
            return labels, depth
        lens = LensDistortion(k1=cfg.lens_k1)

        def seen(image: np.ndarray, fill: float) -> np.ndarray:
            photo = distort_image(image, self.camera, lens, fill=fill, nearest=True, source=self.canvas)
            if not cfg.lens_stated:
                return photo
            return undistort_image(photo, self.stated_camera, lens, fill=fill, nearest=True)

        return seen(labels, IGNORE), (None if depth is None else seen(depth, np.nan))

    def map_confusion(self, pose_local: Pose, labels: np.ndarray) -> np.ndarray:
        """(C, C) int64 confusion [map label, predicted] of ``labels`` against the MAP's own labels at the
        true pose, by the automatic labelling rules (ignore pixels left out): the paper's mIoU. Windows and
        doors are scored as wall when the map has none (an LoD2 map: what its localizer does too)."""
        if self._map_renderer is None:
            self._map_renderer = Renderer(self.map_model, engine="numba")
        reference = auto_label(
            self.map_model, self.camera, self.map_model.pose_to_world(pose_local), renderer=self._map_renderer
        )
        keep = reference != IGNORE
        predicted = fold_to_map_classes(labels, self.map_model.classes)
        return confusion(predicted[keep], reference[keep], NUM_CLASSES)

    def query_with_truth(self, index: int) -> SimulatedView:
        """Query ``index`` plus the clean labels and true depth it was simulated from."""
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
            raise BenchmarkConfigError(f"query index must be an integer >= 0, got {index!r}")
        index = int(index)
        cfg = self.config
        view = view_kind(cfg.seed, index, cfg.oblique_fraction)
        best = None
        attempts = 0
        for attempt in range(MAX_ATTEMPTS):
            attempts = attempt + 1
            pose_local, info = self._pose(
                np.random.default_rng([cfg.seed, index, STREAM_POSE, attempt]), view
            )
            if self._blocked_above(pose_local):
                continue
            out = self.reality.renderer.render(self.camera, pose_local, depth=True)
            labels, depth = out.labels[0], out.depth[0]
            coverage = float(np.isin(labels, BUILDING_CLASSES).mean())
            finite = np.isfinite(depth)
            clearance = float(depth[finite].min()) if finite.any() else math.inf
            ok = coverage >= cfg.min_building_fraction and clearance >= MIN_CLEARANCE_M
            score = (ok, clearance >= MIN_CLEARANCE_M, coverage)
            if best is None or score > best[0]:
                best = (score, pose_local, info, labels, depth, coverage, clearance)
            if ok:
                break
        if best is None:
            raise QuerySimulationError(
                f"query {index}: every one of {MAX_ATTEMPTS} sampled cameras had model geometry above it"
            )
        (ok, _, _), pose_local, info, clean, true_depth, coverage, clearance = best

        extra_meta: dict = {}
        labels = self._segmentation(index, pose_local, clean, extra_meta)
        depth = self._depth(index, true_depth, clean)
        realistic_prior = cfg.prior_height_m is not None or cfg.prior_roll_pitch_sigma_deg is not None
        prior_local, prior_info = sample_prior(
            pose_local,
            cfg,
            np.random.default_rng([cfg.seed, index, STREAM_PRIOR]),
            np.random.default_rng([cfg.seed, index, STREAM_PRIOR_EXTRA]),
            np.random.default_rng([cfg.seed, index, STREAM_PRIOR_REALISTIC]) if realistic_prior else None,
        )
        if cfg.score_against_map:
            extra_meta["map_confusion"] = self.map_confusion(pose_local, labels).reshape(-1).tolist()
        occluded = (clean == 0) & np.isfinite(true_depth)
        meta = {
            "view": view,
            **info,
            "coverage": coverage,
            "accepted": bool(ok),
            "attempts": attempts,
            "clearance_m": clearance,
            "occluder_fraction": float(occluded.mean()),
            "sky_fraction": float((~np.isfinite(true_depth)).mean()),
            "seg_quality": cfg.seg_quality,
            **prior_info,
            **extra_meta,
        }
        seen_labels, seen_depth = self._through_lens(*self._lens_canvas(index, pose_local, labels, depth))
        query = BenchmarkQuery(
            query_id=query_id(index),
            index=index,
            camera=self.stated_camera,
            true_pose_local=pose_local,
            prior_pose_local=prior_local,
            labels=seen_labels,
            depth=seen_depth,
            query_miou=miou(labels, clean),
            meta=meta,
        )
        return SimulatedView(query, clean, true_depth)
