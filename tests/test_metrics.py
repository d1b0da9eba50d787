"""Benchmark metrics: recall conventions at ties, not_localized as failures, mean/median, curves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semcityloc.errors import ShapeError
from semcityloc.evaluation.metrics import (
    CONVENTION,
    RIGHT_DEG,
    RIGHT_M,
    THRESHOLDS,
    cumulative_curve,
    is_right,
    pose_errors,
    recall,
    recalls,
    summarize_errors,
    threshold_key,
)
from semcityloc.geometry.pose import Pose

INF = math.inf


def test_threshold_keys_name_the_three_pairs():
    assert [threshold_key(m, d) for m, d in THRESHOLDS] == ["recall_2m2deg", "recall_3m3deg", "recall_5m5deg"]
    assert threshold_key(2.5, 1) == "recall_2.5m1deg"


def test_le_and_strict_differ_exactly_at_ties():
    # One query exactly at each threshold (2 m / 2 deg, 3 / 3, 5 / 5), one clearly inside, one outside.
    xyz = [2.0, 3.0, 5.0, 0.5, 9.0]
    rot = [2.0, 3.0, 5.0, 0.5, 0.1]
    le = recalls(xyz, rot)
    lt = recalls(xyz, rot, strict=True)
    assert le == {"recall_2m2deg": 40.0, "recall_3m3deg": 60.0, "recall_5m5deg": 80.0}
    assert lt == {"recall_2m2deg": 20.0, "recall_3m3deg": 40.0, "recall_5m5deg": 60.0}
    # A tie in only one of the two errors also separates the conventions.
    assert recall([2.0], [1.0], 2, 2) == 100.0 and recall([2.0], [1.0], 2, 2, strict=True) == 0.0
    assert recall([1.0], [2.0], 2, 2) == 100.0 and recall([1.0], [2.0], 2, 2, strict=True) == 0.0
    # Just above the threshold never counts, just below always does.
    assert recall([np.nextafter(2.0, 3.0)], [0.0], 2, 2) == 0.0
    assert recall([np.nextafter(2.0, 0.0)], [0.0], 2, 2, strict=True) == 100.0


def test_right_is_within_5_m_and_5_deg_inclusive_one_definition():
    """``is_right``: the event the acceptance probability is fitted to, the acceptance precision, the report's
    reliability and the kinds of miss (stop 51: five copies and two literals before)."""
    assert (RIGHT_M, RIGHT_DEG) == (5.0, 5.0)
    assert is_right(5.0, 5.0) is True and is_right(0.0, 0.0) is True
    assert not is_right(np.nextafter(5.0, 6.0), 0.0) and not is_right(0.0, np.nextafter(5.0, 6.0))
    assert not is_right(math.nan, 0.0) and not is_right(0.0, math.inf)
    np.testing.assert_array_equal(is_right([1.0, 6.0, 1.0, math.nan], [1.0, 1.0, 6.0, 1.0]), [1, 0, 0, 0])
    s = summarize_errors([1.0, 5.0, 6.0, 1.0], [1.0, 5.0, 1.0, 5.5], [0, 0, 0, 0])
    assert s["acceptance_precision"] == pytest.approx(50.0)


def test_both_position_and_rotation_must_pass():
    assert recall([0.1, 10.0], [10.0, 0.1], 5, 5) == 0.0


def test_not_localized_are_failures_in_recall_and_excluded_from_means():
    xyz = [1.0, 3.0, INF, INF]
    rot = [1.0, 1.0, INF, INF]
    yaw = [0.5, 1.5, INF, INF]
    s = summarize_errors(xyz, rot, yaw, localized=[True, True, False, False])
    assert (s["queries"], s["localized"], s["not_localized"]) == (4, 2, 2)
    assert s["recall_2m2deg"] == 25.0 and s["recall_3m3deg"] == 50.0 and s["recall_5m5deg"] == 50.0
    assert s["recall_strict"] == {"recall_2m2deg": 25.0, "recall_3m3deg": 25.0, "recall_5m5deg": 50.0}
    assert s["mean_xyz_m"] == 2.0 and s["median_xyz_m"] == 2.0
    assert s["mean_yaw_deg"] == 1.0 and s["median_yaw_deg"] == 1.0
    assert s["median_xyz_m_all"] == INF  # half the queries failed: the median over all is infinite
    assert s["convention"] == CONVENTION and "<=" in CONVENTION and "'<'" in CONVENTION


def test_a_not_localized_flag_overrides_finite_errors_and_nan_is_a_failure():
    s = summarize_errors(
        [1.0, 1.0, float("nan")], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0], localized=[True, False, True]
    )
    assert s["localized"] == 1
    assert s["recall_2m2deg"] == pytest.approx(100 / 3)
    assert s["mean_xyz_m"] == 1.0
    # Without flags, localized = every error finite.
    assert summarize_errors([1.0, INF], [1.0, 1.0], [0.0, 0.0])["localized"] == 1


def test_median_over_all_with_a_minority_of_failures_is_finite():
    s = summarize_errors([1.0, 2.0, 4.0, INF], [0.1] * 4, [0.1] * 4)
    assert s["median_xyz_m_all"] == 3.0
    assert s["median_xyz_m"] == 2.0


def test_no_queries_and_no_localized_give_nan_not_a_crash():
    s = summarize_errors([], [], [])
    assert s["queries"] == 0 and math.isnan(s["recall_2m2deg"]) and math.isnan(s["mean_xyz_m"])
    s = summarize_errors([INF], [INF], [INF])
    assert s["recall_5m5deg"] == 0.0 and math.isnan(s["median_yaw_deg"])


def test_bad_inputs_raise_typed_errors():
    with pytest.raises(ShapeError):
        recall([1.0, 2.0], [1.0], 2, 2)
    with pytest.raises(ShapeError):
        recall([-1.0], [1.0], 2, 2)
    with pytest.raises(ShapeError):
        summarize_errors([1.0], [1.0], [1.0, 2.0])
    with pytest.raises(ShapeError):
        summarize_errors([1.0], [1.0], [1.0], localized=[True, False])
    with pytest.raises(ShapeError):
        recall(1.0, 1.0, 2, 2)


def test_pose_errors_measure_centre_distance_full_rotation_and_yaw():
    gt = Pose.from_xyz_rpy([10.0, 20.0, 80.0], 1.0, 30.0, 45.0)
    est = Pose.from_xyz_rpy([13.0, 24.0, 80.0], 1.0, 30.0, 47.5)
    xyz, rot, yaw = pose_errors(est, gt)
    assert xyz == pytest.approx(5.0)
    assert yaw == pytest.approx(2.5)
    assert rot == pytest.approx(2.5, abs=0.05)  # about z, nearly the yaw for a small roll
    # A pitch change is a rotation error without a yaw error.
    xyz, rot, yaw = pose_errors(Pose.from_xyz_rpy([10.0, 20.0, 80.0], 1.0, 33.0, 45.0), gt)
    assert xyz == pytest.approx(0.0, abs=1e-9) and rot == pytest.approx(3.0, abs=1e-6) and yaw < 0.1
    assert pose_errors(None, gt) == (INF, INF, INF)


def test_cumulative_curve_counts_errors_up_to_each_value():
    y = cumulative_curve([0.5, 1.0, 2.0, INF], [0.0, 1.0, 1.5, 2.0, 100.0])
    np.testing.assert_allclose(y, [0.0, 50.0, 50.0, 75.0, 75.0])
    assert np.isnan(cumulative_curve([], [1.0])).all()


def test_errors_over_all_queries_are_capped_and_precision_counts_accepted_poses():
    from semcityloc.evaluation.metrics import CAP_XYZ_M, summarize_errors

    inf = float("inf")
    s = summarize_errors([0.5, 8.0, 120.0, inf], [0.2, 1.0, 3.0, inf], [0.1, 0.5, 2.0, inf])
    assert s["localized"] == 3 and s["coverage"] == 75.0
    # 8 m and 120 m are accepted but outside 5 m: 1 of 3 accepted poses is right.
    assert s["acceptance_precision"] == pytest.approx(100.0 / 3)
    assert s["mean_xyz_m_capped"] == pytest.approx((0.5 + 8.0 + CAP_XYZ_M + CAP_XYZ_M) / 4)
    assert s["median_xyz_m_capped"] == pytest.approx((8.0 + CAP_XYZ_M) / 2)
    none = summarize_errors([inf], [inf], [inf])
    assert none["coverage"] == 0.0 and math.isnan(none["acceptance_precision"])


def test_pose_errors_refuse_what_is_no_pose_or_a_batch_of_another_shape():
    """Raw numpy / attribute errors before: a batch of 2 against one of 3, None, a matrix."""
    from semcityloc.errors import ArgumentTypeError
    from semcityloc.geometry.errors import center_error_m, rotation_error_deg

    a = Pose.from_xyz_rpy([0.0, 0.0, 10.0], 0, 0, 0)
    two, three = Pose.stack([a, a]), Pose.stack([a, a, a])
    with pytest.raises(ShapeError, match=r"batch shapes \(2,\) and \(3,\) do not broadcast"):
        rotation_error_deg(two, three)
    for est in (None, a.cam_from_world):
        with pytest.raises(ArgumentTypeError, match="est must be a semcityloc Pose"):
            center_error_m(est, a)
    with pytest.raises(ShapeError, match=r"one pose each, got est of batch shape \(2,\)"):
        pose_errors(two, a)
    assert pose_errors(None, a) == (math.inf, math.inf, math.inf)
