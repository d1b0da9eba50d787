"""The default search (issue 13): the prior's stated uncertainty sets the volume, roll and pitch are
estimated, a best cell on the edge extends the volume or is refused, and the acceptance is a calibrated,
monotone probability."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from helpers import CAMERA, perturbed, view
from semcityloc.errors import ParameterError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose, yaw_fan_rotations
from semcityloc.geometry.uncertainty import MAX_POSITION_SIGMA_M, PriorUncertainty
from semcityloc.localization.cascade import BEYOND_WARNING, _lattice, search_volume
from semcityloc.localization.confidence import (
    CALIBRATED_MIN_HFOV_DEG,
    CALIBRATED_MIN_SPAN_M,
    CLOSE_VIEW_WARNING,
    FEATURES_DEPTH,
    NARROW_VIEW_WARNING,
    calibration_error,
    close_view_warning,
    confidence_model,
    field_of_view_warning,
    fit_logistic,
    risk_coverage,
    view_span_m,
)
from semcityloc.localization.config import CascadeConfig, LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.query import Query
from semcityloc.localization.result import (
    LOCALIZED,
    NOT_LOCALIZED,
    REASON_AT_EDGE,
    REASON_LOW_CONFIDENCE,
    REASON_PRIOR_LOOKS_UP,
    REASON_PRIOR_TOO_HIGH,
    REASON_PRIOR_UNDERGROUND,
    LocalizationResult,
)
from semcityloc.localization.search_reach import reached_half
from semcityloc.render import Renderer


@pytest.fixture(scope="module")
def city(generated_lod2):
    return generated_lod2


@pytest.fixture(scope="module")
def localizer(city):
    return Localizer(city)


@pytest.fixture(scope="module")
def renderer(city):
    return Renderer(city, engine="numba")


def query(renderer, pose):
    out = renderer.render(CAMERA, pose, depth=True)
    return out.labels[0], 0.5 * out.depth[0] + 7.0


VIEWS = {"nadir": (10.0, -20.0, 80.0, 0.5, 1.0, 30.0), "oblique": (-30.0, 15.0, 90.0, -1.0, 40.0, 200.0)}


@pytest.mark.parametrize("name", list(VIEWS))
def test_roll_and_pitch_errors_of_2_5_deg_are_recovered(city, localizer, renderer, name):
    true = view(city, *VIEWS[name])
    prior = perturbed(true, [6.0, -5.0, 8.0], droll=2.5, dpitch=-2.5, dyaw=4.0)
    labels, depth = query(renderer, true)
    result = localizer.localize(CAMERA, prior, labels, depth)
    assert result.status == LOCALIZED, result.reason
    _, _, _, roll, pitch, _ = result.pose_local.to_xyz_rpy()
    _, _, _, roll_t, pitch_t, _ = true.to_xyz_rpy()
    assert abs(roll - roll_t) < 0.5 and abs(pitch - pitch_t) < 0.5
    assert rotation_error_deg(result.pose_local, true) < 0.5
    assert center_error_m(result.pose_local, true) < 1.0


def test_a_prior_25m_too_high_is_recovered_with_default_settings(city, localizer, renderer):
    true = view(city, *VIEWS["oblique"])
    prior = perturbed(true, [3.0, 4.0, 25.0], dyaw=-3.0)
    labels, depth = query(renderer, true)
    result = localizer.localize(CAMERA, prior, labels, depth)
    assert result.status == LOCALIZED, result.reason
    assert center_error_m(result.pose_local, true) < 1.0
    assert rotation_error_deg(result.pose_local, true) < 0.5
    assert result.search["volume"]["half_z_m"] == pytest.approx(30.0)


def test_best_on_the_edge_extends_the_volume_toward_it(city, localizer, renderer):
    """The prior is 13 m off in x but states a 3 m sigma (+-9 m searched): the sweep grows toward the
    truth instead of returning the edge."""
    true = view(city, *VIEWS["nadir"])
    prior = perturbed(true, [13.0, 0.0, 0.0])
    labels, depth = query(renderer, true)
    unc = PriorUncertainty(xy_m=3.0, z_m=3.0)
    result = localizer.localize(CAMERA, prior, labels, depth, prior_uncertainty=unc)
    assert "x-" in result.search["extensions"]
    assert result.status == LOCALIZED, result.reason
    assert center_error_m(result.pose_local, true) < 1.0


def test_best_on_the_edge_at_the_bound_is_refused(city, localizer, renderer):
    """A prior 25 m too high that claims a 2 m height sigma: the volume may grow to +-12 m only; the
    best cell stays on its lower face, and the answer is a refusal naming the edge, not a pose 13 m off."""
    true = view(city, *VIEWS["oblique"])
    prior = perturbed(true, [0.0, 0.0, 25.0])
    labels, depth = query(renderer, true)
    unc = PriorUncertainty(z_m=2.0)
    result = localizer.localize(CAMERA, prior, labels, depth, prior_uncertainty=unc)
    assert result.status == NOT_LOCALIZED
    assert result.reason == REASON_AT_EDGE
    assert result.pose_local is None
    assert "z-" in result.search["at_edge"]
    # The warning says which edge, how far was searched and what to state: a volume from twice that bound.
    (said,) = [w for w in result.warnings if "edge at its largest extent" in w]
    assert "z- edge" in said and "z +-12 m" in said
    assert said.endswith("prior_uncertainty=PriorUncertainty.parse('z=8') or correct the prior")
    assert result.search["edge_sigma"] == {"z": 8}
    again = localizer.localize(CAMERA, prior, labels, depth, prior_uncertainty=PriorUncertainty(z_m=8.0))
    assert again.status == LOCALIZED, again.reason
    assert center_error_m(again.pose_local, true) < 1.0


def _ring(localizer, renderer, prior, true, found_xy):
    """``Localizer.ring_beyond`` for a query seen from ``true`` and a prior with the default uncertainty."""
    cfg = localizer.config
    labels = Query.from_arrays(query(renderer, true)[0], None, localizer.has_openings)
    ring, volume = localizer.ring_beyond(
        CAMERA, labels, prior.to_xyz_rpy(), found_xy, cfg, cfg.prior_uncertainty
    )
    return ring, reached_half(volume, cfg.cascade)["xy"]


def test_the_look_beyond_finds_a_view_the_search_volume_does_not_reach(city, localizer, renderer):
    """The truth 38 m from a prior that states 5 m (the search reaches +-30 m): the ring beyond it holds a
    view within a lattice step of the truth; told that the pose found is there, the ring's best is
    another view, at least ``exclude_m`` away, and scores lower."""
    true = view(city, *VIEWS["oblique"])
    prior = perturbed(true, [-38.0, 0.0, 0.0])
    x, y = true.to_xyz_rpy()[:2]
    ring, reach = _ring(localizer, renderer, prior, true, prior.to_xyz_rpy()[:2])
    assert reach == pytest.approx(30.0)
    assert reach < ring.offset_xy_m <= 3 * 15.0 * np.sqrt(2)
    assert np.hypot(ring.state[0] - x, ring.state[1] - y) < 8.0
    other, _ = _ring(localizer, renderer, prior, true, np.array([x, y]))
    assert np.hypot(other.state[0] - x, other.state[1] - y) >= localizer.config.cascade.beyond.exclude_m
    assert other.score < ring.score


def test_a_refusal_says_when_a_view_beyond_the_volume_scores_higher(city, localizer, renderer):
    """The look beyond runs on refused results only: an accepted pose is not looked beyond; a refused
    one with a correct prior has no hint (the ring scores far below the sweep); with a margin that lets
    any ring view count, the warning names the ``--prior-sigma`` whose volume reaches past the ring. The
    reason stays the refusal's own. Switched off, nothing is recorded."""
    true = view(city, *VIEWS["nadir"])
    prior = perturbed(true, [4.0, -3.0, 6.0], dyaw=2.0)
    labels, depth = query(renderer, true)
    accepted = localizer.localize(CAMERA, prior, labels, depth)
    assert accepted.status == LOCALIZED, accepted.reason
    assert "beyond" not in accepted.search
    cfg = replace(localizer.config, min_confidence=1.0)  # refuse whatever was found (p < 1)
    refused = localizer.localize(CAMERA, prior, labels, depth, config=cfg)
    assert refused.reason == REASON_LOW_CONFIDENCE
    beyond = refused.search["beyond"]
    assert not beyond["higher"] and beyond["score"] < refused.search["sweep_best"] - 0.1
    assert not [w for w in refused.warnings if w.startswith(BEYOND_WARNING)]
    eager = replace(cfg, cascade=replace(cfg.cascade, beyond=replace(cfg.cascade.beyond, margin=-1.0)))
    hinted = localizer.localize(CAMERA, prior, labels, depth, config=eager)
    assert hinted.reason == REASON_LOW_CONFIDENCE and hinted.search["beyond"]["higher"]
    assert center_error_m(hinted.found_pose_local, true) < 1.0  # the refused pose is kept
    (said,) = [w for w in hinted.warnings if w.startswith(BEYOND_WARNING)]
    assert "beyond the searched +-30 m" in said
    assert "run again with prior_uncertainty=PriorUncertainty.parse('xy=20')" in said
    assert hinted.search["beyond"]["sigma"] == {"xy": 20}
    off = replace(cfg, cascade=replace(cfg.cascade, beyond=replace(cfg.cascade.beyond, enabled=False)))
    assert "beyond" not in localizer.localize(CAMERA, prior, labels, depth, config=off).search


