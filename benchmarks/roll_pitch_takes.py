"""Judge take rules of the roll/pitch second look on the same runs: which pose each rule would keep.

The second look (``Localizer._settle_roll_pitch_conflict``) refines a pose again with the roll/pitch sigma
widened and keeps the second pose by a take rule; its record holds both poses, so
``compare_configs.py --rows`` writes each one's error against the truth (``roll_pitch_look``). This script
reads those rows and counts, per condition, the accepted poses within 2 m / 2 deg and 5 m / 5 deg had each
rule decided: stop 52's (any gain), stop 54's (beyond ``--sure-sigma`` any gain, within it a gain above
``--unsure-gain``), beyond ``--sure-sigma`` only, and never looking twice. The acceptance is taken as it
decided on the pose kept (a rule that keeps the other pose could change it: an approximation, said in the
table's caption). How stop 54's rule was chosen (docs/localization.md, "A roll/pitch prior the image
contradicts")::

    python benchmarks/compare_configs.py --variant base --seeds 0,1 --queries 100 \\
        --condition realistic --condition hilly --condition flat_eaves --condition outdated \\
        --condition map_err2x --condition map_faults --condition imu2x --condition imu4x --rows rows.jsonl
    python benchmarks/roll_pitch_takes.py rows.jsonl
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path

from semcityloc.localization.result import LOCALIZED

Rule = Callable[[dict], bool]


def rules(sure_sigma: float, unsure_gain: float) -> dict[str, Rule]:
    """Take rules by name: each says, from a look's record, whether the second pose is kept."""
    return {
        "any gain (stop 52)": lambda look: look["gain"] > 0.0,
        f"beyond {sure_sigma:g} sigma any gain, within it > {unsure_gain:g} (stop 54)": lambda look: (
            look["gain"] > (0.0 if look["sigmas"] > sure_sigma else unsure_gain)
        ),
        f"beyond {sure_sigma:g} sigma only": lambda look: look["gain"] > 0.0 and look["sigmas"] > sure_sigma,
        "never": lambda look: False,
    }


def counts(rows: list[dict], take: Rule) -> tuple[int, int, int]:
    """(within 2 m / 2 deg, within 5 m / 5 deg, outside 5 m / 5 deg) of the accepted poses had ``take``
    decided every second look."""
    within2 = within5 = wrong = 0
    for row in rows:
        if row["status"] != LOCALIZED:
            continue
        look = row.get("roll_pitch_look")
        m, deg = (
            (row["err_m"], row["err_deg"])
            if look is None
            else look["second_err" if take(look) else "first_err"]
        )
        within2 += m <= 2.0 and deg <= 2.0
        within5 += m <= 5.0 and deg <= 5.0
        wrong += not (m <= 5.0 and deg <= 5.0)
    return within2, within5, wrong


def table(rows: list[dict], named: dict[str, Rule], variant: str | None = None) -> str:
    """The Markdown table: one line per condition, one column per rule."""
    variant = variant or rows[0]["variant"]
    rows = [r for r in rows if r["variant"] == variant]
    conditions = list(dict.fromkeys(r.get("condition", "realistic") for r in rows))
    lines = [
        "| condition (queries; looked at twice) | " + " | ".join(named) + " |",
        "|---|" + "---|" * len(named),
    ]
    for condition in conditions:
        these = [r for r in rows if r.get("condition", "realistic") == condition]
        looks = sum(r.get("roll_pitch_look") is not None for r in these)
        cells = ["{} / {} ({})".format(*counts(these, take)) for take in named.values()]
        lines.append(f"| {condition} ({len(these)}; {looks}) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rows", type=Path, help="compare_configs.py --rows output")
    ap.add_argument("--variant", help="the variant's rows to read (default: the first)")
    ap.add_argument("--sure-sigma", type=float, default=3.0)
    ap.add_argument("--unsure-gain", type=float, default=0.01)
    args = ap.parse_args(argv)
    try:
        rows = [json.loads(line) for line in args.rows.read_text().splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SystemExit(f"{args.rows}: cannot read it as compare_configs.py --rows output ({exc})") from None
    if not rows or not all(isinstance(r, dict) and {"variant", "status", "err_m"} <= r.keys() for r in rows):
        raise SystemExit(
            f"{args.rows}: not compare_configs.py --rows output (one JSON row per query and variant)"
        )
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    if args.variant is not None and args.variant not in variants:
        raise SystemExit(
            f"no rows of variant {args.variant!r} in {args.rows} (it has: {', '.join(variants)})"
        )
    print(
        "Accepted poses within 2 m / 2 deg / within 5 m / 5 deg (outside 5 m / 5 deg), had each rule "
        "decided; the acceptance as it decided on the pose kept."
    )
    print(table(rows, rules(args.sure_sigma, args.unsure_gain), args.variant))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
