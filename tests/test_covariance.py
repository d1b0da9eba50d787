"""The pose covariance: the score's curvature probed around the estimate, scaled by a fitted model."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import chi2

from helpers import CAMERA, benchmark_script, perturbed, view
from semcityloc.errors import ParameterError
from semcityloc.geometry.errors import center_error_m
from semcityloc.localization import covariance as cov_mod
from semcityloc.localization.covariance import (
    PROBES,
    CovarianceModel,
    covariance_dict,
    mahalanobis_sq,
    pose_covariance,
    probe_states,
    probe_steps,
    score_curvature,
    tangent_covariance,
)
from semcityloc.localization.localize import Localizer
from semcityloc.localization.result import LOCALIZED
from semcityloc.render import Renderer


def _spd(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    return q @ np.diag([0.5, 1.0, 2.0, 4.0, 8.0, 16.0]) @ q.T


def _samples(curv, center, n=200, noise=0.0, seed=0, scales=(0.5, 0.5, 0.3, 0.2, 0.2, 0.3)):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 6)) * np.array(scales)
    states = center + d
    scores = (
        0.7 + d @ np.array([0.01, -0.02, 0.0, 0.03, 0.0, 0.01]) - 0.5 * np.einsum("ni,ij,nj->n", d, curv, d)
    )
    return states, scores + noise * rng.normal(size=n)


def test_curvature_of_a_quadratic_is_recovered():
    curv = _spd(1)
    center = np.array([10.0, -5.0, 80.0, 1.0, 2.0, 30.0])
    states, scores = _samples(curv, center)
    got = score_curvature(states, scores, center)
    np.testing.assert_allclose(got, curv, rtol=1e-6, atol=1e-6)
    noisy = score_curvature(*_samples(curv, center, n=400, noise=0.002, seed=2), center)
    assert np.linalg.norm(noisy - curv) / np.linalg.norm(curv) < 0.1


def test_the_probe_stencil_determines_the_quadratic():
    curv = _spd(8)
    center = np.array([3.0, 4.0, 90.0, 0.5, -1.0, 250.0])
    steps = probe_steps(focal_px=100.0, depth_m=80.0, pixels=2.0)
    assert steps[:3] == pytest.approx([1.6] * 3) and steps[3:] == pytest.approx([np.degrees(0.02)] * 3)
    states = probe_states(center, steps)
    assert states.shape == (PROBES, 6) and np.array_equal(states[0], center)
    d = states - center
    scores = 0.5 + d @ np.arange(6) * 1e-3 - 0.5 * np.einsum("ni,ij,nj->n", d, curv, d)
    np.testing.assert_allclose(score_curvature(states, scores, center), curv, rtol=1e-6, atol=1e-9)


def test_yaw_across_180_is_wrapped():
    curv = _spd(3)
    near_zero = np.array([0.0, 0.0, 50.0, 0.0, 0.0, 0.1])
    states, scores = _samples(curv, near_zero, seed=4)
    across = near_zero.copy()
    across[5] = 179.95
    states_across = states.copy()
    states_across[:, 5] = (states[:, 5] - near_zero[5] + across[5] + 180.0) % 360.0 - 180.0
    assert np.ptp(states_across[:, 5]) > 300  # the samples really straddle +-180
    np.testing.assert_allclose(
        score_curvature(states_across, scores, across), score_curvature(states, scores, near_zero), atol=1e-9
    )


def test_flat_and_rising_directions_are_floored_to_a_positive_definite_curvature():
    curv = np.diag([4.0, 4.0, 4.0, 4.0, 4.0, -1.0])  # yaw: the score rises away from the estimate
    states, scores = _samples(curv, np.zeros(6), scales=(1, 1, 1, 1, 1, 1))
    got = score_curvature(states, scores, np.zeros(6))
    spread = states.std(axis=0)  # the floor is set in units of the samples' spread
    eig = np.linalg.eigvalsh(got * np.outer(spread, spread))
    assert eig.min() > 0
    assert eig.max() / eig.min() == pytest.approx(cov_mod.MAX_SIGMA_RATIO**2, rel=1e-6)


def test_too_few_or_degenerate_samples_give_none_and_bad_shapes_raise():
    curv = _spd(5)
    states, scores = _samples(curv, np.zeros(6), n=40)
    assert score_curvature(states, scores, np.zeros(6)) is None  # fewer than 2 per coefficient
    states, scores = _samples(curv, np.zeros(6))
    states[:, 2] = 0.0  # height never varied: nothing to say about it
    assert score_curvature(states, scores, np.zeros(6)) is None
    with pytest.raises(ParameterError):
        score_curvature(states[:, :5], scores, np.zeros(6))
    with pytest.raises(ParameterError):
        score_curvature(states, scores[:-1], np.zeros(6))


def test_covariance_is_the_tempered_inverse_plus_the_floor():
    curv = _spd(6)
    floor = np.array([0.5, 0.5, 0.3, 0.1, 0.1, 0.2])
    cov = pose_covariance(curv, 0.02, floor)
    np.testing.assert_allclose(cov, 0.02 * np.linalg.inv(curv) + np.diag(floor**2), atol=1e-12)
    np.testing.assert_allclose(cov, cov.T)
    assert CovarianceModel(0.02, tuple(floor)).covariance(curv) == pytest.approx(cov)
    with pytest.raises(ParameterError):
        pose_covariance(curv, 0.0)
    d = covariance_dict(cov)
    assert d["order"] == ["x", "y", "z", "roll", "pitch", "yaw"] and d["units"][3] == "deg"
    assert d["sigma"] == pytest.approx(np.sqrt(np.diag(cov)).tolist())
    e = np.array([1.0, 0, 0, 0, 0, 360.0])  # a whole turn of yaw is no error
    assert mahalanobis_sq(e, cov) == pytest.approx(np.linalg.inv(cov)[0, 0])


def test_the_fitted_model_is_shipped_and_read():
    body = json.loads(cov_mod.MODEL_PATH.read_text())
    for with_depth in (True, False):
        model = cov_mod.covariance_model("semantic", with_depth)
        key = cov_mod.model_key("semantic", with_depth)
        assert model is not None and model.temperature > 0 and len(model.floor_sigma) == 6
        assert model.temperature == body["models"][key]["temperature"]
    assert cov_mod.covariance_model("no-such-kind", True) is None


def test_a_narrow_camera_gets_the_narrow_model_where_one_was_fitted(tmp_path, monkeypatch):
    models = {
        "semantic/depth": {"temperature": 0.01, "floor_sigma": [0.1] * 6},
        "semantic/depth/narrow": {"temperature": 0.05, "floor_sigma": [0.2] * 6},
        "semantic/no-depth": {"temperature": 0.02, "floor_sigma": [0.1] * 6},
    }
    path = tmp_path / "covariance_model.json"
    path.write_text(json.dumps({"fitted_on": "test", "models": models}))
    monkeypatch.setattr(cov_mod, "MODEL_PATH", path)
    cov_mod._models.cache_clear()
    try:
        narrow = cov_mod.NARROW_BELOW_DEG - 1.0
        assert cov_mod.covariance_model("semantic", True, narrow).temperature == 0.05
        assert cov_mod.covariance_model("semantic", True, cov_mod.NARROW_BELOW_DEG).temperature == 0.01
        assert cov_mod.covariance_model("semantic", True).temperature == 0.01  # no camera given: wide
        assert cov_mod.covariance_model("semantic", False, narrow).temperature == 0.02  # none fitted: wide
    finally:
        cov_mod._models.cache_clear()


def test_calibration_recovers_a_known_temperature_and_floor():
    script = benchmark_script("calibrate_covariance")
    rng = np.random.default_rng(7)
    n, temperature, floor = 600, 0.01, np.array([0.4, 0.4, 0.2, 0.05, 0.05, 0.1])
    curvs = np.array([_spd(int(s)) * rng.uniform(0.5, 4.0) for s in rng.integers(0, 10**6, n)])
    covs = temperature * np.linalg.inv(curvs) + np.diag(floor**2)
    errors = np.array([rng.multivariate_normal(np.zeros(6), c) for c in covs])
    model = script.fit_model(errors, curvs, tail=None)
    assert model.temperature == pytest.approx(temperature, rel=0.15)
    np.testing.assert_allclose(model.floor_sigma, floor, rtol=0.3, atol=0.02)
    # Heavier tails than a Gaussian (a tenth of the errors three times larger): widened until the 95 %
    # ellipsoid holds 95 % of them.
    heavy = errors * np.where(rng.random(n) < 0.1, 3.0, 1.0)[:, None]
    narrow, wide = script.fit_model(heavy, curvs, tail=None), script.fit_model(heavy, curvs)
    assert wide.temperature > 1.2 * narrow.temperature
    covs = np.array([wide.covariance(a) for a in curvs])
    m = np.einsum("ni,nij,nj->n", heavy, np.linalg.inv(covs), heavy)
    assert np.mean(m <= chi2.ppf(0.95, 6)) == pytest.approx(0.95, abs=0.01)


@pytest.fixture(scope="module")
def city(generated_lod2):
    return generated_lod2


def test_a_localized_pose_carries_a_covariance_that_holds_its_error(city):
    true = view(city, 10.0, -20.0, 80.0, 1.0, 2.0, 30.0)  # nadir
    prior = perturbed(true, np.array([6.0, -7.0, 3.0]), 0.5, -0.5, 5.0)
    out = Renderer(city, engine="numba").render(CAMERA, true, depth=True)
    result = Localizer(city).localize(CAMERA, prior, out.labels[0], 0.37 * out.depth[0] + 12.0)
    assert result.status == LOCALIZED, result.reason
    cov = result.covariance
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.linalg.eigvalsh(cov).min() > 0
    e = result.pose_local.to_xyz_rpy() - true.to_xyz_rpy()
    assert center_error_m(result.pose_local, true) < 0.5
    assert mahalanobis_sq(e, cov) < 16.8  # inside the 99 % ellipsoid of chi2 with 6 degrees of freedom
    # From above a small tilt and a sideways shift look alike: the covariance couples them.
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert np.abs(corr[:2, 3:5]).max() > 0.5
    record = result.to_dict(city.origin)
    assert record["covariance"]["sigma"] == pytest.approx(np.sqrt(np.diag(cov)).tolist())


@pytest.mark.parametrize("frame", ["world", "camera"])
def test_tangent_covariance_matches_sampled_rotation_vectors(frame):
    """Euler-angle errors drawn from a covariance, turned into rotation vectors about world or camera
    axes, have the covariance ``tangent_covariance`` predicts (first order: small errors)."""
    from scipy.spatial.transform import Rotation

    from semcityloc.geometry.pose import Pose

    state = np.array([5.0, -3.0, 90.0, 2.0, 35.0, 130.0])  # an oblique view
    cov = pose_covariance(_spd(9), 1e-3)
    predicted = tangent_covariance(state, cov, frame)
    draws = np.random.default_rng(10).multivariate_normal(state, cov, size=4000)
    r0 = Pose.from_xyz_rpy(state[:3], *state[3:]).R_world_from_cam
    rs = Pose.from_xyz_rpy(draws[:, :3], draws[:, 3], draws[:, 4], draws[:, 5]).R_world_from_cam
    delta = rs @ r0.T if frame == "world" else r0.T @ rs
    vectors = np.concatenate([Rotation.from_matrix(delta).as_rotvec(), draws[:, :3]], axis=1)
    sampled = np.cov(vectors.T)
    scale = np.sqrt(np.outer(np.diag(predicted), np.diag(predicted)))
    assert np.all(np.abs(sampled - predicted) < 0.08 * scale)  # each entry against its own sigmas
    np.testing.assert_allclose(predicted[3:, 3:], cov[:3, :3])
    other = tangent_covariance(state, cov, "camera" if frame == "world" else "world")
    assert np.abs(other[:3, :3] - predicted[:3, :3]).max() > 0.2 * scale[:3, :3].max()  # frames differ
    with pytest.raises(ParameterError, match="frame"):
        tangent_covariance(state, cov, "body")
