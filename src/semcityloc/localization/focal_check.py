"""One image's check of its focal length: around the pose found, does an oblique view fit the map better
with the focal length a few % longer or shorter? (stop 53)

Why: a focal length 5 % off moves the camera by as much along its axis, and the pose is accepted all the
same: the calibration cities' accepted poses were 77-88 % right (5 m / 5 deg) with the focal length 5 %
off, 100 % with the right one, and nothing in the result said so. Choosing the focal length per image
cost more than it gained (stop 33, ``focal.py``); this check only warns. Seen from above, focal length
and height are one unknown (``focal.py``), so only oblique views are checked.

How (``check_focal``): for the scales ``1 - step``, 1 and ``1 + step`` the camera found is moved back along
its optical axis by ``d (s - 1)`` (``d`` the median depth of the map it sees: where the scaled focal length
sees the scene at the same size), its focal lengths times ``s``; a line of 5 camera centres +-1 m along
the axis and a short polish (``FocalCheckConfig.particles`` x ``iterations``, at the fine level, the same
score and prior term as the refinement) find the best score there. A parabola through the three scores'
gains over scale 1 has its vertex at the scale the view fits best (``FocalCheck.scale``; None when the
scores do not peak). ``focal_warning``: the vertex more than ``FocalCheckConfig.margin`` from 1.

The vertex understates the error (the pose found at the stated focal length is where that focal length
fits best): with one 5 % off the wrongly placed poses' vertices lay mostly 1.1-5 % from 1
(docs/localization.md, "A focal length the image contradicts").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from semcityloc.errors import parameter
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import FocalCheckConfig, RefineConfig
from semcityloc.localization.refine import PriorTerm, ScoringLevel, particle_filter, score_states
from semcityloc.render.scene import RenderScene

MIN_OBLIQUE_DEG = 20.0  # an optical axis at least this far from nadir: an oblique view
FOCAL_WARNING = "focal length may be off"
NOT_CHECKED_WARNING = "focal length not checked"
NADIR = "nadir"  # ``search["focal_check"]["not_checked"]`` of a view the check leaves out
LINE_M = np.linspace(-1.0, 1.0, 5)  # camera centres along the optical axis around the moved one


def off_nadir_deg(pose_local: Pose) -> float:
    """How far the pose's optical axis is from straight down (deg)."""
    down = -float(pose_local.viewing_direction[2])
    return math.degrees(math.acos(max(-1.0, min(1.0, down))))


def is_oblique(pose_local: Pose, min_deg: float = MIN_OBLIQUE_DEG) -> bool:
    """Whether the pose's optical axis is at least ``min_deg`` from straight down."""
    return off_nadir_deg(pose_local) >= min_deg


def with_focal_scale(camera: Camera, scale: float) -> Camera:
    """``camera`` with both focal lengths times ``scale`` (principal point and size unchanged)."""
    return replace(camera, fx=camera.fx * scale, fy=camera.fy * scale)


def moved_back(state: np.ndarray, depth_m: float, scale: float) -> np.ndarray:
    """(6,) ``state``, its camera centre moved back along the optical axis by ``depth_m * (scale - 1)``."""
    axis = np.asarray(Pose.from_state(state).R)[2]
    out = np.array(state, dtype=np.float64)
    out[:3] -= axis * depth_m * (scale - 1.0)
    return out


@dataclass(frozen=True)
class FocalCheck:
    """The check's outcome: ``scale`` the focal scale the view fits best (the parabola's vertex; None when
    the scores do not peak), ``gains`` the best scores at ``1 - step`` and ``1 + step`` minus the one at 1,
    ``depth_m`` the median depth the camera was moved by."""

    scale: float | None
    gains: tuple[float, float]
    step: float
    depth_m: float

    def as_dict(self) -> dict:
        """Plain values for ``result.search["focal_check"]``."""
        return {"scale": self.scale, "gains": list(self.gains), "step": self.step, "depth_m": self.depth_m}


def check_focal(
    scene: RenderScene,
    class_on: np.ndarray,
    fine: ScoringLevel,
    state: np.ndarray,
    depth_m: float,
    check: FocalCheckConfig,
    refine: RefineConfig,
    prior_term: PriorTerm | None,
    seed: int = 0,
) -> FocalCheck | None:
    """The check (module docstring) of the pose ``state`` (local frame) against the query at the fine
    level ``fine``; ``depth_m`` the median depth of the map seen from it at that level (the acceptance's
    render: ``refine_stage.median_seen_depth``); None when the map is not seen from it (0)."""
    if not depth_m > 0.0:
        return None
    depth = float(depth_m)
    xy, z, rp, yaw = refine.polish_sigma
    sigma = np.array([xy, xy, z, rp, rp, yaw])
    best = []
    for s in (1.0 - check.step, 1.0, 1.0 + check.step):
        level = ScoringLevel(with_focal_scale(fine.camera, s), fine.labels, fine.depth)
        moved = moved_back(state, depth, s)
        axis = np.asarray(Pose.from_state(moved).R)[2]
        states = moved[None] + LINE_M[:, None] * np.r_[axis, 0.0, 0.0, 0.0][None]
        score, _, _ = score_states(scene, level, states, class_on, refine, prior_term)
        polished = particle_filter(
            scene,
            [level],
            states[int(np.argmax(score))][None],
            class_on,
            refine,
            np.random.default_rng([seed, 3]),
            sigma,
            particles=check.particles,
            iterations=check.iterations,
            low_res_iterations=0,
            prior_term=prior_term,
            estimate_top=check.particles,
        )
        best.append(max(polished.score, float(score.max())))
    gains = (best[0] - best[1], best[2] - best[1])
    return FocalCheck(vertex(gains, check.step), gains, check.step, depth)


