"""``evaluation/scoring_rules.py``: log-loss and Brier per result, and the paired bootstrap of their
difference between two acceptance models on the same results."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semcityloc.errors import ShapeError
from semcityloc.evaluation.scoring_rules import brier_terms, log_loss_terms, paired_difference


def test_terms_of_known_probabilities():
    p, y = np.array([0.9, 0.9, 0.5, 0.0]), np.array([1, 0, 1, 0])
    assert log_loss_terms(p, y) == pytest.approx([-math.log(0.9), -math.log(0.1), math.log(2), 0.0], abs=1e-8)
    assert brier_terms(p, y) == pytest.approx([0.01, 0.81, 0.25, 0.0])
    assert np.isfinite(log_loss_terms(np.array([0.0]), np.array([1]))).all()  # clipped, not infinite


def _outcomes(n=400, seed=0):
    rng = np.random.default_rng(seed)
    y = (rng.random(n) < 0.6).astype(float)
    sharp = np.clip(np.where(y == 1, 0.85, 0.15) + rng.normal(0, 0.1, n), 0.01, 0.99)  # informative
    vague = np.clip(0.6 + rng.normal(0, 0.1, n), 0.01, 0.99)  # knows only the base rate
    return sharp, vague, y


@pytest.mark.parametrize("rule", ["log-loss", "brier"])
def test_a_better_model_is_surely_better_and_a_model_ties_itself(rule):
    sharp, vague, y = _outcomes()
    d = paired_difference(sharp, vague, y, rule=rule)
    assert d.mean < d.high < 0 and d.low < d.mean
    assert paired_difference(vague, sharp, y, rule=rule).low > 0
    same = paired_difference(sharp, sharp, y, rule=rule)
    assert same.mean == same.low == same.high == 0.0


def test_groups_are_resampled_together():
    """A result seen five times is one piece of evidence, not five: as five copies in one group it gets
    the interval of the single results; as five independent results a falsely narrow one."""
    sharp, vague, y = _outcomes(n=120, seed=1)
    sharp = np.where(np.arange(120) % 2 == 0, sharp, vague)  # a small, uncertain difference
    single = paired_difference(sharp, vague, y, seed=3)
    rep = lambda a: np.repeat(a, 5)  # noqa: E731
    grouped = paired_difference(rep(sharp), rep(vague), rep(y), groups=np.repeat(np.arange(120), 5), seed=3)
    naive = paired_difference(rep(sharp), rep(vague), rep(y), seed=3)
    assert grouped.mean == pytest.approx(single.mean)
    assert (grouped.low, grouped.high) == pytest.approx((single.low, single.high))
    assert grouped.groups == 120 and naive.groups == 600
    assert naive.high - naive.low < 0.6 * (grouped.high - grouped.low)


def test_bad_inputs_are_typed_errors():
    with pytest.raises(ShapeError, match="3 probabilities for 2 outcomes"):
        log_loss_terms(np.array([0.1, 0.2, 0.3]), np.array([0, 1]))
    with pytest.raises(ShapeError, match="within"):
        brier_terms(np.array([1.5]), np.array([1]))
    with pytest.raises(ShapeError, match="0 or 1"):
        brier_terms(np.array([0.5]), np.array([2]))
    with pytest.raises(ShapeError, match="group labels"):
        paired_difference(np.array([0.5, 0.5]), np.array([0.4, 0.4]), np.array([1, 0]), groups=np.array([0]))
    with pytest.raises(ShapeError, match="no results"):
        paired_difference(np.array([]), np.array([]), np.array([]))
    with pytest.raises(ValueError, match="resamples"):
        paired_difference(np.array([0.5]), np.array([0.5]), np.array([1]), resamples=0)
    with pytest.raises(ValueError, match="level"):
        paired_difference(np.array([0.5]), np.array([0.5]), np.array([1]), level=95)
    with pytest.raises(ValueError, match="unknown scoring rule"):
        paired_difference(np.array([0.5]), np.array([0.5]), np.array([1]), rule="ece")
