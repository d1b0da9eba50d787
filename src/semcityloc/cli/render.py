"""``semcityloc render``: semantic mask, depth and (with a photo) a model-edge overlay at one pose.

With lens distortion in the intrinsics (COLMAP ``OPENCV`` / ``RADIAL`` / ``SIMPLE_RADIAL``, JSON ``k1 k2 p1 p2
k3``) everything is written in the photo's own distorted pixels: rendered through the pinhole camera, then
resampled (``geometry.distortion.distort_image``; IGNORE / no depth / no edge where the pinhole render
does not reach), so the overlays lie on the photo as it is.

Its files (``OUTPUT_FILES``) are checked against its inputs before any work (``cli.outputs.check_outputs``:
``--image out/labels.png`` would be overwritten); a write that fails is one line
(``benchmark.runfiles.writing``), every file written whole or not at all (``io.files.write_atomic``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from semcityloc.benchmark.runfiles import writing
from semcityloc.citymodel.pose_crs import check_camera_near_model, read_pose_world
from semcityloc.classes import IGNORE
from semcityloc.cli.city import add_model_arguments, load_model_from_args
from semcityloc.cli.outputs import check_outputs
from semcityloc.cli.pose_input import add_pose_name_argument, photo_name, read_lens_for_photo
from semcityloc.geometry.distortion import distort_image
from semcityloc.io.images import load_image, save_depth, save_labels_png, save_rgb
from semcityloc.render import Renderer
from semcityloc.render.engine import ENGINES
from semcityloc.render.overlay import blend_labels, draw_edges, visible_edges

# What ``render`` writes into ``--out`` (the overlays only with ``--image``).
OUTPUT_FILES = ("labels.png", "depth.png", "depth.npy", "overlay_edges.png", "overlay_labels.png")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc render`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    p = sub.add_parser("render", help="render the semantic mask and depth of a city model at a pose")
    add_model_arguments(p, positional=False)
    p.add_argument(
        "--intrinsics",
        required=True,
        help="LoD-Loc *_intrinsic.txt, COLMAP camera line, JSON, or fx,fy,cx,cy,w,h (with lens distortion: "
        "the outputs in the photo's distorted pixels)",
    )
    p.add_argument(
        "--pose",
        required=True,
        help="pose in the model's CRS: LoD-Loc *_pose.txt (camera-to-world), COLMAP line, JSON, "
        "or x,y,z,roll,pitch,yaw in degrees (0,0,0 looks straight down with image-up north; pitch 90 "
        "looks at the horizon: a DJI gimbal pitch -90 is our 0; yaw counter-clockwise from north)",
    )
    add_pose_name_argument(p, "--pose")
    p.add_argument("--width", type=int, default=None, help="image width (when the intrinsics do not say)")
    p.add_argument("--height", type=int, default=None, help="image height")
    p.add_argument(
        "--image",
        default=None,
        help="photo to overlay the visible model edges on (without --width/--height, every output is at "
        "its size)",
    )
    p.add_argument("--engine", default="numba", choices=ENGINES, help="render engine (default numba)")
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc render`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    out = Path(args.out)
    check_outputs(
        [(name, out / name) for name in OUTPUT_FILES], [args.image, args.intrinsics, args.pose, args.path]
    )
    # With --image the intrinsics must describe that photo (edges drawn with another camera's are
    # misaligned), and without --width/--height its own size wins: labels, depth and overlays on its pixels
    camera, lens = read_lens_for_photo(args.intrinsics, args.width, args.height, args.image)
    model = load_model_from_args(args)
    pose_world = read_pose_world(args.pose, model.crs, name=args.pose_name, photo=photo_name(args.image))
    with writing(folder=out):
        out.mkdir(parents=True, exist_ok=True)
    renderer = Renderer(model, engine=args.engine)
    pose_local = model.pose_to_local(pose_world)
    check_camera_near_model(pose_local, model, args.pose)
    view = renderer.render(camera, pose_local, depth=True, face_ids=True)
    edges = visible_edges(view.face_ids[0], view.depth[0], renderer.scene)
    labels = distort_image(view.labels[0], camera, lens, fill=IGNORE, nearest=True)
    depth = distort_image(view.depth[0], camera, lens, fill=np.nan, nearest=True)
    edges = distort_image(edges, camera, lens, fill=False, nearest=True)
    photo = load_image(args.image) if args.image else None
    with writing(folder=out):  # the error names the file that failed
        written = [save_labels_png(labels, out / "labels.png"), *save_depth(depth, out / "depth.png")]
        if photo is not None:
            written.append(save_rgb(draw_edges(photo, edges), out / "overlay_edges.png"))
            written.append(save_rgb(blend_labels(photo, labels), out / "overlay_labels.png"))
    counts = {int(c): int((labels == c).sum()) for c in set(labels.reshape(-1).tolist())}
    print(json.dumps({"written": [str(p) for p in written], "pixels_per_class": counts}))
    if not np.isfinite(view.depth[0]).any():  # most often a pose in another frame or with other axes
        print(
            "semcityloc: warning: nothing of the model is in view at this pose: is it in the model's CRS "
            "(or local frame), with the camera's z axis forward, y down (OpenCV), and above the ground?",
            file=sys.stderr,
        )
    return 0
