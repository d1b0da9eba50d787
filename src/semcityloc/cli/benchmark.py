"""``semcityloc benchmark``: simulated queries over a city model, localized, scored, resumable.

``--scenario realistic`` (default) or ``clean`` picks the simulation (``benchmark.scenario``); ``--set
knob=value`` (repeatable) changes one knob of it. ``semcityloc sweep`` (``cli/sweep.py``) runs one
benchmark per value of a knob with the same arguments. Writes ``OUT/results.csv`` (a row per query),
``OUT/summary.json`` and ``OUT/run.json`` and prints the summary as a Markdown table
(``semcityloc.benchmark.runfiles`` documents the files). Run the same command again after an
interruption and it continues where it stopped.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from semcityloc.benchmark.methods import available_methods
from semcityloc.benchmark.perception_sim import SEG_PRESETS
from semcityloc.benchmark.report_tables import summary_markdown
from semcityloc.benchmark.scenario import (
    DEFAULT_SCENARIO,
    SCENARIOS,
    parse_value,
    query_config,
    resolve_knob,
)
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.cli.dataset import (
    add_dataset_arguments,
    add_perception_arguments,
    real_data_defaults,
    run_dataset_benchmark,
)
from semcityloc.cli.executor import add_executor_arguments, run_from_args
from semcityloc.cli.localize import add_preset_argument, add_prior_sigma_argument
from semcityloc.errors import BenchmarkConfigError, BenchmarkError, counted


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc benchmark`` and its options to the command's parser (called by
    ``cli.main.build_parser``, once per sub-command module).
    """
    p = sub.add_parser("benchmark", help="localize simulated drone queries over a city model and score them")
    add_simulation_arguments(p)
    add_executor_arguments(p)
    p.add_argument("--out", default="benchmark_output", help="output folder (default benchmark_output)")
    add_dataset_arguments(p, positional=False)
    add_perception_arguments(p)
    p.set_defaults(func=run)


def add_simulation_arguments(p: argparse.ArgumentParser, sweep: bool = False) -> None:
    """The options of a simulated benchmark run (shared by ``benchmark`` and, ``sweep`` true, by ``sweep``,
    which has no ``--dataset``: there ``--city`` is required and ``--stop-after`` counts over the sweep)."""
    city = "CityGML / CityJSON / OBJ file, a tile store, or 'generated' for the embedded city"
    p.add_argument(
        "--city",
        default=None,
        required=sweep,
        help=city
        if sweep
        else city + " (with --dataset: the LoD model, default the *.obj beside the data set)",
    )
    p.add_argument(
        "--lod",
        type=int,
        choices=(1, 2, 3),
        default=None,
        help="map LoD (default: the file's highest; 1 on an LoD2 city derives LoD1 blocks)",
    )
    p.add_argument("--queries", type=int, default=100, help="number of simulated queries (default 100)")
    p.add_argument("--seed", type=int, default=0, help="seed of the query simulation")
    p.add_argument("--method", default="semcityloc", choices=available_methods(), help="method or ablation")
    p.add_argument(
        "--seg-quality",
        default="trained",
        choices=tuple(SEG_PRESETS),
        help="simulated segmentation preset (default trained)",
    )
    p.add_argument(
        "--prior-extra",
        default=None,
        metavar="A-B",
        help="extra per-axis prior perturbation in metres, e.g. 10-20 (default: none)",
    )
    add_preset_argument(p, default=None)
    add_prior_sigma_argument(p)
    p.add_argument(
        "--scenario",
        default=DEFAULT_SCENARIO,
        choices=tuple(SCENARIOS),
        help=f"simulation scenario (default {DEFAULT_SCENARIO}; clean = the queries almost the map itself)",
    )
    p.add_argument(
        "--set",
        dest="settings",
        action="append",
        default=[],
        metavar="KNOB=VALUE",
        help="change one knob of the scenario, e.g. prior_height_m=10 (repeatable; docs/benchmark.md)",
    )
    p.add_argument("--workers", type=int, default=1, help="processes localizing in parallel (default 1)")
    p.add_argument(
        "--keep-details",
        type=int,
        default=3,
        help="save labels, poses and cost volume of the first N queries for the report (default 3)",
    )
    p.add_argument("--crs", default=None, help="override the city file's CRS, e.g. EPSG:25832")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="start the run again: delete the results in --out (needed when made with other arguments)",
    )
    p.add_argument(
        "--stop-after",
        type=int,
        default=None,
        metavar="N",
        help="localize at most N more queries, then stop (run again to continue)"
        + (" - N over the whole sweep, its values in turn" if sweep else ""),
    )


