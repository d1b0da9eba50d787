"""Seconds per image of the localizer (coarse and refinement) next to the naive way, in one run.

Fused path: ``Localizer.localize`` (one wide render per camera centre + lookup tables for the yaws, and
render-and-score kernels that never store masks). Naive path: the same hypotheses rendered one by one
into an (N, H, W) stack with ``Renderer.render`` and scored in numpy afterwards (coarse grid at the coarse
resolution; the same number of refinement evaluations at the fine resolution with depth).

Queries: aerial views of the city (half nadir, half oblique 30-50 deg, 60-110 m above the lowest
point), masks and depth rendered at the true pose (depth under a random affine map), priors 10 m and 5
deg off. Prints one JSON line per query and, last, one JSON summary line with ``coarse_s``, ``refine_s``,
``total_s`` (mean seconds per image), ``naive_total_s``, ``speedup``, ``coarse_hypotheses``,
``refine_evaluations``.

    python benchmarks/bench_localize.py --city PATH [--queries N] [--preset default]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from semcityloc.citymodel.io import load_city_model
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.query import Query
from semcityloc.localization.scoring import depth_cost, semantic_score
from semcityloc.render import Renderer

BERLIN = Path(__file__).resolve().parents[1].parent / "shared/data/berlin_lod2_citygml2/3910_5817.gml"


def default_city() -> Path:
    if BERLIN.exists():
        return BERLIN
    from semcityloc.citymodel.generator import default_city_path

    print("# ../shared/data absent: using the generated city", file=sys.stderr)
    return default_city_path(lod=2)


def make_queries(model, renderer, camera, n, rng):
    lo, hi = model.bounds_local
    queries = []
    while len(queries) < n:
        xy = rng.uniform(lo[:2] + 30, hi[:2] - 30)
        oblique = len(queries) % 2 == 1
        pitch = rng.uniform(30, 50) if oblique else rng.uniform(0, 3)
        true = Pose.from_xyz_rpy(
            [xy[0], xy[1], lo[2] + rng.uniform(60, 110)], rng.uniform(-2, 2), pitch, rng.uniform(0, 360)
        )
        view = renderer.render(camera, true, depth=True)
        if np.isin(view.labels[0], [2, 3]).mean() < 0.15:
            continue
        direction = rng.normal(size=3)
        direction *= 10.0 / np.linalg.norm(direction)
        x, y, z, roll, p, yaw = true.to_xyz_rpy()
        prior = Pose.from_xyz_rpy([x, y, z] + direction, roll + 0.5, p - 0.5, yaw + rng.choice([-5.0, 5.0]))
        depth = rng.uniform(0.5, 2.0) * view.depth[0] + rng.uniform(0, 20)
        queries.append((true, prior, view.labels[0], depth, "oblique" if oblique else "nadir"))
    return queries


def naive(renderer, camera, config, prior, labels, depth, class_ids, refine_evaluations):
    """Render every hypothesis into a mask stack, then score it with numpy."""
    c = config.coarse
    coarse_cam = camera.scaled(c.width, round(c.width * camera.height / camera.width))
    fine_cam = coarse_cam.scale(config.refine.scale)
    query = Query.from_arrays(labels, depth, has_openings=False)
    q_coarse = query.at(coarse_cam.width, coarse_cam.height)[0].reshape(coarse_cam.height, coarse_cam.width)
    q_fine, d_fine = query.at(fine_cam.width, fine_cam.height)
    q_fine = q_fine.reshape(fine_cam.height, fine_cam.width)
    d_fine = d_fine.reshape(fine_cam.height, fine_cam.width)
    x0, y0, z0, roll, pitch, yaw0 = prior.to_xyz_rpy()
    axes = [
        x0 + np.linspace(-c.range_xy_m / 2, c.range_xy_m / 2, c.n_xy),
        y0 + np.linspace(-c.range_xy_m / 2, c.range_xy_m / 2, c.n_xy),
        z0 + np.linspace(-c.range_z_m / 2, c.range_z_m / 2, c.n_z),
        yaw0 + np.linspace(-c.range_yaw_deg / 2, c.range_yaw_deg / 2, c.n_yaw),
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 4)
    t0 = time.perf_counter()
    scores = np.empty(len(grid))
    for start in range(0, len(grid), 2048):
        g = grid[start : start + 2048]
        poses = Pose.from_xyz_rpy(g[:, :3], roll, pitch, g[:, 3])
        masks = renderer.render(coarse_cam, poses).labels
        scores[start : start + len(g)] = [semantic_score(m, q_coarse, class_ids) for m in masks]
    best = grid[int(np.argmax(scores))]
    t1 = time.perf_counter()
    rng = np.random.default_rng(0)
    states = np.tile([best[0], best[1], best[2], roll, pitch, best[3]], (refine_evaluations, 1))
    states += rng.normal(size=states.shape) * [1, 1, 1, 0.3, 0.3, 1]
    for start in range(0, len(states), 256):
        s = states[start : start + 256]
        out = renderer.render(fine_cam, Pose.from_xyz_rpy(s[:, :3], s[:, 3], s[:, 4], s[:, 5]), depth=True)
        for m, d in zip(out.labels, out.depth, strict=True):
            semantic_score(m, q_fine, class_ids) - depth_cost(d_fine, d)
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--city", default=None)
    parser.add_argument("--queries", type=int, default=6)
    parser.add_argument("--preset", default="default")
    parser.add_argument("--naive-queries", type=int, default=2, help="queries also run the naive way")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    city = Path(args.city) if args.city else default_city()
    model = load_city_model(city)
    config = LocalizerConfig.preset(args.preset)
    camera = Camera.from_fov(512, 384, 70.0)
    renderer = Renderer(model, engine="numba")
    localizer = Localizer(model, config, scene=renderer.scene)
    rng = np.random.default_rng(args.seed)
    queries = make_queries(model, renderer, camera, args.queries, rng)

    # Warm-up: compile every kernel once (numba caches, but the first call in a process still loads it).
    true, prior, labels, depth, _ = queries[0]
    localizer.localize(camera, prior, labels, depth)

    rows = []
    for i, (true, prior, labels, depth, kind) in enumerate(queries):
        result = localizer.localize(camera, prior, labels, depth)
        err_m = float(center_error_m(result.pose_local, true)) if result.localized else float("inf")
        err_deg = float(rotation_error_deg(result.pose_local, true)) if result.localized else float("inf")
        row = {
            "query": i,
            "view": kind,
            "status": result.status,
            "coarse_s": result.timings["coarse_s"],
            "refine_s": result.timings["refine_s"],
            "total_s": result.timings["total_s"],
            "error_m": round(err_m, 3),
            "error_deg": round(err_deg, 3),
        }
        if i < args.naive_queries:
            class_ids = tuple(int(c) for c in np.flatnonzero(localizer.class_on))
            nc, nr = naive(
                renderer, camera, config, prior, labels, depth, class_ids, result.counts["refine_evaluations"]
            )
            row.update(naive_coarse_s=nc, naive_refine_s=nr, naive_total_s=nc + nr)
        rows.append(row)
        print(json.dumps(row))

    mean = {k: float(np.mean([r[k] for r in rows])) for k in ("coarse_s", "refine_s", "total_s")}
    with_naive = [r for r in rows if "naive_total_s" in r]
    naive_total = float(np.mean([r["naive_total_s"] for r in with_naive]))
    fused_same = float(np.mean([r["total_s"] for r in with_naive]))
    summary = {
        "city": str(city),
        "triangles": int(model.num_triangles),
        "scene_triangles": int(localizer.scene.num_triangles),
        "preset": args.preset,
        "queries": len(rows),
        **mean,
        "naive_total_s": naive_total,
        "speedup": naive_total / fused_same,
        "coarse_hypotheses": int(config.coarse.hypotheses),
        "refine_evaluations": int(config.refine.particles * config.refine.iterations),
        "median_error_m": float(np.median([r["error_m"] for r in rows])),
        "median_error_deg": float(np.median([r["error_deg"] for r in rows])),
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
