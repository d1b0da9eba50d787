"""Public entry points raise the typed errors of ``errors.py`` (audit s51, finding 11), each still a
subclass of the built-in it replaced, so callers catching ``ValueError`` / ``TypeError`` keep working; the
message is one line saying what is wrong and what to pass."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.benchmark.queries import QueryConfig, QuerySimulator
from semcityloc.benchmark.seg_errors import structured_errors
from semcityloc.benchmark.warmup import box_city_obj
from semcityloc.citymodel.io import load_city_model
from semcityloc.errors import ArgumentTypeError, ParameterError
from semcityloc.evaluation.scoring_rules import paired_difference
from semcityloc.render import Renderer

ONE = (np.array([0.5]), np.array([0.5]), np.array([1]))


def _one_line(info: pytest.ExceptionInfo) -> str:
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize(
    "options, words",
    [
        ({"rule": "ece"}, "unknown scoring rule 'ece'; known: log-loss, brier"),
        ({"level": 95}, "level must be within (0, 1), not 95: pass a confidence level, e.g. 0.95"),
        ({"resamples": 0}, "resamples must be a positive integer, not 0: pass e.g. 2000"),
    ],
)
def test_a_scoring_rule_comparison_with_a_bad_option_is_a_parameter_error(options, words):
    with pytest.raises(ParameterError) as info:
        paired_difference(*ONE, **options)
    assert isinstance(info.value, ValueError) and _one_line(info) == words


def test_the_simulator_and_a_renderer_refuse_arguments_of_the_wrong_kind(tmp_path):
    with pytest.raises(ArgumentTypeError, match="^config must be a QueryConfig .*, got dict$") as info:
        QuerySimulator(None, {"queries": 3})
    assert isinstance(info.value, TypeError) and _one_line(info)
    with pytest.raises(ArgumentTypeError, match=r"^map_model must be a CityModel \(load_city_model"):
        QuerySimulator("city.gml", QueryConfig())
    path = tmp_path / "box.obj"
    path.write_text(box_city_obj(), encoding="utf-8")
    renderer = Renderer(load_city_model(path, cache=False), engine="numba")
    with pytest.raises(ArgumentTypeError, match="^scene must be a RenderScene .*, got str$") as info:
        renderer.with_scene("not a scene")
    assert isinstance(info.value, TypeError) and _one_line(info)


def test_segmentation_errors_of_a_truth_that_is_no_view_truth_are_an_argument_type_error():
    clean = np.zeros((4, 6), np.uint8)
    with pytest.raises(ArgumentTypeError, match="^truth must be a ViewTruth .*, got ndarray$") as info:
        structured_errors(clean, clean, None, np.random.default_rng(0))
    assert isinstance(info.value, TypeError) and _one_line(info)