def test_a_prior_38m_off_against_a_stated_5m_is_refused_with_the_hint(city, localizer, renderer):
    """The truth 38 m west of a prior that states 5 m: the sweep's best inside is a look-alike, refused,
    and the refusal's warning says a view 34 m away (beyond the +-30 m searched) scores higher."""
    true = view(city, *VIEWS["nadir"])
    prior = perturbed(true, [-38.0, 0.0, 0.0])
    labels, depth = query(renderer, true)
    result = localizer.localize(CAMERA, prior, labels, depth)
    assert result.status == NOT_LOCALIZED and result.reason == REASON_LOW_CONFIDENCE
    assert center_error_m(result.found_pose_local, true) > 20.0
    assert result.search["beyond"]["higher"] and result.search["beyond"]["offset_xy_m"] > 30.0
    assert [w for w in result.warnings if w.startswith(BEYOND_WARNING) and "beyond the searched +-30 m" in w]


def test_the_search_stays_above_the_ground(city, localizer, renderer):
    """A GNSS height 25 m low puts a camera flying 30 m up below the ground: the sweep scores no camera
    centre under the volume's floor (``min_clearance_m`` above the lowest ground near the prior), the
    floor is not an edge to grow through, and the view is found above it."""
    true = view(city, 10.0, -20.0, 30.0, 0.5, 1.0, 30.0)
    prior = perturbed(true, [2.0, -1.5, -25.0], dyaw=1.0)
    labels, depth = query(renderer, true)
    result = localizer.localize(CAMERA, prior, labels, depth)
    floor = result.search["volume"]["floor_z"]
    ground = localizer.layout.ground_below(prior.to_xyz_rpy(), PriorUncertainty(), localizer.config)
    assert floor == pytest.approx(ground + CascadeConfig().min_clearance_m)
    assert prior.center[2] < floor < true.center[2]
    assert result.cost_volume.z_values.min() >= floor - 1e-6  # no camera centre below the floor was scored
    assert not any(e.startswith("z-") for e in result.search["extensions"] + result.search["at_edge"])
    assert result.status == LOCALIZED, result.reason
    assert center_error_m(result.pose_local, true) < 1.0
    # Without a floor the same sweep scores camera centres metres under the ground.
    open_cfg = replace(localizer.config, cascade=replace(localizer.config.cascade, min_clearance_m=-1e6))
    below = localizer.localize(CAMERA, prior, labels, depth, config=open_cfg)
    assert below.cost_volume.z_values.min() < ground


