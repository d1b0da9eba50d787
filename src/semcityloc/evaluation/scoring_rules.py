"""Proper scoring rules of a probability of being right, and a paired bootstrap to compare two of them.

Why: an acceptance model (``localization/confidence.py``) is judged on held-out results by how well its
probabilities score, and two candidate models by the DIFFERENCE of their scores on the same results. The
expected calibration error is a poor judge of a small change: on a few hundred results in 10 bins it
moves by more than the change with any reshaping of the probabilities (stop 41). Log-loss and Brier are
proper scoring rules whose per-result terms can be resampled, so a difference gets an interval.

The bootstrap resamples GROUPS (e.g. one query seen under several conditions), not results: results of
one query are correlated, and treating them as independent would narrow the interval.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semcityloc.errors import ParameterError, ShapeError, unknown_choice

# Probabilities are clipped away from 0 and 1 before the logarithm (one certain miss would be infinite).
LOG_LOSS_CLIP = 1e-9


def _checked(p: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(p, dtype=float).reshape(-1)
    y = np.asarray(y, dtype=float).reshape(-1)
    if p.shape != y.shape:
        raise ShapeError(f"{p.size} probabilities for {y.size} outcomes")
    if np.any(~np.isfinite(p)) or np.any((p < 0) | (p > 1)):
        raise ShapeError("probabilities must be finite and within [0, 1]")
    if np.any((y != 0) & (y != 1)):
        raise ShapeError("outcomes must be 0 or 1")
    return p, y


def log_loss_terms(p: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per-result log-loss ``-log p`` if right, ``-log (1 - p)`` if wrong (natural log)."""
    p, y = _checked(p, y)
    q = np.clip(p, LOG_LOSS_CLIP, 1.0 - LOG_LOSS_CLIP)
    return -(y * np.log(q) + (1.0 - y) * np.log(1.0 - q))


def brier_terms(p: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per-result Brier score ``(p - y)^2``."""
    p, y = _checked(p, y)
    return (p - y) ** 2


@dataclass(frozen=True)
class PairedDifference:
    """Mean of (score of A - score of B) over the results, and its bootstrap percentile interval.

    Lower is better for both rules, so a negative ``mean`` (and ``high`` < 0) says A scores better.
    """

    rule: str
    mean: float
    low: float
    high: float
    level: float
    groups: int

    def __str__(self) -> str:
        interval = f"[{self.low:+.4f}, {self.high:+.4f}]"
        return f"{self.rule} {self.mean:+.4f} {interval} ({round(100 * self.level)} %, {self.groups} groups)"


def paired_difference(
    p_a: np.ndarray,
    p_b: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray | None = None,
    rule: str = "log-loss",
    resamples: int = 2000,
    level: float = 0.95,
    seed: int = 0,
) -> PairedDifference:
    """Mean difference of a scoring rule between two models' probabilities on the same results, with a
    percentile interval from resampling ``groups`` (default: every result its own group) with replacement.
    Deterministic for a seed."""
    terms = {"log-loss": log_loss_terms, "brier": brier_terms}
    if rule not in terms:
        raise unknown_choice("scoring rule", rule, terms)
    if not 0.0 < level < 1.0:
        raise ParameterError(f"level must be within (0, 1), not {level}: pass a confidence level, e.g. 0.95")
    if not isinstance(resamples, int) or resamples < 1:
        raise ParameterError(f"resamples must be a positive integer, not {resamples!r}: pass e.g. 2000")
    d = terms[rule](p_a, y) - terms[rule](p_b, y)
    if d.size == 0:
        raise ShapeError("no results to compare")
    if groups is None:
        groups = np.arange(d.size)
    groups = np.asarray(groups).reshape(-1)
    if groups.size != d.size:
        raise ShapeError(f"{groups.size} group labels for {d.size} results")
    _, index = np.unique(groups, return_inverse=True)
    n_groups = int(index.max()) + 1
    sums = np.bincount(index, weights=d, minlength=n_groups)
    counts = np.bincount(index, minlength=n_groups).astype(float)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, n_groups, size=(resamples, n_groups))
    means = sums[draws].sum(axis=1) / counts[draws].sum(axis=1)
    tail = 100 * (1.0 - level) / 2
    low, high = np.percentile(means, [tail, 100 - tail])
    return PairedDifference(rule, float(d.mean()), float(low), float(high), level, n_groups)
