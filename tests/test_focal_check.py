"""The per-image focal-length check (``localization.focal_check``, stop 53): an accepted oblique pose whose
view fits a focal length a few % off better is warned about; the right focal length and nadir views are
not."""

from dataclasses import replace

import pytest

from helpers import CAMERA, perturbed, view
from semcityloc.errors import ParameterError
from semcityloc.localization.config import FocalCheckConfig, LocalizerConfig
from semcityloc.localization.focal_check import (
    FOCAL_WARNING,
    FocalCheck,
    focal_warning,
    vertex,
    with_focal_scale,
)
from semcityloc.localization.localize import Localizer
from semcityloc.localization.result import LOCALIZED
from semcityloc.render import Renderer

# (dx, dy, height, roll, pitch from nadir, yaw): two obliques and a nadir view of the generated city
OBLIQUES = [(-30.0, 15.0, 90.0, -1.0, 40.0, 200.0), (20.0, -25.0, 80.0, 0.5, 45.0, 30.0)]
NADIR = (10.0, -20.0, 80.0, 0.5, 1.0, 30.0)


@pytest.fixture(scope="module")
def views(generated_lod2):
    """The views rendered with the true camera; each prior a few metres and degrees off."""
    renderer = Renderer(generated_lod2, engine="numba")
    out = []
    for k, spec in enumerate([*OBLIQUES, NADIR]):
        true = view(generated_lod2, *spec)
        seen = renderer.render(CAMERA, true, depth=True)
        out.append((perturbed(true, [2.0 - k, 1.0, 3.0], dyaw=1.5), seen.labels[0], seen.depth[0]))
    return Localizer(generated_lod2), out


def warned(result) -> list[str]:
    return [w for w in result.warnings if w.startswith(FOCAL_WARNING)]


@pytest.mark.parametrize("k", range(len(OBLIQUES)))
def test_an_oblique_view_with_the_focal_length_6_percent_long_warns(views, k):
    localizer, out = views
    prior, labels, depth = out[k]
    result = localizer.localize(with_focal_scale(CAMERA, 1.06), prior, labels, depth)
    assert result.status == LOCALIZED  # accepted all the same: the check is what tells
    (warning,) = warned(result)
    assert "shorter than the stated one" in warning and "too far" in warning
    assert "intrinsics=" in warning and "calibrate_focal='on'" in warning
    assert result.search["focal_check"]["scale"] < 0.99


def test_an_oblique_view_with_the_focal_length_6_percent_short_warns(views):
    localizer, out = views
    prior, labels, depth = out[0]
    result = localizer.localize(with_focal_scale(CAMERA, 0.94), prior, labels, depth)
    assert result.status == LOCALIZED
    (warning,) = warned(result)
    assert "longer than the stated one" in warning and "too close" in warning


@pytest.mark.parametrize("k", range(len(OBLIQUES)))
def test_the_right_focal_length_does_not_warn(views, k):
    localizer, out = views
    prior, labels, depth = out[k]
    result = localizer.localize(CAMERA, prior, labels, depth)
    assert result.status == LOCALIZED and not warned(result)
    assert abs(result.search["focal_check"]["scale"] - 1.0) <= FocalCheckConfig().margin
    assert result.timings["focal_check_s"] > 0.0


def test_a_nadir_view_is_not_checked_and_the_check_can_be_switched_off(views):
    localizer, out = views
    prior, labels, depth = out[-1]
    result = localizer.localize(with_focal_scale(CAMERA, 1.06), prior, labels, depth)
    assert "focal_check" not in result.search and not warned(result)  # focal length and height: one unknown
    off = replace(LocalizerConfig(), focal_check=FocalCheckConfig(enabled=False))
    prior, labels, depth = out[0]
    result = localizer.localize(with_focal_scale(CAMERA, 1.06), prior, labels, depth, config=off)
    assert "focal_check" not in result.search and not warned(result)


def test_the_vertex_and_the_warning_follow_the_scores():
    assert vertex((-0.01, -0.01), 0.03) == pytest.approx(1.0)
    assert vertex((0.0, -0.02), 0.03) < 1.0 < vertex((-0.02, 0.0), 0.03)
    assert vertex((0.01, 0.01), 0.03) is None  # no peak: no verdict
    assert focal_warning(FocalCheck(None, (0.01, 0.01), 0.03, 80.0), 0.01) is None
    assert focal_warning(FocalCheck(1.005, (-0.01, -0.008), 0.03, 80.0), 0.01) is None
    assert "2.0 % longer" in focal_warning(FocalCheck(1.02, (-0.02, -0.002), 0.03, 80.0), 0.01)


@pytest.mark.parametrize(
    "field, value", [("margin", -0.01), ("step", 0.0), ("particles", 0), ("enabled", "yes"), ("step", True)]
)
def test_a_bad_focal_check_setting_is_refused(field, value):
    with pytest.raises(ParameterError, match=f"focal_check.{field}"):
        FocalCheckConfig(**{field: value})
