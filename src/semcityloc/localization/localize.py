"""``localize()``: the SemCityLoc pipeline from a query (mask + depth) and a prior to a 6DoF pose.

1. Prepare: the query mask (any resolution with the camera's aspect) is majority-downsampled to the
   coarse and fine search resolutions; window/door merge into wall when the map has no openings.
2. Coarse: 4D cost volume over (x, y, z, yaw) around the prior (``coarse.coarse_search``).
3. Refine: particle filter from the top-k coarse cells, semantic IoU + depth (``refine.particle_filter``).
4. Decide: ``not_localized`` with a reason when the evidence is empty or too weak.

``Localizer`` keeps the render scene of one city model, so a batch of queries builds it once.
"""

from __future__ import annotations

import time

import numpy as np

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES, IGNORE, NUM_CLASSES, SemanticClass
from semcityloc.errors import CameraError, PoseError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.localization.coarse import coarse_search
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.query import Query
from semcityloc.localization.refine import ScoringLevel, evaluate, particle_filter
from semcityloc.localization.result import (
    LOCALIZED,
    NOT_LOCALIZED,
    REASON_LOW_SCORE,
    REASON_NO_BUILDINGS_IN_QUERY,
    REASON_NO_GEOMETRY,
    LocalizationResult,
)
from semcityloc.localization.scoring import map_classes
from semcityloc.render.raster_numba import NumbaEngine
from semcityloc.render.scene import RenderScene, build_scene

# Rays that do not meet the ground plane within this distance are cut here when the view's footprint is
# estimated for the "model geometry in the search volume" check.
MAX_VIEW_RANGE_M = 1500.0


