"""Depth roughness of the benchmark's simulated depth next to noise: the margins of the localizer's checks.

The localizer drops a depth map as noise when its roughness (``localization.query.depth_roughness``:
median neighbour step over the interquartile range, at the search's 64 px width) exceeds
``DEPTH_MAX_ROUGHNESS``; then, block by block (``localization.query.block_measures``, at
``DEPTH_BLOCK_WIDTH``), it blanks the blocks that are rough by the same measure AND whose relative pixel
step is over ``DEPTH_MAX_BLOCK_STEP`` times that of the image's smooth blocks (noise over part of the map).

This prints, for the queries of a simulated benchmark (``--scenario``, the generated city unless
``--city``):

- the whole-map check: the roughness of each query's depth, and of uniform noise with NaN rows of the
  same size, as percentiles; how many of each the check would drop;
- the block check on good depth: the roughest block of all (roughness alone cannot tell a flat roof from
  noise), per query the worst block (the largest step ratio among the blocks rough enough to be judged on
  it; 0 when none is), as percentiles, and how many queries lost any block;
- the block check on partial noise: each query's depth with its left half, its top-left quarter or a dead
  band of columns (a quarter of the width) replaced by noise, either uniform 1..100 (the noise above) or
  uniform between the depth's own 5th and 95th percentiles (noise of a plausible range); for the blocks
  wholly inside the noise, the smallest roughness and step ratio and the share detected; the share of the
  good pixels blanked; how many maps were dropped whole.

    python benchmarks/depth_quality.py [--city generated] [--queries 60] [--scenario realistic]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.localization.query import (
    DEPTH_MAX_BLOCK_STEP,
    DEPTH_MAX_ROUGHNESS,
    block_measures,
    depth_problem,
    depth_roughness,
    usable_depth,
)

PCT = (0, 50, 95, 100)
NOISES = ("uniform 1..100", "uniform p5..p95 of the depth")


def noise_parts(shape: tuple[int, int]) -> dict[str, tuple[slice, slice]]:
    """The regions replaced by noise: left half, top-left quarter, a dead band of columns."""
    h, w = shape
    return {
        "left half": np.s_[:, : w // 2],
        "top-left quarter": np.s_[: h // 2, : w // 2],
        "dead band (columns 25-50 %)": np.s_[:, w // 4 : w // 2],
    }


def worst_block(depth: np.ndarray) -> tuple[float, float]:
    """(the largest block roughness, the largest step ratio among the blocks rough enough to be judged on
    it, 0 when none is)."""
    m = block_measures(depth)
    rough = m.roughness > DEPTH_MAX_ROUGHNESS
    return float(np.nanmax(m.roughness)), float(np.nanmax(m.step_ratio[rough])) if rough.any() else 0.0


def inside_blocks(depth: np.ndarray, region: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(roughness, step ratio, detected) of the blocks whose pixels all lie in ``region``."""
    m = block_measures(depth)
    shape = m.roughness.shape
    pixels = np.zeros(shape, np.int64)
    inside = np.zeros(shape, np.int64)
    rows, cols = np.broadcast_arrays(m.pixel_row[:, None], m.pixel_col[None, :])
    np.add.at(pixels, (rows.ravel(), cols.ravel()), 1)
    np.add.at(inside, (rows.ravel(), cols.ravel()), region.ravel().astype(np.int64))
    whole = (inside == pixels) & np.isfinite(m.roughness)
    return m.roughness[whole], m.step_ratio[whole], m.noisy[whole]


def partial_noise(depth: np.ndarray, rng: np.random.Generator, stats: dict) -> None:
    """Add to ``stats`` the block check's answers on ``depth`` with parts replaced by each noise."""
    valid = np.isfinite(depth) & (depth > 0)
    lo, hi = np.percentile(depth[valid], [5, 95])
    for kind in NOISES:
        s = stats.setdefault(kind, {"roughness": [], "step": [], "detected": [], "good": [0, 0], "whole": 0})
        for where in noise_parts(depth.shape).values():
            noisy = np.array(depth, dtype=np.float64)
            shape = noisy[where].shape
            noisy[where] = rng.uniform(1.0, 100.0, shape) if kind == NOISES[0] else rng.uniform(lo, hi, shape)
            region = np.zeros(depth.shape, bool)
            region[where] = True
            rough, step, detected = inside_blocks(noisy, region)
            s["roughness"] += rough.tolist()
            s["step"] += step.tolist()
            s["detected"] += detected.tolist()
            kept, _ = usable_depth(noisy)
            if kept is None:
                s["whole"] += 1
                continue
            good = valid & ~region
            s["good"][0] += int(np.count_nonzero(good & ~np.isfinite(kept)))
            s["good"][1] += int(np.count_nonzero(good))


def summary(stats: dict) -> dict:
    out = {}
    for kind, s in stats.items():
        out[kind] = {
            "noise_blocks": len(s["detected"]),
            "detected": f"{sum(s['detected'])}/{len(s['detected'])}",
            "roughness_min": round(float(np.nanmin(s["roughness"])), 3),
            "step_ratio_min_p50": np.round(np.nanpercentile(s["step"], (0, 50)), 2).tolist(),
            "good_pixels_blanked_percent": round(100.0 * s["good"][0] / max(s["good"][1], 1), 3),
            "maps_dropped_whole": s["whole"],
        }
    return out


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
    sim, noise, worst, rough_blocks, dropped_sim, dropped_noise, changed_sim = [], [], [], [], 0, 0, 0
    partial: dict = {}
    for i in range(args.queries):
        q = source.query(i)
        if q.depth is None:
            continue
        sim.append(depth_roughness(q.depth))
        dropped_sim += depth_problem(q.depth) is not None
        roughest, step = worst_block(q.depth)
        rough_blocks.append(roughest)
        worst.append(step)
        changed_sim += usable_depth(q.depth)[1] is not None
        fake = rng.uniform(1.0, 100.0, q.depth.shape)
        fake[rng.random(fake.shape[0]) < 0.3] = np.nan
        noise.append(depth_roughness(fake))
        dropped_noise += depth_problem(fake) is not None
        partial_noise(q.depth, rng, partial)
    print(
        json.dumps(
            {
                "city": args.city,
                "scenario": args.scenario,
                "queries_with_depth": len(sim),
                "threshold": DEPTH_MAX_ROUGHNESS,
                "simulated_roughness_p0_p50_p95_p100": np.round(np.nanpercentile(sim, PCT), 3).tolist(),
                "noise_roughness_p0_p50_p95_p100": np.round(np.nanpercentile(noise, PCT), 3).tolist(),
                "simulated_dropped": dropped_sim,
                "noise_dropped": dropped_noise,
                "block_step_threshold": DEPTH_MAX_BLOCK_STEP,
                "simulated_roughest_block": round(max(rough_blocks), 3),
                "simulated_worst_block_p0_p50_p95_p100": np.round(np.percentile(worst, PCT), 2).tolist(),
                "simulated_with_blocks_dropped": changed_sim,
                "partial_noise": summary(partial),
            }
        )
    )


if __name__ == "__main__":
    main()
