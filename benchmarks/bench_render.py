"""Views per second of the renderers: numba rasteriser vs the Embree reference, scaling with city size.

City: ``--city PATH`` (any format ``load_city_model`` reads). Default: the Berlin LoD2 district from
``../shared/data`` when it and the CityGML reader are there, else the generated default district
(``citymodel.generator``: 4 x 3 blocks, LoD2); the ``city`` key of every line says which.

Views: aerial, camera centres uniform over the model's footprint at 40-150 m above the model's LOWEST
point (flight height above ground, so a 40 m view can be lower than the tallest roofs, as a drone's can),
roll ~ N(0, 2 deg), yaw uniform; nadir = pitch 0-10 deg, oblique = pitch 30-60 deg. Camera: square
pixels, principal point at the centre, ``--hfov`` (default 60 deg).

Prints one JSON line per case, each with ``case``, ``engine``, ``width``, ``height``, ``depth``,
``triangles`` (drawn scene triangles, terrain included), ``views_per_s``:

- ``nadir`` / ``oblique`` for (a) 64 x 48 labels and (b) 128 x 96 labels + depth, numba and Embree in the
  same run, plus a ``ratio`` line (numba / embree);
- ``scale10_nadir`` / ``scale10_oblique``: the model tiled 5 x 2 side by side (10x the triangles), numba,
  with ``vs_1x`` = its views/s over the 1x model's (flat time = 1.0); views anywhere over the big city,
  which see more city around them than views near the 1x model's edge;
- ``scale10_gap_nadir`` / ``..._oblique``: the 5 x 2 copies 3 km apart and the 1x run's very views moved
  onto random copies: the same content in view with 10x the triangles, so ``vs_1x`` is the pure cost of
  size (culling).

numba is compiled (or loaded from its cache) before anything is timed. Times are wall-clock, best of
``--repeats`` runs of the whole batch, on all numba threads (``NUMBA_NUM_THREADS``); runs that are
compared (1x / 10x, numba / Embree) take turns, so that load from other processes on a
shared machine hits them alike and their ratios stay meaningful even when absolute rates do not.

    python benchmarks/bench_render.py [--city PATH] [--views 2000] [--embree-views 200] [--quick]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import time
from pathlib import Path

import numba
import numpy as np

from semcityloc.citymodel.generator import footprints_to_model, tile_model
from semcityloc.citymodel.generator_footprints import generate_footprints
from semcityloc.citymodel.model import CityModel
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.render import Renderer
from semcityloc.render.embree_ref import embree_available

BERLIN = Path(__file__).resolve().parents[1].parent / "shared/data/berlin_lod2_citygml2/3910_5817.gml"
PITCH = {"nadir": (0.0, 10.0), "oblique": (30.0, 60.0)}
SIZES = [(64, 48, False), (128, 96, True)]
GAP_M = 3000.0  # far enough apart that a 40-150 m high view of one copy sees no other


def load_city(path: str | None) -> tuple[CityModel, str]:
    if path:
        from semcityloc.citymodel.io import load_city_model

        return load_city_model(path, cache=False), str(path)
    if BERLIN.is_file() and importlib.util.find_spec("semcityloc.citymodel.citygml") is not None:
        from semcityloc.citymodel.citygml import read_citygml

        return read_citygml(BERLIN), "berlin_lod2_citygml2/3910_5817.gml"
    return footprints_to_model(
        generate_footprints(), lod=2
    ), "generated district (seed 0, 4 x 3 blocks, LoD2)"


def aerial_poses(model: CityModel, n: int, pitch: tuple[float, float], seed: int) -> Pose:
    rng = np.random.default_rng(seed)
    lo, hi = model.bounds_local
    xyz = np.column_stack(
        [rng.uniform(lo[0], hi[0], n), rng.uniform(lo[1], hi[1], n), lo[2] + rng.uniform(40.0, 150.0, n)]
    )
    return Pose.from_xyz_rpy(xyz, rng.normal(0.0, 2.0, n), rng.uniform(*pitch, n), rng.uniform(-180, 180, n))


def interleaved_rates(runs: list, repeats: int) -> list[float]:
    """Views/s of each ``(renderer, camera, poses, depth)`` run: the best of ``repeats`` timings, the runs
    taking turns so that a change in machine load hits all of them alike."""
    for renderer, cam, poses, depth in runs:
        renderer.render(cam, poses[:4], depth=depth)  # compile / warm up
    best = [np.inf] * len(runs)
    for _ in range(repeats):
        for k, (renderer, cam, poses, depth) in enumerate(runs):
            best[k] = min(
                best[k], _timed(lambda r=renderer, c=cam, p=poses, d=depth: r.render(c, p, depth=d))
            )
    return [len(run[2]) / b for run, b in zip(runs, best, strict=True)]


def emit(**row) -> None:
    print(json.dumps(row), flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", help="city model file (default: Berlin from ../shared/data, else generated)")
    ap.add_argument("--views", type=int, default=2000, help="views per numba case")
    ap.add_argument("--embree-views", type=int, default=200, help="views per Embree case")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--hfov", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true", help="few views (a smoke run, numbers are noisy)")
    args = ap.parse_args(argv)
    if args.quick:
        args.views, args.embree_views, args.repeats = 200, 20, 2

    model, city = load_city(args.city)
    common = {"city": city, "threads": numba.get_num_threads(), "hfov_deg": args.hfov}
    numba_r = Renderer(model, engine="numba")
    tri = numba_r.scene.num_triangles
    embree_r = Renderer(model, engine="embree") if embree_available() else None

    # 10x: (a) copies side by side, views anywhere over them (they also see more city around them than
    # views near the edge of the 1x model do); (b) copies GAP_M apart and the very views of the 1x run
    # moved onto random copies: the same content in view, 10x the triangles: the pure cost of size.
    ext = model.extent_m
    big_r = Renderer(tile_model(model, 5, 2), engine="numba")
    gap_r = Renderer(tile_model(model, 5, 2, gap_m=GAP_M), engine="numba")
    step = np.array([ext[0] + GAP_M, ext[1] + GAP_M, 0.0])
    for w, h, depth in SIZES:
        cam = Camera.from_fov(w, h, args.hfov)
        for case, pitch in PITCH.items():
            poses = aerial_poses(model, args.views, pitch, seed=1)
            big_poses = aerial_poses(big_r.model, args.views, pitch, seed=2)
            k = np.random.default_rng(4).integers(0, 10, args.views)
            shift = np.stack([k % 5, k // 5, np.zeros_like(k)], 1) * step
            gap_poses = Pose.from_rotation_center(poses.R_world_from_cam, poses.center + shift)
            runs = [
                (numba_r, cam, poses, depth),
                (big_r, cam, big_poses, depth),
                (gap_r, cam, gap_poses, depth),
            ]
            rate, big_rate, gap_rate = interleaved_rates(runs, args.repeats)
            row = {"width": w, "height": h, "depth": depth}
            emit(
                case=case,
                engine="numba",
                **row,
                triangles=tri,
                views_per_s=round(rate, 1),
                pitch_deg=pitch,
                **common,
            )
            if embree_r is not None:
                sub = poses[: args.embree_views]
                # The numba rate on the same views, timed in turns with Embree's.
                e_rate, n_rate = interleaved_rates(
                    [(embree_r, cam, sub, depth), (numba_r, cam, sub, depth)], max(1, args.repeats // 2)
                )
                emit(
                    case=case,
                    engine="embree",
                    **row,
                    triangles=tri,
                    views_per_s=round(e_rate, 1),
                    pitch_deg=pitch,
                    **common,
                )
                emit(
                    case=f"{case}_ratio",
                    engine="numba/embree",
                    **row,
                    triangles=tri,
                    views_per_s=round(n_rate, 1),
                    ratio=round(n_rate / e_rate, 2),
                    **common,
                )
            for name, r, rr in (("scale10", big_r, big_rate), ("scale10_gap", gap_r, gap_rate)):
                emit(
                    case=f"{name}_{case}",
                    engine="numba",
                    **row,
                    triangles=r.scene.num_triangles,
                    views_per_s=round(rr, 1),
                    vs_1x=round(rr / rate, 3),
                    **common,
                )


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
