"""Coarse-to-fine hypothesis search over the prior's uncertainty volume (the default search).

Why: a real GNSS prior can be 30 m off in height and a gimbal 2-3 deg off in roll and pitch. A uniform
4D grid fine enough for the refinement to take over costs time in proportion to the volume, and a grid
sized for a smaller error gives a confident wrong pose at its edge. So:

1. **Volume** (``search_volume``): centred on the prior, half-widths ``n_sigma`` x the stated sigma
   (``PriorUncertainty``), floored so that an RTK prior still leaves room for the map's own errors. The
   volume stops ``CascadeConfig.min_clearance_m`` above the lowest ground near the prior (``floor_z``): a
   GNSS height 25 m low puts a camera flying 23 m up underground, and a camera under the terrain sees a
   ground-only view that can outscore a low flight's true one.
2. **Sweep** (``sweep``): the volume's lattice (steps ``SweepConfig.step_*``, grown when it would need
   more than ``max_centres`` camera centres) scored at a low resolution, one wide render per centre and
   every yaw read through a lookup table (``coarse.score_rotations``). If the best cell lies on the
   volume's edge, the volume grows in that direction (bounded, never below the floor) and only the new
   cells are scored; a best cell on the floor is not on an edge (nothing lies below it); still on the edge
   at the bound -> ``at_edge`` (the localizer refuses: a pose at the edge of what was
   searched is not a pose that was found). Yaw grows to one turn at most (``yaw_turn``): a yaw range
   grown to a turn is the whole circle, which has no edge.
3. **Local** (``local_search``): around the sweep's best distinct cells (greedy non-maximum suppression
   on the lattice), a small grid at a finer resolution that also samples roll and pitch (one wide render
   per centre again; a roll/pitch/yaw hypothesis is a rotation about the centre, read through the lookup
   table). The best distinct hypotheses seed the refinement (one particle filter over all of them).
4. (The refinement, ``refine.py``.)
5. **Beyond** (``look_beyond``, for a refused result): the sweep sees only its volume, so a prior further
   off than its stated uncertainty leads it to the best look-alike inside, which the acceptance refuses
   while the warnings blame the map. A ring of centres just beyond the volume's largest extension, on a
   coarse lattice: if a view there, distinct from the refused pose, scores higher than the sweep's best,
   the refusal's warning says the prior may be further off than stated (a hint: a view whose map differs
   from the world can do the same).

Hypothesis states are ``(x, y, z, roll, pitch, yaw)`` in the model's local frame, degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose, yaw_fan_rotations
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.coarse import CostVolume, rotation_offsets, score_rotations, yaw_sectors
from semcityloc.localization.config import BeyondConfig, CascadeConfig, LocalConfig, SweepConfig
from semcityloc.render.scene import RenderScene

AXES = ("x", "y", "z", "yaw")
# A volume whose yaw half-width reaches this searches every heading (``SearchVolume.full_circle``): a prior
# without a usable heading (no compass, a photo without one: ``--prior-sigma yaw=60`` or more), or one
# whose yaw lattice would hold a turn (``yaw_turn``). Its yaw lattice closes on itself (``_lattice``): no
# yaw edge, no extension in yaw, no heading scored twice.
FULL_CIRCLE_HALF_DEG = 180.0
# What a refused result's warning starts with when ``look_beyond`` found a view outside scoring higher.
BEYOND_WARNING = "a view outside the search volume matches the image better than any inside"


@dataclass(frozen=True)
class SearchVolume:
    """A box around ``centre`` (6-vector state): half-widths in x/y (m), z (m), yaw (deg); roll and
    pitch are not swept but sampled locally within ``half_roll_pitch_deg``. No camera centre below
    ``floor_z`` (local frame, m; -inf: no floor)."""

    centre: np.ndarray
    half_xy_m: float
    half_z_m: float
    half_yaw_deg: float
    half_roll_pitch_deg: float
    floor_z: float = -math.inf

    @property
    def full_circle(self) -> bool:
        """Does the volume search every heading (``FULL_CIRCLE_HALF_DEG``)?"""
        return self.half_yaw_deg >= FULL_CIRCLE_HALF_DEG

    def as_dict(self) -> dict:
        """The half-widths (and a floor, when set; ``full_circle`` when every heading is searched) for a
        result's search record."""
        out = {
            "half_xy_m": self.half_xy_m,
            "half_z_m": self.half_z_m,
            "half_yaw_deg": self.half_yaw_deg,
            "half_roll_pitch_deg": self.half_roll_pitch_deg,
        }
        if math.isfinite(self.floor_z):
            out["floor_z"] = self.floor_z
        if self.full_circle:
            out["full_circle"] = True
        return out


