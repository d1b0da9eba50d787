"""``semcityloc label``: automatic label PNGs for photos with known poses (the paper's annotation pipeline).

For every photo in ``--images`` that has a pose, the city model's classes are projected into the photo
(``perception.autolabel.auto_label``: occlusion-exact, IGNORE = 255 where the model says nothing
reliable) and written as ``--out/<stem>.png`` (palette PNG, ``semcityloc.classes.PALETTE``); with
``--overlay`` also ``--out/overlays/<stem>.png`` for a person to check the alignment.

Poses (``--poses``), in the model's CRS / frame:
- a COLMAP ``images.txt`` (or any file ``geometry.io.read_poses`` reads), matched to photos by name, file
  name or stem;
- a folder of LoD-Loc ``<stem>_pose.txt`` (4x4 camera-to-world) files, e.g. ``GT_pose/``.

Intrinsics (``--intrinsics``): one file for every photo (a LoD-Loc ``*_intrinsic.txt``, a COLMAP line,
JSON, ``fx,fy,cx,cy[,w,h]``), a COLMAP ``cameras.txt`` (several cameras: the camera id of each photo comes
from the ``images.txt`` given as ``--poses``), or a folder of LoD-Loc ``<stem>_intrinsic.txt``. Without
``--intrinsics``: ``cameras.txt`` beside a COLMAP ``images.txt``, or the ``intrinsic/`` folder beside a
LoD-Loc pose folder. The photo's own size always wins (intrinsics of another size are rescaled).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from semcityloc.classes import IGNORE
from semcityloc.cli.city import add_model_arguments, load_model_from_args
from semcityloc.errors import CameraError, InputFileError
from semcityloc.geometry.io import read_colmap_camera_ids, read_intrinsics, read_pose, read_poses
from semcityloc.io.images import image_size, load_image, save_labels_png, save_rgb
from semcityloc.perception.autolabel import auto_label_render, label_overlay
from semcityloc.render import Renderer
from semcityloc.render.engine import ENGINES

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("label", help="automatic label PNGs: project the city model into posed photos")
    add_model_arguments(p, positional=False)
    p.add_argument("--images", required=True, help="folder of photos")
    p.add_argument("--poses", required=True, help="COLMAP images.txt, or a folder of LoD-Loc <stem>_pose.txt")
    p.add_argument(
        "--intrinsics", default=None, help="file, COLMAP cameras.txt, or folder of <stem>_intrinsic.txt"
    )
    p.add_argument("--out", required=True, help="output folder for <stem>.png label maps")
    p.add_argument("--max-range", type=float, default=1500.0, help="ignore surfaces farther than this (m)")
    p.add_argument(
        "--min-incidence", type=float, default=10.0, help="ignore rays this close to a surface (deg)"
    )
    p.add_argument(
        "--extent-margin", type=float, default=25.0, help="terrain this far outside the buildings counts (m)"
    )
    p.add_argument("--boundary-px", type=int, default=1, help="ignore band at class boundaries (px, 0 = off)")
    p.add_argument("--overlay", action="store_true", help="also write overlays/<stem>.png (photo + labels)")
    p.add_argument("--engine", default="auto", choices=ENGINES, help="render engine (default auto)")
    p.set_defaults(func=run)


# ---------------------------------------------------------------------------------------------- inputs
def list_images(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise InputFileError(f"{folder}: no such images folder")
    images = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise InputFileError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return images


def _match(entries: dict, image: Path):
    """Entry for ``image`` in a name-keyed dict: exact file name, then stem (paths in keys allowed)."""
    for key in (lambda n: Path(n).name, lambda n: Path(n).stem):
        hits = [k for k in entries if key(k) == key(image.name)]
        if len(hits) == 1:
            return entries[hits[0]]
    return None


def _per_stem_file(folder: Path, stem: str, suffix: str) -> Path | None:
    for name in (f"{stem}_{suffix}.txt", f"{stem}.txt"):
        if (folder / name).is_file():
            return folder / name
    return None


class PoseSource:
    """Poses by image from a COLMAP images.txt (or any read_poses file) or a LoD-Loc pose folder."""

    def __init__(self, spec: str):
        self.path = Path(spec)
        self.folder = self.path if self.path.is_dir() else None
        self.entries = {} if self.folder else read_poses(self.path)
        self.camera_ids = {} if self.folder else read_colmap_camera_ids(self.path)

    def pose(self, image: Path):
        if self.folder is not None:
            f = _per_stem_file(self.folder, image.stem, "pose")
            return read_pose(f) if f is not None else None
        if list(self.entries) == [""]:
            return self.entries[""]
        return _match(self.entries, image)


class IntrinsicsSource:
    """Camera per image (module docstring)."""

    def __init__(self, spec: str | None, poses: PoseSource):
        self.poses = poses
        if spec is None:
            spec = self._default(poses)
        self.path = Path(spec)
        self.folder = self.path if self.path.is_dir() else None

    @staticmethod
    def _default(poses: PoseSource) -> str:
        if poses.folder is not None:
            sibling = poses.folder.parent / "intrinsic"
            if sibling.is_dir():
                return str(sibling)
        else:
            sibling = poses.path.parent / "cameras.txt"
            if sibling.is_file():
                return str(sibling)
        raise InputFileError(
            "no --intrinsics given and none found beside the poses (expected cameras.txt beside images.txt "
            "or an intrinsic/ folder beside the pose folder)"
        )

    def camera(self, image: Path, width: int, height: int):
        if self.folder is not None:
            f = _per_stem_file(self.folder, image.stem, "intrinsic")
            if f is None:
                raise InputFileError(f"{self.folder}: no {image.stem}_intrinsic.txt for {image.name}")
            return read_intrinsics(f, width=width, height=height)
        try:  # one camera for every photo
            return read_intrinsics(self.path, width=width, height=height)
        except CameraError:
            pass
        # Several cameras: COLMAP cameras.txt is keyed by camera id (from images.txt), other files by name.
        camera_id = _match(self.poses.camera_ids, image) if self.poses.camera_ids else None
        return read_intrinsics(self.path, width=width, height=height, name=camera_id or image.name)


# ---------------------------------------------------------------------------------------------- run
def run(args: argparse.Namespace) -> int:
    images = list_images(Path(args.images))
    poses = PoseSource(args.poses)
    intrinsics = IntrinsicsSource(args.intrinsics, poses)
    model = load_model_from_args(args)
    renderer = Renderer(model, engine=args.engine)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written, skipped = 0, []
    for image in images:
        pose = poses.pose(image)
        if pose is None:
            skipped.append(image.name)
            continue
        width, height = image_size(image)
        camera = intrinsics.camera(image, width, height)
        res = auto_label_render(
            model,
            camera,
            pose,
            renderer=renderer,
            max_range_m=args.max_range,
            min_incidence_deg=args.min_incidence,
            extent_margin_m=args.extent_margin,
            boundary_px=args.boundary_px,
        )
        save_labels_png(res.labels, out / f"{image.stem}.png")
        if args.overlay:
            save_rgb(label_overlay(load_image(image), res.labels), out / "overlays" / f"{image.stem}.png")
        labelled = float((res.labels != IGNORE).mean())
        print(json.dumps({"image": image.name, "labelled": round(labelled, 4), "ignored": res.reasons}))
        written += 1
    if skipped:
        print(
            f"no pose for {len(skipped)} image(s): {', '.join(skipped[:5])}"
            + (" ..." if len(skipped) > 5 else "")
        )
    if written == 0:
        raise InputFileError(f"none of the {len(images)} images in {args.images} has a pose in {args.poses}")
    print(f"wrote {written} label map(s) to {out}")
    return 0