def vertex(gains: tuple[float, float], step: float) -> float | None:
    """The vertex of the parabola through (1 - step, gains[0]), (1, 0), (1 + step, gains[1]); None when it
    opens upwards (no peak)."""
    lower, upper = gains
    curvature = lower + upper  # 2 a step^2
    if not curvature < 0.0:
        return None
    return float(1.0 - step * (upper - lower) / (2.0 * curvature))


def fires(check: FocalCheck | None, margin: float) -> bool:
    """Whether the view fits a focal scale more than ``margin`` from 1 (the check warns)."""
    return check is not None and check.scale is not None and abs(check.scale - 1.0) > margin


def correction_scale(check: FocalCheck, config: FocalCheckConfig) -> float:
    """The focal scale the pose is re-found with where the check fires: ``1 + stretch (vertex - 1)``, at
    most one probe step beyond the probed scales (``2 step`` from 1)."""
    if check.scale is None:
        raise ValueError("correction_scale needs a check whose scores peak (FocalCheck.scale)")
    wide = 2.0 * check.step
    return float(np.clip(1.0 + config.stretch * (check.scale - 1.0), 1.0 - wide, 1.0 + wide))


def corrected_warning(check: FocalCheck, scale: float) -> str:
    """The warning when the pose was re-found with the focal length times ``scale`` and kept."""
    off = 100.0 * abs(scale - 1.0)
    return (
        f"{FOCAL_WARNING}: this oblique view fits a focal length {off:.1f} % "
        f"{'longer' if scale > 1.0 else 'shorter'} than the stated one better (the check's vertex "
        f"{check.scale:.3f}), so the pose was found again with it and fits the image better: kept. It holds "
        f"with the focal length times {scale:.3f}: re-project with fx and fy times {scale:.3f}, not the "
        f"stated intrinsics (the pose file's intrinsics are the scaled ones, its focal_scale this scale). "
        f"The stated focal length may be off by about twice {off:.1f} %. Give the camera's calibrated "
        f"intrinsics ({parameter('calibrated_camera')}, docs/your-data.md section 4), or estimate the focal "
        f"length from the flight's oblique photos ({parameter('calibrate_focal', 'on')})"
    )


def focal_scale_used(search: dict) -> float | None:
    """The focal scale a result's pose was found with, from its ``search`` record: the correction's where it
    was taken (``Localizer._correct_focal``), else None (the stated focal lengths)."""
    correction = (search.get("focal_check") or {}).get("correction") or {}
    return float(correction["scale"]) if correction.get("taken") else None


def found_camera(camera: Camera, focal_scale: float | None) -> Camera:
    """The camera a pose holds with: ``camera`` (the stated one) with its focal lengths times
    ``focal_scale`` where the focal check's correction re-found the pose with it, else ``camera`` (None).
    ``focal_scale`` as a result's ``focal_scale_used(result.search)``, a ``results.csv`` row's or a details
    file's ``focal_scale``, or a pose file's (``pose_json.focal_scale_of``). The one camera of such a pose:
    its pose file's ``intrinsics``, its COLMAP camera, ``localize``'s overlay, a run's overlays and the
    report's drawings of it."""
    return camera if focal_scale is None else with_focal_scale(camera, focal_scale)


def nadir_record(pose_local: Pose) -> dict:
    """``result.search["focal_check"]`` of an accepted view the check leaves out because it looks down
    (``is_oblique`` false): ``not_checked`` names why, ``off_nadir_deg`` how far its axis is from nadir."""
    return {
        "not_checked": NADIR,
        "off_nadir_deg": off_nadir_deg(pose_local),
        "min_oblique_deg": MIN_OBLIQUE_DEG,
    }


def nadir_warning(record: dict) -> str:
    """The warning of a view the check left out (``nadir_record``) where the user asked for the
    correction (``FocalCheckConfig.correct``): nothing was checked or re-found, and why."""
    return (
        f"{NOT_CHECKED_WARNING}: nadir view (its optical axis {record['off_nadir_deg']:.0f} deg from "
        f"straight down, under the {record['min_oblique_deg']:g} deg the check needs): seen from above, "
        "focal length and height are one unknown, so the pose was neither checked nor found again with "
        "another focal length, and a focal length x % off places the camera about x % too high or too low. "
        f"Give the camera's calibrated intrinsics ({parameter('calibrated_camera')}, docs/your-data.md "
        "section 4), or estimate the focal length from the flight's oblique photos "
        f"({parameter('calibrate_focal', 'on')})"
    )


def focal_warning(check: FocalCheck | None, margin: float) -> str | None:
    """The warning when the view fits a focal scale more than ``margin`` from 1 (None otherwise): the
    direction, what it does to the pose and the remedies."""
    if not fires(check, margin):
        return None
    off = 100.0 * abs(check.scale - 1.0)
    longer = check.scale > 1.0
    return (
        f"{FOCAL_WARNING}: around the pose found, this oblique view fits a focal length {off:.1f} % "
        f"{'longer' if longer else 'shorter'} than the stated one better (the check understates the error, "
        f"about by half), so the camera may be placed too {'close' if longer else 'far'} along its axis. "
        f"Give the camera's calibrated intrinsics ({parameter('calibrated_camera')}, docs/your-data.md "
        "section 4), estimate the focal length from the flight's oblique photos "
        f"({parameter('calibrate_focal', 'on')}), or find each pose again with the focal length its view "
        f"fits ({parameter('preset', 'focal-correct')})"
    )
