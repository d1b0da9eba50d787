"""The per-image focal-length check (``localization.focal_check``, stop 53): an accepted oblique pose whose
view fits a focal length a few % off better is warned about; the right focal length and nadir views are
not. Since stop 54 the pose is found again with the focal scale the view fits (``FocalCheckConfig.correct``)
and kept when it fits the image better; ``correct=False`` is stop 53's warning alone."""

from dataclasses import replace

import pytest

from helpers import CAMERA, perturbed, view
from semcityloc.errors import ParameterError
from semcityloc.evaluation.metrics import pose_errors
from semcityloc.geometry.pose import Pose
from semcityloc.localization import focal_check
from semcityloc.localization.config import FocalCheckConfig, LocalizerConfig
from semcityloc.localization.focal_check import (
    FOCAL_WARNING,
    FocalCheck,
    corrected_warning,
    correction_scale,
    focal_scale_used,
    focal_warning,
    found_camera,
    vertex,
    with_focal_scale,
)
from semcityloc.localization.localize import Localizer
from semcityloc.localization.result import LOCALIZED
from semcityloc.render import Renderer

# (dx, dy, height, roll, pitch from nadir, yaw): two obliques and a nadir view of the generated city
OBLIQUES = [(-30.0, 15.0, 90.0, -1.0, 40.0, 200.0), (20.0, -25.0, 80.0, 0.5, 45.0, 30.0)]
NADIR = (10.0, -20.0, 80.0, 0.5, 1.0, 30.0)
WARN_ONLY = replace(LocalizerConfig(), focal_check=FocalCheckConfig(correct=False))  # stop 53's check
CORRECT = LocalizerConfig.preset("focal-correct")  # the correction: opt-in (stop 54)


@pytest.fixture(scope="module")
def views(generated_lod2):
    """The views rendered with the true camera; each prior a few metres and degrees off."""
    renderer = Renderer(generated_lod2, engine="numba")
    out = []
    for k, spec in enumerate([*OBLIQUES, NADIR]):
        true = view(generated_lod2, *spec)
        seen = renderer.render(CAMERA, true, depth=True)
        out.append((perturbed(true, [2.0 - k, 1.0, 3.0], dyaw=1.5), seen.labels[0], seen.depth[0], true))
    return Localizer(generated_lod2), out


def warned(result) -> list[str]:
    return [w for w in result.warnings if w.startswith(FOCAL_WARNING)]


def not_checked(result) -> list[str]:
    return [w for w in result.warnings if w.startswith(focal_check.NOT_CHECKED_WARNING)]


@pytest.mark.parametrize("k", range(len(OBLIQUES)))
def test_an_oblique_view_with_the_focal_length_6_percent_long_warns(views, k):
    localizer, out = views
    prior, labels, depth, _ = out[k]
    result = localizer.localize(with_focal_scale(CAMERA, 1.06), prior, labels, depth, config=WARN_ONLY)
    assert result.status == LOCALIZED  # accepted all the same: the check is what tells
    (warning,) = warned(result)
    assert "shorter than the stated one" in warning and "too far" in warning
    assert "intrinsics=" in warning and "calibrate_focal='on'" in warning
    assert result.search["focal_check"]["scale"] < 0.99


def test_an_oblique_view_with_the_focal_length_6_percent_short_warns(views):
    localizer, out = views
    prior, labels, depth, _ = out[0]
    result = localizer.localize(with_focal_scale(CAMERA, 0.94), prior, labels, depth, config=WARN_ONLY)
    assert result.status == LOCALIZED
    (warning,) = warned(result)
    assert "longer than the stated one" in warning and "too close" in warning


@pytest.mark.parametrize("k", range(len(OBLIQUES)))
def test_the_right_focal_length_does_not_warn(views, k):
    localizer, out = views
    prior, labels, depth, _ = out[k]
    result = localizer.localize(CAMERA, prior, labels, depth)
    assert result.status == LOCALIZED and not warned(result)
    assert abs(result.search["focal_check"]["scale"] - 1.0) <= FocalCheckConfig().margin
    assert result.timings["focal_check_s"] > 0.0


