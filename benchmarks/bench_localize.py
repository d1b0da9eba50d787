"""Seconds per image of the localizer, the default search next to the first design, in one run.

Queries: the benchmark's realistic scenario (``semcityloc benchmark`` default) on Berlin, seed 0: GNSS/IMU
priors as flown (horizontal 2-15 m, height +-30 m, yaw +-8 deg, roll/pitch N(0, 1 deg)), structured
segmentation errors at the ``trained`` quality, realistic relative depth. Every preset in ``--presets``
localizes the same queries in the same process, one after the other, after one warm-up query each (numba
kernels load or compile outside the timing).

``default`` is the cascade (sweep over the prior's uncertainty volume, local grids with roll/pitch, one
particle filter over the best hypotheses); ``legacy`` is the first design (one fixed +-16 m / +-8 m /
+-9 deg grid, roll and pitch held). ``--naive-queries N`` also times the first design the naive way for
N queries: every grid hypothesis rendered into an (N, H, W) stack with ``Renderer.render`` and scored in
numpy afterwards, and the same number of refinement evaluations rendered with depth.

Prints one JSON line per query and preset and, last, one JSON summary line: per preset the mean
``coarse_s``, ``refine_s``, ``total_s``, ``coarse_hypotheses``, ``refine_evaluations`` and the recall at
2 m / 2 deg of its localized poses; ``ratio_total_s`` (each preset's total over the first preset's) and,
with ``--naive-queries``, ``naive_total_s`` and ``speedup_fused_vs_naive`` (first design).

    python benchmarks/bench_localize.py [--city PATH] [--queries 20] [--presets default,legacy]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numba
import numpy as np

from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.query import Query
from semcityloc.localization.scoring import depth_cost, semantic_score
from semcityloc.render import Renderer

BERLIN = Path(__file__).resolve().parents[1].parent / "shared/data/berlin_lod2_citygml2/3910_5817.gml"


def default_city() -> str:
    if BERLIN.exists():
        return str(BERLIN)
    print("# ../shared/data absent: using the generated city", file=sys.stderr)
    return "generated"


def naive(renderer, camera, config, prior, labels, depth, class_ids, refine_evaluations):
    """The first design the naive way: render every grid hypothesis into a mask stack, score in numpy."""
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
    parser.add_argument("--queries", type=int, default=20)
    parser.add_argument("--presets", default="default,legacy", help="comma-separated, the first is the base")
    parser.add_argument("--naive-queries", type=int, default=0, help="queries also run the naive way")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    city = args.city or default_city()
    spec = BenchmarkSpec(city=city, query=query_config("realistic", queries=args.queries, seed=args.seed))
    source = spec.open_source(spec.run_config())
    model = source.map_model
    queries = [q for q in (source.query(i) for i in range(args.queries)) if q.meta.get("accepted", True)]
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    renderer = Renderer(model, engine="numba")

    summary: dict = {
        "city": str(city),
        "scene_triangles": int(renderer.scene.num_triangles),
        "queries": len(queries),
        "threads": int(numba.get_num_threads()),
        "presets": {},
    }
    for name in presets:
        config = LocalizerConfig.preset(name)
        localizer = Localizer(model, config)  # its own scene: presets may differ in eaves
        q0 = queries[0]
        localizer.localize(q0.camera, q0.prior_pose_local, q0.labels, q0.depth)  # warm-up, not timed
        rows = []
        for q in queries:
            result = localizer.localize(q.camera, q.prior_pose_local, q.labels, q.depth)
            ok = False
            if result.localized:
                e_m = float(center_error_m(result.pose_local, q.true_pose_local))
                e_deg = float(rotation_error_deg(result.pose_local, q.true_pose_local))
                ok = e_m <= 2.0 and e_deg <= 2.0
            row = {
                "preset": name,
                "query": q.query_id,
                "view": q.meta.get("view"),
                "status": result.status,
                "within_2m_2deg": ok,
                **{k: result.timings.get(k, 0.0) for k in ("coarse_s", "refine_s", "total_s")},
                **result.counts,
            }
            rows.append(row)
            print(json.dumps(row))
        summary["presets"][name] = {
            **{k: float(np.mean([r[k] for r in rows])) for k in ("coarse_s", "refine_s", "total_s")},
            "coarse_hypotheses": float(np.mean([r["coarse_hypotheses"] for r in rows])),
            "refine_evaluations": float(np.mean([r["refine_evaluations"] for r in rows])),
            "recall_2m2deg": float(np.mean([r["within_2m_2deg"] for r in rows])),
        }
    base = summary["presets"][presets[0]]["total_s"]
    summary["ratio_total_s"] = {n: p["total_s"] / base for n, p in summary["presets"].items()}

    if args.naive_queries > 0:
        config = LocalizerConfig.preset("legacy")
        localizer = Localizer(model, config)  # its own scene: presets may differ in eaves
        class_ids = tuple(int(c) for c in np.flatnonzero(localizer.class_on))
        fused, slow = [], []
        for q in queries[: args.naive_queries]:
            result = localizer.localize(q.camera, q.prior_pose_local, q.labels, q.depth)
            nc, nr = naive(
                renderer,
                q.camera,
                config,
                q.prior_pose_local,
                q.labels,
                q.depth,
                class_ids,
                result.counts["refine_evaluations"],
            )
            fused.append(result.timings["total_s"])
            slow.append(nc + nr)
        summary["naive_total_s"] = float(np.mean(slow))
        summary["speedup_fused_vs_naive"] = float(np.mean(slow) / np.mean(fused))
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