def test_the_looking_up_reason_names_the_pitch_convention_of_each_source():
    """Stop 52's audit: the hint "is its pitch in our convention (0 = straight down; ...)?" read backwards
    for a geotag CSV or a DJI photo, whose gimbal pitch is -90 straight down: each source's convention is
    named now."""
    assert "a DJI photo's or a geotag CSV's gimbal pitch: -90 = straight down" in REASON_PRIOR_LOOKS_UP
    assert "semcityloc's x,y,z,roll,pitch,yaw and ODM's geo.txt: 0 = straight down" in REASON_PRIOR_LOOKS_UP


@pytest.mark.parametrize(
    "dz, pitch, reason",
    [
        (-400.0, 1.0, REASON_PRIOR_UNDERGROUND),  # a height in another datum, or its sign lost
        (5000.0, 1.0, REASON_PRIOR_TOO_HIGH),  # a height in feet, or above another datum
        (100.0, 160.0, REASON_PRIOR_LOOKS_UP),  # DJI's gimbal pitch (-90 = down) taken for ours (0 = down)
    ],
)
def test_a_prior_no_camera_of_the_search_sees_the_model_from_is_refused_saying_why(
    city, localizer, renderer, dz, pitch, reason
):
    """Such priors were searched and refused on the volume's edge with a --prior-sigma to try (or at low
    confidence): advice that cannot help. They are refused before any search, saying what is wrong; a
    prior 25 m under the ground is still searched from the volume's floor (the test above)."""
    true = view(city, *VIEWS["nadir"])
    labels, depth = query(renderer, true)
    x, y, z, roll, _, yaw = true.to_xyz_rpy()
    prior = Pose.from_xyz_rpy([x + 3.0, y - 2.0, z + dz], roll, pitch, yaw)
    result = localizer.localize(CAMERA, prior, labels, depth)
    assert (result.status, result.reason) == (NOT_LOCALIZED, reason)
    assert result.counts["coarse_hypotheses"] == 0 and not result.warnings
    near = Pose.from_xyz_rpy([x + 3.0, y - 2.0, z + 20.0], roll, 1.0, yaw)
    assert localizer.localize(CAMERA, near, labels, depth).status == LOCALIZED


