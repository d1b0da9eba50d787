"""Buildings, or large parts of them, on one side only (localization/agreement.py): the hint that the map is
outdated."""

import numpy as np
import pytest

from helpers import CAMERA, benchmark_script, view
from semcityloc.classes import IGNORE, SemanticClass
from semcityloc.localization.agreement import (
    MIN_REGION_SHARE,
    WARN_SHARE,
    agreed_depth_cost,
    boundary_distance_px,
    building_agreement,
)
from semcityloc.localization.localize import Localizer
from semcityloc.localization.query import Query
from semcityloc.localization.scoring import robust_depth_cost

G, R, W = int(SemanticClass.GROUND), int(SemanticClass.ROOF), int(SemanticClass.WALL)


def _scene(*boxes: tuple[int, int, int, int]) -> np.ndarray:
    """40 x 60 ground with roof boxes (row0, row1, col0, col1)."""
    out = np.full((40, 60), G, dtype=np.uint8)
    for r0, r1, c0, c1 in boxes:
        out[r0:r1, c0:c1] = R
    return out


A, B = (5, 15, 5, 20), (20, 35, 30, 50)  # 150 and 300 pixels of 2,400


def test_the_same_buildings_agree():
    a = building_agreement(_scene(A, B), _scene(A, B))
    assert a.building_iou == 1.0 and a.unmapped_share == 0.0 and a.unseen_share == 0.0
    assert a.warnings() == []


def test_a_building_the_map_lacks_and_one_the_image_lacks():
    lacks = building_agreement(_scene(A, B), _scene(A))  # B built after the survey
    assert lacks.building_iou == pytest.approx(150 / 450)
    assert lacks.unmapped_share == pytest.approx(300 / 2400) and lacks.unseen_share == 0.0
    (warning,) = lacks.warnings()
    assert warning.startswith("the image shows buildings the map lacks or parts of them (12 %")
    assert "or the pose wrong" in warning
    gone = building_agreement(_scene(A), _scene(A, B))  # B torn down
    assert gone.unseen_share == pytest.approx(300 / 2400) and gone.unmapped_share == 0.0
    (warning,) = gone.warnings()
    assert warning.startswith("the map has buildings the image does not show or parts of them (12 %")


def test_thin_bands_are_not_a_change_and_wide_ones_are():
    # Off by 2 px in both directions (a slightly wrong pose, a height error, eaves): bands only.
    near = building_agreement(_scene(A, B), _scene((7, 17, 7, 22), (22, 37, 32, 52)))
    assert near.building_iou < 0.75 and near.unmapped_share == 0.0 and near.unseen_share == 0.0
    # Off by 3 px sideways: a 3 px band is a blob (a pose this far off, or a changed building).
    far = building_agreement(_scene(A, B), _scene((5, 15, 8, 23), (20, 35, 33, 53)))
    assert far.unmapped_share == pytest.approx((10 * 3 + 15 * 3) / 2400)
    assert far.unseen_share == pytest.approx((10 * 3 + 15 * 3) / 2400)


def test_part_of_a_block_the_map_lacks_counts():
    block = _scene((20, 35, 10, 50))  # one block in the image ...
    part = building_agreement(block, _scene((20, 35, 10, 30)))  # ... of which the map has the left half
    assert part.unmapped_share == pytest.approx(15 * 20 / 2400) and part.unseen_share == 0.0
    assert len(part.warnings()) == 1


def test_noise_blobs_are_not_buildings_the_map_lacks():
    query = _scene(A)
    query[30, 40] = R  # one stray pixel: below MIN_REGION_SHARE
    assert 1 / 2400 < MIN_REGION_SHARE
    a = building_agreement(query, _scene(A))
    assert a.unmapped_share == 0.0 and a.warnings() == []
    small = _scene(A, (30, 33, 40, 44))  # 12 pixels: counted, but under WARN_SHARE
    a = building_agreement(small, _scene(A))
    assert 0.0 < a.unmapped_share < WARN_SHARE and a.warnings() == []


def test_ignored_and_background_pixels_are_left_out():
    query, render = _scene(A), _scene(A)
    query[0:3, :] = IGNORE
    render[0:3, :] = W  # buildings rendered where the query does not know: not counted
    query[38:40, :] = int(SemanticClass.BACKGROUND)
    render[38:40, :] = R  # nor where the query sees sky or trees
    a = building_agreement(query, render)
    assert a.building_iou == 1.0 and a.unseen_share == 0.0


def test_nothing_labelled_gives_zeros():
    empty = np.zeros((40, 60), dtype=np.uint8)
    nothing = building_agreement(empty, empty)
    assert nothing.building_iou == nothing.unmapped_share == nothing.unseen_share == 0.0
    assert building_agreement(empty, _scene(A)) == nothing  # buildings rendered where the query sees none
    assert building_agreement(_scene(), _scene()) == nothing  # ground only


def test_shapes_must_match():
    with pytest.raises(ValueError, match="same 2D shape"):
        building_agreement(_scene(A), _scene(A)[:, :30])


def test_the_warning_study_counts_warnings_against_real_changes():
    study = benchmark_script("map_change_warnings")
    rows = [
        {"right": True, "warned": [True, False], "real": [True, False]},  # a new building, seen
        {"right": True, "warned": [True, False], "real": [False, False]},  # warned, nothing changed
        {"right": True, "warned": [False, False], "real": [True, True]},  # both missed
        {"right": False, "warned": [True, True], "real": [False, False]},  # a wrong pose
    ]
    assert study.row("x", rows) == "| x | 3 | 2 / 1 / 1 | 0 / 0 / 1 | 1 of 1 |"