def search_volume(
    prior_state: np.ndarray,
    uncertainty: PriorUncertainty,
    config: CascadeConfig,
    ground_z: float = -math.inf,
) -> SearchVolume:
    """The volume the cascade searches for a prior with this uncertainty (module docstring, step 1).
    ``ground_z``: the lowest ground near the prior (local frame); the volume's floor lies
    ``config.min_clearance_m`` above it. A yaw half-width whose lattice would hold a turn (``yaw_turn``:
    more than 59.33 deg of yaw sigma at the default 3 sigma and 2 deg step) is the full circle."""
    k = config.n_sigma
    half_yaw = min(max(k * uncertainty.yaw_deg, config.min_half_yaw_deg), FULL_CIRCLE_HALF_DEG)
    step_yaw = config.sweep.step_yaw_deg
    if 2 * _lattice_extent(half_yaw, step_yaw) + 1 >= yaw_turn(step_yaw):  # the lattice -n..n holds a turn
        half_yaw = FULL_CIRCLE_HALF_DEG
    return SearchVolume(
        centre=np.asarray(prior_state, dtype=np.float64).copy(),
        half_xy_m=max(k * uncertainty.xy_m, config.min_half_xy_m),
        half_z_m=max(k * uncertainty.z_m, config.min_half_z_m),
        half_yaw_deg=half_yaw,
        half_roll_pitch_deg=k * uncertainty.roll_pitch_deg,
        floor_z=float(ground_z) + config.min_clearance_m,
    )


@dataclass
class Sweep:
    """The scored lattice of stage 2 of the module docstring. Lattice index ``i`` on an axis is the value
    ``origin + i * step``; ``lo``/``hi`` the scored index box (inclusive), ``scores`` over that box."""

    origin: np.ndarray  # (4,) x, y, z, yaw of lattice index 0 (the prior's)
    step: np.ndarray  # (4,)
    lo: np.ndarray  # (4,) int
    hi: np.ndarray  # (4,) int
    scores: np.ndarray  # (nx, ny, nz, nyaw)
    roll: float
    pitch: float
    floor_index: float = -math.inf  # lowest z lattice index at or above the volume's floor
    full_circle: bool = False  # the yaw lattice closes on itself (every heading): yaw has no edge (a
    # full-circle volume's, or a yaw range grown to ``yaw_turn`` steps)
    extensions: list[str] = field(default_factory=list)  # e.g. ["z-", "x+"]
    at_edge: list[str] = field(default_factory=list)  # edges the best cell still sits on at the bound
    hypotheses: int = 0  # cells scored (the lattice plus any extension)

    def values(self, axis: int) -> np.ndarray:
        """The lattice values on ``axis`` (x, y, z, yaw) over the scored index box."""
        return self.origin[axis] + np.arange(self.lo[axis], self.hi[axis] + 1) * self.step[axis]

    def state(self, index: np.ndarray) -> np.ndarray:
        """(6,) state of a cell given by its position in ``scores``."""
        v = self.origin + (self.lo + np.asarray(index)) * self.step
        return np.array([v[0], v[1], v[2], self.roll, self.pitch, v[3]])

    def cost_volume(self) -> CostVolume:
        """The scored lattice as the paper's 4D cost volume (axis order x, y, z, yaw)."""
        return CostVolume(
            self.scores, self.values(0), self.values(1), self.values(2), self.values(3), self.roll, self.pitch
        )

    def best(self) -> np.ndarray:
        """Index in ``scores`` of the best-scoring cell."""
        return np.array(np.unravel_index(int(np.argmax(self.scores)), self.scores.shape))

    def score_margin(self) -> float:
        """Best score minus the best score of cells more than 2 steps away in x or y (NaN if none)."""
        s = self.scores
        b = self.best()
        far = np.ones(s.shape[:2], dtype=bool)
        far[max(0, b[0] - 2) : b[0] + 3, max(0, b[1] - 2) : b[1] + 3] = False
        return float(s[tuple(b)] - s[far].max()) if far.any() else float("nan")

    def top_distinct(self, k: int, radius: int) -> list[np.ndarray]:
        """Up to ``k`` cells, best first, none within ``radius`` lattice steps (all four axes) of a
        better kept one (greedy non-maximum suppression)."""
        flat = self.scores.reshape(-1)
        order = np.argsort(-flat, kind="stable")
        kept: list[np.ndarray] = []
        for f in order[: max(64 * k, 256)]:
            idx = np.array(np.unravel_index(int(f), self.scores.shape))
            if all(np.any(np.abs(idx - other) > radius) for other in kept):
                kept.append(idx)
                if len(kept) == k:
                    break
        return kept


