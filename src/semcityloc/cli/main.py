"""The ``semcityloc`` command: one sub-command module per job, typed errors become one-line messages.

Every ``SemCityLocError`` (bad input) is printed as ``semcityloc: error: <message>`` with exit code 2;
anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import sys

from semcityloc import __version__
from semcityloc.benchmark.warmup import COMPILE_NOTICE, kernels_cached
from semcityloc.cli import (
    benchmark,
    city,
    dataset,
    demo,
    label,
    localize,
    render,
    report,
    run,
    sweep,
    train,
    warmup,
)
from semcityloc.errors import SemCityLocError

COMMANDS = (city, render, localize, run, benchmark, sweep, report, dataset, label, train, demo, warmup)
# Commands that run numba kernels, and which (``benchmark.warmup.KERNEL_GROUPS``): each says so once when it
# is about to compile them.
RENDERS, LOCALIZES = ("render",), ("render", "localize")
KERNELS_OF = {
    "render": RENDERS,
    "label": RENDERS,
    "report": RENDERS,
    "localize": LOCALIZES,
    "run": LOCALIZES,
    "dataset": LOCALIZES,
    "benchmark": LOCALIZES,
    "sweep": LOCALIZES,
    "demo": None,  # every group: the demo runs the wireframe baseline too
}


def kernels_of(args: argparse.Namespace) -> tuple[str, ...] | None | bool:
    """The kernel groups ``args``' command runs (None: all), or False when it runs none."""
    if args.command not in KERNELS_OF:
        return False
    groups = KERNELS_OF[args.command]
    if groups is not None and getattr(args, "method", None) == "lodloc-wireframe":
        groups = (*groups, "wireframe")
    return groups


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="semcityloc",
        description="6DoF UAV image localization against semantic 3D city models.",
    )
    parser.add_argument("--version", action="version", version=f"semcityloc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        groups = kernels_of(args)
        if groups is not False and not kernels_cached(groups):
            print(f"semcityloc: {COMPILE_NOTICE}", file=sys.stderr, flush=True)
        return int(args.func(args) or 0)
    except SemCityLocError as exc:
        print(f"semcityloc: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("semcityloc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