def test_an_accepted_pose_far_from_a_confident_prior_says_they_disagree(city, localizer, renderer):
    """An RTK prior (0.5 m) 4 m off the camera: the image finds the camera (the volume's floor leaves room
    for it) and is accepted, and the result says the pose lies 8 sigma from the prior: one of them is wrong
    (on a real flight most often the image's focal length). The same pose from a default prior: no word."""
    true = view(city, *VIEWS["nadir"])
    labels, depth = query(renderer, true)
    prior = perturbed(true, [4.0, 0.0, 0.0])
    rtk = localizer.localize(CAMERA, prior, labels, depth, prior_uncertainty=PriorUncertainty.rtk(0.5, 0.5))
    assert rtk.status == LOCALIZED and center_error_m(rtk.pose_local, true) < 1.0
    (said,) = [w for w in rtk.warnings if w.startswith("the pose lies")]
    assert "sigma of its stated uncertainty (xy 0.5 m, z 0.5 m; RTK fixed" in said and "focal length" in said
    default = localizer.localize(CAMERA, prior, labels, depth)
    assert default.status == LOCALIZED and not [w for w in default.warnings if w.startswith("the pose lies")]


def test_search_volume_follows_the_stated_uncertainty():
    cfg = CascadeConfig()
    state = np.array([1.0, 2.0, 3.0, 0.0, 0.0, 10.0])
    default = search_volume(state, PriorUncertainty(), cfg)
    assert (default.half_xy_m, default.half_z_m, default.half_yaw_deg) == (15.0, 30.0, 9.0)
    rtk = search_volume(state, PriorUncertainty.rtk(0.02, 0.03), cfg)
    assert rtk.half_xy_m == cfg.min_half_xy_m and rtk.half_z_m == cfg.min_half_z_m  # floors hold
    wide = search_volume(state, PriorUncertainty.parse("xy=10,z=20"), cfg)
    assert (wide.half_xy_m, wide.half_z_m) == (30.0, 60.0)


@pytest.mark.parametrize(("pitch", "dyaw"), [(60.0, 170.0), (75.0, 120.0)])
def test_a_prior_without_a_heading_finds_an_oblique_view_turned_away(city, localizer, renderer, pitch, dyaw):
    """Stop 53: with ``yaw=60`` (no compass) the sweep's one wide view read nothing of an oblique view
    turned 120-170 deg (its rays lay beyond ``MAX_WIDE_RAY_DEG``), and the yaw lattice's +-180 deg ends
    were edges to grow past: refused at the edge or at a look-alike. Every heading is searched now."""
    true = view(city, -30.0, 15.0, 90.0, -1.0, pitch, 200.0)
    prior = perturbed(true, [6.0, -5.0, 8.0], dyaw=dyaw)
    labels, depth = query(renderer, true)
    result = localizer.localize(
        CAMERA, prior, labels, depth, prior_uncertainty=PriorUncertainty.parse("yaw=60")
    )
    assert result.status == LOCALIZED, result.reason
    assert result.search["volume"]["full_circle"] and result.search["extensions"].count("yaw+") == 0
    assert center_error_m(result.pose_local, true) < 2.0 and rotation_error_deg(result.pose_local, true) < 2.0


