"""``semcityloc localize``: the pose of one image from its semantic mask (+ depth) and a prior."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from semcityloc.citymodel.model import crs_label
from semcityloc.cli.city import add_model_arguments, load_model_from_args
from semcityloc.errors import InputFileError
from semcityloc.geometry.io import read_intrinsics, read_pose, write_pose_json
from semcityloc.io.images import load_depth, load_image, load_labels_png, save_rgb
from semcityloc.localization.config import PRESETS, LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.methods import ABLATIONS
from semcityloc.perception.registry import available_backends, get_depth_backend, get_segmentation_backend
from semcityloc.render.overlay import blend_labels, draw_edges, visible_edges
from semcityloc.render.raster_numba import NumbaEngine


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("localize", help="estimate the 6DoF pose of one image against a city model")
    add_model_arguments(p, positional=False)
    p.add_argument(
        "--intrinsics", required=True, help="LoD-Loc *_intrinsic.txt, COLMAP line, JSON or fx,fy,cx,cy,w,h"
    )
    p.add_argument(
        "--prior", required=True, help="prior pose in the model's CRS (same forms as render --pose)"
    )
    p.add_argument("--semantic", default=None, help="query label mask (palette/grey PNG of class ids)")
    p.add_argument("--depth", default=None, help="query relative depth (.npy or 16-bit PNG); optional")
    p.add_argument("--image", default=None, help="the photo: overlay background, or input to --seg-backend")
    p.add_argument(
        "--seg-backend",
        default=None,
        choices=available_backends("segmentation"),
        help="segmentation backend to run on --image",
    )
    p.add_argument(
        "--depth-backend",
        default=None,
        choices=available_backends("depth"),
        help="depth backend to run on --image",
    )
    p.add_argument(
        "--backend-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="option passed to the perception backends (repeatable), e.g. weights=DIR",
    )
    p.add_argument(
        "--preset", default="default", choices=tuple(PRESETS), help="localizer preset (default: default)"
    )
    p.add_argument(
        "--method", default="semcityloc", choices=tuple(ABLATIONS), help="the method or one of its ablations"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--height", type=int, default=None)
    p.add_argument("--out", required=True, help="output folder: pose.json and overlay.png")
    p.set_defaults(func=run)


def _query_inputs(args, camera):
    if args.semantic:
        labels = load_labels_png(args.semantic)
        depth = load_depth(args.depth) if args.depth else None
        return labels, depth
    if not (args.image and args.seg_backend):
        raise InputFileError(
            "give --semantic MASK.png (and optionally --depth), or --image with --seg-backend"
        )

    options = dict(opt.split("=", 1) for opt in args.backend_option if "=" in opt)
    image = load_image(args.image)
    name = Path(args.image).name
    labels = get_segmentation_backend(args.seg_backend, **options).predict(image, name=name).labels
    depth = None
    if args.depth_backend:
        out = get_depth_backend(args.depth_backend, **options).predict(image, name=name)
        depth = np.where(out.valid, out.depth, np.nan)
    return labels, depth


def run(args: argparse.Namespace) -> int:
    model = load_model_from_args(args)
    camera = read_intrinsics(args.intrinsics, width=args.width, height=args.height)
    prior_world = read_pose(args.prior)  # the model's CRS
    labels, depth = _query_inputs(args, camera)
    config = replace(LocalizerConfig.preset(args.preset).with_ablation(args.method), seed=args.seed)
    localizer = Localizer(model, config)
    result = localizer.localize(camera, model.pose_to_local(prior_world), labels, depth)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    crs = crs_label(model.crs)
    record = result.to_dict(model.origin, crs)  # the pose, if any, in CRS coordinates
    if result.pose_local is not None:
        # pose.json: the pose at the top level (read_pose reads it), the whole result record in "extra".
        data = write_pose_json(
            result.pose_local, out / "pose.json", origin=model.origin, crs=crs, extra=record
        )

        view = NumbaEngine(localizer.scene).render(
            camera, result.pose_local.R[None], result.pose_local.t[None], depth=True, face_ids=True
        )
        background = (
            load_image(args.image)
            if args.image
            else blend_labels(np.zeros(labels.shape + (3,), np.uint8) + 40, labels, alpha=0.8)
        )
        edges = visible_edges(view.face_ids[0], view.depth[0], localizer.scene)
        save_rgb(draw_edges(background, edges), out / "overlay.png")
        print(
            json.dumps(
                {
                    "status": result.status,
                    "position": data["position"],
                    "roll": data["roll"],
                    "pitch": data["pitch"],
                    "yaw": data["yaw"],
                    "crs": data.get("crs"),
                    "timings_s": result.timings,
                }
            )
        )
        return 0
    (out / "pose.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    print(json.dumps({"status": result.status, "reason": result.reason}))
    return 1