def _lattice_extent(half: float, step: float) -> int:
    """Lattice indices -n..n cover +-half with spacing <= step."""
    return max(1, int(math.ceil(half / step - 1e-9)))


def yaw_turn(step_deg: float) -> int:
    """How many yaws ``step_deg`` apart make one turn: as many lie within 360 deg (180 at 2 deg), so that the
    seam between the first and the last is at least one step and less than two. A yaw lattice of this many
    is the whole circle: the volume searches the closed circle (``search_volume``) and the sweep grows yaw
    no further (``sweep``); one more would score a heading twice (or two within a step of each other)."""
    return max(1, int(math.floor(360.0 / step_deg + 1e-9)))


def _lattice(volume: SearchVolume, config: SweepConfig, max_centres: int) -> tuple[np.ndarray, np.ndarray]:
    """(step, n) of the lattice ``-n..n`` over ``volume`` per axis (x, y, z, yaw): the sweep's steps, the
    xy and z ones grown together until it needs at most ``max_centres`` camera centres. A full-circle
    volume's yaw lattice is the circle cut into 2n+1 equal steps of at most the sweep's (no heading
    twice, none beyond the circle)."""
    step = np.array([config.step_xy_m, config.step_xy_m, config.step_z_m, config.step_yaw_deg], dtype=float)
    half = np.array([volume.half_xy_m, volume.half_xy_m, volume.half_z_m, volume.half_yaw_deg])
    n = np.array([_lattice_extent(h, st) for h, st in zip(half, step, strict=True)])
    if volume.full_circle:
        n[3] = max(1, int(math.ceil((360.0 / config.step_yaw_deg - 1.0) / 2.0 - 1e-9)))
        step[3] = 360.0 / (2 * n[3] + 1)
    while float(2 * n[0] + 1) ** 2 * float(2 * n[2] + 1) > max_centres and n[:3].max() > 1:
        step[:3] *= 1.1
        n[:3] = [_lattice_extent(h, st) for h, st in zip(half[:3], step[:3], strict=True)]
    return step, n


def _floor_index(volume: SearchVolume, step_z: float) -> float:
    """The lowest z lattice index (spacing ``step_z`` from the volume's centre) at or above the volume's
    floor; -inf when it has none."""
    if not math.isfinite(volume.floor_z):
        return -math.inf
    return int(math.ceil((volume.floor_z - volume.centre[2]) / step_z - 1e-9))


