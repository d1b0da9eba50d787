"""The found pose's uncertainty: a 6 x 6 covariance of (x, y, z, roll, pitch, yaw) from the curvature of
the score around the estimate, scaled by a temperature fitted on the calibration cities.

Why: a navigation filter that fuses the pose (an EKF with the IMU and GNSS) needs a covariance, and a
user needs to know which directions the image pins down and which it does not (from above, a small tilt
and a sideways shift look alike: the tilt-versus-shift ridge). The particles' spread says more about how
the filter was run than about the evidence (its softmax temperature is relative to the population's own
score spread); the score's curvature is the evidence.

How: after the refinement the score (the prior's roll/pitch term included) is probed at ``PROBES`` = 73
states around the estimate (``probe_states``: a central composite design, steps that move the image by
``RefineConfig.covariance_probe_px`` pixels, ``probe_steps``); a quadratic
``score(s) ~ c + g.d + 1/2 d' H d`` (``d = s - estimate``, angles wrapped) is fitted to them by least
squares, in coordinates standardised by the samples' own spread (``score_curvature``, which takes any
samples). ``A = -H`` is the score's curvature, made symmetric positive definite (eigenvalues floored at the
largest over ``MAX_SIGMA_RATIO`` squared, so a flat or upward direction reads as "barely constrained": its
sigma at most ``MAX_SIGMA_RATIO`` times the best-constrained direction's, in standardised units). The
Laplace approximation of a posterior ``exp(score / T)`` gives ``T * A^-1``. The score is the map's, so that
describes how well the image fits *this map*; where the map is not the world (eaves, a changed building, a
warped depth) the estimate sits off the truth by an error the curvature cannot see, so a constant floor
is added: ``covariance = T * A^-1 + diag(floor^2)``. The temperature ``T`` (score units) and the six floor
sigmas are fitted by maximum likelihood on the calibration cities' right poses, then widened together
until the 95 % ellipsoid holds 95 % of them (the errors are heavier-tailed than a Gaussian;
``benchmarks/calibrate_covariance.py``), and checked on Berlin (``docs/localization.md``, "Pose
covariance"); they live in ``covariance_model.json`` beside this module.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from semcityloc.errors import ParameterError
from semcityloc.geometry.conventions import state_difference
from semcityloc.geometry.pose import Pose
from semcityloc.localization.confidence import CALIBRATED_MIN_HFOV_DEG

MODEL_PATH = Path(__file__).with_name("covariance_model.json")
# Cameras narrower than this (degrees across) get the covariance model fitted on narrow views: the same
# bound as the acceptance's narrow-camera warning (``confidence.CALIBRATED_MIN_HFOV_DEG``).
NARROW_BELOW_DEG = CALIBRATED_MIN_HFOV_DEG
STATE_NAMES = ("x", "y", "z", "roll", "pitch", "yaw")
STATE_UNITS = ("m", "m", "m", "deg", "deg", "deg")
# Samples per fitted coefficient below which the quadratic is not fitted (28 coefficients in 6D).
MIN_SAMPLES_PER_COEFFICIENT = 2
# A direction the samples say nothing about gets at most this many times the sigma of the best-constrained
# one, in standardised units (the curvature's eigenvalues are floored at the largest / MAX_SIGMA_RATIO**2).
MAX_SIGMA_RATIO = 100.0
_IU = np.triu_indices(6)
N_COEFFICIENTS = 1 + 6 + len(_IU[0])
PROBES = 1 + 2 * 6 + 4 * 15  # states of ``probe_states``


def probe_steps(focal_px: float, depth_m: float, pixels: float) -> np.ndarray:
    """(6,) probe steps in state units that move the image by about ``pixels`` at ``depth_m``: a
    translation of ``pixels * depth / focal`` metres, a rotation of ``pixels / focal`` radians."""
    metres = pixels * depth_m / focal_px
    return np.array([metres] * 3 + [np.degrees(pixels / focal_px)] * 3)


def probe_states(center: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(73, 6) states around ``center`` where the score is probed: the centre, one step either way along
    each axis, and the four diagonal corners of every pair of axes (a central composite design: every
    coefficient of the quadratic, the 15 cross terms included, is determined)."""
    offsets = [np.zeros(6)]
    eye = np.eye(6) * np.asarray(steps, dtype=np.float64)
    for i in range(6):
        offsets += [eye[i], -eye[i]]
    for i in range(6):
        for j in range(i + 1, 6):
            offsets += [si * eye[i] + sj * eye[j] for si in (1.0, -1.0) for sj in (1.0, -1.0)]
    return np.asarray(center, dtype=np.float64) + np.array(offsets)


