"""``semcityloc warmup``: compile and cache the numba kernels now (``benchmark.warmup``), so the first real
command does not spend a minute compiling. ``make demo`` and ``make test`` run it after installing."""

from __future__ import annotations

import argparse
import sys

from semcityloc.benchmark.warmup import cached_kernels, kernels_cached, warm_up


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc warmup`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    p = sub.add_parser("warmup", help="compile the numba kernels once (about a minute), ahead of first use")
    p.add_argument(
        "--check", action="store_true", help="only say whether the kernels are compiled (exit 1 if not)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc warmup`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    n = len(cached_kernels())  # every group
    if args.check:
        cached = kernels_cached()
        print(f"{n} numba kernels: {'compiled and cached' if cached else 'not all compiled yet'}")
        return 0 if cached else 1
    if kernels_cached():
        print(f"{n} numba kernels already compiled and cached; nothing to do")
        return 0
    print(f"compiling {n} numba kernels (about a minute, once per install) ...", file=sys.stderr, flush=True)
    times = warm_up()
    print(f"compiled and cached in {times['total_s']:.0f} s")
    return 0
