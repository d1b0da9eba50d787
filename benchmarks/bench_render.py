"""Views per second of the renderers: numba rasteriser vs the Embree reference, scaling, rotation reuse.

City: ``--city PATH`` (any format ``load_city_model`` reads). Default: the Berlin LoD2 district from
``../shared/data`` when it and the CityGML reader are there, else a generated 20 x 20 houses city
(``render.synthetic.synthetic_city``); the ``city`` key of every line says which.

Views: aerial, camera centres uniform over the model's footprint at 40-150 m above the model's LOWEST
point (flight height above ground, so a 40 m view can be lower than the tallest roofs, as a drone's can),
roll ~ N(0, 2 deg), yaw uniform; nadir = pitch 0-10 deg, oblique = pitch 30-60 deg. Camera: square pixels, principal point at the centre, ``--hfov`` (default 60 deg).

Prints one JSON line per case, each with ``case``, ``engine``, ``width``, ``height``, ``depth``,
``triangles`` (drawn scene triangles, terrain included), ``views_per_s``:

- ``nadir`` / ``oblique`` for (a) 64 x 48 labels and (b) 128 x 96 labels + depth, numba and Embree in the
  same run, plus a ``ratio`` line (numba / embree);
- ``scale10_nadir`` / ``scale10_oblique``: the model tiled 5 x 2 side by side (10x the triangles), numba,
  with ``vs_1x`` = its views/s over the 1x model's (flat time = 1.0);
- ``rotation_reuse``: ``render_yaw_fan`` vs direct rendering for ``--yaws`` yaws per centre, with
  ``speedup`` and ``agreement`` (fraction of equal label pixels) per pitch.

numba is compiled (or loaded from its cache) before anything is timed. Times are wall-clock, best of
``--repeats`` runs of the whole batch, on all numba threads (``NUMBA_NUM_THREADS``).

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

from semcityloc.citymodel.model import CityModel
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.render import Renderer, render_yaw_fan
from semcityloc.render.embree_ref import embree_available
from semcityloc.render.synthetic import synthetic_city, tile_model

BERLIN = Path(__file__).resolve().parents[1].parent / "shared/data/berlin_lod2_citygml2/3910_5817.gml"
PITCH = {"nadir": (0.0, 10.0), "oblique": (30.0, 60.0)}
SIZES = [(64, 48, False), (128, 96, True)]


def load_city(path: str | None) -> tuple[CityModel, str]:
    if path:
        from semcityloc.citymodel.io import load_city_model

        return load_city_model(path, cache=False), str(path)
    if BERLIN.is_file() and importlib.util.find_spec("semcityloc.citymodel.citygml") is not None:
        from semcityloc.citymodel.citygml import read_citygml

        return read_citygml(BERLIN), "berlin_lod2_citygml2/3910_5817.gml"
    return synthetic_city(n=20, seed=0), "synthetic_city(n=20)"


def aerial_poses(model: CityModel, n: int, pitch: tuple[float, float], seed: int) -> Pose:
    rng = np.random.default_rng(seed)
    lo, hi = model.bounds_local
    xyz = np.column_stack(
        [rng.uniform(lo[0], hi[0], n), rng.uniform(lo[1], hi[1], n), lo[2] + rng.uniform(40.0, 150.0, n)]
    )
    return Pose.from_xyz_rpy(xyz, rng.normal(0.0, 2.0, n), rng.uniform(*pitch, n), rng.uniform(-180, 180, n))


def views_per_s(renderer: Renderer, cam: Camera, poses: Pose, depth: bool, repeats: int) -> float:
    renderer.render(cam, poses[:4], depth=depth)  # compile / warm up
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        renderer.render(cam, poses, depth=depth)
        best = min(best, time.perf_counter() - t0)
    return len(poses) / best


def emit(**row) -> None:
    print(json.dumps(row), flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", help="city model file (default: Berlin from ../shared/data, else generated)")
    ap.add_argument("--views", type=int, default=2000, help="views per numba case")
    ap.add_argument("--embree-views", type=int, default=200, help="views per Embree case")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--hfov", type=float, default=60.0)
    ap.add_argument("--yaws", type=int, nargs="+", default=[9, 36, 72], help="yaws per centre (rotation reuse)")
    ap.add_argument("--centres", type=int, default=20, help="camera centres per rotation-reuse case")
    ap.add_argument("--quick", action="store_true", help="few views (a smoke run, numbers are noisy)")
    args = ap.parse_args(argv)
    if args.quick:
        args.views, args.embree_views, args.repeats, args.centres = 200, 20, 2, 3

    model, city = load_city(args.city)
    common = {"city": city, "threads": numba.get_num_threads(), "hfov_deg": args.hfov}
    numba_r = Renderer(model, engine="numba")
    tri = numba_r.scene.num_triangles
    embree_r = Renderer(model, engine="embree") if embree_available() else None

    base_rate = {}
    for w, h, depth in SIZES:
        cam = Camera.from_fov(w, h, args.hfov)
        for case, pitch in PITCH.items():
            poses = aerial_poses(model, args.views, pitch, seed=1)
            rate = views_per_s(numba_r, cam, poses, depth, args.repeats)
            base_rate[(w, case)] = rate
            emit(case=case, engine="numba", width=w, height=h, depth=depth, triangles=tri,
                 views_per_s=round(rate, 1), pitch_deg=pitch, **common)
            if embree_r is not None:
                e_rate = views_per_s(embree_r, cam, poses[: args.embree_views], depth, max(1, args.repeats // 2))
                emit(case=case, engine="embree", width=w, height=h, depth=depth, triangles=tri,
                     views_per_s=round(e_rate, 1), pitch_deg=pitch, **common)
                emit(case=f"{case}_ratio", engine="numba/embree", width=w, height=h, depth=depth, triangles=tri,
                     views_per_s=round(rate, 1), ratio=round(rate / e_rate, 2), **common)

    big = tile_model(model, 5, 2)
    big_r = Renderer(big, engine="numba")
    for w, h, depth in SIZES:
        cam = Camera.from_fov(w, h, args.hfov)
        for case, pitch in PITCH.items():
            poses = aerial_poses(big, args.views, pitch, seed=2)
            rate = views_per_s(big_r, cam, poses, depth, args.repeats)
            emit(case=f"scale10_{case}", engine="numba", width=w, height=h, depth=depth,
                 triangles=big_r.scene.num_triangles, views_per_s=round(rate, 1),
                 vs_1x=round(rate / base_rate[(w, case)], 3), **common)

    cam = Camera.from_fov(64, 48, args.hfov)
    rng = np.random.default_rng(3)
    lo, hi = model.bounds_local
    for n_yaw in args.yaws:
        yaws = np.arange(n_yaw) * (360.0 / n_yaw)
        for pitch in (0.0, 30.0, 45.0, 60.0):
            centres = [np.array([rng.uniform(lo[0], hi[0]), rng.uniform(lo[1], hi[1]), lo[2] + rng.uniform(40, 150)])
                       for _ in range(args.centres)]
            bases = [Pose.from_xyz_rpy(c, 0.0, pitch, rng.uniform(-180, 180)) for c in centres]
            render_yaw_fan(numba_r, cam, bases[0], yaws)  # compile
            t_direct = t_fan = 0.0
            agree = []
            for base in bases:
                targets = base.rotate_world_z(yaws)
                t0 = time.perf_counter()
                direct = numba_r.render(cam, targets)
                t_direct += time.perf_counter() - t0
                t0 = time.perf_counter()
                fan = render_yaw_fan(numba_r, cam, base, yaws)
                t_fan += time.perf_counter() - t0
                agree.append(float((fan.labels == direct.labels).mean()))
            emit(case="rotation_reuse", engine="numba", width=64, height=48, depth=False, triangles=tri,
                 views_per_s=round(n_yaw * len(bases) / t_fan, 1), yaws_per_centre=n_yaw, pitch_deg=pitch,
                 speedup=round(t_direct / t_fan, 2), agreement=round(float(np.mean(agree)), 4),
                 agreement_min=round(float(np.min(agree)), 4), **common)


if __name__ == "__main__":
    main()
