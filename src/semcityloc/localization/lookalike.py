"""The acceptance's look for a look-alike: is there another pose, more than 5 m or 5 deg from the one found,
that the image fits as well? (stop 52)

Why: in a neighbourhood of equal houses the view one house along (or one row over) scores within a few
thousandths of the truth, and the probability's margins do not see it: ``hypothesis_margin`` compares
the local stage's hypotheses (about 2 m apart, before refinement), ``score_margin`` the sweep's cells at
32 x 24 pixels. The audit's grid of identical houses had poses 14-25 m off accepted at 0.84-0.97.

How: the sweep's best other peak (``distant_peak``: a cell that is the best of its x/y neighbours, more
than ``LookalikeConfig.min_distance_m`` from the pose found) goes through one local grid with roll and
pitch (``cascade.local_search``) and a small refinement of its own (``refine_stage.Refiner.refine_lookalike``:
a small filter and the polish, the same score at the same resolution with the same prior term). If the
refined pose still lies more than ``min_distance_m`` / ``min_rotation_deg`` from the pose found
(``is_distinct``), the **look-alike margin** is the pose's final score minus that pose's (``Lookalike``);
else there is no look-alike (NaN). An accepted pose whose margin is below ``min_margin`` is refused with
``result.REASON_AMBIGUOUS`` and a reason naming where the look-alike lies (``ambiguous_reason``).

Off by default (``LookalikeConfig.enabled``; the ``lookalikes`` preset turns it on): held out on Berlin it
refused three right poses and no wrong one, at 1.3-1.4 x the time (docs/localization.md, "Look-alikes").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semcityloc.geometry.errors import rotation_error_deg
from semcityloc.geometry.pose import Pose
from semcityloc.localization.cascade import Sweep

COMPASS = ("east", "north-east", "north", "north-west", "west", "south-west", "south", "south-east")


@dataclass(frozen=True)
class Lookalike:
    """The refined look-alike: its ``state`` (local frame), final ``score`` and the pose's ``margin`` over
    it (pose's score minus this one's), its offset from the pose (``offset_m`` horizontal, ``dz_m``,
    ``rotation_deg``)."""

    state: np.ndarray
    score: float
    margin: float
    offset_xy: tuple[float, float]
    dz_m: float
    rotation_deg: float

    @property
    def offset_m(self) -> float:
        """Horizontal distance from the pose found (m)."""
        return float(math.hypot(*self.offset_xy))

    def as_dict(self) -> dict:
        """Plain values for ``result.search["lookalike"]``."""
        return {
            "state": [float(v) for v in self.state],
            "score": self.score,
            "margin": self.margin,
            "offset_m": self.offset_m,
            "direction": compass(*self.offset_xy),
            "dz_m": self.dz_m,
            "rotation_deg": self.rotation_deg,
        }


def distant_peak(sw: Sweep, found_state: np.ndarray, min_distance_m: float) -> np.ndarray | None:
    """(6,) state of the sweep's best cell that is a peak in x/y (no better cell among its 8 neighbours,
    each column's best over z and yaw) and lies more than ``min_distance_m`` horizontally from
    ``found_state``; None when no such cell exists. A peak, not merely a cell: the best cell just past
    ``min_distance_m`` is mostly the flank of the pose's own peak, and would refine back onto it."""
    column = sw.scores.max(axis=(2, 3))  # (nx, ny)
    padded = np.pad(column, 1, constant_values=-np.inf)
    nx, ny = column.shape
    neighbours = np.stack(
        [padded[1 + dx : 1 + dx + nx, 1 + dy : 1 + dy + ny] for dx in (-1, 0, 1) for dy in (-1, 0, 1)]
    )
    peak = column >= neighbours.max(axis=0)
    xs, ys = sw.values(0), sw.values(1)
    far = np.hypot(xs[:, None] - found_state[0], ys[None, :] - found_state[1]) > min_distance_m
    candidates = np.where(peak & far, column, -np.inf)
    if not np.isfinite(candidates).any():
        return None
    ix, iy = np.unravel_index(int(np.argmax(candidates)), candidates.shape)
    iz, iyaw = np.unravel_index(int(np.argmax(sw.scores[ix, iy])), sw.scores.shape[2:])
    return sw.state(np.array([ix, iy, iz, iyaw]))


def is_distinct(a: np.ndarray, b: np.ndarray, min_distance_m: float, min_rotation_deg: float) -> bool:
    """Do states ``a`` and ``b`` lie more than ``min_distance_m`` apart (camera centres, horizontally) or
    turned by more than ``min_rotation_deg`` (two different answers by the 5 m / 5 deg measure)?"""
    if math.hypot(a[0] - b[0], a[1] - b[1]) > min_distance_m:
        return True
    return float(rotation_error_deg(Pose.from_state(a), Pose.from_state(b))) > min_rotation_deg


def lookalike_of(found_state: np.ndarray, found_score: float, state: np.ndarray, score: float) -> Lookalike:
    """The ``Lookalike`` at ``state`` with its final ``score`` against the pose found (``found_state`` and
    its final ``found_score``): the margin is ``found_score - score``."""
    d = np.asarray(state, dtype=np.float64) - np.asarray(found_state, dtype=np.float64)
    rotation = float(rotation_error_deg(Pose.from_state(state), Pose.from_state(found_state)))
    return Lookalike(
        np.asarray(state, dtype=np.float64),
        float(score),
        float(found_score - score),
        (float(d[0]), float(d[1])),
        float(d[2]),
        rotation,
    )


def compass(dx: float, dy: float) -> str:
    """The direction of a local (east, north) offset in eight compass points (x east, y north)."""
    sector = int(round(math.degrees(math.atan2(dy, dx)) / 45.0)) % 8
    return COMPASS[sector]


def ambiguous_reason(lookalike: dict, min_margin: float) -> str:
    """What follows ``REASON_AMBIGUOUS`` in a refused result's reason: where the look-alike lies and how
    close its score came (``lookalike``: ``Lookalike.as_dict``, as ``result.search["lookalike"]`` holds
    it)."""
    where = f"{lookalike['offset_m']:.0f} m {lookalike['direction']}"
    dz = lookalike["dz_m"]
    if abs(dz) >= 1.0:
        where += f", {abs(dz):.0f} m {'higher' if dz > 0 else 'lower'}"
    if lookalike["rotation_deg"] > 1.0:
        where += f", turned {lookalike['rotation_deg']:.0f} deg"
    margin = lookalike["margin"]
    if margin < 0.0:
        how = f"scores {-margin:.3f} higher than the pose found"
    else:
        how = f"scores within {margin:.3f} of the pose found"
    return (
        f"a look-alike {where} {how} (the look-alike margin must be at least {min_margin:g}: the image fits "
        "both, e.g. a row of equal houses); a smaller prior uncertainty may tell them apart"
    )
