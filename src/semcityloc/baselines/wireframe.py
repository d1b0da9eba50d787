"""LoD-Loc-style wireframe alignment (Zhu et al., NeurIPS 2024), re-implemented from its description and
public code as a baseline on the same benchmark as SemCityLoc.

Pipeline of ``WireframeLocalizer.localize(camera, prior_local, edge_map)`` (poses in the local frame):

1. Map side: points every ``spacing_m`` along the model's feature edges (``edges.extract_edges``),
   kept when visible at the PRIOR: a z-depth render at the prior, a point is visible when at most
   ``visibility_tol_m`` (0.3 m, LoD-Loc's value) behind the surface at its pixel (3x3 max). At most
   ``max_points`` are kept (uniform random subset, seeded).
2. Query side: the edge-probability map, resampled to ``width`` and to each stage's resolution and
   blurred (``edge_score.EdgePyramid``).
3. Search: 3 stages of a uniform 4D grid over (yaw, x, y, z) with roll and pitch at the prior's,
   ``n_yaw x n_xy x n_xy x n_z`` = 8 x 10 x 10 x 30 samples from ``centre - half_range`` to
   ``centre + half_range`` (LoD-Loc: yaw +-7.5 deg, x/y +-10 m, z +-30 m). Each hypothesis scores the
   mean edge probability at the projected points (``edge_score.grid_scores``). Stage k+1 is centred on
   stage k's best cell; its half-ranges are LoD-Loc's ``0.8 x`` the softmax-weighted standard deviation
   of the samples around the best one (softmax of the scores over ``temperature x`` their std), kept
   between one grid step of stage k and stage k's half-range.
4. Refinement: ``refine_iterations`` (5) damped Gauss-Newton steps on the finest map
   (``gauss_newton.gauss_newton``).
5. Decision (LoD-Loc always returns a pose; here, as for SemCityLoc, empty evidence is refused):
   ``not_localized`` when the edge map has no edges, when fewer than ``min_points`` model points are
   visible at the prior, or when the final mean edge score is below ``min_score`` or below
   ``min_contrast`` x the map's mean (a map without structure scores its mean anywhere).

The result is the main method's ``LocalizationResult``: ``score`` = final mean edge probability (fine
map), ``semantic`` and ``depth_cost`` are NaN (not measured), ``cost_volume`` is stage 1's grid.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from semcityloc.baselines.edge_score import NEAR_M, EdgePyramid, check_edge_map, grid_scores, score_poses
from semcityloc.baselines.edge_sim import edge_visibility, max_depth_3x3, render_depth
from semcityloc.baselines.edges import DEFAULT_CREASE_DEG, ModelEdges, extract_edges
from semcityloc.baselines.gauss_newton import gauss_newton
from semcityloc.citymodel.model import CityModel
from semcityloc.errors import ParameterError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose, yaw_fan_rotations
from semcityloc.localization.coarse import CostVolume, axis_samples
from semcityloc.localization.input_checks import check_camera_and_prior
from semcityloc.localization.result import (
    LOCALIZED,
    NOT_LOCALIZED,
    REASON_LOW_SCORE,
    REASON_NO_GEOMETRY,
    LocalizationResult,
)
from semcityloc.render.scene import RenderScene, build_scene

# Stable reason string (benchmark CSVs match on it), in the style of localization.result.
REASON_NO_EDGES = "query edge map has no edges"


@dataclass(frozen=True)
class WireframeConfig:
    """Every number of the wireframe baseline. Half-ranges and counts are LoD-Loc's validation setting."""

    half_range_yaw_deg: float = 7.5
    half_range_xy_m: float = 10.0
    half_range_z_m: float = 30.0
    n_yaw: int = 8
    n_xy: int = 10
    n_z: int = 30
    stages: int = 3
    range_lambda: float = 0.8  # LoD-Loc lamb_val: next half-range = lambda x weighted std
    temperature: float = 0.3  # softmax temperature in units of the stage's score std
    width: int = 512  # working resolution of the finest map (height from the camera's aspect)
    stage_scales: tuple[float, ...] = (0.25, 0.5, 1.0)  # map resolution of each stage, share of width
    stage_blur_px: tuple[float, ...] = (1.5, 1.5, 1.5)  # Gaussian sigma at each stage's resolution
    refine_iterations: int = 5
    refine_blur_px: float = 1.0
    refine_damping: float = 0.01
    refresh_visibility: bool = False  # re-select the visible points at the grid's best pose before GN
    spacing_m: float = 1.0  # LoD-Loc samples its wireframe every metre (used when the localizer is built)
    max_points: int = 4000
    visibility_tol_m: float = 0.3
    crease_deg: float = DEFAULT_CREASE_DEG  # used when the localizer is built
    min_points: int = 30
    min_edge_fraction: float = 1e-4  # share of pixels above 0.2 below which the map "has no edges"
    min_score: float = 0.15
    min_contrast: float = 1.5  # final score / mean of the map: ~1 on a map without structure
    no_refine: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("n_yaw", "n_xy", "n_z", "stages", "width", "max_points", "min_points"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ParameterError(f"WireframeConfig.{name} must be a positive integer, got {value!r}")
        for name in ("half_range_yaw_deg", "half_range_xy_m", "half_range_z_m", "refine_blur_px"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ParameterError(f"WireframeConfig.{name} must be >= 0, got {value!r}")
        for name in ("spacing_m", "temperature", "range_lambda"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ParameterError(f"WireframeConfig.{name} must be positive, got {value!r}")
        if len(self.stage_scales) != self.stages or len(self.stage_blur_px) != self.stages:
            raise ParameterError("WireframeConfig.stage_scales and stage_blur_px need one entry per stage")
        if any(not (0 < s <= 1) for s in self.stage_scales):
            raise ParameterError(f"stage_scales must lie in (0, 1], got {self.stage_scales}")

    def as_dict(self) -> dict:
        """The settings as plain values, for run.json (a changed setting is another run)."""
        return asdict(self)


@dataclass
class StageResult:
    """One stage of the wireframe baseline's coarse-to-fine grid: its best state, the yaw / x / y / z
    half-ranges it searched and its cost volume, kept so the next stage can centre on it and the report can
    show the volumes.
    """

    centre: np.ndarray  # (6,) best state of the stage
    half_ranges: np.ndarray  # (4,) yaw, x, y, z half-ranges it searched
    volume: CostVolume


class WireframeLocalizer:
    """LoD-Loc-style wireframe alignment against one city model (module docstring). Build once per model."""

    def __init__(
        self,
        model: CityModel,
        config: WireframeConfig | None = None,
        scene: RenderScene | None = None,
        edges: ModelEdges | None = None,
    ):
        if not isinstance(model, CityModel):
            raise TypeError(f"WireframeLocalizer needs a CityModel, got {type(model).__name__}")
        self.model = model
        self.config = config or WireframeConfig()
        self.scene = scene if scene is not None else build_scene(model)
        self.edges = edges if edges is not None else extract_edges(model, self.config.crease_deg)
        self.points, _ = self.edges.sample(self.config.spacing_m)

    # ------------------------------------------------------------------ map side
    def visible_points(self, camera: Camera, prior_local: Pose, config: WireframeConfig | None = None):
        """(P, 3) model edge points visible at ``prior_local`` (local frame), at most ``max_points``."""
        cfg = config or self.config
        cam = camera.scaled(cfg.width, max(1, round(cfg.width * camera.height / camera.width)))
        pts_cam = prior_local.transform(self.points)
        uv, _ = cam.project(pts_cam)
        candidate = (pts_cam[:, 2] > NEAR_M) & cam.in_image(uv)
        if not candidate.any():
            return np.zeros((0, 3))
        depth_max = max_depth_3x3(render_depth(self.scene, cam, prior_local))
        idx = np.flatnonzero(candidate)
        vis = idx[edge_visibility(pts_cam[idx], uv[idx], depth_max, cfg.visibility_tol_m)]
        if len(vis) > cfg.max_points:
            rng = np.random.default_rng(cfg.seed)
            vis = np.sort(rng.choice(vis, cfg.max_points, replace=False))
        return self.points[vis]

    def score(
        self,
        camera: Camera,
        edge_map: np.ndarray,
        poses_local: Pose,
        prior_local: Pose | None = None,
        config: WireframeConfig | None = None,
    ) -> np.ndarray:
        """Mean edge probability at each pose of ``poses_local`` on the finest search map, with the model
        points visible at ``prior_local`` (default: the first pose). For sweeps and diagnostics."""
        cfg = config or self.config
        pyramid = EdgePyramid(
            edge_map, camera, cfg.width, cfg.stage_scales, cfg.stage_blur_px, cfg.refine_blur_px
        )
        first = poses_local if not poses_local.batch_shape else poses_local[0]
        points = self.visible_points(camera, prior_local if prior_local is not None else first, cfg)
        level = pyramid.levels[-1]
        return score_poses(points, poses_local, level.camera, level.emap)

    # ------------------------------------------------------------------ search
    def _stage(
        self, points: np.ndarray, centre: np.ndarray, half: np.ndarray, level, cfg: WireframeConfig
    ) -> StageResult:
        x0, y0, z0, roll, pitch, yaw0 = (float(v) for v in centre)
        yaws = axis_samples(yaw0, 2 * half[0], cfg.n_yaw)
        xs = axis_samples(x0, 2 * half[1], cfg.n_xy)
        ys = axis_samples(y0, 2 * half[2], cfg.n_xy)
        zs = axis_samples(z0, 2 * half[3], cfg.n_z)
        M = yaw_fan_rotations(roll, pitch, yaws)  # (Y, 3, 3)
        Q = np.einsum("yij,nj->iyn", M, points)  # (3, Y, N)
        gx, gy, gz = np.meshgrid(xs, ys, zs, indexing="ij")
        centres = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], 1)
        T = np.ascontiguousarray(np.einsum("yij,cj->yci", M, centres))
        out = np.empty((len(centres), len(yaws)))
        cam = level.camera
        qx, qy, qz = (np.ascontiguousarray(q) for q in Q)
        grid_scores(
            qx, qy, qz, T, cam.fx, cam.fy, cam.cx, cam.cy, level.padded, cam.width, cam.height, NEAR_M, out
        )
        scores = out.reshape(len(xs), len(ys), len(zs), len(yaws))
        volume = CostVolume(scores, xs, ys, zs, yaws, roll, pitch)
        best = volume.best_indices(1)[0]
        return StageResult(volume.xyz_rpy(best), half, volume)

    def _next_half_ranges(self, stage: StageResult, cfg: WireframeConfig) -> np.ndarray:
        """LoD-Loc's rule: lambda x softmax-weighted std of the samples around the best, per axis."""
        v = stage.volume
        s = v.scores.reshape(-1)
        spread = max(float(np.std(s)), 1e-12)
        w = np.exp((s - s.max()) / (cfg.temperature * spread))
        w /= w.sum()
        gx, gy, gz, gyaw = np.meshgrid(v.x_values, v.y_values, v.z_values, v.yaw_values, indexing="ij")
        best = stage.centre
        axes = (gyaw.reshape(-1) - best[5], gx.reshape(-1) - best[0], gy.reshape(-1) - best[1])
        axes = axes + (gz.reshape(-1) - best[2],)
        std = np.array([np.sqrt(np.sum(w * a**2)) for a in axes])
        counts = np.array([cfg.n_yaw, cfg.n_xy, cfg.n_xy, cfg.n_z])
        step = 2 * stage.half_ranges / np.maximum(counts - 1, 1)
        return np.clip(cfg.range_lambda * std, step, stage.half_ranges)

    # ------------------------------------------------------------------ public
    def localize(
        self,
        camera: Camera,
        prior_local: Pose,
        edge_map: np.ndarray,
        config: WireframeConfig | None = None,
    ) -> LocalizationResult:
        """Estimate the pose of one query from its edge-probability map (module docstring).

        Args:
            camera: intrinsics of the query image (any resolution; the map is resampled to ``width``).
            prior_local: prior cam_from_world pose in the model's LOCAL frame (a world/CRS pose comes in
                through ``model.pose_to_local``); the result's poses are in the local frame too.
            edge_map: (H, W) edge probability in [0, 1] with the camera's aspect (``ShapeError`` if not).
        """
        cfg = config or self.config
        t0 = time.perf_counter()
        check_camera_and_prior(camera, prior_local)
        check_edge_map(edge_map, camera)
        state = prior_local.to_xyz_rpy()

        result = LocalizationResult(status=NOT_LOCALIZED)
        result.counts = {"coarse_hypotheses": 0, "refine_evaluations": 0, "edge_points": 0}
        pyramid = EdgePyramid(
            edge_map, camera, cfg.width, cfg.stage_scales, cfg.stage_blur_px, cfg.refine_blur_px
        )
        if pyramid.edge_fraction() < cfg.min_edge_fraction:
            return result.finish(REASON_NO_EDGES, t0)
        points = self.visible_points(camera, prior_local, cfg)
        result.counts["edge_points"] = int(len(points))
        result.timings["prep_s"] = time.perf_counter() - t0
        if len(points) < cfg.min_points:
            return result.finish(REASON_NO_GEOMETRY, t0)

        t1 = time.perf_counter()
        half = np.array(
            [cfg.half_range_yaw_deg, cfg.half_range_xy_m, cfg.half_range_xy_m, cfg.half_range_z_m]
        )
        stages = []
        for k in range(cfg.stages):
            stage = self._stage(points, state, half, pyramid.levels[k], cfg)
            stages.append(stage)
            state = stage.centre
            half = self._next_half_ranges(stage, cfg)
        result.cost_volume = stages[0].volume
        result.coarse_pose_local = Pose.from_state(state)
        result.counts["coarse_hypotheses"] = int(sum(s.volume.scores.size for s in stages))
        result.confidence["score_margin"] = stages[0].volume.score_margin()
        result.confidence["stage_half_ranges"] = [s.half_ranges.tolist() for s in stages]
        result.timings["coarse_s"] = time.perf_counter() - t1

        t2 = time.perf_counter()
        if not cfg.no_refine and cfg.refine_iterations > 0:
            if cfg.refresh_visibility:
                refreshed = self.visible_points(camera, Pose.from_state(state), cfg)
                if len(refreshed) >= cfg.min_points:
                    points = refreshed
            outcome = gauss_newton(
                points,
                state,
                pyramid.refine.camera,
                pyramid.refine.emap,
                cfg.refine_iterations,
                cfg.refine_damping,
            )
            state = outcome.state
            result.counts["refine_evaluations"] = outcome.evaluations
            result.confidence["refine_gain"] = outcome.score_after - outcome.score_before
            result.confidence["refine_accepted_steps"] = outcome.accepted_steps
        result.timings["refine_s"] = time.perf_counter() - t2

        pose_local = Pose.from_state(state)
        fine = pyramid.levels[-1]
        result.score = float(score_poses(points, pose_local, fine.camera, fine.emap)[0])
        result.pose_local = pose_local
        chance = float(fine.emap.mean())  # expected score of points thrown anywhere in the image
        result.confidence["contrast"] = result.score / max(chance, 1e-9)
        if not (result.score >= cfg.min_score and result.confidence["contrast"] >= cfg.min_contrast):
            result.pose_local = None
            return result.finish(REASON_LOW_SCORE, t0)
        result.status = LOCALIZED
        return result.finish(None, t0)
