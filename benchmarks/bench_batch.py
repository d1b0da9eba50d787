"""Images per second of a flight's batch: serial, the local process pool and Ray, on the same queries.

Usage: ``python benchmarks/bench_batch.py [--queries 8] [--preset fast] [--size 256x192]``.

Runs the simulated benchmark of the generated city (``semcityloc benchmark --city generated``) through the
one run loop (``benchmark.run.run_queries``) with: serial (``--executor local --workers 1``), the local
process pool at 2 workers, and Ray at 1 and 2 workers, each into a fresh output folder, after the numba
kernels are compiled. A run's time is its whole ``run_benchmark`` call (the workers' start-up, shipping the
models, localizing, writing rows); Ray's own start-up (``ray.init`` of a local runtime with 2 CPUs and
its first task) is measured once, separately, and the Ray runs use that runtime. Prints a table with
images/s and the ratio to serial, and whether every run's rows equal the serial rows (timing columns
aside). Needs the ``[ray]`` extra for the Ray rows (skipped with the install hint otherwise).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from semcityloc.benchmark.queries import QueryConfig
from semcityloc.benchmark.results import TIMING_COLUMNS
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.benchmark.warmup import ensure_compiled, kernel_groups


def _untimed(rows: list[dict[str, str]]) -> dict[str, dict[str, str]]:
    return {r["query_id"]: {k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=8)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--size", default="256x192", help="query resolution WxH")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    spec = BenchmarkSpec(
        "generated", QueryConfig(queries=args.queries, seed=0, width=width, height=height), preset=args.preset
    )
    ensure_compiled(kernel_groups(spec.method), None)
    runs = [("serial (local, 1 worker)", "local", 1), ("local, 2 workers", "local", 2)]
    try:
        import ray  # optional extra [ray]: the Ray rows need it

        t0 = time.perf_counter()
        ray.init(  # a runtime of its own, as the CLI starts one: never a stale or running cluster's
            address="local",
            num_cpus=2,
            include_dashboard=False,
            log_to_driver=False,
            object_store_memory=512 * 1024**2,
        )
        ray.get(ray.remote(lambda: 0).remote())
        ray_startup = time.perf_counter() - t0
        runs += [("ray, 1 worker", "ray", 1), ("ray, 2 workers", "ray", 2)]
    except ImportError:
        ray, ray_startup = None, None
        print("Ray rows skipped: pip install 'semcityloc[ray]'")

    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, executor, workers) in enumerate(runs):
            t0 = time.perf_counter()
            outcome = run_benchmark(
                spec, Path(tmp) / f"run{i}", workers=workers, progress=False, executor=executor
            )
            seconds = time.perf_counter() - t0
            results.append((label, seconds, _untimed(outcome.rows)))
    if ray is not None:
        ray.shutdown()

    serial_s, serial_rows = results[0][1], results[0][2]
    print(f"{args.queries} generated-city queries, preset {args.preset}, {width}x{height}, 2 cores")
    print(f"{'run':<26}{'seconds':>9}{'images/s':>10}{'vs serial':>11}  rows = serial")
    for label, seconds, rows in results:
        same = "yes" if rows == serial_rows else "NO"
        print(f"{label:<26}{seconds:9.2f}{args.queries / seconds:10.3f}{serial_s / seconds:10.2f}x  {same}")
    if ray_startup is not None:
        print(f"Ray start-up (ray.init, 2 CPUs, first task): {ray_startup:.2f} s, not in the Ray rows above")


if __name__ == "__main__":
    main()
