"""Depth roughness of the benchmark's simulated depth next to noise: the margin of the localizer's check.

The localizer drops a depth map as noise when its roughness (``localization.query.depth_roughness``:
median neighbour step over the interquartile range, at the search's 64 px width) exceeds
``DEPTH_MAX_ROUGHNESS``. This prints, for the queries of a simulated benchmark (``--scenario``, the
generated city unless ``--city``), the roughness of each query's depth, and of uniform noise with NaN
rows of the same size, as percentiles; and how many of each the check would drop.

    python benchmarks/depth_quality.py [--city generated] [--queries 60] [--scenario realistic]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.localization.query import DEPTH_MAX_ROUGHNESS, depth_problem, depth_roughness


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--city", default="generated")
    parser.add_argument("--queries", type=int, default=60)
    parser.add_argument("--scenario", default="realistic")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    spec = BenchmarkSpec(
        city=args.city, query=query_config(args.scenario, queries=args.queries, seed=args.seed)
    )
    source = spec.open_source(spec.run_config())
    rng = np.random.default_rng(args.seed)
    sim, noise, dropped_sim, dropped_noise = [], [], 0, 0
    for i in range(args.queries):
        q = source.query(i)
        if q.depth is None:
            continue
        sim.append(depth_roughness(q.depth))
        dropped_sim += depth_problem(q.depth) is not None
        fake = rng.uniform(1.0, 100.0, q.depth.shape)
        fake[rng.random(fake.shape[0]) < 0.3] = np.nan
        noise.append(depth_roughness(fake))
        dropped_noise += depth_problem(fake) is not None
    pct = (0, 50, 95, 100)
    print(
        json.dumps(
            {
                "city": args.city,
                "scenario": args.scenario,
                "queries_with_depth": len(sim),
                "threshold": DEPTH_MAX_ROUGHNESS,
                "simulated_roughness_p0_p50_p95_p100": np.round(np.nanpercentile(sim, pct), 3).tolist(),
                "noise_roughness_p0_p50_p95_p100": np.round(np.nanpercentile(noise, pct), 3).tolist(),
                "simulated_dropped": dropped_sim,
                "noise_dropped": dropped_noise,
            }
        )
    )


if __name__ == "__main__":
    main()
