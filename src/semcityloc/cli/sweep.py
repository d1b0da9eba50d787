"""``semcityloc sweep``: one benchmark run per value of one knob, the rest of the arguments the same.

``semcityloc sweep --knob prior_roll_pitch_sigma_deg --values 0,1,2,3 --city MODEL --out DIR`` runs
``DIR/<knob>=<value>/`` for each value (each resumable like ``semcityloc benchmark``; a killed sweep
continues where it stopped), prints one table with a row per value and tells how to draw the report:
``semcityloc report DIR/*`` writes the sweep's table and a recall-against-value plot.

The swept knob is set by ``--values`` alone: ``--set KNOB=...`` of the same knob, or the option that sets it
(``--seed`` when sweeping ``seed``, ``--seg-quality``, ``--prior-extra``, ``--queries``), is refused, and
so is a value given twice (``1,1.0``). ``--stop-after N`` counts over the whole sweep: at most N queries
are localized, the values in turn, then the sweep stops (run again to continue).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from semcityloc.benchmark.report_tables import summary_markdown
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.scenario import parse_value, resolve_knob
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.cli.benchmark import add_simulation_arguments, parse_settings, spec_from_args
from semcityloc.errors import BenchmarkError, counted


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc sweep`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    p = sub.add_parser("sweep", help="one benchmark run per value of one simulation knob")
    p.add_argument("--knob", required=True, help="the knob to sweep (any name --set takes)")
    p.add_argument("--values", required=True, help="comma-separated values, e.g. 0,1,2 or 2-5,5-10 for pairs")
    add_simulation_arguments(p, sweep=True)
    p.add_argument("--out", required=True, help="folder of the sweep: one run folder per value")
    # The options that set a knob sweep can sweep: unset unless given, so a given one can be told apart
    _DEFAULTS.update({dest: p.get_default(dest) for dest, _ in _KNOB_OPTIONS.values()})
    p.set_defaults(func=run, **dict.fromkeys(_DEFAULTS))


# QueryConfig field -> (the option's dest, its flag): options that set a knob sweep can sweep
_KNOB_OPTIONS = {
    "queries": ("queries", "--queries"),
    "seed": ("seed", "--seed"),
    "seg_quality": ("seg_quality", "--seg-quality"),
    "prior_extra_m": ("prior_extra", "--prior-extra"),
}
_DEFAULTS: dict[str, object] = {}  # their defaults, applied when not given


def check_swept_knob_alone(args: argparse.Namespace, knob: str) -> None:
    """Refuse what else sets the swept ``knob`` (its values would be dropped without a word: stop 56
    audit): ``--set`` of the same knob, the option that sets it; then fill in the options' defaults."""
    target = (None, knob) if knob == "queries" else resolve_knob(knob)
    for item in args.settings:
        name = item.partition("=")[0].strip()
        if resolve_knob(name) == target:
            raise BenchmarkError(f"--set {item} sets the swept knob {knob}; give its values in --values only")
    for field, (dest, flag) in _KNOB_OPTIONS.items():
        if target == (None, field) and getattr(args, dest) is not None:
            raise BenchmarkError(f"{flag} sets the swept knob {knob}; give its values in --values only")
        if getattr(args, dest) is None:
            setattr(args, dest, _DEFAULTS.get(dest))


def sweep_spec(args: argparse.Namespace, knob: str, value) -> BenchmarkSpec:
    """The run of one swept value: a knob set as ``--set`` sets it, ``queries`` as ``--queries`` does."""
    if knob == "queries":
        return spec_from_args(argparse.Namespace(**{**vars(args), "queries": value}), sweep=(knob, value))
    return spec_from_args(args, {knob: value}, sweep=(knob, value))


def sweep_values(text: str) -> list:
    """The values of ``--values`` (each parsed as ``--set`` parses a value)."""
    texts = [v.strip() for v in text.split(",") if v.strip()]
    values = [parse_value(v) for v in texts]
    if not values:
        raise BenchmarkError("--values needs at least one value")
    for i, value in enumerate(values):
        twice = [texts[j] for j in range(i) if values[j] == value]
        if twice:
            raise BenchmarkError(f"--values gives a value twice ({twice[0]} and {texts[i]}); give each once")
    return values


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc sweep`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    knob = args.knob.strip()
    if knob != "queries":  # set by --queries, no knob of --set
        parse_settings([f"{knob}=0"])  # an unknown knob fails before anything runs
    check_swept_knob_alone(args, knob)
    values = sweep_values(args.values)
    specs = [sweep_spec(args, knob, v) for v in values]  # all checked first
    out = Path(args.out)
    run_dirs = [out / f"{knob}={value}".replace("/", "_").replace(" ", "") for value in values]
    summaries, labels, done = [], [], True
    left = args.stop_after  # --stop-after: queries the sweep may still localize (None: all)
    for value, spec, run_dir in zip(values, specs, run_dirs, strict=True):
        outcome = run_benchmark(spec, run_dir, workers=args.workers, overwrite=args.overwrite, limit=left)
        if left is not None:  # the next values get what is left (0: a finished run summarised, no work)
            left = max(0, left - outcome.new_rows)
        if not outcome.complete:
            done = False
            print(
                f"{knob}={value}: {len(outcome.rows)}/{counted(outcome.config['queries'], 'query')} done in "
                f"{run_dir}"
            )
            continue
        summaries.append(outcome.summary)
        labels.append(f"{knob}={value}")
    if summaries:
        print(summary_markdown(summaries, labels, label_header=f"{args.method}, {knob}"))
    others = sorted(p.name for p in out.iterdir() if (p / "run.json").is_file() and p not in run_dirs)
    if others:  # another sweep's runs in the same folder (--overwrite clears a run, not its neighbours)
        print(
            f"semcityloc: warning: {out} also holds {counted(len(others), 'run folder')} of another sweep "
            f"({', '.join(others[:4])}{', ...' if len(others) > 4 else ''}): the report below names this "
            "sweep's runs only",
            file=sys.stderr,
        )
        hint = "semcityloc report " + " ".join(shlex.quote(str(d)) for d in run_dirs)
    else:
        hint = f"semcityloc report {out}/*"
    print(("" if done else "run again to continue; ") + f"report: {hint}")
    return 0