@pytest.mark.parametrize("k", range(len(OBLIQUES)))
@pytest.mark.parametrize("error", [0.05, -0.05])
def test_an_oblique_view_told_a_focal_length_5_percent_off_is_found_again_nearer_the_truth(views, k, error):
    localizer, out = views
    prior, labels, depth, true = out[k]
    told = with_focal_scale(CAMERA, 1.0 + error)
    first = localizer.localize(told, prior, labels, depth, config=WARN_ONLY)
    result = localizer.localize(told, prior, labels, depth, config=CORRECT)
    assert first.status == result.status == LOCALIZED
    correction = result.search["focal_check"]["correction"]
    assert correction["taken"] and correction["accepted"] and correction["gain"] > 0.0
    # The first pose is the one found without the correction; the corrected one lies nearer the truth.
    assert Pose.from_state(correction["first_state"]).to_xyz_rpy() == pytest.approx(
        first.pose_local.to_xyz_rpy()
    )
    assert pose_errors(result.pose_local, true)[0] < pose_errors(first.pose_local, true)[0] - 0.5
    # The focal length re-found with is nearer the true one: 0.3-3.4 % off here (the stated one 5 %; the
    # vertex mostly understates the error: stretch 1, chosen in docs/localization.md).
    off = told.fx * correction["scale"] / CAMERA.fx - 1.0
    assert abs(off) < 0.035
    (warning,) = warned(result)
    assert "found again with it" in warning and f"{100 * abs(correction['scale'] - 1):.1f} %" in warning
    assert "intrinsics=" in warning


@pytest.mark.parametrize("k", range(len(OBLIQUES)))
def test_the_correction_switched_off_is_stop_53s_warning_alone(views, k):
    localizer, out = views
    prior, labels, depth, _ = out[k]
    told = with_focal_scale(CAMERA, 1.05)
    off = localizer.localize(told, prior, labels, depth, config=WARN_ONLY)
    on = localizer.localize(told, prior, labels, depth, config=CORRECT)
    assert "correction" not in off.search["focal_check"]
    assert off.pose_local.to_xyz_rpy().tolist() == on.search["focal_check"]["correction"]["first_state"]
    (warning,) = warned(off)
    assert "too far" in warning and "found again" not in warning
    no_check = replace(LocalizerConfig(), focal_check=FocalCheckConfig(enabled=False))
    plain = localizer.localize(told, prior, labels, depth, config=no_check)
    assert plain.pose_local.to_xyz_rpy().tolist() == off.pose_local.to_xyz_rpy().tolist()  # only warned
    # The default only warns (the correction costs the views it fires on where the focal length is
    # right: held out, past its criterion), and its warning names the preset that corrects.
    default = localizer.localize(told, prior, labels, depth)
    assert default.pose_local.to_xyz_rpy().tolist() == off.pose_local.to_xyz_rpy().tolist()
    assert "config='focal-correct'" in warned(default)[0]


def test_a_re_found_poses_lookalike_margin_is_found_again_with_the_scaled_camera(views):
    """(stop 55) With look-alikes on, a pose the correction re-found kept the first pose's look-alike
    margin: the first pose's score minus its look-alike's, both at the stated focal length, beside a pose
    and score found with the scaled one. Now the look-alike is refined again with the scaled camera from
    the place the first look found: the margin is the re-found pose's score minus that one's (the first
    pose's look-alike kept in the correction's record); a re-found pose ambiguous that way is not kept."""
    localizer, out = views
    prior, labels, depth, _ = out[0]
    told = with_focal_scale(CAMERA, 1.05)

    def with_lookalikes(min_margin: float) -> LocalizerConfig:
        look = replace(CORRECT.cascade.lookalike, enabled=True, min_margin=min_margin)
        return replace(CORRECT, cascade=replace(CORRECT.cascade, lookalike=look))

    result = localizer.localize(told, prior, labels, depth, config=with_lookalikes(0.05))
    correction = result.search["focal_check"]["correction"]
    assert result.status == LOCALIZED and correction["taken"]
    look = result.search["lookalike"]  # this view has one
    margin = result.confidence["lookalike_margin"]
    # The re-found pose's score minus its look-alike's (was: the first pose's minus the first look-alike's).
    assert margin == pytest.approx(result.score - look["score"]) == pytest.approx(look["margin"])
    first = correction["first_lookalike"]
    assert correction["lookalike_margin"] == margin and margin != pytest.approx(first["margin"])
    # A margin needed between the two: the first pose passes, the re-found one is ambiguous: not kept.
    needed = 0.5 * (margin + first["margin"])
    strict = localizer.localize(told, prior, labels, depth, config=with_lookalikes(needed))
    kept = strict.search["focal_check"]["correction"]
    assert strict.status == LOCALIZED and not kept["taken"] and kept["accepted"]
    assert kept["ambiguous"].startswith("a look-alike") and f"at least {needed:g}" in kept["ambiguous"]
    assert strict.pose_local.to_xyz_rpy().tolist() == kept["first_state"]
    assert strict.confidence["lookalike_margin"] == pytest.approx(first["margin"])


