"""The localizer's refinement stage: from the search's hypotheses to the refined pose, its scores and its
covariance on a ``LocalizationResult``.

Why apart from ``refine.py``: that is the particle filter, one run from seeds on one scene. The stage around
it decides how it runs and what the result keeps: the filter over the search's best distinct hypotheses
(cascade) or best grid cells (grid), its rotations about a pivot on the optical axis (``RefineConfig.pivot``,
``refine.pivot_jacobian``), then its polish, a narrow filter from its best particle; with ``restarts`` the
best final score of several such runs; the score's curvature at the final pose, which a fitted model turns
into a covariance (``covariance.py``); ``no_refine`` keeps the first seed, scored at the fine level. With
``map_eaves_flat_roofs="auto"`` a second look runs the same refinement on the map with eaves on its flat
roofs too (``map_scenes.flat_eaves_scene``) and takes its pose where that map fits the view better.

Random draws: restart ``r``'s filter draws from ``[seed, 2, r]`` (restart 0 from ``seed`` itself) and its
polish from ``[seed, 1, r]``; the second look draws the same numbers on the other map.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.covariance import (
    PROBES,
    covariance_model,
    probe_states,
    probe_steps,
    score_curvature,
)
from semcityloc.localization.refine import (
    PriorTerm,
    RefineResult,
    ScoringLevel,
    particle_filter,
    pivot_jacobian,
    score_states,
)
from semcityloc.localization.result import NOT_LOCALIZED, LocalizationResult
from semcityloc.render.raster_numba import NumbaEngine
from semcityloc.render.scene import RenderScene


@dataclass(frozen=True)
class Refiner:
    """The refinement on one map: ``scene`` scored over the classes of ``class_on``; ``kind`` names the
    fitted covariance model that applies (``Localizer.confidence_kind``)."""

    scene: RenderScene
    class_on: np.ndarray
    kind: str

    def refine(
        self,
        result: LocalizationResult,
        levels: list[ScoringLevel],
        seeds: np.ndarray,
        cfg: LocalizerConfig,
        sigma: np.ndarray,
        prior_term: PriorTerm | None = None,
        seed_depth: np.ndarray | None = None,
    ) -> None:
        """One particle filter seeded by ``seeds`` ((k, 6), best first), its polish, the covariance's probe;
        ``no_refine`` keeps the first seed, scored at the fine resolution. ``seed_depth``: the map's depth
        seen from the first seed at ``levels[0]``, when the caller rendered it already (the pivot reuses
        it). Fills ``result``'s pose, scores, spread, covariance, evaluations and ``refine_s``."""
        t0 = time.perf_counter()
        fine = levels[-1]
        if cfg.no_refine:
            final = seeds[0]
            score, sem, dep = score_states(
                self.scene, fine, final[None], self.class_on, cfg.refine, prior_term
            )
            result.score, result.semantic, result.depth_cost = float(score[0]), float(sem[0]), float(dep[0])
        else:
            if cfg.refine.pivot == "both":  # the same first seed for every restart: one pivot render
                sigma = self._about_pivot(levels[0].camera, seeds[0], sigma, seed_depth)
            restarts = range(cfg.refine.restarts)
            runs = [self._filter_and_polish(levels, seeds, cfg, sigma, prior_term, r) for r in restarts]
            best = max(runs, key=lambda run: run.score)
            best.evaluations = sum(run.evaluations for run in runs)
            final = best.xyz_rpy
            result.counts["refine_evaluations"] += best.evaluations
            result.score, result.semantic, result.depth_cost = best.score, best.semantic, best.depth_cost
            result.confidence.update(spread_m=best.spread_m, spread_deg=best.spread_deg)
            # The covariance's probe, where a fitted model will turn its curvature into one.
            cov_model = covariance_model(self.kind, fine.depth is not None, fine.camera.hfov_deg)
            if cfg.refine.covariance_probe_px > 0 and cov_model is not None:
                result.score_curvature = self._probe_curvature(levels, final, cfg, prior_term)
                result.counts["refine_evaluations"] += PROBES
                if result.score_curvature is not None:
                    result.covariance = cov_model.covariance(result.score_curvature)
        result.pose_local = Pose.from_state(final)
        result.timings["refine_s"] = time.perf_counter() - t0

    def look_with_flat_eaves(
        self,
        flat_scene: RenderScene,
        result: LocalizationResult,
        levels: list[ScoringLevel],
        seeds: np.ndarray,
        cfg: LocalizerConfig,
        sigma: np.ndarray,
        prior_term: PriorTerm | None,
    ) -> None:
        """``map_eaves_flat_roofs="auto"``: does the view fit ``flat_scene`` (the map with eaves on its flat
        roofs too) better? Where ``result``'s pose (refined on this map) scores higher there by
        ``flat_eaves_gate``, the refinement runs again on that map from the found pose and ``seeds`` (the
        search's hypotheses); its pose replaces the first when its semantic score is higher by
        ``flat_eaves_margin``. Recorded in ``result.search["flat_roof_eaves"]``."""
        t0 = time.perf_counter()
        fine = levels[-1]
        state = result.pose_local.to_xyz_rpy()
        # result.semantic is already this pose's score on the plain map at the fine level (the refinement
        # scores its estimate with score_states there): one render, not two.
        _, flat, _ = score_states(flat_scene, fine, state[None], self.class_on, cfg.refine, prior_term)
        look = {"gain_at_found": float(flat[0] - result.semantic), "used": False}
        result.search["flat_roof_eaves"] = look
        result.counts["refine_evaluations"] += 1
        if look["gain_at_found"] > cfg.flat_eaves_gate:
            trial = replace(self, scene=flat_scene).refine_again(
                result, levels, seeds, cfg, sigma, prior_term
            )
            look["gain"] = float(trial.semantic - result.semantic)
            moved = trial.pose_local.to_xyz_rpy() - state
            look["moved_m"] = float(np.linalg.norm(moved[:3]))
            if look["gain"] > cfg.flat_eaves_margin:
                look["used"] = True
                adopt(result, trial)
        result.timings["flat_eaves_s"] = time.perf_counter() - t0

    def refine_again(
        self,
        result: LocalizationResult,
        levels: list[ScoringLevel],
        seeds: np.ndarray,
        cfg: LocalizerConfig,
        sigma: np.ndarray,
        prior_term: PriorTerm | None,
    ) -> LocalizationResult:
        """The refinement once more, into a result of its own, from ``result``'s pose and ``seeds`` (the
        search's hypotheses) with other perturbation scales and prior (``Localizer`` after a roll/pitch
        conflict, ``prior.roll_pitch_conflict``), or on another map (``look_with_flat_eaves``); its
        evaluations are counted on ``result``."""
        trial = LocalizationResult(status=NOT_LOCALIZED, counts={"refine_evaluations": 0})
        state = result.pose_local.to_xyz_rpy()
        self.refine(trial, levels, np.vstack([state[None], seeds]), cfg, sigma, prior_term=prior_term)
        result.counts["refine_evaluations"] += trial.counts["refine_evaluations"]
        return trial

    def refine_lookalike(
        self,
        levels: list[ScoringLevel],
        moved: np.ndarray,
        cfg: LocalizerConfig,
        sigma: np.ndarray,
        prior_term: PriorTerm | None,
    ) -> RefineResult:
        """The look-alike's own refinement (``lookalike.py``). ``moved``: the pose found moved to the
        look-alike's place (its height, tilt and yaw; the place from the local grid). A look-alike is the
        same view elsewhere, so its place is searched first, on an x/y grid of ``LookalikeConfig.grid`` x
        ``grid`` camera centres ``grid_half_m`` around ``moved`` at the fine level; then a small filter
        (``particles`` x ``iterations``, at the fine level) and the polish from the grid's best, as the
        pose's: its final score is comparable with the pose's ``result.score``."""
        look = cfg.cascade.lookalike
        fine = levels[-1]
        offsets = np.linspace(-look.grid_half_m, look.grid_half_m, look.grid)
        gx, gy = np.meshgrid(offsets, offsets, indexing="ij")
        states = np.repeat(moved[None], gx.size, axis=0)
        states[:, 0] += gx.ravel()
        states[:, 1] += gy.ravel()
        score, _, _ = score_states(self.scene, fine, states, self.class_on, cfg.refine, prior_term)
        best = states[int(np.argmax(score))]
        small = replace(
            cfg,
            refine=replace(
                cfg.refine, particles=look.particles, iterations=look.iterations, low_res_iterations=0
            ),
        )
        if cfg.refine.pivot == "both":
            sigma = self._about_pivot(levels[0].camera, best, sigma)
        refined = self._filter_and_polish(levels, best[None], small, sigma, prior_term, 0)
        refined.evaluations += len(states)
        return refined

    def _filter_and_polish(
        self,
        levels: list[ScoringLevel],
        seeds: np.ndarray,
        cfg: LocalizerConfig,
        sigma: np.ndarray,
        prior_term: PriorTerm | None,
        restart: int,
    ) -> RefineResult:
        """One particle filter over ``seeds`` and its polish; ``restart`` > 0 draws other random numbers
        (restart 0 is the single run of ``restarts=1``: a seed sequence ignores trailing zeros, so
        ``[seed, 1, 0]`` is ``[seed, 1]``)."""
        rng = np.random.default_rng(cfg.seed if restart == 0 else [cfg.seed, 2, restart])
        best = particle_filter(
            self.scene, levels, seeds, self.class_on, cfg.refine, rng, sigma, prior_term=prior_term
        )
        if cfg.refine.polish_iterations == 0:
            return best
        xy, z, rp, yaw = cfg.refine.polish_sigma
        polish_sigma = np.array([xy, xy, z, rp, rp, yaw])
        if cfg.refine.pivot != "none":
            polish_sigma = self._about_pivot(levels[0].camera, best.xyz_rpy, polish_sigma)
        polished = particle_filter(
            self.scene,
            levels[-1:],
            best.xyz_rpy[None],
            self.class_on,
            cfg.refine,
            np.random.default_rng([cfg.seed, 1, restart]),
            polish_sigma,
            particles=cfg.refine.polish_particles,
            iterations=cfg.refine.polish_iterations,
            low_res_iterations=0,
            prior_term=prior_term,
            estimate_top=cfg.refine.polish_estimate_top,
        )
        polished.evaluations += best.evaluations
        polished.spread_m, polished.spread_deg = best.spread_m, best.spread_deg  # the search's
        return polished

    def _about_pivot(
        self, camera: Camera, state: np.ndarray, sigma: np.ndarray, seen: np.ndarray | None = None
    ) -> np.ndarray:
        """(6, 6) perturbation matrix: ``sigma``'s rotations about the point of the optical axis at the
        median depth of the model seen from ``state`` (``refine.pivot_jacobian``; ``seen``: that view's
        depth if already rendered); the plain scales when nothing is seen."""
        depth = self._median_depth(camera, state) if seen is None else median_seen_depth(seen)
        return pivot_jacobian(state, depth) @ np.diag(sigma)

    def _median_depth(self, camera: Camera, state: np.ndarray) -> float:
        """Median z-depth (m) of the model seen from ``state`` (0 when nothing is seen)."""
        pose = Pose.from_state(state)
        seen = NumbaEngine(self.scene).render(camera, pose.R[None], pose.t[None], depth=True).depth
        return median_seen_depth(seen)

    def _probe_curvature(
        self,
        levels: list[ScoringLevel],
        state: np.ndarray,
        cfg: LocalizerConfig,
        prior_term: PriorTerm | None,
    ) -> np.ndarray | None:
        """The score's curvature at ``state`` (``covariance.py``), probed at the fine level with steps that
        move the image by ``refine.covariance_probe_px`` pixels; None when nothing is seen."""
        fine = levels[-1]
        depth = self._median_depth(levels[0].camera, state)
        if not depth > 0.0:
            return None
        steps = probe_steps(fine.camera.fx, depth, cfg.refine.covariance_probe_px)
        states = probe_states(state, steps)
        score, _, _ = score_states(self.scene, fine, states, self.class_on, cfg.refine, prior_term)
        return score_curvature(states, score, state)


def image_score(result: LocalizationResult, cfg: LocalizerConfig, with_depth: bool) -> float:
    """What the refinement maximises at ``result``'s pose without the prior's term: ``lambda_1 * C_s -
    lambda_2 * C_d`` (no depth term without depth), from the scores it recorded there."""
    lam_d = cfg.refine.lambda_depth if with_depth else 0.0
    return float(cfg.refine.lambda_semantic * result.semantic - lam_d * result.depth_cost)


def adopt(result: LocalizationResult, trial: LocalizationResult) -> None:
    """``trial``'s pose and its evidence (scores, covariance, spread) into ``result``: a second refinement's
    pose taken (the flat-eaves look; ``Localizer``'s roll/pitch conflict)."""
    for name in ("pose_local", "score", "semantic", "depth_cost", "covariance", "score_curvature"):
        setattr(result, name, getattr(trial, name))
    result.confidence.update(spread_m=trial.confidence["spread_m"], spread_deg=trial.confidence["spread_deg"])


def median_seen_depth(depth: np.ndarray) -> float:
    """Median of a render's finite depths (0 when it sees nothing)."""
    seen = depth[np.isfinite(depth)]
    return float(np.median(seen)) if seen.size else 0.0
