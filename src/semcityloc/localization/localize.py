"""``localize()``: the SemCityLoc pipeline from a query (mask + depth) and a prior to a 6DoF pose.

1. Check and prepare: inputs no photo could have are refused with a typed error (``input_checks.py``);
   the query mask (any resolution with the camera's aspect) is majority-downsampled to the search
   resolutions, window/door merged into wall when the map has no openings (``query.py``). A query without
   building pixels, or a prior from whose view no building lies within the search's reach
   (``search_reach.py``), is refused before any search.
2. Search (``config.search``): the cascade over the prior's uncertainty volume (``cascade.py``: sweep,
   edge extension, local grids with roll/pitch) gives a few distinct hypotheses; or the first design's
   uniform 4D grid (``coarse.coarse_search``, preset ``legacy``).
3. Refine (``refine_stage.py``): one particle filter (``refine.particle_filter``: semantic IoU + depth, in
   the cascade also the prior's roll/pitch penalty, ``prior.py``) seeded by the search's best distinct
   hypotheses (cascade) or best grid cells (grid), then its polish; with ``restarts`` the best final score
   wins; the score's curvature at the pose gives its covariance (``covariance.py``). With
   ``map_eaves_flat_roofs="auto"`` a second look on the map with eaves on its flat roofs too
   (``map_scenes.py``). A found roll/pitch far outside the IMU's stated sigma (``prior.roll_pitch_conflict``):
   the refinement again with that sigma widened, the pose that fits the image better kept, and a warning.
4. Accept: ``not_localized`` with a reason when the evidence is empty, the best hypothesis sits on the
   edge of the search volume, or the calibrated probability of being right (``confidence.py``) is
   below ``min_confidence`` (``acceptance="thresholds"``: the first design's hand-set gates). A pose the
   cascade found and the acceptance refused gets a look beyond the search's reach (``cascade.look_beyond``,
   ``ring_beyond``): a better view there is named in a warning.
   An accepted oblique pose gets a focal-length check (``focal_check.py``): scored at focal scales 0.97 /
   1 / 1.03 around it, a warning when its view fits one more than ``FocalCheckConfig.margin`` from 1.
   Then (``FocalCheckConfig.correct``) the pose is found again with the focal length that scale points at
   and kept when the acceptance takes it and it fits the image better (``_correct_focal``). A nadir view
   is not checked (focal length and height are one unknown): its record says so
   (``focal_check.nadir_record``), and with the correction asked for, a warning.
5. Result: a ``LocalizationResult`` with the pose (or the refused one), the evidence and the timings.

``Localizer`` keeps the render scene of one city model, so a batch of queries builds it once.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import NUM_CLASSES, SemanticClass
from semcityloc.errors import ParameterError, parameter
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import state_difference
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.agreement import agreed_depth_cost, boundary_distance_px, building_agreement
from semcityloc.localization.cascade import (
    BEYOND_WARNING,
    Beyond,
    SearchVolume,
    local_search,
    look_beyond,
    search_volume,
    sweep,
)
from semcityloc.localization.coarse import coarse_search
from semcityloc.localization.confidence import (
    close_view_warning,
    confidence_model,
    field_of_view_warning,
    is_close_view,
    view_span_m,
)
from semcityloc.localization.config import LocalizerConfig, config_or_preset
from semcityloc.localization.focal_check import (
    FocalCheck,
    check_focal,
    corrected_warning,
    correction_scale,
    focal_warning,
    is_oblique,
    moved_back,
    nadir_record,
    nadir_warning,
    with_focal_scale,
)
from semcityloc.localization.input_checks import check_query_inputs
from semcityloc.localization.lookalike import (
    Lookalike,
    ambiguous_reason,
    distant_peak,
    is_distinct,
    lookalike_of,
)
from semcityloc.localization.map_scenes import flat_eaves_scene, localizer_scene
from semcityloc.localization.prior import (
    ROLL_PITCH_APART_DEG,
    ROLL_PITCH_APART_M,
    prior_conflict_warning,
    prior_distance,
    prior_term,
    roll_pitch_conflict,
    roll_pitch_conflict_warning,
    roll_pitch_departure,
    roll_pitch_take_gain,
    roll_pitch_wide_sigma,
)
from semcityloc.localization.query import (
    Query,
    check_mask_pixels,
    coarse_mask_warning,
    depth_rank_correlation,
    inverted_depth_warning,
    usable_depth,
)
from semcityloc.localization.refine import ScoringLevel, initial_sigma, score_states
from semcityloc.localization.refine_stage import Refiner, adopt, image_score, median_seen_depth
from semcityloc.localization.result import (
    LOCALIZED,
    NOT_LOCALIZED,
    REASON_AMBIGUOUS,
    REASON_AT_EDGE,
    REASON_LOW_CONFIDENCE,
    REASON_LOW_SCORE,
    REASON_NO_BUILDINGS_IN_QUERY,
    REASON_NO_GEOMETRY,
    REASON_ROLL_PITCH_CONFLICT,
    LocalizationResult,
)
from semcityloc.localization.scoring import map_classes, merge_openings_lut
from semcityloc.localization.search_reach import MapLayout, edge_sigma, edge_warning, reached_half
from semcityloc.render.raster_numba import NumbaEngine
from semcityloc.render.scene import RenderScene


@dataclass(frozen=True)
class _Found:
    """What the acceptance judged a found pose with, for the focal check's second look: the query's
    ``camera``, the search's scoring ``levels`` (fine last), the prior's state, the query's building share
    and how many warnings the result had before the acceptance added its own."""

    camera: Camera
    levels: list[ScoringLevel]
    prior_state: np.ndarray
    building: float
    warnings_before: int


class Localizer:
    """Localize queries against one city model. Thread-compatible; build once, call many times."""

    # Which fitted confidence model applies (``confidence.confidence_model``); a subclass scoring
    # something else (the silhouette baseline) names its own.
    confidence_kind = "semantic"

    def __init__(
        self, model: CityModel, config: LocalizerConfig | None = None, scene: RenderScene | None = None
    ):
        if not isinstance(model, CityModel):
            raise ParameterError(
                f"model must be a CityModel (citymodel.load_city_model), got {type(model).__name__}"
            )
        self.model = model
        self.config = config_or_preset(config)
        self.scene = scene if scene is not None else localizer_scene(model, self.config)
        map_openings = bool(np.isin(model.classes, [SemanticClass.WINDOW, SemanticClass.DOOR]).any())
        # Openings not scored (``LocalizerConfig.score_openings``): the map's become wall, like the query's.
        self.has_openings = map_openings and self.config.score_openings
        if map_openings and not self.has_openings:
            self.scene = replace(self.scene, classes=merge_openings_lut(False)[self.scene.classes])
        # The map with eaves on its flat roofs too, for the second look of ``map_eaves_flat_roofs="auto"``
        # (None: not asked for, or no flat roof to give them).
        cfg = self.config
        auto = cfg.map_eaves_flat_roofs == "auto" and cfg.map_eaves_m > 0.0
        self.flat_eaves_scene = flat_eaves_scene(self.scene, model, cfg.map_eaves_m) if auto else None
        class_ids = map_classes(self.has_openings)
        self.class_on = np.zeros(NUM_CLASSES, dtype=bool)
        self.class_on[list(class_ids)] = True
        self.layout = MapLayout.of(model)  # where the buildings and the ground lie, for the reach's checks

    # ------------------------------------------------------------------ public
    def localize(
        self,
        camera: Camera,
        prior_local: Pose,
        semantic: np.ndarray,
        depth: np.ndarray | None = None,
        config: LocalizerConfig | None = None,
        prior_uncertainty: PriorUncertainty | None = None,
    ) -> LocalizationResult:
        """Estimate the pose of one query.

        Args:
            camera: intrinsics of the query image (any resolution; masks are resampled to the search's).
            prior_local: prior cam_from_world pose in the model's LOCAL frame (a world/CRS pose comes in
                through ``model.pose_to_local``). The result's poses are in the local frame too.
            semantic: (H, W) class ids (``SemanticClass``), 255 = ignore. Same aspect as ``camera``.
            depth: optional (H', W') relative depth (any positive scale and shift), NaN/inf/<=0 = invalid;
                same aspect as ``semantic``.
            prior_uncertainty: how far the prior may be off (1 sigma); default ``config.prior_uncertainty``
                (DJI single-point GNSS + gimbal IMU). The cascade searches ``n_sigma`` of it.
        """
        cfg = self.config if config is None else config_or_preset(config)
        unc = prior_uncertainty if prior_uncertainty is not None else cfg.prior_uncertainty
        if not isinstance(unc, PriorUncertainty):
            raise ParameterError(f"prior_uncertainty must be a PriorUncertainty, got {type(unc).__name__}")
        t0 = time.perf_counter()
        check_query_inputs(camera, prior_local, semantic, depth)
        query = Query.from_arrays(semantic, None if cfg.no_depth else depth, self.has_openings)
        prior_state = prior_local.to_xyz_rpy()

        result = LocalizationResult(status=NOT_LOCALIZED)
        fine_camera = self.fine_camera(camera, cfg)
        level = cfg.cascade.sweep if cfg.search == "cascade" else cfg.coarse
        check_mask_pixels(np.shape(semantic), level.width, level.height)
        warning = coarse_mask_warning(np.shape(semantic), fine_camera.width, fine_camera.height)
        if warning is not None:
            result.warnings.append(warning)
        depth, warning = usable_depth(query.depth)  # noise blocks dropped; unusable depth: semantics alone
        if warning is not None:
            query = Query(query.labels, depth)
            result.warnings.append(warning)
        result.counts = {"coarse_hypotheses": 0, "refine_evaluations": 0}
        result.search = {"search": cfg.search, "prior_uncertainty": unc.as_dict()}
        building_fraction = query.building_fraction()
        if building_fraction < cfg.min_building_fraction:
            return result.finish(REASON_NO_BUILDINGS_IN_QUERY, t0)
        problem = self.layout.prior_problem(camera, prior_local, cfg, unc)
        if problem is not None:
            return result.finish(problem, t0)
        if not self.layout.buildings_in_reach(camera, prior_local, cfg, unc):
            if (far := self.layout.distance_warning(prior_local)) is not None:
                result.warnings.append(far)
            return result.finish(REASON_NO_GEOMETRY, t0)
        if cfg.search == "grid":
            levels = self._localize_grid(result, camera, query, prior_state, cfg)
        else:
            levels = self._localize_cascade(result, camera, query, prior_state, cfg, unc)
        fine = levels[-1]
        if result.reason is not None:
            return result.finish(result.reason, t0)

        found = _Found(camera, levels, prior_state, building_fraction, len(result.warnings))
        accepted, reason, seen_depth_m = self._decide(
            result, camera, fine, prior_state, cfg, unc, building_fraction
        )
        if not accepted and "sweep_best" in result.search and cfg.cascade.beyond.enabled:
            t_beyond = time.perf_counter()
            self._look_beyond(result, camera, query, prior_state, cfg, unc)
            result.timings["beyond_s"] = time.perf_counter() - t_beyond
        min_margin = cfg.cascade.lookalike.min_margin
        if accepted and result.confidence.get("lookalike_margin", math.nan) < min_margin:
            accepted = False
            reason = f"{REASON_AMBIGUOUS}: {ambiguous_reason(result.search['lookalike'], min_margin)}"
        if not accepted:
            result.rejected_pose_local = result.pose_local
            result.pose_local = None
            return result.finish(reason, t0)
        result.status = LOCALIZED
        conflict = prior_conflict_warning(result.pose_local, prior_state, unc)
        if conflict is not None:
            result.warnings.append(conflict)
        if cfg.focal_check.enabled and not cfg.no_refine:
            if is_oblique(result.pose_local):
                self._check_focal(result, found, seen_depth_m, cfg, unc)
            else:  # seen from above, focal length and height are one unknown: not checked, and said so
                result.search["focal_check"] = nadir_record(result.pose_local)
                if cfg.focal_check.correct:  # asked to re-find poses with the focal length the view fits
                    result.warnings.append(nadir_warning(result.search["focal_check"]))
        return result.finish(None, t0)

    # ------------------------------------------------------------------ searches
    # Each search fills ``result`` and returns its scoring levels (camera and query at the refinement's
    # resolutions, the fine one last), which the acceptance and the focal check reuse.
    def _localize_grid(self, result, camera, query, prior_state, cfg) -> list[ScoringLevel]:
        """The first design: one 4D grid (optionally re-centred by a pre-stage), one particle filter."""
        c = cfg.coarse
        coarse_cam = _scaled(camera, c.width)
        fine_cam = self.fine_camera(camera, cfg)
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
                pre_cam = _scaled(camera, pre.width)
                q_pre, _ = query.at(pre_cam.width, pre_cam.height)
                pre_volume = coarse_search(self.scene, pre_cam, prior_state, q_pre, self.class_on, pre)
                centre = pre_volume.xyz_rpy(pre_volume.best_indices(1)[0])
                n_pre = int(pre_volume.scores.size)
            volume = coarse_search(self.scene, coarse_cam, centre, q_coarse, self.class_on, c)
            top = volume.best_indices(c.top_k)
            seeds = np.stack([volume.xyz_rpy(i) for i in top])
            result.cost_volume = volume
            result.coarse_pose_local = Pose.from_state(seeds[0])
            result.counts["coarse_hypotheses"] = int(volume.scores.size) + n_pre
            result.confidence["score_margin"] = volume.score_margin()
            result.timings["coarse_s"] = time.perf_counter() - t_prep
        levels = [ScoringLevel(coarse_cam, q_coarse, d_coarse), ScoringLevel(fine_cam, q_fine, d_fine)]
        if not cfg.no_coarse:
            levels, _ = self._drop_inverted_depth(result, levels, result.coarse_pose_local)
        self._refiner().refine(result, levels, seeds, cfg, initial_sigma(cfg.refine, 0.3))
        return levels

    def _localize_cascade(self, result, camera, query, prior_state, cfg, unc) -> list[ScoringLevel]:
        """The default: sweep, local grids with roll/pitch, one particle filter over the best distinct
        hypotheses, a polish."""
        cc = cfg.cascade
        local_cam = _scaled(camera, cc.local.width, cc.local.height)
        fine_cam = self.fine_camera(camera, cfg)
        q_local, d_local = query.at(local_cam.width, local_cam.height)
        q_fine, d_fine = query.at(fine_cam.width, fine_cam.height)
        levels = [ScoringLevel(local_cam, q_local, d_local), ScoringLevel(fine_cam, q_fine, d_fine)]
        sigma = initial_sigma(cfg.refine, unc.roll_pitch_deg)
        prior = prior_term(prior_state, cfg, unc)
        refiner = self._refiner()
        t_prep = time.perf_counter()
        if cfg.no_coarse:
            result.timings["coarse_s"] = 0.0
            refiner.refine(result, levels, prior_state[None, :], cfg, sigma, prior_term=prior)
            return levels
        volume = search_volume(prior_state, unc, cc, self.layout.ground_below(prior_state, unc, cfg))
        sweep_cam = _scaled(camera, cc.sweep.width, cc.sweep.height)
        q_sweep, _ = query.at(sweep_cam.width, sweep_cam.height)
        sw = sweep(self.scene, sweep_cam, volume, q_sweep, self.class_on, cc.sweep)
        result.search.update(
            volume=volume.as_dict(),
            sweep_step=sw.step.tolist(),
            extensions=sw.extensions,
            at_edge=sw.at_edge,
        )
        result.confidence["score_margin"] = sw.score_margin()
        result.search["sweep_best"] = float(np.max(sw.scores))
        result.cost_volume = sw.cost_volume()
        result.coarse_pose_local = Pose.from_state(sw.state(sw.best()))
        if sw.at_edge:
            result.counts["coarse_hypotheses"] = sw.hypotheses
            result.timings["coarse_s"] = time.perf_counter() - t_prep
            result.rejected_pose_local = result.coarse_pose_local
            result.reason = REASON_AT_EDGE
            result.search["edge_sigma"] = edge_sigma(sw.at_edge, volume, cc)
            result.warnings.append(edge_warning(sw.at_edge, volume, cc))
            return levels
        seeds = [sw.state(c) for c in sw.top_distinct(cc.sweep.keep, cc.sweep.nms_radius)]
        hyps = local_search(
            self.scene, local_cam, seeds, sw.step, unc.roll_pitch_deg, q_local, self.class_on, cc.local
        )
        result.coarse_pose_local = Pose.from_state(hyps.states[0])
        levels, seen = self._drop_inverted_depth(result, levels, result.coarse_pose_local)
        result.counts["coarse_hypotheses"] = sw.hypotheses + hyps.evaluated
        result.timings["coarse_s"] = time.perf_counter() - t_prep
        result.hypotheses = [
            {"state": st.tolist(), "local_score": float(sc)}
            for st, sc in zip(hyps.states, hyps.scores, strict=True)
        ]
        result.confidence["hypothesis_margin"] = (
            float(hyps.scores[0] - hyps.scores[1]) if len(hyps.scores) > 1 else float("nan")
        )
        refiner.refine(result, levels, hyps.states, cfg, sigma, prior_term=prior, seed_depth=seen)
        if self.flat_eaves_scene is not None and cfg.map_eaves_flat_roofs == "auto" and not cfg.no_refine:
            refiner.look_with_flat_eaves(
                self.flat_eaves_scene, result, levels, hyps.states, cfg, sigma, prior
            )
        if not cfg.no_refine:
            self._settle_roll_pitch_conflict(result, levels, hyps.states, prior_state, cfg, unc)
        if cc.lookalike.enabled and not cfg.no_refine:
            self._look_for_lookalike(result, sw, levels, q_local, unc, cfg, sigma, prior)
        return levels

    def _settle_roll_pitch_conflict(self, result, levels, seeds, prior_state, cfg, unc) -> None:
        """A found roll/pitch that departs from the prior's by more than ``roll_pitch_conflict_sigma``
        sigmas (``prior.roll_pitch_conflict``): the IMU is worse than stated, and its penalty may have
        pulled the pose onto a tilt-for-shift compromise. The refinement runs again from the found pose and
        ``seeds`` with the roll/pitch sigma widened (``prior.roll_pitch_wide_sigma``) on the map the pose
        was found on; the pose whose image score (``refine_stage.image_score``: the same score without the
        prior's term) is higher is kept, or with ``roll_pitch_conflict_refuse`` the result is refused when
        the two lie farther apart than the acceptance tolerates. A departure the stated IMU itself gives now
        and then asks more of the second pose's gain (``prior.roll_pitch_take_gain``). A warning names the
        departure; recorded in ``result.search["roll_pitch_conflict"]``. Runs only on a conflict."""
        state = result.pose_local.to_xyz_rpy()
        if not roll_pitch_conflict(state, prior_state, unc, cfg.roll_pitch_conflict_sigma):
            return
        t0 = time.perf_counter()
        departure = roll_pitch_departure(state, prior_state)
        wide = roll_pitch_wide_sigma(departure, unc)
        wide_unc = replace(unc, roll_pitch_deg=wide)
        trial = (
            self.map_of(result)
            ._refiner()
            .refine_again(
                result,
                levels,
                seeds,
                cfg,
                initial_sigma(cfg.refine, wide),
                prior_term(prior_state, cfg, wide_unc),
            )
        )
        with_depth = levels[-1].depth is not None
        gain = image_score(trial, cfg, with_depth) - image_score(result, cfg, with_depth)
        moved = state_difference(trial.pose_local.to_xyz_rpy(), state)
        moved_m, moved_deg = float(np.linalg.norm(moved[:3])), float(np.max(np.abs(moved[3:])))
        apart = moved_m > ROLL_PITCH_APART_M or moved_deg > ROLL_PITCH_APART_DEG
        needed = roll_pitch_take_gain(departure, unc, cfg.roll_pitch_sure_sigma, cfg.roll_pitch_unsure_gain)
        look = {
            "departure_deg": departure,
            "sigmas": departure / unc.roll_pitch_deg,
            "wide_sigma_deg": wide,
            "gain": gain,
            "gain_needed": needed,
            "moved_m": moved_m,
            "moved_deg": moved_deg,
            "taken": bool(gain > needed),
            "refused": bool(apart and cfg.roll_pitch_conflict_refuse),
            "first_xyz_rpy_local": state.tolist(),  # both poses, whichever is kept: a take rule can be
            "second_xyz_rpy_local": trial.pose_local.to_xyz_rpy().tolist(),  # judged on the same runs
        }
        result.search["roll_pitch_conflict"] = look
        if look["taken"]:
            adopt(result, trial)
        look["final_departure_deg"] = roll_pitch_departure(result.pose_local.to_xyz_rpy(), prior_state)
        widened = f"refined again with its sigma widened to {wide:.1f} deg, "
        moved_by = f"the pose moved {moved_m:.1f} m / {moved_deg:.1f} deg"
        if look["refused"]:
            outcome = f"{widened}{moved_by}: more than the acceptance tolerates, so it is refused"
            result.rejected_pose_local = result.pose_local
            result.reason = REASON_ROLL_PITCH_CONFLICT
        elif look["taken"]:
            now = look["final_departure_deg"]
            outcome = f"{widened}{moved_by} and fits the image better (now {now:.1f} deg from the prior's)"
        elif gain > 0.0:
            outcome = (
                f"{widened}its pose, {moved_m:.1f} m / {moved_deg:.1f} deg away, fits the image only "
                f"{gain:.4f} better, less than the {needed:g} a departure within "
                f"{cfg.roll_pitch_sure_sigma:g} sigma asks: the first pose is kept"
            )
        else:
            outcome = f"{widened}the first pose fits the image best"
        result.warnings.append(roll_pitch_conflict_warning(departure, unc, outcome))
        result.timings["roll_pitch_conflict_s"] = time.perf_counter() - t0

    def _look_for_lookalike(
        self, result, sw, levels, q_local, unc, cfg: LocalizerConfig, sigma, prior
    ) -> None:
        """The look-alike margin (``lookalike.py``): the sweep's best other peak, more than
        ``LookalikeConfig.min_distance_m`` from the pose found, through one local grid and a small
        refinement on the map the pose was found on; ``result.confidence["lookalike_margin"]`` is the pose's
        final score minus that one's (NaN: none, or it came back within 5 m / 5 deg of the pose), its pose in
        ``result.search["lookalike"]``. ``localize`` refuses an accepted pose below ``min_margin``."""
        t0 = time.perf_counter()
        look = cfg.cascade.lookalike
        found = result.pose_local.to_xyz_rpy()
        result.confidence["lookalike_margin"] = float("nan")
        seed = distant_peak(sw, found, look.min_distance_m)
        if seed is not None:
            local = replace(cfg.cascade.local, keep=1)
            camera, rp = levels[0].camera, unc.roll_pitch_deg
            hyps = local_search(self.scene, camera, [seed], sw.step, rp, q_local, self.class_on, local)
            refiner = self.map_of(result)._refiner()
            moved = found.copy()  # the pose found, moved to the look-alike's place: its tilt, height, yaw
            moved[:2] = hyps.states[0, :2]
            result.search["lookalike_seed_xy"] = moved[:2].tolist()  # the place (``_lookalike_again``)
            refined = refiner.refine_lookalike(levels, moved, cfg, sigma, prior)
            result.counts["coarse_hypotheses"] += hyps.evaluated
            result.counts["refine_evaluations"] += refined.evaluations
            if is_distinct(refined.xyz_rpy, found, look.min_distance_m, look.min_rotation_deg):
                other = lookalike_of(found, result.score, refined.xyz_rpy, refined.score)
                result.confidence["lookalike_margin"] = other.margin
                result.search["lookalike"] = other.as_dict()
        result.timings["lookalike_s"] = time.perf_counter() - t0

    def _drop_inverted_depth(
        self, result: LocalizationResult, levels: list[ScoringLevel], pose_local: Pose
    ) -> tuple[list[ScoringLevel], np.ndarray | None]:
        """Depth that runs against the map (a disparity map) is dropped from every level, and said so:
        judged at the first level against the map rendered at ``pose_local`` (the search's best
        hypothesis). Returns the levels and that render's depth (None when the query has no depth)."""
        level = levels[0]
        if level.depth is None:
            return levels, None
        seen = self._render_one(level.camera, pose_local, depth=True).depth
        warning = inverted_depth_warning(depth_rank_correlation(level.depth, seen))
        if warning is not None:
            result.warnings.append(warning)
            levels = [ScoringLevel(lv.camera, lv.labels, None) for lv in levels]
        return levels, seen

    # ------------------------------------------------------------------ refinement
    def _refiner(self) -> Refiner:
        """The refinement stage on this localizer's map (``refine_stage.py``)."""
        return Refiner(self.scene, self.class_on, self.confidence_kind)

    # ------------------------------------------------------------------ acceptance
    def _decide(
        self,
        result: LocalizationResult,
        camera: Camera,
        fine: ScoringLevel,
        prior_state: np.ndarray,
        cfg: LocalizerConfig,
        unc: PriorUncertainty,
        building_fraction: float,
    ) -> tuple[bool, str, float]:
        """Is the found pose accepted, the reason if not, and the median depth of the map seen from it at
        the fine level (its render here; the focal check's camera move)? The evidence goes into
        ``result.confidence`` and ``result.warnings`` first: the map at the pose against the query
        (``agreement.py``), the query's building share, the distance from the prior. Then the calibrated
        probability is held against ``min_confidence`` (at least ``min_confidence_close_view`` for a close
        view), or with ``acceptance="thresholds"`` the scores against the first design's gates
        (``_accept``)."""
        found_2d, found_depth = self.map_of(result).render_labels_and_depth(fine.camera, result.pose_local)
        query_2d = fine.labels.reshape(fine.camera.height, fine.camera.width)
        agreement = building_agreement(query_2d, found_2d)
        result.confidence["building_iou"] = agreement.building_iou
        result.confidence["unmapped_building_share"] = agreement.unmapped_share
        result.confidence["unseen_building_share"] = agreement.unseen_share
        result.warnings.extend(agreement.warnings())
        result.confidence["boundary_distance_px"] = boundary_distance_px(query_2d, found_2d)
        with_depth = fine.depth is not None
        if with_depth:
            result.confidence["depth_cost_agreed"] = agreed_depth_cost(
                fine.labels, fine.depth, found_2d, found_depth, cfg.refine.depth_cap
            )
        result.confidence["building_fraction"] = building_fraction
        result.confidence["prior_distance"] = prior_distance(result.pose_local, prior_state, unc)
        if cfg.acceptance != "calibrated":
            return self._accept(result, cfg, with_depth), REASON_LOW_SCORE, median_seen_depth(found_depth)
        p = confidence_model(self.confidence_kind, with_depth).probability(result)
        result.confidence["probability"] = p
        seen = found_depth[np.isfinite(found_depth)]
        span = view_span_m(camera.hfov_deg, float(np.mean(seen)) if seen.size else 0.0)
        result.confidence["view_span_m"] = span
        needed = cfg.min_confidence
        if is_close_view(span):
            needed = max(needed, cfg.min_confidence_close_view)
        result.confidence["min_probability"] = needed  # what this result was accepted or refused at
        for warning in (field_of_view_warning(camera.hfov_deg), close_view_warning(span, needed)):
            if warning is not None:
                result.warnings.append(warning)
        return p >= needed, REASON_LOW_CONFIDENCE, median_seen_depth(found_depth)

    @staticmethod
    def _accept(result: LocalizationResult, cfg: LocalizerConfig, with_depth: bool) -> bool:
        """Is the evidence for the final pose strong enough (see ``LocalizerConfig`` thresholds)?"""
        if result.confidence["building_iou"] < cfg.min_building_iou:
            return False
        if with_depth:
            return result.semantic >= cfg.min_semantic_with_depth and result.depth_cost <= cfg.max_depth_cost
        return result.semantic >= cfg.min_score

    def _check_focal(self, result, found: _Found, seen_depth_m: float, cfg: LocalizerConfig, unc) -> None:
        """An accepted oblique pose's focal-length check (``focal_check.py``) on the map it was found on:
        recorded in ``result.search["focal_check"]``, a warning when the view fits a focal scale more than
        ``FocalCheckConfig.margin`` from 1; then, with ``FocalCheckConfig.correct``, the pose found again
        with that focal scale (``_correct_focal``)."""
        t0 = time.perf_counter()
        term = prior_term(found.prior_state, cfg, unc) if cfg.search == "cascade" else None
        state = result.pose_local.to_xyz_rpy()
        check = check_focal(
            self.map_of(result).scene,
            self.class_on,
            found.levels[-1],
            state,
            seen_depth_m,
            cfg.focal_check,
            cfg.refine,
            term,
            cfg.seed,
        )
        if check is not None:
            result.search["focal_check"] = check.as_dict()
        warning = focal_warning(check, cfg.focal_check.margin)
        correct = warning is not None and cfg.focal_check.correct
        if correct and self._correct_focal(result, found, check, cfg, unc):
            warning = corrected_warning(check, result.search["focal_check"]["correction"]["scale"])
        if warning is not None:
            result.warnings.append(warning)
        result.timings["focal_check_s"] = time.perf_counter() - t0

    def _correct_focal(self, result, found: _Found, check: FocalCheck, cfg: LocalizerConfig, unc) -> bool:
        """Where the focal check fires: the refinement once more with every level's focal lengths times
        ``focal_check.correction_scale`` (the check's vertex), seeded at the pose found moved back along its
        axis by ``d (s - 1)`` (``focal_check.moved_back``); the acceptance (``_decide``) judges that pose
        with the scaled camera, as any other. Kept (True) when accepted and its image score
        (``refine_stage.image_score``) is higher; recorded in ``result.search["focal_check"]
        ["correction"]``. With look-alikes on (``LookalikeConfig``) its look-alike margin is found again
        with the scaled camera (``_lookalike_again``): below ``min_margin`` the pose is not kept
        (``correction["ambiguous"]`` says where the look-alike lies); kept, the margin is the result's
        ``lookalike_margin`` and its look-alike ``search["lookalike"]`` (the first pose's in
        ``correction["first_lookalike"]``)."""
        s = correction_scale(check, cfg.focal_check)
        levels = [ScoringLevel(with_focal_scale(lv.camera, s), lv.labels, lv.depth) for lv in found.levels]
        first = result.pose_local.to_xyz_rpy()
        seed = moved_back(first, check.depth_m, s)
        rp = unc.roll_pitch_deg if cfg.search == "cascade" else 0.3
        term = prior_term(found.prior_state, cfg, unc) if cfg.search == "cascade" else None
        refined = LocalizationResult(status=NOT_LOCALIZED, counts={"refine_evaluations": 0})
        self.map_of(result)._refiner().refine(
            refined, levels, seed[None], cfg, initial_sigma(cfg.refine, rp), prior_term=term
        )
        result.counts["refine_evaluations"] += refined.counts["refine_evaluations"]
        # The trial: this result with the re-found pose, judged from the evidence before the acceptance.
        trial = copy.copy(result)
        trial.confidence, trial.warnings = dict(result.confidence), result.warnings[: found.warnings_before]
        adopt(trial, refined)
        accepted, _, _ = self._decide(
            trial, with_focal_scale(found.camera, s), levels[-1], found.prior_state, cfg, unc, found.building
        )
        with_depth = levels[-1].depth is not None
        gain = image_score(trial, cfg, with_depth) - image_score(result, cfg, with_depth)
        moved = state_difference(trial.pose_local.to_xyz_rpy(), first)
        correction = {
            "scale": s,
            "gain": gain,
            "accepted": bool(accepted),
            "taken": bool(accepted and gain > 0.0),
            "moved_m": float(np.linalg.norm(moved[:3])),
            "first_state": first.tolist(),
        }
        result.search["focal_check"]["correction"] = correction
        looked = "lookalike_margin" in result.confidence  # look-alikes on: the margin again, same camera
        other: Lookalike | None = None
        if correction["taken"] and looked:
            other = self._lookalike_again(result, trial, levels, cfg, unc, found.prior_state)
            margin = other.margin if other is not None else math.nan
            trial.confidence["lookalike_margin"] = margin
            correction["lookalike_margin"] = margin
            if margin < cfg.cascade.lookalike.min_margin:  # ambiguous with the scaled camera: not taken
                correction["taken"] = False
                correction["ambiguous"] = ambiguous_reason(other.as_dict(), cfg.cascade.lookalike.min_margin)
        if not correction["taken"]:
            return False
        conflict = prior_conflict_warning(trial.pose_local, found.prior_state, unc)
        if conflict is not None:
            trial.warnings.append(conflict)
        adopt(result, trial)  # its pose and evidence; then the acceptance's judgement of it
        result.confidence, result.warnings = trial.confidence, trial.warnings
        if looked:  # the look-alike of the pose kept, the first pose's beside the correction
            if "lookalike" in result.search:
                correction["first_lookalike"] = result.search.pop("lookalike")
            if other is not None:
                result.search["lookalike"] = other.as_dict()
        return True

    def _lookalike_again(
        self, result, trial, levels, cfg: LocalizerConfig, unc, prior_state
    ) -> Lookalike | None:
        """The look-alike margin of the pose the focal correction re-found (``trial``), with the camera it
        was re-found with (``levels``: the focal lengths times the correction's scale): the look-alike's
        refinement (``Refiner.refine_lookalike``, same prior term) again, from ``trial``'s pose moved to
        the place the first look found (``search["lookalike_seed_xy"]``), as ``_look_for_lookalike`` does
        from the first pose. None when the first look found no place (the sweep that finds one is not run
        again) or the refined pose lies within 5 m / 5 deg of ``trial``'s (no look-alike). Both scores
        with one camera: the margin compares like with like."""
        seed_xy = result.search.get("lookalike_seed_xy")
        if seed_xy is None:
            return None
        look = cfg.cascade.lookalike
        state = trial.pose_local.to_xyz_rpy()
        moved = state.copy()
        moved[:2] = seed_xy
        sigma = initial_sigma(cfg.refine, unc.roll_pitch_deg)
        term = prior_term(prior_state, cfg, unc)
        refined = self.map_of(result)._refiner().refine_lookalike(levels, moved, cfg, sigma, term)
        result.counts["refine_evaluations"] += refined.evaluations
        if not is_distinct(refined.xyz_rpy, state, look.min_distance_m, look.min_rotation_deg):
            return None
        return lookalike_of(state, trial.score, refined.xyz_rpy, refined.score)

    # ------------------------------------------------------------------ refused poses: a look beyond
    def ring_beyond(
        self, camera: Camera, query: Query, prior_state: np.ndarray, found_xy, cfg: LocalizerConfig, unc
    ) -> tuple[Beyond | None, SearchVolume]:
        """The best view of the ring beyond the cascade's reach (``cascade.look_beyond``) for ``query`` and
        a pose found at ``found_xy`` (local x, y), with the volume it is around. ``_look_beyond`` uses it
        on refused results; ``benchmarks/look_beyond.py`` on any."""
        cc = cfg.cascade
        volume = search_volume(prior_state, unc, cc, self.layout.ground_below(prior_state, unc, cfg))
        sweep_cam = _scaled(camera, cc.sweep.width, cc.sweep.height)
        q_sweep, _ = query.at(sweep_cam.width, sweep_cam.height)
        reach = reached_half(volume, cc)["xy"]
        ring = look_beyond(
            self.scene,
            sweep_cam,
            volume,
            reach,
            np.asarray(found_xy),
            q_sweep,
            self.class_on,
            cc.sweep,
            cc.beyond,
        )
        return ring, volume

    def _look_beyond(self, result, camera, query, prior_state, cfg: LocalizerConfig, unc) -> None:
        """For a refused result: does a view beyond the search's reach, distinct from the refused pose,
        score higher than the sweep's best (``ring_beyond``)? Recorded in ``result.search["beyond"]``; if
        so, a warning names the prior uncertainty that would search there (``errors.parameter``). A hint,
        not a verdict: a prior further off than stated does this, and so does a view whose map differs from
        the world (Berlin seed 0: one of its three such refusals had a wrong prior)."""
        cc = cfg.cascade
        ring, volume = self.ring_beyond(
            camera, query, prior_state, result.pose_local.to_xyz_rpy()[:2], cfg, unc
        )
        reach = reached_half(volume, cc)["xy"]
        if ring is None:
            return
        sweep_best = result.search["sweep_best"]
        higher = ring.score >= sweep_best + cc.beyond.margin
        result.search["beyond"] = {**ring.as_dict(), "hypotheses": ring.hypotheses, "higher": bool(higher)}
        if higher:
            sigma = edge_sigma(["x+"], volume, cc)
            result.search["beyond"]["sigma"] = sigma
            result.warnings.append(
                f"{BEYOND_WARNING}: a view {ring.offset_xy_m:.0f} m from the prior, beyond the searched "
                f"+-{reach:.0f} m, scores {ring.score:.2f} against the best inside's {sweep_best:.2f}; if "
                "the prior may be further off than its stated uncertainty, run again with "
                f"{parameter('prior_sigma', 'xy=' + str(sigma['xy']))} (a map that differs from the world in "
                "view can do the same)"
            )

    # ------------------------------------------------------------------ diagnostics
    def score_poses(
        self,
        camera: Camera,
        semantic: np.ndarray,
        depth: np.ndarray | None,
        poses_local: list[Pose],
        prior_local: Pose | None = None,
        config: LocalizerConfig | None = None,
        prior_uncertainty: PriorUncertainty | None = None,
    ) -> dict[str, np.ndarray]:
        """The refinement's own scores of given poses (local frame), at its final resolution: ``semantic``
        (C_s), ``depth_cost`` (C_d) and ``score`` (what the particle filter maximises; with ``prior_local``
        including the prior's roll/pitch term). Tells a failure of the search (the true pose scores higher
        than the estimate) from one of the score (it scores lower): ``benchmarks/score_at_truth.py``."""
        cfg = self.config if config is None else config_or_preset(config)
        unc = prior_uncertainty if prior_uncertainty is not None else cfg.prior_uncertainty
        if not poses_local:
            raise ParameterError("score_poses needs at least one pose")
        check_query_inputs(camera, poses_local[0] if prior_local is None else prior_local, semantic, depth)
        query = Query.from_arrays(semantic, None if cfg.no_depth else depth, self.has_openings)
        query = Query(query.labels, usable_depth(query.depth)[0])
        fine_cam = self.fine_camera(camera, cfg)
        level = ScoringLevel(fine_cam, *query.at(fine_cam.width, fine_cam.height))
        states = np.stack([p.to_xyz_rpy() for p in poses_local])
        with_prior = prior_local is not None and cfg.search == "cascade"  # the grid search has no prior term
        prior = prior_term(prior_local.to_xyz_rpy(), cfg, unc) if with_prior else None
        score, sem, dep = score_states(self.scene, level, states, self.class_on, cfg.refine, prior)
        return {"semantic": sem, "depth_cost": dep, "score": score}

    def _with_scene(self, scene: RenderScene) -> Localizer:
        """This localizer searching ``scene`` instead (a shallow copy: the rest is shared)."""
        other = copy.copy(self)
        other.scene, other.flat_eaves_scene = scene, None
        return other

    def map_of(self, result: LocalizationResult) -> Localizer:
        """The localizer whose map ``result``'s pose was found on: this one, or the one with eaves on the
        flat roofs too where ``map_eaves_flat_roofs="auto"`` took that map (``Refiner.look_with_flat_eaves``).
        Its ``render_labels`` draw the map the result was scored on."""
        if result.search.get("flat_roof_eaves", {}).get("used") and self.flat_eaves_scene is not None:
            return self._with_scene(self.flat_eaves_scene)
        return self

    def fine_camera(self, camera: Camera, config: LocalizerConfig | None = None) -> Camera:
        """``camera`` at the refinement's final resolution: where the final scores, the building IoU and
        the outdated-map warnings of a result are computed."""
        cfg = self.config if config is None else config_or_preset(config)
        if cfg.search == "cascade":
            return _scaled(camera, cfg.cascade.local.width, cfg.cascade.local.height).scale(cfg.refine.scale)
        return _scaled(camera, cfg.coarse.width).scale(cfg.refine.scale)

    def render_labels(self, camera: Camera, pose_local: Pose) -> np.ndarray:
        """(H, W) class ids of the map as this localizer searches it (``localizer_scene``: with its eaves)
        seen by ``camera`` at ``pose_local`` (model's local frame)."""
        return self._render_one(camera, pose_local).labels.reshape(camera.height, camera.width)

    def render_labels_and_depth(self, camera: Camera, pose_local: Pose) -> tuple[np.ndarray, np.ndarray]:
        """``render_labels`` and the map's z-depth there, (H, W) float32, +inf where nothing is hit: what the
        acceptance's map agreement and agreed depth cost compare the query with."""
        out = self._render_one(camera, pose_local, depth=True)
        shape = (camera.height, camera.width)
        return out.labels.reshape(shape), out.depth.reshape(shape)

    # ------------------------------------------------------------------ helpers
    def _render_one(self, camera: Camera, pose_local: Pose, depth: bool = False):
        """One view of the scene (a ``RenderOutput`` of batch 1): for the few single renders of a search."""
        return NumbaEngine(self.scene).render(camera, pose_local.R[None], pose_local.t[None], depth=depth)


def _scaled(camera: Camera, width: int, height: int | None = None) -> Camera:
    """``camera`` at about ``width`` x ``height`` pixels in all, in its own aspect: a cascade level's size
    (given for 4:3, where it is exact) is a pixel budget, so a 16:9 or a portrait image is scored on as
    many pixels as the 4:3 views the search was tuned on, not on a thinner or a taller strip. Without
    ``height``: ``width`` pixels across, the height following the aspect (the first design's grid, kept
    as it was)."""
    aspect = camera.width / camera.height
    w = width if height is None else max(1, round(math.sqrt(width * height * aspect)))
    return camera.scaled(w, max(1, round(w / aspect)))


def localize(
    city: CityModel,
    camera: Camera,
    prior_local: Pose,
    semantic: np.ndarray,
    depth: np.ndarray | None = None,
    config: LocalizerConfig | str | None = None,
    prior_uncertainty: PriorUncertainty | None = None,
) -> LocalizationResult:
    """One-shot ``Localizer(city, config).localize(...)``; ``config`` may be a preset name. Poses in and
    out are in ``city``'s local frame (``city.pose_to_local`` / ``city.pose_to_world`` at the boundary)."""
    localizer = Localizer(city, config_or_preset(config))
    return localizer.localize(camera, prior_local, semantic, depth, prior_uncertainty=prior_uncertainty)