def test_a_heading_not_known_searches_the_circle_once_in_sectors():
    """Stop 53: ``yaw=60`` or more is a full circle of 2n+1 equal yaw steps, none twice, no yaw edge; up to
    180 is accepted, beyond it the error says what to state. An oblique fan is cut into sectors whose
    rays each lie within ``SECTOR_MAX_RAY_DEG`` of their wide view; a fan of a few degrees is one, on the
    base given (as before)."""
    from semcityloc.localization.cascade import FULL_CIRCLE_HALF_DEG
    from semcityloc.localization.coarse import SECTOR_MAX_RAY_DEG, rotation_offsets, yaw_sectors

    cfg = CascadeConfig()
    state = np.array([1.0, 2.0, 3.0, 0.0, 50.0, 10.0])
    assert not search_volume(state, PriorUncertainty(), cfg).full_circle
    for text in ("yaw=60", "yaw=180"):
        volume = search_volume(state, PriorUncertainty.parse(text), cfg)
        assert volume.full_circle and volume.half_yaw_deg == FULL_CIRCLE_HALF_DEG
        step, n = _lattice(volume, cfg.sweep, cfg.sweep.max_centres)
        assert step[3] * (2 * n[3] + 1) == pytest.approx(360.0) and step[3] <= cfg.sweep.step_yaw_deg
        assert reached_half(volume, cfg)["yaw"] == FULL_CIRCLE_HALF_DEG
    with pytest.raises(ParameterError, match="60 or more searches every heading"):
        PriorUncertainty.parse("yaw=181")
    camera = CAMERA.scaled(32, 24)
    base = Pose.from_xyz_rpy(np.zeros(3), 0.0, 50.0, 10.0).R
    (one,) = yaw_sectors(camera, 0.0, 50.0, 10.0 + np.arange(-9.0, 10.0, 2.0), base)
    assert one[0] is base or np.array_equal(one[0], base)
    yaws = 10.0 + np.arange(-180.0, 180.0, 2.0)
    sectors = yaw_sectors(camera, 0.0, 50.0, yaws, base)
    assert len(sectors) > 1 and np.array_equal(
        np.concatenate([idx for _, idx in sectors]), np.arange(len(yaws))
    )
    rays = camera.ray_directions().reshape(-1, 3)
    for R_base, idx in sectors:
        d = np.matmul(rays[None], rotation_offsets(R_base, yaw_fan_rotations(0.0, 50.0, yaws[idx])))
        cos = d[..., 2] / np.linalg.norm(d, axis=-1)
        assert np.degrees(np.arccos(cos.min())) <= SECTOR_MAX_RAY_DEG + 1e-6
    nadir = yaw_sectors(camera, 0.0, 0.0, yaws, Pose.from_xyz_rpy(np.zeros(3), 0.0, 0.0, 10.0).R)
    assert len(nadir) == 1  # a nadir view turned about its own axis: one wide view reads every heading


class _IndexScorer:
    """A sweep scorer without a map: each cell scores ``score(ix, iy, iz, iyaw)`` of its lattice indices."""

    score_of = None

    def __init__(self, scene, camera, query_labels, class_on, origin, step, roll, pitch):
        self.count = 0

    def score(self, ix, iy, iz, iyaw):
        out = type(self).score_of(*np.meshgrid(ix, iy, iz, iyaw, indexing="ij")).astype(float)
        self.count += out.size
        return out


def _yaw_edge_scores(n: int) -> dict:
    """Scores that keep the best cell on a yaw edge of the sweep (x, y, z best at the prior): always the +
    edge, always the - edge, and both in turn (the best on the x+ and yaw- edges, then, among the cells the
    x extension adds, on the yaw+ edge). ``n``: the lattice's x extent."""
    centre = lambda ix, iy, iz: np.abs(ix) + np.abs(iy) + np.abs(iz)  # noqa: E731
    return {
        "yaw+": lambda ix, iy, iz, iyaw: iyaw - 1000.0 * centre(ix, iy, iz),
        "yaw-": lambda ix, iy, iz, iyaw: -iyaw - 1000.0 * centre(ix, iy, iz),
        "both": lambda ix, iy, iz, iyaw: (
            np.where(ix > n, 1000.0 + ix + iyaw, ix - iyaw) - 1000.0 * (np.abs(iy) + np.abs(iz))
        ),
    }