class _SweepScorer:
    """Scores lattice cells of a sweep; keeps the base rotation and query fixed."""

    def __init__(self, scene, camera, query_labels, class_on, origin, step, roll, pitch):
        self.scene, self.camera, self.query, self.class_on = scene, camera, query_labels, class_on
        self.origin, self.step, self.roll, self.pitch = origin, step, roll, pitch
        self.R_base = Pose.from_xyz_rpy(np.zeros(3), roll, pitch, origin[3]).R
        self.count = 0

    def score(self, ix, iy, iz, iyaw) -> np.ndarray:
        """Scores (len(ix), len(iy), len(iz), len(iyaw)) of the cells with these lattice indices."""
        o, s = self.origin, self.step
        xs, ys, zs = o[0] + ix * s[0], o[1] + iy * s[1], o[2] + iz * s[2]
        yaws = o[3] + iyaw * s[3]
        gx, gy, gz = np.meshgrid(xs, ys, zs, indexing="ij")
        centres = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
        rotations = yaw_fan_rotations(self.roll, self.pitch, yaws)
        out = np.empty((len(centres), len(yaws)))
        for R_base, idx in yaw_sectors(self.camera, self.roll, self.pitch, yaws, self.R_base):
            offsets = rotation_offsets(R_base, rotations[idx])
            out[:, idx] = score_rotations(
                self.scene, self.camera, centres, R_base, offsets, self.query, self.class_on
            )
        self.count += out.size
        return out.reshape(len(xs), len(ys), len(zs), len(yaws))


def sweep(
    scene: RenderScene,
    camera: Camera,
    volume: SearchVolume,
    query_labels: np.ndarray,
    class_on: np.ndarray,
    config: SweepConfig,
) -> Sweep:
    """Stage 2 of the module docstring. ``camera``/``query_labels`` at the sweep's resolution."""
    c = volume.centre
    step, n = _lattice(volume, config, config.max_centres)
    origin = np.array([c[0], c[1], c[2], c[5]])
    scorer = _SweepScorer(scene, camera, query_labels, class_on, origin, step, float(c[3]), float(c[4]))
    lo, hi = -n.copy(), n.copy()
    bound = n + np.ceil(config.max_extensions * config.extension * n).astype(int)
    if volume.full_circle:
        bound[3] = n[3]  # every heading is scored already
    turn = yaw_turn(step[3])  # yaw grows to this many headings at most: then it is the whole circle
    lower = -bound.copy()  # lowest index an extension may reach, per axis
    floor_index = _floor_index(volume, step[2])
    if math.isfinite(floor_index):
        lo[2] = max(lo[2], floor_index)
        hi[2] = max(hi[2], lo[2])  # a prior further underground than its volume reaches: the floor's layer
        lower[2] = max(lower[2], floor_index)
    scores = scorer.score(*(np.arange(lo[a], hi[a] + 1) for a in range(4)))
    closed = bool(hi[3] - lo[3] + 1 >= turn)  # a full-circle volume's lattice is a turn
    result = Sweep(origin, step, lo, hi, scores, float(c[3]), float(c[4]), floor_index, full_circle=closed)
    for _ in range(config.max_extensions + 1):
        edges = _edges(result)
        if not edges:
            break
        grow = [(a, sgn) for a, sgn in edges if (hi[a] < bound[a] if sgn > 0 else lo[a] > lower[a])]
        if not grow:
            result.at_edge = [f"{AXES[a]}{'+' if s > 0 else '-'}" for a, s in edges]
            break
        for a, sgn in grow:
            amount = max(1, int(math.ceil(config.extension * n[a])))
            if a == 3:  # never past one turn: a heading once
                amount = min(amount, turn - (hi[3] - lo[3] + 1))
            if sgn > 0:
                new = np.arange(hi[a] + 1, min(hi[a] + amount, bound[a]) + 1)
            else:
                new = np.arange(max(lo[a] - amount, lower[a]), lo[a])
            ranges = [np.arange(lo[b], hi[b] + 1) for b in range(4)]
            ranges[a] = new
            block = scorer.score(*ranges)
            result.scores = (
                np.concatenate([result.scores, block], axis=a)
                if sgn > 0
                else np.concatenate([block, result.scores], axis=a)
            )
            if sgn > 0:
                hi[a] = new[-1]
            else:
                lo[a] = new[0]
            result.extensions.append(f"{AXES[a]}{'+' if sgn > 0 else '-'}")
        result.lo, result.hi = lo.copy(), hi.copy()
        result.full_circle = bool(hi[3] - lo[3] + 1 >= turn)  # grown to a turn: the whole circle
    else:
        result.at_edge = [f"{AXES[a]}{'+' if s > 0 else '-'}" for a, s in _edges(result)]
    result.hypotheses = scorer.count
    return result