class Localizer:
    """Localize queries against one city model. Thread-compatible; build once, call many times."""

    def __init__(
        self, model: CityModel, config: LocalizerConfig | None = None, scene: RenderScene | None = None
    ):
        self.model = model
        self.config = config or LocalizerConfig()
        self.scene = scene if scene is not None else build_scene(model)
        self.has_openings = bool(np.isin(model.classes, [SemanticClass.WINDOW, SemanticClass.DOOR]).any())
        class_ids = map_classes(self.has_openings)
        self.class_on = np.zeros(NUM_CLASSES, dtype=bool)
        self.class_on[list(class_ids)] = True
        building = np.isin(model.classes, BUILDING_CLASSES)
        corners = model.vertices[model.triangles[building]].astype(np.float64)
        self._building_xy = corners.mean(1)[:, :2]
        self._ground_z = float(np.median(corners[:, :, 2].min(1))) if len(corners) else 0.0

    # ------------------------------------------------------------------ public
    def localize(
        self,
        camera: Camera,
        prior_local: Pose,
        semantic: np.ndarray,
        depth: np.ndarray | None = None,
        config: LocalizerConfig | None = None,
    ) -> LocalizationResult:
        """Estimate the pose of one query.

        Args:
            camera: intrinsics of the query image (any resolution; masks are resampled to the search's).
            prior_local: prior cam_from_world pose in the model's LOCAL frame (a world/CRS pose comes in
                through ``model.pose_to_local``). The result's poses are in the local frame too.
            semantic: (H, W) class ids (``SemanticClass``), 255 = ignore. Same aspect as ``camera``.
            depth: optional (H', W') relative depth (any positive scale and shift), NaN/<=0 = invalid.
        """
        cfg = config or self.config
        t0 = time.perf_counter()
        self._check_inputs(camera, prior_local, semantic)
        query = Query.from_arrays(semantic, None if cfg.no_depth else depth, self.has_openings)
        prior_state = prior_local.to_xyz_rpy()

        result = LocalizationResult(status=NOT_LOCALIZED)
        result.counts = {"coarse_hypotheses": 0, "refine_evaluations": 0}
        if query.building_fraction() < cfg.min_building_fraction:
            return self._finish(result, REASON_NO_BUILDINGS_IN_QUERY, t0)
        if not self._geometry_near(camera, prior_local, cfg):
            return self._finish(result, REASON_NO_GEOMETRY, t0)

        c = cfg.coarse
        coarse_cam = camera.scaled(c.width, max(1, round(c.width * camera.height / camera.width)))
        fine_cam = coarse_cam.scale(cfg.refine.scale)
        q_coarse, d_coarse = query.at(coarse_cam.width, coarse_cam.height)
        q_fine, d_fine = query.at(fine_cam.width, fine_cam.height)
        t_prep = time.perf_counter()

        if cfg.no_coarse:
            seeds = prior_state[None, :]
            result.timings["coarse_s"] = 0.0
        else:
            centre = prior_state
            n_pre = 0
            if cfg.pre_coarse is not None:
                pre = cfg.pre_coarse
                pre_cam = camera.scaled(pre.width, max(1, round(pre.width * camera.height / camera.width)))
                q_pre, _ = query.at(pre_cam.width, pre_cam.height)
                pre_volume = coarse_search(self.scene, pre_cam, prior_state, q_pre, self.class_on, pre)
                centre = pre_volume.xyz_rpy(pre_volume.best_indices(1)[0])
                n_pre = int(pre_volume.scores.size)
            volume = coarse_search(self.scene, coarse_cam, centre, q_coarse, self.class_on, c)
            top = volume.best_indices(c.top_k)
            seeds = np.stack([volume.xyz_rpy(i) for i in top])
            result.cost_volume = volume
            result.coarse_pose_local = _pose(seeds[0])
            result.counts["coarse_hypotheses"] = int(volume.scores.size) + n_pre
            result.confidence["score_margin"] = volume.score_margin()
            result.timings["coarse_s"] = time.perf_counter() - t_prep
        t_coarse = time.perf_counter()

        if cfg.no_refine:
            final = seeds[0]
            sem, dep = evaluate(self.scene, fine_cam, final[None], q_fine, d_fine, self.class_on)
            lam_d = cfg.refine.lambda_depth if d_fine is not None else 0.0
            result.semantic, result.depth_cost = float(sem[0]), float(dep[0])
            result.score = cfg.refine.lambda_semantic * result.semantic - lam_d * result.depth_cost
            result.timings["refine_s"] = 0.0
        else:
            rng = np.random.default_rng(cfg.seed)
            levels = [ScoringLevel(coarse_cam, q_coarse, d_coarse), ScoringLevel(fine_cam, q_fine, d_fine)]
            refined = particle_filter(self.scene, levels, seeds, self.class_on, cfg.refine, rng)
            final = refined.xyz_rpy
            result.semantic, result.depth_cost, result.score = (
                refined.semantic,
                refined.depth_cost,
                refined.score,
            )
            result.confidence.update(spread_m=refined.spread_m, spread_deg=refined.spread_deg)
            result.counts["refine_evaluations"] = refined.evaluations
            result.timings["refine_s"] = time.perf_counter() - t_coarse

        pose_local = _pose(final)
        result.pose_local = pose_local
        result.confidence["building_iou"] = self._building_iou(fine_cam, pose_local, q_fine)
        if not self._accept(result, cfg, with_depth=d_fine is not None):
            result.pose_local = None
            return self._finish(result, REASON_LOW_SCORE, t0)
        result.status = LOCALIZED
        return self._finish(result, None, t0)

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _accept(result: LocalizationResult, cfg: LocalizerConfig, with_depth: bool) -> bool:
        """Is the evidence for the final pose strong enough (see ``LocalizerConfig`` thresholds)?"""
        if result.confidence["building_iou"] < cfg.min_building_iou:
            return False
        if with_depth:
            return result.semantic >= cfg.min_semantic_with_depth and result.depth_cost <= cfg.max_depth_cost
        return result.semantic >= cfg.min_score

    def _finish(self, result: LocalizationResult, reason: str | None, t0: float) -> LocalizationResult:
        result.reason = reason
        if reason is not None:
            result.status = NOT_LOCALIZED
        result.timings["total_s"] = time.perf_counter() - t0
        return result

    def _check_inputs(self, camera, prior, semantic) -> None:
        check_camera_and_prior(camera, prior)
        shape = np.shape(semantic)
        if len(shape) != 2:
            raise ShapeError(f"semantic mask must be (H, W), got shape {shape}")
        aspect_mask, aspect_cam = shape[1] / shape[0], camera.width / camera.height
        if abs(aspect_mask / aspect_cam - 1) > 0.02:
            raise ShapeError(
                f"semantic mask {shape[1]}x{shape[0]} does not have the camera's aspect "
                f"({camera.width}x{camera.height})"
            )

    def _geometry_near(self, camera: Camera, prior_local: Pose, cfg: LocalizerConfig) -> bool:
        """Does any building lie where the prior's view, widened by the search range, could see it?"""
        if not len(self._building_xy):
            return False
        corners_uv = np.array(
            [
                [0, 0],
                [camera.width, 0],
                [camera.width, camera.height],
                [0, camera.height],
                [camera.cx, camera.cy],
            ],
            dtype=np.float64,
        )
        rays = prior_local.R_world_from_cam @ camera.unproject(corners_uv).T  # (3, 5)
        centre = prior_local.center
        dz = self._ground_z - centre[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(rays[2] * dz > 0, dz / rays[2], np.inf)
        s = np.minimum(s, MAX_VIEW_RANGE_M / np.linalg.norm(rays, axis=0))
        pts = centre[:2, None] + rays[:2] * s
        pts = np.concatenate([pts, centre[:2, None]], axis=1)
        reach = cfg.coarse.range_xy_m + (cfg.pre_coarse.range_xy_m if cfg.pre_coarse is not None else 0.0)
        margin = reach / 2 + 1.0
        lo, hi = pts.min(1) - margin, pts.max(1) + margin
        inside = np.all((self._building_xy >= lo) & (self._building_xy <= hi), axis=1)
        return bool(inside.any())

    def _building_iou(self, camera: Camera, pose_local: Pose, query_flat: np.ndarray) -> float:
        """Building (wall/roof/window/door) vs rest IoU at one pose, ignoring query background/ignore."""
        out = NumbaEngine(self.scene).render(camera, pose_local.R[None], pose_local.t[None])
        labels = out.labels.reshape(1, -1)
        valid = (query_flat != 0) & (query_flat != IGNORE)
        r = np.isin(labels[0], BUILDING_CLASSES)[valid]
        q = np.isin(query_flat, BUILDING_CLASSES)[valid]
        union = np.count_nonzero(r | q)
        return float(np.count_nonzero(r & q) / union) if union else 0.0


def check_camera_and_prior(camera: Camera, prior: Pose) -> None:
    """Typed errors for the inputs every localizer shares (this one and the baselines)."""
    if not isinstance(camera, Camera):
        raise CameraError(f"camera must be a semcityloc Camera, got {type(camera).__name__}")
    if not isinstance(prior, Pose) or prior.batch_shape:
        raise PoseError("prior must be a single Pose (cam_from_world)")


def _pose(state: np.ndarray) -> Pose:
    return Pose.from_xyz_rpy(state[:3], state[3], state[4], state[5])


def localize(
    city: CityModel,
    camera: Camera,
    prior_local: Pose,
    semantic: np.ndarray,
    depth: np.ndarray | None = None,
    config: LocalizerConfig | str | None = None,
) -> LocalizationResult:
    """One-shot ``Localizer(city, config).localize(...)``; ``config`` may be a preset name. Poses in and
    out are in ``city``'s local frame (``city.pose_to_local`` / ``city.pose_to_world`` at the boundary)."""
    if isinstance(config, str):
        config = LocalizerConfig.preset(config)
    return Localizer(city, config).localize(camera, prior_local, semantic, depth)
