"""Damped Gauss-Newton refinement of a 6DoF pose on an edge-probability map (LoD-Loc's last step).

LoD-Loc refines the best grid pose with 5 Gauss-Newton steps on its finest feature map: per point a
residual, the Jacobian from the map's image gradient through the projection, the normal equations damped
as ``H + 0.01 diag(H) + 1e-4 I``. Here:

- residual of point i: ``r_i = 1 - E(pi(s, P_i))`` with ``E`` the (blurred, bilinear) edge probability, so
  minimising ``sum r_i^2`` pulls points onto edges; points behind the camera or within ``pad_px`` of the
  image border are left out (LoD-Loc: 4 px);
- state ``s = (x, y, z, roll, pitch, yaw)`` in the model's local frame (angles handled in radians);
  the Jacobian ``dr/ds`` is numeric (central differences, steps ``STEP``), i.e. the map gradient through
  the projection without writing the projection's derivative by hand;
- Levenberg-style safeguard (LoD-Loc applies every step blindly): a step is kept only if the mean edge
  score over all points does not drop; otherwise the relative damping grows x10 and the pose stays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semcityloc.baselines.edge_score import NEAR_M, pad_map, sample_bilinear
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose

# Central-difference steps: metres for x, y, z and radians for roll, pitch, yaw.
STEP = np.array([0.02, 0.02, 0.02, 2e-4, 2e-4, 2e-4])
RAD_UNITS = np.array([1.0, 1.0, 1.0, np.pi / 180, np.pi / 180, np.pi / 180])


@dataclass
class RefineOutcome:
    """What the Gauss-Newton refinement returns: the final state (x, y, z in m, angles in degrees), the edge
    score before and after, how many damped steps were accepted and how many pose evaluations it took (for
    the baseline's timing and for telling a refinement that moved from one that did not).
    """

    state: np.ndarray  # (6,) x, y, z, roll, pitch, yaw (degrees)
    score_before: float
    score_after: float
    accepted_steps: int
    evaluations: int  # pose evaluations (each over all points)


def _project(points: np.ndarray, state_rad: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Image coordinates (K, N, 2) and in-front mask (K, N) of points at states (K, 6) (angles rad)."""
    deg = state_rad / RAD_UNITS
    poses = Pose.from_state(deg)
    cam = poses.transform(points)  # (K, N, 3)
    z = cam[..., 2]
    front = z > NEAR_M
    zs = np.where(front, z, 1.0)
    uv = np.stack([camera.fx * cam[..., 0] / zs + camera.cx, camera.fy * cam[..., 1] / zs + camera.cy], -1)
    return uv, front


def _values(points, states_rad, camera, emap, pmap=None) -> tuple[np.ndarray, np.ndarray]:
    uv, front = _project(points, states_rad, camera)
    e = np.where(front, sample_bilinear(emap, uv[..., 0], uv[..., 1], pmap), 0.0)
    return e, uv


def mean_score(
    points: np.ndarray, state_deg: np.ndarray, camera: Camera, emap: np.ndarray, pmap=None
) -> float:
    """Mean edge probability of ``points`` at one state (degrees), 0 for points outside / behind."""
    e, _ = _values(points, (np.asarray(state_deg, dtype=np.float64) * RAD_UNITS)[None], camera, emap, pmap)
    return float(e.mean())


def gauss_newton(
    points: np.ndarray,
    state_deg: np.ndarray,
    camera: Camera,
    emap: np.ndarray,
    iterations: int = 5,
    damping: float = 0.01,
    damping_abs: float = 1e-4,
    pad_px: float = 4.0,
) -> RefineOutcome:
    """Refine ``state_deg`` (x, y, z, roll, pitch, yaw in degrees) by ``iterations`` damped GN steps."""
    s = np.asarray(state_deg, dtype=np.float64) * RAD_UNITS
    h, w = emap.shape
    pmap = pad_map(emap)
    lam = damping
    e0, _ = _values(points, s[None], camera, emap, pmap)
    best = float(e0.mean())
    start = best
    accepted = 0
    evaluations = 1
    for _ in range(iterations):
        probes = np.concatenate([s + np.diag(STEP), s - np.diag(STEP), s[None]])  # (13, 6)
        e, uv = _values(points, probes, camera, emap, pmap)
        evaluations += 13
        u, v = uv[12, :, 0], uv[12, :, 1]
        valid = (u >= pad_px) & (u <= w - pad_px) & (v >= pad_px) & (v <= h - pad_px)
        if not valid.any():
            break
        J = -((e[:6] - e[6:12]) / (2 * STEP[:, None])).T[valid]  # (n, 6): d(1 - E)/ds
        r = 1.0 - e[12, valid]
        H = J.T @ J
        g = J.T @ r
        A = H + lam * np.diag(np.diag(H)) + damping_abs * np.eye(6)
        try:
            delta = -np.linalg.solve(A, g)
        except np.linalg.LinAlgError:
            break
        candidate = s + delta
        score = mean_score(points, candidate / RAD_UNITS, camera, emap, pmap)
        evaluations += 1
        if np.isfinite(score) and score >= best:
            s, best = candidate, score
            lam = max(lam / 10.0, 1e-6)
            accepted += 1
        else:
            lam *= 10.0
    return RefineOutcome(s / RAD_UNITS, start, best, accepted, evaluations)
