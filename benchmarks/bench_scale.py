"""City-scale localization from a tile store: per-image time and peak memory at 1x, 10x and 100x Berlin's
area, and the throughput of ``semcityloc tiles build``.

Usage: ``python benchmarks/bench_scale.py [--sizes 1,10,100] [--queries 6] [--preset fast] [--work DIR]``.

The city: generated districts of 10 x 10 blocks (about 1 km x 0.95 km, ~600 LoD2 buildings, 4 MB of
CityGML: one Berlin geoportal tile's area), one per tile on a 1.05 km grid, each with its own seed; the
tile at grid (0, 0) is the same in every size and the bigger cities surround it (10x: 5 x 2 tiles, 100x:
10 x 10). For each size the script builds a store of its tiles (``build_store``: timed, MB/s of CityGML
read) and then, in a fresh child process, simulates ``--queries`` realistic queries over tile (0, 0)
alone (the same queries at every size, moved into each store's frame) and localizes them with
``localization.tiled.TiledMethod`` (the tiles in reach of each query, LRU of parsed tiles, default
budget). Per-image time is the mean over the queries (the first query's tile loads included); peak RSS
is the child's ``ru_maxrss`` (Python, numba, the simulator of tile (0, 0) and the localizer; before
semcityloc is imported: ``baseline``). Tiles are generated once into ``--work`` (default a temporary
folder) and kept there when it is given.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GRIDS = {1: (1, 1), 10: (5, 2), 100: (10, 10)}
BLOCKS = (10, 10)
PITCH_M = 1050.0


def _grid(n: int) -> list[tuple[int, int]]:
    nx, ny = GRIDS[n]
    return [(i - nx // 2, j - ny // 2) for j in range(ny) for i in range(nx)]


def _tile_path(work: Path, i: int, j: int) -> Path:
    from semcityloc.citymodel.generator import generate_city  # the parent's job only
    from semcityloc.citymodel.generator_footprints import DEFAULT_ORIGIN  # the parent's job only

    path = work / "all_tiles" / f"tile_{i:+03d}_{j:+03d}.gml"
    if not path.exists():
        origin = (DEFAULT_ORIGIN[0] + i * PITCH_M, DEFAULT_ORIGIN[1] + j * PITCH_M)
        seed = 1000 + (i + 50) * 100 + (j + 50)
        made = generate_city(work / "gen" / path.stem, seed=seed, blocks=BLOCKS, lods=(2,), origin=origin)[2]
        path.parent.mkdir(parents=True, exist_ok=True)
        made.replace(path)
    return path


def _child(store_path: str, centre_tile: str, queries: int, preset: str) -> None:
    """Runs in a fresh process: localize the queries of the centre tile against the store, print JSON."""
    import resource

    import numpy as np

    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    from semcityloc.benchmark.queries import QueryConfig, QuerySimulator
    from semcityloc.citymodel.io import load_city_model
    from semcityloc.citymodel.tiles import TileStore
    from semcityloc.localization.config import LocalizerConfig
    from semcityloc.localization.tiled import TiledMethod

    store = TileStore.open(store_path)
    own = load_city_model(centre_tile, cache=False)
    sim = QuerySimulator(own, QueryConfig(queries=queries, seed=0, width=256, height=192))
    shift = store.origin - own.origin  # tile-local -> store-local: world = own.origin + local
    method = TiledMethod("semcityloc", store, LocalizerConfig.preset(preset))
    times, loaded, errors, statuses = [], [], [], []
    for k in range(queries):
        q = sim.query(k)
        q = dataclasses.replace(
            q,
            prior_pose_local=q.prior_pose_local.shift_world(shift),
            true_pose_local=q.true_pose_local.shift_world(shift),
        )
        t0 = time.perf_counter()
        result = method.localize(q)
        times.append(time.perf_counter() - t0)
        loaded.append(len(method.last_tiles))
        statuses.append(result.status)
        if result.pose_local is not None:
            errors.append(float(np.linalg.norm(result.pose_local.center - q.true_pose_local.center)))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(
        json.dumps(
            {
                "per_image_s": float(np.mean(times)),
                "per_image_s_after_first": float(np.mean(times[1:])) if len(times) > 1 else None,
                "tiles_loaded_mean": float(np.mean(loaded)),
                "localized": statuses.count("localized"),
                "median_err_m": float(np.median(errors)) if errors else None,
                "peak_rss_mb": peak,
                "baseline_rss_mb": baseline,
                "cache_mb": store.cache.held_bytes / 1e6,
            }
        )
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1,10,100")
    ap.add_argument("--queries", type=int, default=6)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--work", default=None, help="folder for the generated tiles and stores (kept)")
    ap.add_argument("--child", nargs=2, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _child(args.child[0], args.child[1], args.queries, args.preset)
        return
    from semcityloc.citymodel.tiles import build_store  # the parent's job only

    sizes = [int(s) for s in args.sizes.split(",")]
    tmp = None if args.work else tempfile.TemporaryDirectory()
    work = Path(args.work or tmp.name)
    rows = []
    for n in sizes:
        t0 = time.perf_counter()
        folder = work / f"tiles_{n}"
        folder.mkdir(parents=True, exist_ok=True)
        for i, j in _grid(n):
            link = folder / _tile_path(work, i, j).name
            if not link.exists():
                link.symlink_to(_tile_path(work, i, j))
        gen_s = time.perf_counter() - t0
        report = build_store(folder, work / f"store_{n}")
        centre = str(_tile_path(work, 0, 0))
        out = subprocess.run(
            [sys.executable, __file__, "--child", str(report.store.root), centre]
            + ["--queries", str(args.queries), "--preset", args.preset],
            check=True,
            capture_output=True,
            text=True,
        )
        child = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append((n, report, gen_s, child))
        print(f"{n}x done: {json.dumps(child)}", file=sys.stderr, flush=True)

    print(f"{args.queries} queries over the centre tile, preset {args.preset}, 256x192, 2 cores")
    head = (
        f"{'size':>5}{'tiles':>6}{'buildings':>10}{'MB':>8}{'build s':>9}{'MB/s':>7}{'tiles/img':>10}"
        f"{'s/image':>9}{'vs 1x':>7}{'peak RSS MB':>12}{'localized':>10}"
    )
    print(head)
    first = rows[0][3]["per_image_s"]
    for n, report, _gen_s, c in rows:
        print(
            f"{n:>4}x{report.tiles:>6}{report.buildings:>10}{report.input_bytes / 1e6:>8.1f}"
            f"{report.seconds:>9.1f}"
            f"{report.mb_per_s:>7.2f}{c['tiles_loaded_mean']:>10.1f}{c['per_image_s']:>9.2f}"
            f"{c['per_image_s'] / first:>7.2f}{c['peak_rss_mb']:>12.0f}{c['localized']:>7}/{args.queries}"
        )
    print(f"RSS of the child before semcityloc is imported: {rows[0][3]['baseline_rss_mb']:.0f} MB")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
