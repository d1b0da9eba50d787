"""A photo run's notes about its priors as a whole (``photo_exports.prior_offset_notes``,
``prior_yaw_notes``): a shared height, horizontal or yaw offset is said, independent GNSS and compass
noise is not."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from semcityloc.benchmark.photo_exports import (
    OFFSET_MIN_PHOTOS,
    beyond_notes,
    edge_count,
    edge_notes,
    focal_notes,
    left_out_warning,
    offset_sigma,
    prior_offset_notes,
    prior_yaw_notes,
    rerun_sigma,
    space_split_names,
    yaw_moves_deg,
)
from semcityloc.errors import as_flags, counted
from semcityloc.geometry.pose import Pose
from semcityloc.localization.result import LOCALIZED, NOT_LOCALIZED, REASON_AT_EDGE


def test_a_shared_height_offset_is_said_with_its_size_and_side():
    rng = np.random.default_rng(0)
    moves = np.c_[rng.normal(0, 2, 12), rng.normal(0, 2, 12), -20.7 + rng.normal(0, 1, 12)]
    notes = prior_offset_notes(moves)
    assert len(notes) == 1 and "12 localized photos" in notes[0] and "below their priors" in notes[0]
    median = float(np.median(moves[:, 2]))
    assert f"a median {abs(median):.1f} m below" in notes[0] and "height reference" in notes[0]
    assert "above their priors" in prior_offset_notes(moves * [1, 1, -1])[0]
    assert "prior_sigma=" not in notes[0]  # nothing was refused at the volume's edge
    spread = 1.4826 * float(np.median(np.abs(moves[:, 2] - median)))
    sigma = math.ceil((abs(median) + 2 * spread) / 3)  # 3 sigma covers the offset and twice the spread
    (edge,) = prior_offset_notes(moves, at_edge=3)
    assert f"(3 were; or run again with prior_sigma='z={sigma}')" in edge and 7 <= sigma <= 9
    assert f"(3 were; or run again with --prior-sigma z={sigma})" in as_flags(edge)  # as the command says it


def test_a_shared_horizontal_offset_is_said_apart_from_the_height():
    rng = np.random.default_rng(1)
    moves = np.c_[8.0 + rng.normal(0, 1, 10), -6.0 + rng.normal(0, 1, 10), rng.normal(0, 3, 10)]
    (note,) = prior_offset_notes(moves)
    assert "horizontally" in note and "x +8" in note and "y -6" in note
    assert "(a wrong crs=... or offset=..., or a GNSS bias)" in note and "prior_sigma=" not in note
    assert "(a wrong --crs or --offset, or a GNSS bias)" in as_flags(note)
    (edge,) = prior_offset_notes(moves, at_edge=2, at_edge_xy=3)  # refused at the height edge: no z note
    spread = 1.4826 * float(np.median(np.linalg.norm(moves[:, :2] - np.median(moves[:, :2], axis=0), axis=1)))
    sigma = math.ceil((abs(float(np.median(moves[:, 0]))) + 2 * spread) / 3)  # x is the larger axis
    assert (
        edge.endswith(
            f"3 photos were refused at the search volume's horizontal edge: run again with "
            f"prior_sigma='xy={sigma}'"
        )
        and 3 <= sigma <= 5
    )


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


def test_a_shared_yaw_offset_is_said_with_its_turn_and_the_sigma_that_covers_it():
    rng = np.random.default_rng(3)
    moves = -12.4 + rng.normal(0, 1, 10)  # every photo found turned clockwise from its prior
    (note,) = prior_yaw_notes(moves)
    median = float(np.median(moves))
    assert f"turned a median {abs(median):.1f} deg clockwise" in note and "compass" in note
    assert "prior_sigma=" not in note
    assert "counter-clockwise" in prior_yaw_notes(-moves)[0]
    spread = 1.4826 * float(np.median(np.abs(moves - median)))
    (edge,) = prior_yaw_notes(moves, at_edge=4)
    assert "4 photos were refused at the search volume's yaw edge: run again with prior_sigma='yaw=" in edge
    assert edge.endswith(f"yaw={math.ceil((abs(median) + 2 * spread) / 3)}'")
    assert as_flags(edge).endswith(
        f"run again with --prior-sigma yaw={math.ceil((abs(median) + 2 * spread) / 3)}"
    )


def test_independent_compass_noise_is_not_a_yaw_offset():
    rng = np.random.default_rng(4)
    for n, allowed in ((5, 0.02), (10, 0.005), (30, 0.0)):  # the default yaw sigma, 3 deg
        said = np.mean([bool(prior_yaw_notes(rng.normal(0, 3, n))) for _ in range(2000)])
        assert said <= allowed, (n, said)
    assert prior_yaw_notes(np.full(OFFSET_MIN_PHOTOS - 1, 10.0)) == []
    assert prior_yaw_notes(np.full(10, 2.0)) == []  # within the stated uncertainty


def test_yaw_moves_wrap_and_edges_are_counted_per_axis():
    centre = np.array([1.0, 2.0, 80.0])
    found = [Pose.from_xyz_rpy(centre, 0.0, 30.0, 179.0), Pose.from_xyz_rpy(centre, 0.0, 0.0, 10.0)]
    prior = [Pose.from_xyz_rpy(centre, 0.5, 29.0, -179.0), Pose.from_xyz_rpy(centre, 0.0, 0.0, 4.0)]
    np.testing.assert_allclose(yaw_moves_deg(found, prior), [-2.0, 6.0], atol=0.05)
    assert yaw_moves_deg([], []).shape == (0,)
    # Exactly half a turn is +180, as ``wrap_deg`` says it (stop 51: this copy said -180).
    half = [Pose.from_xyz_rpy(centre, 0.0, 0.0, 100.0)], [Pose.from_xyz_rpy(centre, 0.0, 0.0, -80.0)]
    assert yaw_moves_deg(*half)[0] == pytest.approx(180.0)
    records = [
        {"reason": REASON_AT_EDGE, "search": {"at_edge": ["yaw+"]}},
        {"reason": REASON_AT_EDGE, "search": {"at_edge": ["z-", "yaw-"]}},
        {"reason": REASON_AT_EDGE, "search": {"at_edge": ["z+"]}},
        {"reason": None, "search": {}},
        {"status": "not_localized"},
    ]
    assert edge_count(records, "yaw") == 2 and edge_count(records, "z") == 2 and edge_count(records, "x") == 0
    assert edge_count(records, "z", "yaw") == 3  # a photo at two edges counts once


def test_photos_refused_at_the_edge_get_one_note_with_the_widest_sigma_they_ask_for():
    records = [
        {"reason": REASON_AT_EDGE, "search": {"at_edge": ["z-"], "edge_sigma": {"z": 12}}},
        {"reason": REASON_AT_EDGE, "search": {"at_edge": ["z-", "yaw+"], "edge_sigma": {"z": 40, "yaw": 12}}},
        {"reason": REASON_AT_EDGE, "search": {"at_edge": ["x+"], "edge_sigma": {"xy": 20}}},
        {"reason": None, "search": {}},
    ]
    (note,) = edge_notes(records)
    assert note.startswith("3 photos were refused at the search volume's edge (x+: 1, yaw+: 1, z-: 2)")
    assert "prior_sigma='xy=20,z=40,yaw=12' to cover all of them" in note
    assert "--prior-sigma xy=20,z=40,yaw=12 to cover all of them" in as_flags(note)
    assert edge_notes(records[3:]) == []
    (old,) = edge_notes([{"reason": REASON_AT_EDGE, "search": {}}])  # a record without the edges
    assert "edges not recorded" in old and "prior_sigma" not in old and old.startswith("1 photo was")


def test_refused_photos_with_a_better_view_beyond_the_volume_get_one_note_with_the_widest_sigma():
    def record(status, higher, xy=None):
        beyond = {"higher": higher, **({"sigma": {"xy": xy}} if xy else {})}
        return {"status": status, "search": {"beyond": beyond}}

    records = [
        record(NOT_LOCALIZED, True, 20),
        record(NOT_LOCALIZED, True, 27),
        record(NOT_LOCALIZED, False),
        {"status": NOT_LOCALIZED, "search": {}},
        record(LOCALIZED, True, 40),  # never looked beyond in practice; an accepted photo is no hint
    ]
    (note,) = beyond_notes(records)
    assert note.startswith("2 refused photos have a view beyond the searched volume")
    assert "run again with prior_sigma='xy=27' (a map that differs" in note
    assert beyond_notes(records[2:]) == []
    (old,) = beyond_notes([record(NOT_LOCALIZED, True)])  # a record without the sigma
    assert (
        old.startswith("1 refused photo has")
        and "state a larger horizontal sigma (prior_sigma='xy=...')" in old
    )
    assert "state a larger horizontal sigma (--prior-sigma xy=...)" in as_flags(old)


def test_the_offset_note_and_the_edge_note_name_one_sigma_for_the_same_refusals():
    rng = np.random.default_rng(3)
    moves = np.c_[rng.normal(0, 1, 10), rng.normal(0, 1, 10), -24.0 + rng.normal(0, 1, 10)]
    yaws = 8.0 + rng.normal(0, 0.5, 10)
    own = offset_sigma(moves, yaws)
    assert set(own) == {"z", "yaw"} and 8 <= own["z"] <= 10 and 3 <= own["yaw"] <= 4
    for warned in (4, 30):  # the refused photos' warnings ask for less, then for more, than the offset
        records = [
            {"reason": REASON_AT_EDGE, "search": {"at_edge": ["z-"], "edge_sigma": {"z": warned}}},
            {"reason": REASON_AT_EDGE, "search": {"at_edge": ["yaw+"], "edge_sigma": {"yaw": 2}}},
        ]
        asked = rerun_sigma(records, moves, yaws)
        assert asked == {"z": max(warned, own["z"]), "yaw": own["yaw"]}
        (height,) = prior_offset_notes(moves, at_edge=1, asked=asked)
        (yaw,) = prior_yaw_notes(yaws, at_edge=1, asked=asked)
        (edge,) = edge_notes(records, asked)
        assert f"prior_sigma='z={asked['z']}')" in height and f"prior_sigma='yaw={asked['yaw']}'" in yaw
        assert f"prior_sigma='z={asked['z']},yaw={asked['yaw']}' to cover all of them" in edge
    assert rerun_sigma([], moves, yaws) == {}  # nothing refused: nothing to run again


def test_counts_of_one_are_singular_in_every_note():
    """The notes said "the focal length of 1 photos", "1 photos were refused", "(1 were; ...)"."""
    assert [counted(1, "photo"), counted(2, "photo"), counted(0, "query"), counted(1, "query")] == [
        "1 photo",
        "2 photos",
        "0 queries",
        "1 query",
    ]
    assert counted(1, "photo was", "photos were") == "1 photo was" and counted(3, "building") == "3 buildings"
    one = SimpleNamespace(focal_estimate={"scale": None, "reason": "0 oblique images; need 5"})
    assert focal_notes([one]) == [
        "the focal length of 1 photo could not be estimated: 0 oblique images; need 5"
    ]
    rng = np.random.default_rng(4)
    moves = np.c_[8.0 + rng.normal(0, 1, 10), -6.0 + rng.normal(0, 1, 10), -20.0 + rng.normal(0, 1, 10)]
    height, horizontal = prior_offset_notes(moves, at_edge=1, at_edge_xy=1)
    assert "(1 was; or run again with prior_sigma='z=" in height
    assert "; 1 photo was refused at the search volume's horizontal edge" in horizontal
    (yaw,) = prior_yaw_notes(-12.0 + rng.normal(0, 1, 10), at_edge=1)
    assert "; 1 photo was refused at the search volume's yaw edge" in yaw
    assert "1 photos" not in " ".join([height, horizontal, yaw])


def test_names_with_white_space_are_those_colmap_text_and_geo_txt_cannot_hold():
    """COLMAP's images.txt and ODM's geo.txt split a line on spaces: such names are left out of them with
    one warning naming them (the first five, then how many more)."""
    names = ["DJI_0001.JPG", "my photo ü.JPG", "tab\there.JPG", "ünïcode.JPG", " lead.JPG", ""]
    assert space_split_names(names) == ["my photo ü.JPG", "tab\there.JPG", " lead.JPG", ""]
    assert left_out_warning([], ["geo.txt"]) == []
    (one,) = left_out_warning(["my photo ü.JPG"], ["colmap/images.txt"])
    assert one.startswith("1 localized photo left out of colmap/images.txt (their readers split a line")
    (many,) = left_out_warning([f"p {i}.JPG" for i in range(7)], ["colmap/images.txt", "geo.txt"])
    assert many.startswith("7 localized photos left out of colmap/images.txt and geo.txt")
    assert "p 0.JPG, p 1.JPG, p 2.JPG, p 3.JPG, p 4.JPG (+2 more);" in many
