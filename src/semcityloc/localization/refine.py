"""Particle-filter refinement with joint semantic and depth alignment (paper Sec. 3.2).

State: (x, y, z, roll, pitch, yaw) in the model's local frame. Each iteration scores every particle with
``score = lambda_1 * C_s - lambda_2 * C_d`` (``C_s`` mean per-class IoU, higher is better; ``C_d`` the
affine-invariant depth cost, lower is better; so higher ``score`` is better), turns scores into weights
by a softmax with a temperature, resamples (systematic) and perturbs with Gaussian noise whose scale
shrinks geometrically. Roll and pitch move less than yaw (gravity is known). The estimate is the best
particle seen in any iteration, or (``estimate_top``, the polish) the mean of the best evaluations; the
weighted spread of the last population is reported as confidence.
Deterministic for a given seed (numpy Generator; the kernel is a pure function of its inputs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import state_difference
from semcityloc.geometry.pose import Pose
from semcityloc.localization.coarse import _slots
from semcityloc.localization.config import RefineConfig
from semcityloc.localization.kernels import refine_scores
from semcityloc.localization.scoring import DEPTH_COST_INVALID, MIN_DEPTH_PIXELS
from semcityloc.render.raster_numba import NEAR_M, work_chunks
from semcityloc.render.scene import RenderScene


@dataclass
class RefineResult:
    """What one particle-filter run returns: the best particle and the scores and spread behind it.

    ``xyz_rpy`` is the best particle's state (local frame; m, deg), ``score`` its combined score and
    ``semantic`` / ``depth_cost`` its two terms; ``spread_m`` / ``spread_deg`` are the final population's
    weighted spread (an acceptance feature: a filter that did not converge is less likely right);
    ``evaluations`` counts the poses scored (for timing). ``states`` / ``weights`` hold the final population
    when kept, for the covariance and the refinement stage's choices.
    """

    xyz_rpy: np.ndarray  # (6,) best particle
    score: float
    semantic: float
    depth_cost: float
    spread_m: float  # weighted std of the final particle centres (metres, 3D)
    spread_deg: float  # weighted std of the final particles' yaw (degrees)
    evaluations: int
    states: np.ndarray | None = None  # (n, 6) final population
    weights: np.ndarray | None = None  # (n,) its weights


def evaluate(
    scene: RenderScene,
    camera: Camera,
    states: np.ndarray,
    query_labels: np.ndarray,
    query_depth: np.ndarray | None,
    class_on: np.ndarray,
    depth_robust: bool = False,
    depth_cap: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Semantic score and depth cost of each state (N, 6); depth cost 0 where ``query_depth`` is None.
    ``depth_robust`` / ``depth_cap``: the depth cost's form (``RefineConfig.depth_cost``)."""
    poses = Pose.from_state(states)
    n = len(states)
    sem = np.empty(n)
    dep = np.empty(n)
    use_depth = query_depth is not None
    qd = np.ascontiguousarray(query_depth if use_depth else np.zeros(1), dtype=np.float64)
    refine_scores(
        scene.tri_xyz,
        scene.classes,
        scene.tile_start,
        scene.tile_bbox,
        scene.block_start,
        scene.block_bbox,
        np.ascontiguousarray(poses.R),
        np.ascontiguousarray(poses.t),
        camera.fx,
        camera.fy,
        camera.cx,
        camera.cy,
        camera.width,
        camera.height,
        NEAR_M,
        np.ascontiguousarray(query_labels, dtype=np.uint8),
        qd,
        use_depth,
        _slots(class_on),
        float(MIN_DEPTH_PIXELS),
        DEPTH_COST_INVALID,
        sem,
        dep,
        work_chunks(n),
        bool(depth_robust),
        float(depth_cap),
    )
    return sem, dep


def softmax_weights(score: np.ndarray, temperature: float) -> np.ndarray:
    """Particle weights ``exp((score - max) / T)``, normalised. ``T`` is relative to the score spread
    of the population (``temperature * std``, floored), so the same setting works for any score scale."""
    spread = max(float(np.std(score)), 1e-9)
    z = (score - score.max()) / (temperature * spread)
    w = np.exp(z)
    return w / w.sum()


def _systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    n = len(weights)
    positions = (rng.random() + np.arange(n)) / n
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0
    return np.searchsorted(cumulative, positions)


