"""The ``semcityloc`` command: one sub-command module per job, typed errors become one-line messages.

Every ``SemCityLocError`` (bad input) is printed as ``semcityloc: error: <message>`` with exit code 2;
anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import sys

from semcityloc import __version__
from semcityloc.cli import benchmark, city, dataset, demo, label, localize, render, report, sweep, train
from semcityloc.errors import SemCityLocError

COMMANDS = (city, render, localize, benchmark, sweep, report, dataset, label, train, demo)


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
        return int(args.func(args) or 0)
    except SemCityLocError as exc:
        print(f"semcityloc: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("semcityloc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
