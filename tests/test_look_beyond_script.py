"""``benchmarks/look_beyond.py``: its summary counts what the hint and a refusal at a margin would do."""

from __future__ import annotations

from helpers import benchmark_script
from semcityloc.localization.result import LOCALIZED, NOT_LOCALIZED

look_beyond = benchmark_script("look_beyond")


def row(status: str, right: bool, gap: float) -> dict:
    return {"status": status, "right": right, "sweep_best": 0.5, "ring_best": 0.5 + gap}


def test_the_summary_counts_hints_on_refused_results_and_what_a_margin_would_take():
    rows = [
        row(NOT_LOCALIZED, False, 0.05),  # a far prior: refused, the ring scores higher -> hinted
        row(NOT_LOCALIZED, False, -0.2),  # refused, no hint
        row(NOT_LOCALIZED, True, 0.01),  # a right pose refused by the acceptance, hinted
        row(LOCALIZED, True, -0.05),  # accepted; a refusal at margin -0.06 would take it
        row(LOCALIZED, True, -0.3),
        row(LOCALIZED, False, 0.02),  # an accepted wrong pose that the ring beats
        {"status": NOT_LOCALIZED, "reason": "query mask has no building pixels"},  # nothing to score
    ]
    s = look_beyond.summarize(rows, margin=-0.06)
    assert (s["queries"], s["scored"], s["right"], s["wrong"]) == (7, 6, 3, 3)
    assert (s["right_refused"], s["right_refused_hinted"], s["wrong_refused"], s["wrong_refused_hinted"]) == (
        1,
        1,
        2,
        1,
    )
    assert s["right_accepted_taken_at_margin"] == 1 and s["wrong_accepted_taken_at_margin"] == 1
    assert s["right_all_taken_at_margin"] == 2 and s["wrong_all_taken_at_margin"] == 2
    strict = look_beyond.summarize(rows, margin=0.0)
    assert strict["right_accepted_taken_at_margin"] == 0 and strict["wrong_accepted_taken_at_margin"] == 1
