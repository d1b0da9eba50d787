"""How far along the tilt-versus-shift ridge does a query's own score tell poses apart, per resolution?

From the air, turning the camera about a point on its optical axis at the scene's depth moves the image
almost like not moving at all: a tilt traded against a sideways shift (``refine.pivot_jacobian``). This
scores a grid of such turns (roll and pitch about the pivot, ``--span-deg`` each way, ``--steps`` per
axis) around the TRUE pose of one real-data query, at several image widths, with the refinement's
semantic score (mean per-class IoU against the query mask; no depth, no prior term), and prints per
width the truth's score and, per ring of camera-centre distance from the truth, the highest and lowest
score there. Where the highest score within a ring matches the truth's, the image cannot place the camera
closer than that ring: what decides there is the prior's roll/pitch and the masks' noise.

    python benchmarks/ridge_profile.py [--dataset ../shared/data] [--perception oracle]
        [--label-seed 0] [--query 0] [--widths 128,256,640] [--span-deg 1.0] [--steps 11]

A diagnosis, not a tuning tool (``docs/benchmark.md``, "Why the thermal image stays near 1-2 m").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from semcityloc.benchmark.dataset_source import DatasetSpec
from semcityloc.localization.localize import Localizer
from semcityloc.localization.query import Query
from semcityloc.localization.refine import evaluate, pivot_jacobian
from semcityloc.render import Renderer

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
RINGS_M = (0.5, 1.0, 1.5, 2.5, 4.0)


def ridge_states(truth: np.ndarray, pivot_m: float, span_deg: float, steps: int) -> np.ndarray:
    """(steps^2, 6) states: roll and pitch offsets on a grid, each turning the camera about the pivot."""
    g = np.linspace(-span_deg, span_deg, steps)
    roll, pitch = np.meshgrid(g, g, indexing="ij")
    offsets = np.zeros((roll.size, 6))
    offsets[:, 3], offsets[:, 4] = roll.ravel(), pitch.ravel()
    return truth + offsets @ pivot_jacobian(truth, pivot_m).T


def profile(scores: np.ndarray, distance_m: np.ndarray, truth_score: float) -> list[str]:
    """One line per ring: the best and lowest score of the states within it (truth excluded)."""
    lines = []
    for ring in RINGS_M:
        inside = (distance_m > 1e-9) & (distance_m <= ring)
        if not inside.any():
            continue
        best, low = scores[inside].max(), scores[inside].min()
        lines.append(
            f"  within {ring:.1f} m: best {best:.5f} ({best - truth_score:+.5f}), lowest {low:.5f} "
            f"({low - truth_score:+.5f}), {int(inside.sum())} poses"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", type=Path, default=SHARED)
    ap.add_argument("--perception", default="oracle", help="oracle or oracle-degraded")
    ap.add_argument("--label-seed", type=int, default=0, help="noise seed of the degraded labels")
    ap.add_argument("--query", type=int, default=0, help="query index (0: the thermal image)")
    ap.add_argument("--widths", default="128,256,640", help="image widths to score at, comma-separated")
    ap.add_argument("--span-deg", type=float, default=1.0, help="largest roll / pitch turn about the pivot")
    ap.add_argument("--steps", type=int, default=11, help="grid points per axis (odd: the truth is one)")
    args = ap.parse_args(argv)
    if not args.dataset.is_dir():
        print(f"{args.dataset}: no such data set folder", file=sys.stderr)
        return 2
    if args.steps < 3 or args.steps % 2 == 0:
        print("--steps must be odd and at least 3 (the truth is the grid's centre)", file=sys.stderr)
        return 2

    spec = DatasetSpec(dataset=str(args.dataset), perception=args.perception, seed=args.label_seed)
    source = spec.open_source(spec.run_config())
    loc = Localizer(source.map_model)
    q = source.query(args.query)
    truth_pose = q.true_pose_local
    seen = Renderer(source.map_model, engine="numba").render(q.camera, truth_pose, depth=True).depth[0]
    pivot_m = float(np.median(seen[np.isfinite(seen)]))
    truth = truth_pose.to_xyz_rpy()
    states = ridge_states(truth, pivot_m, args.span_deg, args.steps)
    distance_m = np.linalg.norm(states[:, :3] - truth[:3], axis=1)
    centre = len(states) // 2
    query = Query.from_arrays(q.labels, None, loc.has_openings)
    print(
        f"{q.query_id}, {args.perception} (label seed {args.label_seed}): pivot {pivot_m:.0f} m ahead, "
        f"turns up to {args.span_deg:g} deg = {distance_m.max():.2f} m of camera shift"
    )
    for width in (int(w) for w in args.widths.split(",")):
        cam = q.camera.scaled(width, max(1, round(width * q.camera.height / q.camera.width)))
        labels, _ = query.at(cam.width, cam.height)
        scores, _ = evaluate(loc.scene, cam, states, labels, None, loc.class_on)
        print(f"{cam.width} x {cam.height}: truth {scores[centre]:.5f}")
        print("\n".join(profile(scores, distance_m, scores[centre])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