@dataclass
class PriorTerm:
    """What the prior says, as a penalty on the score: ``weight * 0.5 * sum(((s - prior) / sigma)^2)``
    over the components with a finite sigma (the gimbal's roll and pitch: the image alone barely tells a
    nadir camera's tilt from a sideways shift, the IMU does; the score is a mean IoU, so ``weight`` is
    in IoU units per squared sigma)."""

    state: np.ndarray  # (6,) the prior's state
    sigma: np.ndarray  # (6,) 1-sigma per component; inf = not penalised
    weight: float

    def penalty(self, states: np.ndarray) -> np.ndarray:
        """(N,) penalty of each state (N, 6); components with an infinite sigma add nothing."""
        d = (np.atleast_2d(states) - self.state) / self.sigma
        return self.weight * 0.5 * np.sum(np.where(np.isfinite(d), d * d, 0.0), axis=1)


@dataclass
class ScoringLevel:
    """A camera and the query arrays at its resolution (flat labels, flat depth or None)."""

    camera: Camera
    labels: np.ndarray
    depth: np.ndarray | None


def score_states(
    scene: RenderScene,
    level: ScoringLevel,
    states: np.ndarray,
    class_on: np.ndarray,
    config: RefineConfig,
    prior_term: PriorTerm | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(score, C_s, C_d) of states (N, 6) at a scoring level: ``score = lambda_1 * C_s - lambda_2 * C_d``
    (no depth term when the level has no depth) minus the prior's penalty. What the refinement maximises,
    in one place for the filter, its polish, the ``no-refine`` ablation and ``Localizer.score_poses``."""
    sem, dep = evaluate(
        scene,
        level.camera,
        states,
        level.labels,
        level.depth,
        class_on,
        config.depth_cost == "robust",
        config.depth_cap,
    )
    lam_d = config.lambda_depth if level.depth is not None else 0.0
    score = config.lambda_semantic * sem - lam_d * dep
    if prior_term is not None:
        score = score - prior_term.penalty(states)
    return score, sem, dep


def initial_sigma(config: RefineConfig, roll_pitch_deg: float) -> np.ndarray:
    """(6,) initial perturbation scales in state order; half of ``roll_pitch_deg`` (the prior's sigma) is
    used when the config leaves roll/pitch to the prior (``sigma_roll_pitch_deg=None``)."""
    rp = config.sigma_roll_pitch_deg if config.sigma_roll_pitch_deg is not None else 0.5 * roll_pitch_deg
    return np.array([config.sigma_xy_m, config.sigma_xy_m, config.sigma_z_m, rp, rp, config.sigma_yaw_deg])


def pivot_jacobian(state: np.ndarray, pivot_depth_m: float) -> np.ndarray:
    """(6, 6) map from perturbations about a pivot to state perturbations: a roll / pitch / yaw offset
    also moves the camera centre so that the point ``pivot_depth_m`` ahead on the optical axis stays put.

    Why: from the air a small tilt and a sideways shift of ``depth * tilt`` move the image alike (the
    tilt-versus-shift ridge); sampled independently, the filter explores that ridge only by chance. About
    the pivot, a rotation offset *is* a step along the ridge. Translation columns are the identity."""
    jac = np.eye(6)
    if not pivot_depth_m > 0.0:
        return jac
    eps = 1e-3  # degrees
    steps = np.zeros((3, 6))
    steps[:, 3:] = np.eye(3) * eps
    # One batch of the six turned states (each rotation is computed on its own: the same bits as one by one).
    turned = np.concatenate([state + steps, state - steps])
    axes = Pose.from_state(turned).R[:, 2]  # the optical axes in the local frame
    for k in range(3, 6):
        d_axis = (axes[k - 3] - axes[k]) / (2.0 * eps)
        jac[:3, k] = -pivot_depth_m * d_axis
    return jac


def particle_filter(
    scene: RenderScene,
    levels: list[ScoringLevel],
    seeds: np.ndarray,
    class_on: np.ndarray,
    config: RefineConfig,
    rng: np.random.Generator,
    sigma: np.ndarray | None = None,
    particles: int | None = None,
    iterations: int | None = None,
    low_res_iterations: int | None = None,
    prior_term: PriorTerm | None = None,
    estimate_top: int = 0,
) -> RefineResult:
    """Refine from ``seeds`` ((k, 6) states, best first). ``levels[-1]`` is the fine resolution; with
    ``config.low_res_iterations`` > 0 the first iterations score at ``levels[0]``. The best particle is
    chosen among fine-resolution scores only (scores of different resolutions are not comparable).
    ``sigma``: (6,) initial perturbation scales (default ``initial_sigma(config, 0.3)``), or a (6, 6)
    matrix ``L`` whose perturbations are ``L @ n`` for standard normal ``n`` (``pivot_jacobian`` times
    the scales); the floors shrink it alike;
    ``particles`` / ``iterations`` / ``low_res_iterations`` override the config's; ``prior_term``: the
    prior's penalty subtracted from every score (``PriorTerm``); ``estimate_top`` > 0: the estimate is
    the mean of the best ``estimate_top`` fine-resolution evaluations (``top_mean``), scored once more,
    instead of the single best one (use it where the population stays in one basin: the polish)."""
    sigma = initial_sigma(config, 0.3) if sigma is None else np.asarray(sigma, dtype=np.float64)
    full = sigma.ndim == 2
    n = config.particles if particles is None else int(particles)
    n_iter = config.iterations if iterations is None else int(iterations)
    low_res = config.low_res_iterations if low_res_iterations is None else int(low_res_iterations)
    # Initial population: half around the best seed, the rest spread over the other seeds.
    owner = np.where(np.arange(n) < n // 2, 0, np.arange(n) % len(seeds))
    noise = rng.normal(size=(n, 6))
    states = seeds[owner] + (noise @ sigma.T if full else noise * sigma)
    states[0] = seeds[0]  # the coarse pose itself is always evaluated

    best = (-np.inf, seeds[0].copy(), 0.0, 0.0)
    evaluations = 0
    weights = np.full(n, 1.0 / n)
    seen_states, seen_scores = [], []  # every fine evaluation, for estimate_top
    for it in range(n_iter):
        # The last iteration always scores at the fine resolution, whatever low_res_iterations says.
        fine = it >= min(low_res, n_iter - 1) or len(levels) == 1
        level = levels[-1] if fine else levels[0]
        score, sem, dep = score_states(scene, level, states, class_on, config, prior_term)
        evaluations += n
        i = int(np.argmax(score))
        if fine and estimate_top > 0:
            seen_states.append(states.copy())
            seen_scores.append(score)
        if fine and score[i] > best[0]:
            best = (float(score[i]), states[i].copy(), float(sem[i]), float(dep[i]))
        weights = softmax_weights(score, config.temperature)
        if it == n_iter - 1:
            break
        floor = sigma * config.shrink ** (it + 1)
        floor_cov = floor @ floor.T if full else np.diag(floor**2)
        if config.update == "gaussian":
            # Gaussian particle filter: draw the next population from the weighted mean and covariance,
            # so directions where the score is flat or coupled (roll ~ x, pitch ~ y) are explored along
            # their correlation; a floor that shrinks per iteration keeps it from collapsing early.
            mean = weights @ states
            centred = states - mean
            cov = (centred * weights[:, None]).T @ centred + floor_cov
            states = rng.multivariate_normal(mean, cov, size=n, method="cholesky")
        else:
            keep = _systematic_resample(weights, rng)
            noise = rng.normal(size=(n, 6))
            states = states[keep] + (noise @ floor.T if full else noise * floor)
        if best[0] > -np.inf:
            states[0] = best[1]  # elitism: the best so far stays in the population

    if estimate_top > 0 and seen_scores:
        est = top_mean(np.concatenate(seen_states), np.concatenate(seen_scores), estimate_top)
        score, sem, dep = score_states(scene, levels[-1], est[None], class_on, config, prior_term)
        evaluations += 1
        best = (float(score[0]), est, float(sem[0]), float(dep[0]))

    mean = np.average(states, axis=0, weights=weights)
    spread_m = float(np.sqrt(np.average(np.sum((states[:, :3] - mean[:3]) ** 2, axis=1), weights=weights)))
    spread_deg = float(np.sqrt(np.average((states[:, 5] - mean[5]) ** 2, weights=weights)))
    return RefineResult(
        best[1], best[0], best[2], best[3], spread_m, spread_deg, evaluations, states, weights
    )


def top_mean(states: np.ndarray, scores: np.ndarray, k: int) -> np.ndarray:
    """(6,) mean of the ``k`` best-scoring states (N, 6); angles averaged as offsets from the best one's,
    wrapped (``state_difference``), so a yaw near +-180 does not average to 0."""
    top = states[np.argsort(-scores, kind="stable")[:k]]
    offsets = state_difference(top, top[0])
    return top[0] + offsets.mean(axis=0)