def test_no_yaw_sigma_scores_a_heading_twice(monkeypatch):
    """Stop 54: a yaw sigma from 35 to 59 (3 sigma short of the closed circle) let the sweep's yaw lattice
    grow past a turn at its edge (sigma 40 +-120 deg grown twice to -120..+240, sigma 59 to -178..+356: 88
    headings twice), and 59.4-59.9 built -180..+180 (both ends one heading); a lattice grown to the whole
    circle still had a yaw edge to refuse at. Now the volume is the closed circle when its lattice holds a
    turn (``yaw_turn``), yaw grows to a turn at most, and a turn has no edge."""
    from semcityloc.localization import cascade

    cfg = CascadeConfig()
    monkeypatch.setattr(cascade, "_SweepScorer", _IndexScorer)
    for sigma in [*np.arange(1.0, 181.0, 1.0), 59.3, 59.4, 59.5, 59.9]:
        unc = PriorUncertainty(xy_m=1.0, z_m=1.0, yaw_deg=float(sigma), roll_pitch_deg=1.0)
        volume = search_volume(np.array([0.0, 0.0, 50.0, 0.0, 40.0, 37.0]), unc, cfg)
        n_x = _lattice(volume, cfg.sweep, cfg.sweep.max_centres)[1][0]
        assert reached_half(volume, cfg)["yaw"] <= cascade.FULL_CIRCLE_HALF_DEG, sigma
        for name, score_of in _yaw_edge_scores(n_x).items():
            monkeypatch.setattr(_IndexScorer, "score_of", staticmethod(score_of))
            sw = cascade.sweep(None, CAMERA, volume, None, None, cfg.sweep)
            case = (sigma, name, sw.extensions, sw.at_edge, sw.values(3)[[0, -1]] - 37.0)
            yaws = np.sort(np.mod(sw.values(3), 360.0))
            gaps = np.diff(np.append(yaws, yaws[0] + 360.0))
            assert gaps.min() > 0.25 * sw.step[3], case  # no heading twice
            turn = len(yaws) >= int(360.0 / sw.step[3] + 1e-9)  # every heading within a step of a scored one
            assert sw.full_circle == turn and (gaps.max() < 2 * sw.step[3] - 1e-9 or not turn), case
            assert not (turn and any(e.startswith("yaw") for e in sw.at_edge)), case  # a circle has no edge
            if volume.full_circle:  # a closed circle does not grow in yaw
                assert not any(e.startswith("yaw") for e in sw.extensions), case


def test_wider_uncertainty_keeps_the_number_of_camera_centres_bounded(city, localizer, renderer):
    true = view(city, *VIEWS["nadir"])
    labels, depth = query(renderer, true)
    small = localizer.localize(CAMERA, true, labels, depth, prior_uncertainty=PriorUncertainty())
    big = localizer.localize(
        CAMERA, true, labels, depth, prior_uncertainty=PriorUncertainty.parse("xy=20,z=20")
    )
    assert big.search["sweep_step"][0] > small.search["sweep_step"][0]  # steps grow, not the centre count
    assert big.counts["coarse_hypotheses"] < 3 * small.counts["coarse_hypotheses"]
    assert big.status == LOCALIZED and center_error_m(big.pose_local, true) < 1.0


def test_prior_uncertainty_parsing_and_errors():
    u = PriorUncertainty.parse("xy=5, z=15, yaw=5, rp=1")
    assert (u.xy_m, u.z_m, u.yaw_deg, u.roll_pitch_deg) == (5.0, 15.0, 5.0, 1.0)
    assert PriorUncertainty.parse("z=40").xy_m == PriorUncertainty().xy_m
    for bad in ("", "xy", "q=3", "z=abc", "z=-1", "yaw=181"):
        with pytest.raises(ParameterError):
            PriorUncertainty.parse(bad)
    with pytest.raises(ParameterError, match="z is given twice"):  # stop 48: the last one won, silently
        PriorUncertainty.parse("xy=5,z=15,z=30")
    with pytest.raises(ParameterError, match="height is given twice"):  # an alias of z counts as z
        PriorUncertainty.parse("z=15,height=30")


def test_position_sigma_beyond_a_local_search_is_refused_and_the_largest_allowed_stays_bounded():
    """Stop 45's audit: xy=1e9 (or an RTK tag of 1e9 m) overflowed the lattice's centre count and asked
    for 10 GB; now refused by name, and the largest sigma allowed keeps the sweep's centres bounded."""
    for text in ("xy=1e9", "z=20000"):
        with pytest.raises(ParameterError, match="too large for a local search"):
            PriorUncertainty.parse(text)
    cfg = CascadeConfig()
    state = np.array([1.0, 2.0, 3.0, 0.0, 0.0, 10.0])
    volume = search_volume(
        state, PriorUncertainty.parse(f"xy={MAX_POSITION_SIGMA_M},z={MAX_POSITION_SIGMA_M}"), cfg
    )
    _, n = _lattice(volume, cfg.sweep, cfg.sweep.max_centres)
    assert (2 * n[0] + 1) ** 2 * (2 * n[2] + 1) <= cfg.sweep.max_centres


def test_localize_refuses_a_non_uncertainty(city, localizer, renderer):
    true = view(city, *VIEWS["nadir"])
    labels, depth = query(renderer, true)
    with pytest.raises(ParameterError):
        localizer.localize(CAMERA, true, labels, depth, prior_uncertainty={"xy": 5})


def test_legacy_preset_runs_the_first_design(city, renderer):
    legacy = Localizer(city, LocalizerConfig.preset("legacy"))
    true = view(city, *VIEWS["nadir"])
    labels, depth = query(renderer, true)
    result = legacy.localize(CAMERA, perturbed(true, [5.0, -5.0, 2.0], dyaw=3.0), labels, depth)
    assert result.search["search"] == "grid"
    assert result.counts["coarse_hypotheses"] == LocalizerConfig.preset("legacy").coarse.hypotheses
    assert result.status == LOCALIZED and center_error_m(result.pose_local, true) < 1.0


