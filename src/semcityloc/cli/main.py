"""The ``semcityloc`` command: one sub-command module per job, typed errors become one-line messages.

Every ``SemCityLocError`` (bad input) is printed as ``semcityloc: error: <message>`` with exit code 2;
anything else is a bug and keeps its traceback. What a command prints names the flags its user types: the
library's messages name a parameter as a Python caller passes it (``crs='EPSG:25832'``), and ``main``
prints through ``FlagStream``, which turns each such spelling into its flag (``--crs EPSG:25832``,
``errors.as_flags``). An unwritable ``--out`` is refused so before any work
(``cli.outputs``). A Ctrl-C is one line and exit 130; the console script is ``cli.entry``, which imports
this module inside its own ``try`` (a Ctrl-C during these imports is one line too).
"""

from __future__ import annotations

import argparse
import contextlib
import re
import sys
from collections.abc import Iterator
from typing import TextIO

if __name__ == "__main__":
    # lazy, ``python -m semcityloc.cli.main`` only: handed to ``entry`` before the slow imports below
    from semcityloc.cli import entry

    sys.exit(entry())


from semcityloc import __version__
from semcityloc.benchmark.warmup import COMPILE_NOTICE, kernels_cached
from semcityloc.cli import (
    benchmark,
    city,
    dataset,
    demo,
    interrupted,
    label,
    localize,
    render,
    report,
    run,
    sweep,
    tiles,
    train,
    warmup,
)
from semcityloc.cli.outputs import check_output_args
from semcityloc.errors import SemCityLocError, as_flags

COMMANDS = (city, tiles, render, localize, run, benchmark, sweep, report, dataset, label, train, demo, warmup)
# Commands that run numba kernels, and which (``benchmark.warmup.KERNEL_GROUPS``): each says so once when it
# is about to compile them. Those that time the localizer (TIMED) go through the run loop, which says so and
# compiles before the first query (``benchmark.warmup.ensure_compiled``), after their arguments are checked.
RENDERS, LOCALIZES = ("render",), ("render", "localize")
KERNELS_OF = {
    "render": RENDERS,
    "label": RENDERS,
    "report": RENDERS,
    "dataset overlay": RENDERS,
    "localize": LOCALIZES,
    "run": LOCALIZES,
    "dataset benchmark": LOCALIZES,
    "benchmark": LOCALIZES,
    "sweep": LOCALIZES,
    "demo": None,  # every group: the demo runs the wireframe baseline too
}
TIMED = {"run", "dataset benchmark", "benchmark", "sweep", "demo"}


class FlagStream:
    """``stream`` (stdout or stderr) with what is written to it in the command line's words: each parameter a
    library message names as a Python caller passes it becomes its flag (``errors.as_flags``). Why here and
    not at each ``print``: every message the command prints (an error, a reader's or the localizer's warning,
    a note) reaches the user through these two streams, whichever layer worded it."""

    def __init__(self, stream: TextIO):
        self.stream = stream

    def write(self, text: str) -> int:
        self.stream.write(as_flags(text))
        return len(text)

    def __getattr__(self, name: str):  # flush, isatty, fileno, encoding: the stream's own
        return getattr(self.stream, name)


@contextlib.contextmanager
def flag_streams() -> Iterator[None]:
    """stdout and stderr as ``FlagStream`` while the command runs, the originals back after it."""
    stdout, stderr = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = FlagStream(stdout), FlagStream(stderr)
    try:
        yield
    finally:
        sys.stdout, sys.stderr = stdout, stderr


def _command(args: argparse.Namespace) -> str:
    sub = getattr(args, "dataset_command", None)
    return f"{args.command} {sub}" if sub else args.command


def kernels_of(args: argparse.Namespace) -> tuple[str, ...] | None | bool:
    """The kernel groups ``args``' command runs (None: all), or False when it runs none."""
    if _command(args) not in KERNELS_OF:
        return False
    groups = KERNELS_OF[_command(args)]
    if groups is not None and getattr(args, "method", None) == "lodloc-wireframe":
        groups = (*groups, "wireframe")
    return groups


def compile_notice(args: argparse.Namespace) -> None:
    """Say once that the command's kernels are about to compile (timed commands: the run loop says it)."""
    groups = kernels_of(args)
    if groups is False or _command(args) in TIMED or kernels_cached(groups):
        return
    print(f"semcityloc: {COMPILE_NOTICE}", file=sys.stderr, flush=True)


def build_parser() -> argparse.ArgumentParser:
    """The ``semcityloc`` argument parser: ``--version`` and every sub-command of ``COMMANDS``."""
    parser = argparse.ArgumentParser(
        prog="semcityloc",
        description="6DoF UAV image localization against semantic 3D city models.",
    )
    parser.add_argument("--version", action="version", version=f"semcityloc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def joined_dash_values(argv: list[str]) -> list[str]:
    """``argv`` with each option of ``benchmark.DASH_VALUE_OPTIONS`` joined to a value that starts with a
    minus and a digit (``--prior-extra -5-10`` -> ``--prior-extra=-5-10``). Why: argparse takes such a
    value, unless it is one plain number, for an option and says only "expected one argument"; joined, it
    reaches the option's own check, which says what is wrong with it."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] in benchmark.DASH_VALUE_OPTIONS and re.match(r"-\.?\d", str(arg)):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


def main(argv: list[str] | None = None) -> int:
    """The ``semcityloc`` command: parse ``argv``, check ``--out`` before any work, run the sub-command; a
    ``SemCityLocError`` is one line and exit 2, a Ctrl-C one line and exit 130, anything else a bug with
    its traceback. What it prints names flags, not Python parameters (``flag_streams``).
    """
    parser = build_parser()
    args = parser.parse_args(joined_dash_values(sys.argv[1:] if argv is None else list(argv)))
    with flag_streams():
        try:
            check_output_args(args)  # before any work: an unwritable --out would lose it
            compile_notice(args)
            return int(args.func(args) or 0)
        except SemCityLocError as exc:
            print(f"semcityloc: error: {exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt as exc:
            return interrupted(exc)