def _edges(sw: Sweep) -> list[tuple[int, int]]:
    """(axis, +1/-1) of every volume face the best cell lies on (axes with a single sample excluded; the
    floor is not a face: no camera lies below it; nor is a full circle of yaw)."""
    best = sw.best()
    out = []
    for a in range(4):
        size = sw.scores.shape[a]
        if size < 3 or (a == 3 and sw.full_circle):
            continue
        if best[a] == 0:
            if a == 2 and sw.lo[2] <= sw.floor_index:
                continue
            out.append((a, -1))
        elif best[a] == size - 1:
            out.append((a, +1))
    return out


@dataclass(frozen=True)
class Beyond:
    """The best distinct view of the ring beyond the search's reach (``look_beyond``)."""

    score: float  # its sweep score (mean per-class IoU at the sweep's resolution)
    state: np.ndarray  # (6,) its cell
    offset_xy_m: float  # its horizontal distance from the prior
    hypotheses: int  # ring cells scored

    def as_dict(self) -> dict:
        """Score, state and xy offset of the best cell beyond the volume, for the search record."""
        return {"score": self.score, "state": self.state.tolist(), "offset_xy_m": self.offset_xy_m}


def look_beyond(
    scene: RenderScene,
    camera: Camera,
    volume: SearchVolume,
    reach_xy_m: float,
    found_xy: np.ndarray,
    query_labels: np.ndarray,
    class_on: np.ndarray,
    sweep_config: SweepConfig,
    config: BeyondConfig,
) -> Beyond | None:
    """Stage 5 of the module docstring: the ring of centres whose x or y lies beyond ``reach_xy_m`` from the
    prior, up to ``config.factor_xy`` x the volume's half-width, at the prior's roll and pitch, on a lattice
    of the sweep's steps grown to ``config.max_centres`` over the whole box; cells within
    ``config.exclude_m`` of ``found_xy`` (the pose found, local x/y) are the same view and left out. None
    when the ring holds no cell."""
    box = replace(
        volume,
        half_xy_m=config.factor_xy * volume.half_xy_m,
        half_z_m=config.factor_z * volume.half_z_m,
    )
    step, n = _lattice(box, sweep_config, config.max_centres)
    c = volume.centre
    origin = np.array([c[0], c[1], c[2], c[5]])
    scorer = _SweepScorer(scene, camera, query_labels, class_on, origin, step, float(c[3]), float(c[4]))
    ixy = np.arange(-n[0], n[0] + 1)
    outside = np.abs(ixy * step[0]) > reach_xy_m
    if not outside.any():
        return None
    lo_z = int(max(-n[2], _floor_index(volume, step[2])))  # as the sweep: never below the floor
    iz = np.arange(lo_z, max(n[2], lo_z) + 1)
    iyaw = np.arange(-n[3], n[3] + 1)
    best: tuple[float, np.ndarray] | None = None
    for ix, iy in ((ixy[outside], ixy), (ixy[~outside], ixy[outside])):  # the ring as two blocks
        if ix.size == 0 or iy.size == 0:
            continue
        scores = scorer.score(ix, iy, iz, iyaw)
        x, y = origin[0] + ix * step[0], origin[1] + iy * step[1]
        same = np.hypot(x[:, None] - found_xy[0], y[None, :] - found_xy[1]) < config.exclude_m
        scores = np.where(same[:, :, None, None], -np.inf, scores)
        k = np.unravel_index(int(np.argmax(scores)), scores.shape)
        if np.isfinite(scores[k]) and (best is None or scores[k] > best[0]):
            z, yaw = origin[2] + iz[k[2]] * step[2], origin[3] + iyaw[k[3]] * step[3]
            best = (float(scores[k]), np.array([x[k[0]], y[k[1]], z, c[3], c[4], yaw]))
    if best is None:
        return None
    score, state = best
    offset = float(np.hypot(state[0] - c[0], state[1] - c[1]))
    return Beyond(score, state, offset, scorer.count)