def test_the_scale_found_again_with_is_the_stretched_vertex_at_most_a_probe_step_beyond():
    check = FocalCheck(0.98, (0.004, -0.02), 0.03, 80.0)
    assert correction_scale(check, FocalCheckConfig(stretch=1.0)) == pytest.approx(0.98)
    assert correction_scale(check, FocalCheckConfig(stretch=2.0)) == pytest.approx(0.96)
    far = FocalCheck(0.9, (0.03, -0.02), 0.03, 80.0)
    assert correction_scale(far, FocalCheckConfig(stretch=1.0)) == pytest.approx(0.94)  # 2 steps at most


def test_a_nadir_view_is_not_checked_and_says_so_and_the_check_can_be_switched_off(views):
    """Seen from above, focal length and height are one unknown: a nadir view is not checked. (stop 55) Its
    record said nothing, and with ``--preset focal-correct`` a nadir pose found with a wrong focal length
    came back as if checked. Now its record names why (``not_checked: nadir``), and with the correction
    asked for a warning says it was neither checked nor found again; the default's warnings are as before."""
    localizer, out = views
    prior, labels, depth, _ = out[-1]
    result = localizer.localize(with_focal_scale(CAMERA, 1.06), prior, labels, depth)
    assert result.status == LOCALIZED and not warned(result) and not not_checked(result)
    record = result.search["focal_check"]
    assert record["not_checked"] == focal_check.NADIR
    assert record["off_nadir_deg"] < record["min_oblique_deg"] == 20.0
    assert focal_scale_used(result.search) is None
    corrected = localizer.localize(with_focal_scale(CAMERA, 1.06), prior, labels, depth, config=CORRECT)
    assert corrected.pose_local.to_xyz_rpy().tolist() == result.pose_local.to_xyz_rpy().tolist()
    (warning,) = not_checked(corrected)
    assert "nadir view" in warning and "neither checked nor found again" in warning
    assert "intrinsics=" in warning and "calibrate_focal='on'" in warning and not warned(corrected)
    off = replace(LocalizerConfig(), focal_check=FocalCheckConfig(enabled=False))
    prior, labels, depth, _ = out[0]
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
    "field, value",
    [
        ("margin", -0.01),
        ("step", 0.0),
        ("particles", 0),
        ("enabled", "yes"),
        ("step", True),
        ("correct", 1),
        ("stretch", -1.0),
    ],
)
def test_a_bad_focal_check_setting_is_refused(field, value):
    with pytest.raises(ParameterError, match=f"focal_check.{field}"):
        FocalCheckConfig(**{field: value})


def test_a_results_row_says_the_focal_scale_a_re_found_pose_used():
    from semcityloc.benchmark.results import ADDED_COLUMNS, COLUMNS

    assert "focal_scale" in COLUMNS and "focal_scale" in ADDED_COLUMNS  # older runs still resume
    taken = {"focal_check": {"scale": 0.97, "correction": {"scale": 0.97, "taken": True}}}
    assert focal_scale_used(taken) == pytest.approx(0.97)
    assert (
        focal_scale_used({"focal_check": {"scale": 0.97, "correction": {"scale": 0.97, "taken": False}}})
        is None
    )
    assert focal_scale_used({"focal_check": {"scale": 1.0}}) is None and focal_scale_used({}) is None


def test_the_corrected_warning_says_the_pose_holds_with_the_scaled_focal_length_and_which_camera_that_is():
    """(stop 54) The warning said "kept, with the focal scale in the result" only: a user re-projecting
    with the stated intrinsics was off by the scale. Now it names the scale to multiply fx, fy by."""
    text = corrected_warning(FocalCheck(0.988, (0.1, -0.2), 0.02, 80.0), 0.976)
    assert "focal length times 0.976" in text and "fx and fy times 0.976, not the stated intrinsics" in text
    assert "the pose file's intrinsics are the scaled ones" in text
    taken = {"focal_check": {"correction": {"scale": 0.976, "taken": True}}}
    assert found_camera(CAMERA, focal_scale_used(taken)) == with_focal_scale(CAMERA, 0.976)
    assert found_camera(CAMERA, focal_scale_used({})) is CAMERA