# ----------------------------------------------------------------------------- confidence


def _result(**features) -> LocalizationResult:
    r = LocalizationResult(
        status=LOCALIZED, semantic=features.pop("semantic"), depth_cost=features.pop("depth_cost")
    )
    r.confidence.update(features)
    return r


BASE = dict(
    semantic=0.75,
    depth_cost=0.06,
    depth_cost_agreed=0.05,
    building_iou=0.85,
    hypothesis_margin=0.02,
    score_margin=0.05,
    spread_m=0.4,
    building_fraction=0.4,
    prior_distance=1.5,
    boundary_distance_px=1.0,
)
# Evidence that must lower the probability as it grows (the rest must raise it).
LESS_CONFIDENT = ("depth_cost", "depth_cost_agreed", "spread_m", "prior_distance", "boundary_distance_px")


@pytest.mark.parametrize("kind,with_depth", [("semantic", True), ("semantic", False), ("silhouette", False)])
def test_confidence_is_monotone_in_every_piece_of_evidence(kind, with_depth):
    model = confidence_model(kind, with_depth)
    base = model.probability(_result(**BASE))
    assert 0.0 < base < 1.0
    for name in model.features:
        step = 0.1 * (abs(BASE[name]) + 0.1)
        more = model.probability(_result(**{**BASE, name: BASE[name] + step}))
        less = model.probability(_result(**{**BASE, name: BASE[name] - step}))
        sign = -1 if name in LESS_CONFIDENT else +1
        assert sign * (more - base) >= 0 and sign * (base - less) >= 0, name
    # A missing feature (one hypothesis only) sits at its mean: no NaN comes out.
    assert np.isfinite(model.probability(_result(**{**BASE, "hypothesis_margin": float("nan")})))


def test_a_close_view_is_accepted_only_at_the_close_view_probability(city, localizer, renderer):
    low = view(city, 10.0, -20.0, 45.0, 0.5, 1.0, 30.0)  # 24 m above the roof under it
    args = (CAMERA, perturbed(low, [2.0, -1.5, 3.0], dyaw=1.0), *query(renderer, low))
    result = localizer.localize(*args)
    p = result.confidence["probability"]
    assert result.confidence["view_span_m"] < CALIBRATED_MIN_SPAN_M
    assert result.confidence["min_probability"] == 0.9
    assert result.localized == (p >= 0.9)
    # The same view decided at a bar just above and just below its probability (the pose is the same):
    cfg = localizer.config
    above = localizer.localize(*args, config=replace(cfg, min_confidence_close_view=min(p + 1e-6, 1.0)))
    below = localizer.localize(*args, config=replace(cfg, min_confidence=0.0, min_confidence_close_view=p))
    assert not above.localized and above.reason == REASON_LOW_CONFIDENCE
    assert below.localized and below.confidence["probability"] == p
    # A usual view keeps the usual bar; the bar is a probability.
    high = view(city, *VIEWS["nadir"])
    usual = localizer.localize(CAMERA, perturbed(high, [2.0, -1.5, 3.0], dyaw=1.0), *query(renderer, high))
    assert usual.confidence["min_probability"] == 0.5
    with pytest.raises(ParameterError, match="min_confidence_close_view must be a probability"):
        replace(cfg, min_confidence_close_view=1.5)


def test_a_camera_narrower_than_the_calibration_views_is_warned_about(city, localizer, renderer):
    true = view(city, 10.0, -20.0, 160.0, 0.5, 1.0, 30.0)
    prior = perturbed(true, [3.0, -2.0, 4.0], dyaw=2.0)
    narrow = Camera.from_fov(CAMERA.width, CAMERA.height, 34.0)  # a thermal camera's field of view
    out = renderer.render(narrow, true, depth=True)
    result = localizer.localize(narrow, prior, out.labels[0], out.depth[0])
    assert result.pose_local is not None or result.rejected_pose_local is not None
    (warning,) = [w for w in result.warnings if w.startswith(NARROW_VIEW_WARNING)]
    assert "34 deg across" in warning
    wide = localizer.localize(CAMERA, prior, *query(renderer, true))
    assert not any(w.startswith(NARROW_VIEW_WARNING) for w in wide.warnings)
    assert field_of_view_warning(CALIBRATED_MIN_HFOV_DEG) is None
    assert field_of_view_warning(CALIBRATED_MIN_HFOV_DEG - 1) is not None