@dataclass
class Hypotheses:
    """Distinct hypotheses from the local stage, best first."""

    states: np.ndarray  # (K, 6)
    scores: np.ndarray  # (K,) mean per-class IoU at the local stage's resolution
    evaluated: int  # hypotheses scored in the local stage


def local_search(
    scene: RenderScene,
    camera: Camera,
    seeds: list[np.ndarray],
    step: np.ndarray,
    roll_pitch_sigma_deg: float,
    query_labels: np.ndarray,
    class_on: np.ndarray,
    config: LocalConfig,
) -> Hypotheses:
    """Stage 3 of the module docstring. ``seeds``: (6,) states of the kept sweep cells; ``step``: the
    sweep's (x, y, z, yaw) steps; ``camera``/``query_labels`` at the local resolution."""

    def offsets(n: int, half: float) -> np.ndarray:
        return np.linspace(-half, half, n) if n > 1 else np.zeros(1)

    dxy = offsets(config.n_xy, step[0] / 2)
    dz = offsets(config.n_z, step[2] / 2)
    dyaw = offsets(config.n_yaw, step[3])
    s = config.roll_pitch_sigmas * roll_pitch_sigma_deg
    drp = np.array([-s, 0.0, s]) if s > 0 else np.zeros(1)
    dr, dp, dy = np.meshgrid(drp, drp, dyaw, indexing="ij")
    dr, dp, dy = dr.ravel(), dp.ravel(), dy.ravel()
    gx, gy, gz = np.meshgrid(dxy, dxy, dz, indexing="ij")
    dcentres = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)

    # Every sweep cell has the prior's roll and pitch, so one table of offsets serves all seeds.
    roll0, pitch0, yaw0 = (float(v) for v in seeds[0][3:6])
    n_rot = len(dr)
    R_base0 = Pose.from_xyz_rpy(np.zeros(3), roll0, pitch0, yaw0).R
    R_hyps0 = Pose.from_xyz_rpy(np.zeros((n_rot, 3)), roll0 + dr, pitch0 + dp, yaw0 + dy).R
    offsets = rotation_offsets(R_base0, R_hyps0)
    seeds_arr = np.asarray(seeds, dtype=np.float64)
    if not np.allclose(seeds_arr[:, 3:5], seeds_arr[0, 3:5]):
        raise ValueError("local_search: seeds must share roll and pitch")  # internal invariant
    R_seed = Pose.from_xyz_rpy(np.zeros((len(seeds), 3)), seeds_arr[:, 3], seeds_arr[:, 4], seeds_arr[:, 5]).R
    centres = (seeds_arr[:, None, :3] + dcentres[None]).reshape(-1, 3)
    R_bases = np.repeat(R_seed, len(dcentres), axis=0)
    scores = score_rotations(scene, camera, centres, R_bases, offsets, query_labels, class_on).reshape(-1)
    states = np.empty((len(seeds), len(dcentres), n_rot, 6))
    states[..., :3] = centres.reshape(len(seeds), len(dcentres), 1, 3)
    states[..., 3] = roll0 + dr
    states[..., 4] = pitch0 + dp
    states[..., 5] = seeds_arr[:, 5, None, None] + dy
    states = states.reshape(-1, 6)
    order = np.argsort(-scores, kind="stable")
    kept: list[int] = []
    for i in order:
        st = states[i]
        if all(not _same(st, states[j], config) for j in kept):
            kept.append(int(i))
            if len(kept) == config.keep:
                break
    return Hypotheses(states[kept], scores[kept], int(scores.size))


def _same(a: np.ndarray, b: np.ndarray, config: LocalConfig) -> bool:
    return (
        np.hypot(a[0] - b[0], a[1] - b[1]) < config.distinct_xy_m
        and abs(a[2] - b[2]) < config.distinct_z_m
        and abs(a[5] - b[5]) < config.distinct_yaw_deg
    )
