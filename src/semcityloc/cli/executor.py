"""``--executor local|ray`` and ``--ray-address``: where ``semcityloc run`` and ``benchmark`` localize
(``benchmark.run.EXECUTORS``; Ray: ``benchmark.ray_executor``, docs/scale.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from semcityloc.benchmark.ray_executor import check_address
from semcityloc.benchmark.run import EXECUTORS, BenchmarkOutcome, RunSpec, run_benchmark
from semcityloc.errors import BenchmarkError


def add_executor_arguments(p: argparse.ArgumentParser) -> None:
    """Add ``--executor`` and ``--ray-address`` to a sub-command, so ``run`` and ``benchmark`` offer the same
    choices (``benchmark.run.EXECUTORS``).
    """
    p.add_argument(
        "--executor",
        default="local",
        choices=EXECUTORS,
        help="local (default: this process, or --workers processes) or ray (a local Ray runtime of --workers "
        "CPUs, or the cluster at --ray-address; pip install 'semcityloc[ray]')",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDRESS",
        help="join this Ray cluster: HOST:PORT, ray://HOST:PORT (pip install 'ray[client]') or auto "
        "(with --executor ray)",
    )


def executor_options(args: argparse.Namespace) -> dict:
    """The ``run_benchmark`` keywords of the parsed options (defaults for commands without them)."""
    executor = getattr(args, "executor", "local")
    address = getattr(args, "ray_address", None)
    if address and executor != "ray":
        raise BenchmarkError("--ray-address needs --executor ray")
    if address:
        check_address(address)  # a malformed address fails here, before anything loads
    return {"executor": executor, "ray_address": address}


def run_from_args(spec: RunSpec, out: str | Path, args: argparse.Namespace) -> BenchmarkOutcome:
    """``run_benchmark`` with the options every run command shares: ``--workers``, ``--overwrite``,
    ``--stop-after`` and the executor's."""
    return run_benchmark(
        spec,
        out,
        workers=args.workers,
        overwrite=args.overwrite,
        limit=args.stop_after,
        **executor_options(args),
    )
