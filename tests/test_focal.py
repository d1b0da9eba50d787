"""A flight's focal length from its oblique images (``localization.focal``)."""

from __future__ import annotations

import pytest

from helpers import CAMERA, perturbed, view
from semcityloc.errors import ParameterError
from semcityloc.localization.focal import (
    MIN_IMAGES,
    FocalView,
    estimate_focal_scale,
)
from semcityloc.localization.focal_check import is_oblique, with_focal_scale
from semcityloc.localization.localize import Localizer
from semcityloc.render import Renderer

# (dx, dy, height, roll, pitch from nadir, yaw) of the flight's views over the generated city
OBLIQUES = [
    (-30.0, 15.0, 90.0, -1.0, 40.0, 200.0),
    (20.0, -25.0, 80.0, 0.5, 45.0, 30.0),
    (-10.0, -30.0, 85.0, 0.0, 35.0, 120.0),
    (25.0, 20.0, 95.0, 1.0, 50.0, 300.0),
    (0.0, 0.0, 75.0, -0.5, 40.0, 80.0),
    (-25.0, -10.0, 90.0, 0.0, 45.0, 250.0),
]
NADIR = (10.0, -20.0, 80.0, 0.5, 1.0, 30.0)


@pytest.fixture(scope="module")
def flight(generated_lod2):
    """The views rendered with the true camera; each prior a few metres and degrees off."""
    renderer = Renderer(generated_lod2, engine="numba")
    views = []
    for k, spec in enumerate([*OBLIQUES, NADIR]):
        true = view(generated_lod2, *spec)
        out = renderer.render(CAMERA, true, depth=True)
        prior = perturbed(true, [3.0 - k, 2.0, 4.0], dyaw=2.0)
        views.append((true, prior, out.labels[0], out.depth[0]))
    return Localizer(generated_lod2), views


@pytest.mark.slow
def test_a_focal_length_2_5_percent_short_is_found_from_the_obliques(flight):
    localizer, views = flight
    stated = with_focal_scale(CAMERA, 0.975)  # what an EXIF 35 mm-equivalent value might say
    estimate = estimate_focal_scale(localizer, [FocalView(stated, p, lab, d) for _, p, lab, d in views])
    assert estimate.reason is None and estimate.images == len(OBLIQUES)  # the nadir view is left out
    assert estimate.scale == pytest.approx(1 / 0.975, abs=0.008)
    assert max(estimate.curve) == 0.0 and min(estimate.curve) < 0.0


@pytest.mark.slow
def test_the_right_focal_length_is_kept(flight):
    localizer, views = flight
    estimate = estimate_focal_scale(localizer, [FocalView(CAMERA, p, lab, d) for _, p, lab, d in views])
    assert estimate.scale == pytest.approx(1.0, abs=0.008)


def test_too_few_obliques_or_a_bad_grid_give_no_estimate_and_say_why(flight):
    localizer, views = flight
    nadir = views[-1]
    assert not is_oblique(nadir[1]) and is_oblique(views[0][1])
    few = [FocalView(CAMERA, p, lab, d) for _, p, lab, d in views[: MIN_IMAGES - 1]] + [
        FocalView(CAMERA, nadir[1], nadir[2], nadir[3])
    ]
    estimate = estimate_focal_scale(localizer, few)
    assert estimate.scale is None and f"need {MIN_IMAGES}" in estimate.reason
    assert estimate.as_dict()["scale"] is None
    with pytest.raises(ParameterError, match="increasing"):
        estimate_focal_scale(localizer, few, scales=(1.0, 0.99, 1.01))
