"""The look-alike check (``localization/lookalike.py``, stop 52): a pose that the image fits no better than
another one more than 5 m away is refused as ambiguous, not accepted at a confident probability."""

from __future__ import annotations

import json

import numpy as np
import pytest

from helpers import CAMERA, perturbed
from semcityloc.citymodel.io import load_city_model
from semcityloc.geometry.errors import center_error_m
from semcityloc.geometry.pose import Pose
from semcityloc.localization.cascade import Sweep
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.lookalike import (
    ambiguous_reason,
    compass,
    distant_peak,
    is_distinct,
    lookalike_of,
)
from semcityloc.localization.result import NOT_LOCALIZED, REASON_AMBIGUOUS
from semcityloc.render import Renderer

PITCH_ALONG_M, PITCH_ACROSS_M = 15.0, 25.0


def rows_city(path, nx: int = 10, ny: int = 7) -> str:
    """A CityJSON suburb of identical gabled houses (10 x 8 m, eaves 6 m, ridge 9 m) in rows: ``nx`` along
    x every ``PITCH_ALONG_M``, ``ny`` rows every ``PITCH_ACROSS_M`` (the audit's ``make_rows.py``)."""
    verts: list[list[int]] = []
    objs = {}

    def v(x, y, z):
        verts.append([round(x * 1000), round(y * 1000), round(z * 1000)])
        return len(verts) - 1

    for i in range(nx):
        for j in range(ny):
            x0, y0 = i * PITCH_ALONG_M, j * PITCH_ACROSS_M
            x1, y1, ym = x0 + 10.0, y0 + 8.0, y0 + 4.0
            faces = [
                ([v(x0, y0, 0), v(x0, y1, 0), v(x1, y1, 0), v(x1, y0, 0)], 0),
                ([v(x0, y0, 0), v(x1, y0, 0), v(x1, y0, 6), v(x0, y0, 6)], 1),
                ([v(x1, y1, 0), v(x0, y1, 0), v(x0, y1, 6), v(x1, y1, 6)], 1),
                ([v(x1, y0, 0), v(x1, y1, 0), v(x1, y1, 6), v(x1, ym, 9), v(x1, y0, 6)], 1),
                ([v(x0, y1, 0), v(x0, y0, 0), v(x0, y0, 6), v(x0, ym, 9), v(x0, y1, 6)], 1),
                ([v(x0, y0, 6), v(x1, y0, 6), v(x1, ym, 9), v(x0, ym, 9)], 2),
                ([v(x1, y1, 6), v(x0, y1, 6), v(x0, ym, 9), v(x1, ym, 9)], 2),
            ]
            surfaces = [{"type": "GroundSurface"}, {"type": "WallSurface"}, {"type": "RoofSurface"}]
            objs[f"house_{i}_{j}"] = {
                "type": "Building",
                "geometry": [
                    {
                        "type": "MultiSurface",
                        "lod": "2.2",
                        "boundaries": [[f] for f, _ in faces],
                        "semantics": {"surfaces": surfaces, "values": [s for _, s in faces]},
                    }
                ],
            }
    doc = {
        "type": "CityJSON",
        "version": "2.0",
        "transform": {"scale": [0.001, 0.001, 0.001], "translate": [85000.0, 446000.0, 0.0]},
        "metadata": {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/7415"},
        "CityObjects": objs,
        "vertices": verts,
    }
    path.write_text(json.dumps(doc))
    return str(path)


def test_a_pose_one_house_along_in_a_row_of_equal_houses_is_refused_as_ambiguous(tmp_path):
    """The truth looks down on the middle of the rows; the prior lies one house along (15 m east, within
    the stated +-15 m), where the view is the same. The default localizer accepts the pose 15 m off at
    probability 0.9+; with the ``lookalikes`` preset the truth is found as a look-alike as good and the
    pose is refused."""
    city = load_city_model(rows_city(tmp_path / "rows.json"), cache=False)
    lo, hi = city.bounds_local
    centre = 0.5 * (lo + hi)
    true = Pose.from_xyz_rpy([centre[0], centre[1], lo[2] + 60.0], 0.0, 0.0, 0.0)
    prior = perturbed(true, [PITCH_ALONG_M, 0.0, 3.0])
    out = Renderer(city, engine="numba").render(CAMERA, true, depth=True)
    depth = 0.5 * out.depth[0] + 7.0
    default = Localizer(city).localize(CAMERA, prior, out.labels[0], depth)
    assert "lookalike_margin" not in default.confidence  # off by default: not looked for
    result = Localizer(city, LocalizerConfig.preset("lookalikes")).localize(
        CAMERA, prior, out.labels[0], depth
    )
    assert result.status == NOT_LOCALIZED, "a pose with an equal look-alike 15 m away was accepted"
    assert result.reason.startswith(REASON_AMBIGUOUS + ": a look-alike 1"), result.reason
    look = result.search["lookalike"]
    assert look["margin"] < 0.05 and 12.0 < look["offset_m"] < 18.0
    # One of the two is the truth: the pose refused or its look-alike.
    found = float(center_error_m(result.rejected_pose_local, true))
    other = float(center_error_m(Pose.from_state(np.array(look["state"])), true))
    assert min(found, other) < 2.0


def _sweep(scores: np.ndarray) -> Sweep:
    """A sweep over x, y = 0, 4, 8, ... m (z 0, yaw 0) with ``scores`` (nx, ny)."""
    grid = scores[:, :, None, None]
    hi = np.array([grid.shape[0] - 1, grid.shape[1] - 1, 0, 0])
    return Sweep(np.zeros(4), np.array([4.0, 4.0, 7.5, 2.0]), np.zeros(4, dtype=int), hi, grid, 0.0, 0.0)


def test_the_distant_peak_is_another_peak_not_the_flank_of_the_pose_s_own():
    scores = np.zeros((9, 3))
    scores[:, 1] = [0.90, 0.80, 0.70, 0.40, 0.60, 0.85, 0.50, 0.30, 0.20]  # peaks at x = 0 and x = 20 m
    found = np.array([0.3, 4.0, 0.0, 0.0, 0.0, 0.0])
    seed = distant_peak(_sweep(scores), found, 5.0)
    assert seed is not None and seed[0] == pytest.approx(20.0) and seed[1] == pytest.approx(4.0)
    # the flank at x = 8 m scores higher than any cell past 5 m but is no peak
    assert distant_peak(_sweep(scores), found, 30.0) is None


def test_the_lookalike_margin_is_the_pose_s_final_score_minus_the_lookalike_s():
    found = np.array([10.0, 20.0, 60.0, 0.5, 0.5, 30.0])
    other = found + [15.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    look = lookalike_of(found, 0.612, other, 0.609)
    assert look.margin == pytest.approx(0.003)
    assert look.offset_m == pytest.approx(15.0) and look.rotation_deg == pytest.approx(0.0, abs=1e-6)
    assert lookalike_of(found, 0.600, other, 0.610).margin == pytest.approx(-0.010)  # it scores higher
    d = look.as_dict()
    assert d["direction"] == "east" and d["margin"] == pytest.approx(0.003)
    text = ambiguous_reason(d, 0.01)
    assert text.startswith("a look-alike 15 m east scores within 0.003 of the pose found"), text
    assert "scores 0.010 higher" in ambiguous_reason(lookalike_of(found, 0.6, other, 0.61).as_dict(), 0.01)


def test_distinct_means_more_than_5m_or_5deg_apart():
    a = np.array([0.0, 0.0, 60.0, 0.0, 0.0, 0.0])
    assert not is_distinct(a, a + [3.0, 3.0, 0, 0, 0, 2.0], 5.0, 5.0)
    assert is_distinct(a, a + [4.0, 4.0, 0, 0, 0, 0], 5.0, 5.0)
    assert is_distinct(a, a + [0, 0, 0, 0, 0, 6.0], 5.0, 5.0)
    assert not is_distinct(a, a + [0, 0, 9.0, 0, 0, 0], 5.0, 5.0)  # height alone: the same view, closer


@pytest.mark.parametrize(
    "dx, dy, name", [(1, 0, "east"), (0, 1, "north"), (-1, -1, "south-west"), (1, -0.1, "east")]
)
def test_compass(dx, dy, name):
    assert compass(dx, dy) == name