def score_curvature(states: np.ndarray, scores: np.ndarray, center: np.ndarray) -> np.ndarray | None:
    """(6, 6) symmetric positive definite curvature ``A = -H`` of the score at ``center`` (state units:
    m and deg), from a quadratic fitted to ``scores`` (N,) of ``states`` (N, 6); None when there are too
    few samples or they do not span all six directions (``module docstring``)."""
    states = np.atleast_2d(np.asarray(states, dtype=np.float64))
    scores = np.asarray(scores, dtype=np.float64).ravel()
    if states.shape[1:] != (6,) or len(scores) != len(states):
        raise ParameterError(f"states must be (N, 6) and scores (N,), got {states.shape} and {scores.shape}")
    keep = np.isfinite(scores) & np.all(np.isfinite(states), axis=1)
    states, scores = states[keep], scores[keep]
    if len(scores) < MIN_SAMPLES_PER_COEFFICIENT * N_COEFFICIENTS:
        return None
    d = state_difference(states, center)
    scale = d.std(axis=0)
    if not np.all(scale > 1e-9):
        return None
    z = d / scale
    quad = z[:, _IU[0]] * z[:, _IU[1]]
    design = np.concatenate([np.ones((len(z), 1)), z, quad], axis=1)
    coef, *_ = np.linalg.lstsq(design, scores - scores.mean(), rcond=None)
    hess = np.zeros((6, 6))
    hess[_IU] = coef[7:]
    hess = hess + hess.T  # off-diagonal: c_ij z_i z_j = 1/2 (H_ij + H_ji) z_i z_j; diagonal: 1/2 H_ii z_i^2
    eigval, eigvec = np.linalg.eigh(-hess)
    span = max(float(eigval.max()), 0.0)
    if span <= 0.0:
        return None
    floor = span / MAX_SIGMA_RATIO**2
    curv_z = (eigvec * np.maximum(eigval, floor)) @ eigvec.T
    return curv_z / np.outer(scale, scale)


def pose_covariance(
    curvature: np.ndarray, temperature: float, floor_sigma: np.ndarray | None = None
) -> np.ndarray:
    """(6, 6) covariance ``temperature * curvature^-1 + diag(floor_sigma^2)`` (state units squared)."""
    if not temperature > 0.0:
        raise ParameterError(f"temperature must be > 0, got {temperature}")
    cov = temperature * np.linalg.inv(curvature)
    if floor_sigma is not None:
        cov = cov + np.diag(np.asarray(floor_sigma, dtype=np.float64) ** 2)
    return 0.5 * (cov + cov.T)


def state_error(pose_local: Pose, truth_local: Pose) -> np.ndarray:
    """(6,) ``pose_local - truth_local`` in state units (m, deg; angles wrapped to +-180): what a covariance
    describes."""
    return state_difference(pose_local.to_xyz_rpy(), truth_local.to_xyz_rpy())


def horizontal_sigma(sigma_x: float, sigma_y: float) -> float:
    """The horizontal 1-sigma per axis (the root mean square of x's and y's), as a prior's ``xy`` and the
    photogrammetry tools' camera accuracy are stated."""
    return float(np.sqrt((sigma_x * sigma_x + sigma_y * sigma_y) / 2.0))


def mahalanobis_sq(error: np.ndarray, covariance: np.ndarray) -> float:
    """``e' C^-1 e`` of a (6,) state error (angles wrapped) under a (6, 6) covariance."""
    e = state_difference(error, np.zeros(6))
    return float(e @ np.linalg.solve(covariance, e))


