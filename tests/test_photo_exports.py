"""A photo run's notes about its priors as a whole (``photo_exports.prior_offset_notes``): a shared height
or horizontal offset is said, independent GNSS noise is not."""

from __future__ import annotations

import math

import numpy as np

from semcityloc.benchmark.photo_exports import OFFSET_MIN_PHOTOS, prior_offset_notes


def test_a_shared_height_offset_is_said_with_its_size_and_side():
    rng = np.random.default_rng(0)
    moves = np.c_[rng.normal(0, 2, 12), rng.normal(0, 2, 12), -20.7 + rng.normal(0, 1, 12)]
    notes = prior_offset_notes(moves)
    assert len(notes) == 1 and "12 localized photos" in notes[0] and "below their priors" in notes[0]
    median = float(np.median(moves[:, 2]))
    assert f"a median {abs(median):.1f} m below" in notes[0] and "height reference" in notes[0]
    assert "above their priors" in prior_offset_notes(moves * [1, 1, -1])[0]
    assert "--prior-sigma" not in notes[0]  # nothing was refused at the volume's edge
    spread = 1.4826 * float(np.median(np.abs(moves[:, 2] - median)))
    sigma = math.ceil((abs(median) + 2 * spread) / 3)  # 3 sigma covers the offset and twice the spread
    (edge,) = prior_offset_notes(moves, at_edge=3)
    assert f"(3 were; or run again with --prior-sigma z={sigma})" in edge and 7 <= sigma <= 9


def test_a_shared_horizontal_offset_is_said_apart_from_the_height():
    rng = np.random.default_rng(1)
    moves = np.c_[8.0 + rng.normal(0, 1, 10), -6.0 + rng.normal(0, 1, 10), rng.normal(0, 3, 10)]
    (note,) = prior_offset_notes(moves)
    assert "horizontally" in note and "x +8" in note and "y -6" in note and "--crs" in note


def test_independent_priors_and_few_photos_say_nothing():
    rng = np.random.default_rng(2)
    said = 0
    for _ in range(200):  # the realistic benchmark's priors: independent per photo
        r, a = rng.uniform(2, 15, 20), rng.uniform(0, 2 * np.pi, 20)
        said += bool(prior_offset_notes(np.c_[r * np.cos(a), r * np.sin(a), rng.uniform(-30, 30, 20)]))
    assert said == 0
    shared = np.tile([0.0, 0.0, -25.0], (OFFSET_MIN_PHOTOS - 1, 1))
    assert prior_offset_notes(shared) == [] and prior_offset_notes(np.zeros((0, 3))) == []
    assert prior_offset_notes(np.tile([1.0, -2.0, 4.0], (10, 1))) == []  # within the stated uncertainty
    mixed = np.r_[np.tile([0.0, 0.0, -20.0], (8, 1)), np.tile([0.0, 0.0, 20.0], (4, 1))]
    assert prior_offset_notes(mixed) == []  # two flights' offsets, or none: not one shared offset