def test_a_view_closer_to_the_scene_than_the_calibration_views_is_warned_about(city, localizer, renderer):
    low = view(city, 10.0, -20.0, 45.0, 0.5, 1.0, 30.0)  # 24 m above the roof under it
    result = localizer.localize(CAMERA, perturbed(low, [2.0, -1.5, 3.0], dyaw=1.0), *query(renderer, low))
    seen = renderer.render(CAMERA, result.found_pose_local, depth=True).depth[0]
    expected = view_span_m(CAMERA.hfov_deg, float(np.mean(seen[np.isfinite(seen)])))
    span = result.confidence["view_span_m"]
    assert 0.0 < span < CALIBRATED_MIN_SPAN_M
    assert span == pytest.approx(expected, rel=0.1)  # the localizer's 128-pixel render, its map's eaves
    (warning,) = [w for w in result.warnings if w.startswith(CLOSE_VIEW_WARNING)]
    assert f"spans {span:.0f} m across" in warning
    high = view(city, *VIEWS["nadir"])
    usual = localizer.localize(CAMERA, perturbed(high, [2.0, -1.5, 3.0], dyaw=1.0), *query(renderer, high))
    assert usual.confidence["view_span_m"] > CALIBRATED_MIN_SPAN_M
    assert not any(w.startswith(CLOSE_VIEW_WARNING) for w in usual.warnings)
    assert close_view_warning(CALIBRATED_MIN_SPAN_M, 0.9) is None and close_view_warning(0.0, 0.9) is None
    assert "accepted only at 0.9 or more" in close_view_warning(CALIBRATED_MIN_SPAN_M - 1, 0.9)
    assert view_span_m(90.0, 10.0) == pytest.approx(20.0) and view_span_m(70.0, 0.0) == 0.0


def test_fit_logistic_is_calibrated_on_held_out_data():
    rng = np.random.default_rng(3)
    n = 4000
    X = rng.normal(size=(n, len(FEATURES_DEPTH)))
    # True model: depends on semantic (+) and depth_cost (-) only.
    sem, dep = FEATURES_DEPTH.index("semantic"), FEATURES_DEPTH.index("depth_cost")
    z = 1.5 * X[:, sem] - 1.0 * X[:, dep] + 0.3
    y = (rng.random(n) < 1 / (1 + np.exp(-z))).astype(float)
    model = fit_logistic(X[:3000], y[:3000], FEATURES_DEPTH, "semantic", True)
    p = model.probability_of(X[3000:])
    assert calibration_error(p, y[3000:]) < 0.05
    assert model.weights[sem] > 1.0 and model.weights[dep] < -0.5
    curve = risk_coverage(p, y[3000:])
    assert curve[-1][1] == pytest.approx(1.0)  # all accepted at the lowest threshold
    assert curve[len(curve) // 10][2] > curve[-1][2]  # the most confident tenth is more often right


def test_calibration_error_of_a_perfect_and_a_useless_forecast():
    rng = np.random.default_rng(0)
    p = rng.random(20000)
    y = (rng.random(20000) < p).astype(float)
    assert calibration_error(p, y) < 0.02
    assert calibration_error(np.full(20000, 0.9), (rng.random(20000) < 0.5).astype(float)) > 0.35


def test_fit_refuses_one_class_data():
    with pytest.raises(ParameterError):
        fit_logistic(np.zeros((5, len(FEATURES_DEPTH))), np.ones(5), FEATURES_DEPTH, "semantic", True)


def test_calibrated_acceptance_refuses_a_look_alike_that_thresholds_would_pass(city, localizer, renderer):
    """A flipped mask gives a pose, but the probability says it is not to be trusted."""
    true = view(city, *VIEWS["nadir"])
    labels, _ = query(renderer, true)
    result = localizer.localize(CAMERA, true, labels[::-1, ::-1].copy(), None)
    assert result.status == NOT_LOCALIZED
    assert result.confidence.get("probability", 0.0) < LocalizerConfig().min_confidence or result.reason


def test_acceptance_probability_is_a_config_knob(city, localizer, renderer):
    true = view(city, *VIEWS["nadir"])
    labels, depth = query(renderer, true)
    prior = perturbed(true, [4.0, -3.0, 6.0], dyaw=2.0)
    strict = localizer.localize(
        CAMERA, prior, labels, depth, config=replace(localizer.config, min_confidence=1.0)
    )
    assert strict.status == NOT_LOCALIZED and strict.rejected_pose_local is not None
    ok = localizer.localize(CAMERA, prior, labels, depth)
    assert ok.status == LOCALIZED and ok.confidence["probability"] >= 0.5