def tangent_covariance(state: np.ndarray, covariance: np.ndarray, frame: str = "world") -> np.ndarray:
    """The (x, y, z, roll, pitch, yaw) covariance of a pose at ``state`` as that of a rotation vector
    (radians) and the camera centre (m): the form a navigation filter or a factor graph takes.

    ``frame="world"``: ``R_world_from_cam = Exp(dtheta) R0`` (a turn about world axes), ``frame="camera"``:
    ``R_world_from_cam = R0 Exp(dtheta)`` (about the camera's own OpenCV axes, GTSAM's ``Pose3``
    convention for the rotation); rows ``(dtheta (3), dcentre (3))``, the centre in world axes either
    way. First order: the Euler angles' Jacobian at ``state`` by central differences (a few thousandths
    of a degree; good while the errors are small against the distance to gimbal lock at roll +-90)."""
    if frame not in ("world", "camera"):
        raise ParameterError(f"frame must be 'world' or 'camera', got {frame!r}")
    state = np.asarray(state, dtype=np.float64)
    covariance = np.asarray(covariance, dtype=np.float64)
    if state.shape != (6,) or covariance.shape != (6, 6):
        shapes = f"{state.shape} and {covariance.shape}"
        raise ParameterError(f"need a (6,) state and a (6, 6) covariance, got {shapes}")

    def rotation(s: np.ndarray) -> np.ndarray:
        return Pose.from_state(s).R_world_from_cam

    r0 = rotation(state)
    jac = np.zeros((6, 6))
    jac[3:, :3] = np.eye(3)  # the centre is the state's x, y, z
    eps = 1e-3  # degrees
    for k in range(3, 6):
        step = np.zeros(6)
        step[k] = eps
        turns = []
        for sign in (1.0, -1.0):
            r = rotation(state + sign * step)
            delta = r @ r0.T if frame == "world" else r0.T @ r
            turns.append(Rotation.from_matrix(delta).as_rotvec())
        jac[:3, k] = (turns[0] - turns[1]) / (2.0 * eps)
    out = jac @ covariance @ jac.T
    return 0.5 * (out + out.T)


def covariance_dict(covariance: np.ndarray) -> dict:
    """JSON-ready record of a pose covariance: the order and units of its rows, the matrix and the 1-sigma
    of each component. The position block is the same in the model's CRS (world = origin + local)."""
    cov = np.asarray(covariance, dtype=np.float64)
    return {
        "order": list(STATE_NAMES),
        "units": list(STATE_UNITS),
        "matrix": cov.tolist(),
        "sigma": np.sqrt(np.clip(np.diag(cov), 0.0, None)).tolist(),
    }


@dataclass(frozen=True)
class CovarianceModel:
    """A fitted temperature and floor (module docstring) for one localizer kind, with or without depth."""

    temperature: float
    floor_sigma: tuple[float, ...]  # (6,) state units

    def covariance(self, curvature: np.ndarray) -> np.ndarray:
        """(6, 6) pose covariance from the score's curvature, scaled and floored as fitted."""
        return pose_covariance(curvature, self.temperature, np.array(self.floor_sigma))


def model_key(kind: str, with_depth: bool, narrow: bool = False) -> str:
    """The key of a covariance model in ``covariance_model.json``: the localizer kind, with or without depth,
    and ``/narrow`` for cameras under 50 degrees across, which have a model of their own.
    """
    key = f"{kind}/{'depth' if with_depth else 'no-depth'}"
    return f"{key}/narrow" if narrow else key


@lru_cache(maxsize=1)
def _models() -> dict:
    if not MODEL_PATH.exists():
        return {}
    return json.loads(MODEL_PATH.read_text()).get("models", {})


def covariance_model(kind: str, with_depth: bool, hfov_deg: float | None = None) -> CovarianceModel | None:
    """The model fitted for a localizer kind (``Localizer.confidence_kind``) with or without depth, or
    None when none was fitted (the result then carries no covariance). A camera narrower than
    ``NARROW_BELOW_DEG`` across (``hfov_deg``) gets the model fitted on narrow views where there is one:
    along its longer tilt-versus-shift ridge the wide views' model held 55 % of a 34 deg camera's right
    poses in its 95 % ellipsoid on Berlin seed 1 (``docs/localization.md``, "Pose covariance")."""
    models = _models()
    entry = None
    if hfov_deg is not None and hfov_deg < NARROW_BELOW_DEG:
        entry = models.get(model_key(kind, with_depth, narrow=True))
    if entry is None:
        entry = models.get(model_key(kind, with_depth))
    if entry is None:
        return None
    return CovarianceModel(float(entry["temperature"]), tuple(float(v) for v in entry["floor_sigma"]))


def save_models(models: dict[str, CovarianceModel], fitted_on: str, checks: dict | None = None) -> None:
    """Write the fitted models (``{model_key: CovarianceModel}``) to ``MODEL_PATH`` (the calibration
    script), with what they were fitted on and, optionally, what the check measured."""
    body = {
        "fitted_on": fitted_on,
        "models": {
            k: {"temperature": m.temperature, "floor_sigma": list(m.floor_sigma)} for k, m in models.items()
        },
    }
    if checks:
        body["checks"] = checks
    MODEL_PATH.write_text(json.dumps(body, indent=2) + "\n")
    _models.cache_clear()