def parse_settings(items: list[str] | None) -> dict[str, Any]:
    """``--set``'s ``["knob=value", ...]`` -> {knob: value} (``scenario.query_config``'s ``settings``); each
    knob checked (``scenario.resolve_knob``, ``BenchmarkConfigError``). Here, not in ``benchmark.scenario``:
    it reads the command line's text, and its refusals name the flag."""
    out: dict[str, Any] = {}
    for item in items or []:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise BenchmarkConfigError(f"--set takes knob=value, got {item!r}")
        resolve_knob(name.strip())
        if name.strip() in out:
            raise BenchmarkConfigError(f"--set {name.strip()} is given twice; give each knob once")
        out[name.strip()] = parse_value(text.strip())
    return out


# Options whose value may start with a minus (``--prior-extra -5-10``, ``run --offset -3.5,12,0``):
# ``cli.main.joined_dash_values`` hands such a value to the option, which reads or refuses it in its words.
DASH_VALUE_OPTIONS = ("--prior-extra", "--offset")


def parse_prior_extra(text: str | None) -> tuple[float, float] | None:
    """``"A-B"`` (metres, 0 <= A <= B) -> (A, B); None / ``"none"`` -> None."""
    if text is None or text.strip().lower() in ("", "none", "0"):
        return None
    if text.strip().startswith("-") or "--" in text:  # -5-10, 5--10: split at "-" they read as no pair
        raise BenchmarkError(f"--prior-extra A-B needs 0 <= A <= B, got {text!r}: no negative distances")
    parts = text.split("-")
    try:
        if len(parts) != 2:
            raise ValueError
        a, b = float(parts[0]), float(parts[1])
    except ValueError as exc:
        raise BenchmarkError(
            f"--prior-extra must look like A-B in metres (e.g. 10-20), got {text!r}"
        ) from exc
    if not (math.isfinite(a) and math.isfinite(b) and 0 <= a <= b):
        raise BenchmarkError(f"--prior-extra A-B needs 0 <= A <= B, got {text!r}")
    return a, b


def dataset_only_options(args: argparse.Namespace) -> list[str]:
    """The real-data options given to a simulated run (``--masks``, ...): they would be silently ignored."""
    return [
        "--" + name.replace("_", "-")
        for name, unset in real_data_defaults().items()
        if getattr(args, name, unset) != unset
    ]


def spec_from_args(
    args: argparse.Namespace, settings: dict | None = None, sweep: tuple | None = None
) -> BenchmarkSpec:
    """The simulated run of the parsed arguments (``settings``: knobs set on top of ``--set``)."""
    if not args.city:
        raise BenchmarkError("give --city MODEL (or 'generated') for simulated queries, or --dataset PATH")
    ignored = dataset_only_options(args)
    if ignored:
        raise BenchmarkError(
            f"{', '.join(ignored)}: only with --dataset (a real data set); simulated queries make their own "
            "masks and depth"
        )
    query = query_config(
        args.scenario,
        {**parse_settings(args.settings), **(settings or {})},
        queries=args.queries,
        seed=args.seed,
        seg_quality=args.seg_quality,
        prior_extra_m=parse_prior_extra(args.prior_extra),
    )
    return BenchmarkSpec(
        city=args.city,
        query=query,
        lod=args.lod,
        method=args.method,
        preset=args.preset or "default",
        prior_sigma=args.prior_sigma,
        crs=args.crs,
        keep_details=args.keep_details,
        sweep=sweep,
    )


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc benchmark`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    if args.dataset:  # a real data set (LoD-Loc layout) instead of simulated queries
        return run_dataset_benchmark(args)
    spec = spec_from_args(args)
    out = Path(args.out)
    outcome = run_from_args(spec, out, args)
    if not outcome.complete:
        total = counted(outcome.config["queries"], "query")
        print(f"{len(outcome.rows)}/{total} done in {out}; run again to continue")
        return 0
    print(summary_markdown([outcome.summary], [args.method]))
    skipped = outcome.summary.get("skipped", 0)
    if skipped:
        print(
            f"{skipped} of {counted(outcome.config['queries'], 'query')} skipped: the simulator found no "
            "view with enough building pixels (a small or sparse city model); they are not in the metrics"
        )
    print(f"wrote {out / 'results.csv'} and {out / 'summary.json'}")
    return 0