C = (25, 31, 8, 14)  # a small third building, 36 pixels


def test_boundaries_on_each_other_are_zero_apart_and_a_shift_moves_them():
    assert boundary_distance_px(_scene(A, B), _scene(A, B)) == 0.0
    apart = [boundary_distance_px(_scene(A, B), _scene(*[_moved(b, k) for b in (A, B)])) for k in (1, 3, 6)]
    assert 0.0 < apart[0] < apart[1] < apart[2]
    # Symmetric: query and render swapped give the same distance.
    moved = _scene(*[_moved(b, 3) for b in (A, B)])
    assert boundary_distance_px(moved, _scene(A, B)) == boundary_distance_px(_scene(A, B), moved)


def _moved(box: tuple[int, int, int, int], k: int) -> tuple[int, int, int, int]:
    """The box moved k pixels down and k right."""
    return box[0] + k, box[1] + k, box[2] + k, box[3] + k


def test_a_building_on_one_side_only_does_not_move_the_boundaries_that_agree():
    """A small building the map lacks, or one the image lacks: the median reads the boundaries that exist
    on both sides, which lie on each other; a pose 3 px off moves all of them."""
    assert boundary_distance_px(_scene(A, B, C), _scene(A, B)) == 0.0  # C built after the survey
    assert boundary_distance_px(_scene(A, B), _scene(A, B, C)) == 0.0  # C torn down
    off = boundary_distance_px(_scene(A, B, C), _scene(*[_moved(b, 3) for b in (A, B, C)]))
    assert off >= 1.0


def test_boundaries_of_unlabelled_pixels_do_not_count():
    query, rendered = _scene(A, B), _scene(A, B)
    rendered[0:4, 40:60] = R  # a roof under query pixels that are ignored or background
    query[0:4, 40:60] = IGNORE
    assert boundary_distance_px(query, rendered) == 0.0
    query[0:4, 40:60] = 0
    assert boundary_distance_px(query, rendered) == 0.0


def test_no_boundary_on_a_side_is_no_evidence():
    assert np.isnan(boundary_distance_px(_scene(), _scene(A)))  # the query is all ground
    assert np.isnan(boundary_distance_px(_scene(A), _scene()))
    with pytest.raises(ValueError, match="same 2D shape"):
        boundary_distance_px(_scene(A), _scene(A)[:, :10])


def test_depth_on_agreed_pixels_leaves_out_a_building_the_map_lacks():
    """A building new since the survey: the query sees its roof 20 m nearer than the map's ground there.
    Over every pixel that reads as a depth error; over the pixels where query and map agree on building
    or not it does not, while a depth that does not fit the map anywhere still costs."""
    rng = np.random.default_rng(0)
    rendered = _scene(A)
    render_depth = 100.0 + 5.0 * rng.random((40, 60))
    render_depth[rendered == R] -= 15.0
    query = _scene(A, B)
    true_depth = render_depth.copy()
    true_depth[20:35, 30:50] -= 20.0  # B's roof
    query_depth = 0.5 * true_depth + 7.0  # relative depth: any scale and shift
    full = robust_depth_cost(query_depth, render_depth, cap=0.3)
    agreed = agreed_depth_cost(query, query_depth, rendered, render_depth, cap=0.3)
    assert full > 0.02 and agreed == pytest.approx(0.0, abs=1e-9)
    shuffled = rng.permutation(query_depth.reshape(-1)).reshape(query_depth.shape)
    assert agreed_depth_cost(query, shuffled, rendered, render_depth, cap=0.3) > 0.02
    # Background and ignored query pixels never count; nothing rendered (+inf) neither.
    query[:3] = IGNORE
    render_depth[:, :2] = np.inf
    left = agreed_depth_cost(query, query_depth, rendered, render_depth, cap=0.3)
    assert left == pytest.approx(0, abs=1e-9)
    with pytest.raises(ValueError, match="one size"):
        agreed_depth_cost(query, query_depth[:, :10], rendered, render_depth, cap=0.3)


def test_the_numpy_depth_cost_is_the_refinements(generated_lod2):
    """``robust_depth_cost`` on all of a view's pixels equals the fused kernel's C_d at that pose."""
    localizer = Localizer(generated_lod2)
    pose = view(generated_lod2, 10.0, -20.0, 80.0, 1.0, 2.0, 30.0)
    cam = localizer.fine_camera(CAMERA)
    labels, truth_depth = localizer.render_labels_and_depth(cam, pose)
    assert labels.shape == truth_depth.shape == (cam.height, cam.width)
    depth = 2.0 * truth_depth + 3.0
    depth *= 1.0 + 0.05 * np.sin(np.arange(cam.width) / 7.0)  # not affine: the fit and the cap matter
    moved = view(generated_lod2, 11.0, -20.0, 80.0, 1.0, 2.0, 30.5)
    scores = localizer.score_poses(CAMERA.scaled(cam.width, cam.height), labels, depth, [moved])
    kernel = scores["depth_cost"][0]
    _, at_depth = localizer.render_labels_and_depth(cam, moved)
    q_labels, q_depth = Query.from_arrays(labels, depth, localizer.has_openings).at(cam.width, cam.height)
    cost = agreed_depth_cost(q_labels, q_depth, q_labels, at_depth, localizer.config.refine.depth_cap)
    assert kernel > 0.01 and cost == pytest.approx(kernel, rel=1e-6)
