"""``semcityloc label``: automatic label PNGs for photos with known poses (the paper's annotation pipeline).

For every photo in ``--images`` that has a pose, the city model's classes are projected into the photo
(``perception.autolabel.auto_label``: occlusion-exact, IGNORE = 255 where the model says nothing
reliable) and written as ``--out/<stem>.png`` (palette PNG, ``semcityloc.classes.PALETTE``); with
``--overlay`` also ``--out/overlays/<stem>.png`` for a person to check the alignment.

Poses (``--poses``), in the model's CRS / frame:
- a COLMAP ``images.txt`` / ``images.bin`` or the model folder holding one (or any file
  ``geometry.io.read_poses`` reads), matched to photos by name, file name or stem;
- a folder of LoD-Loc ``<stem>_pose.txt`` (4x4 camera-to-world) files, e.g. ``GT_pose/``.
A photo whose pose lies farther from the model than a local frame reaches (another CRS:
``citymodel.pose_crs.check_camera_near_model``, as ``render`` checks its pose) is left out with a warning
naming photo, pose file and distance; the others are labelled.

Intrinsics (``--intrinsics``): one file for every photo (a LoD-Loc ``*_intrinsic.txt``, a COLMAP line,
JSON, ``fx,fy,cx,cy[,w,h]``), a COLMAP ``cameras.txt`` (several cameras: the camera id of each photo comes
from the ``images.txt`` given as ``--poses``), a folder of LoD-Loc ``<stem>_intrinsic.txt``, or ``exif``
(each photo's DJI calibration tags, else its 35 mm-equivalent focal length, approximate: a note says for
how many photos, ``datasets.photos.APPROXIMATE_INTRINSICS_NOTE``). Without
``--intrinsics``: ``cameras.txt`` beside a COLMAP ``images.txt``, or the ``intrinsic/`` folder beside a
LoD-Loc pose folder. The photo's own size always wins (intrinsics of another size are rescaled). With
lens distortion in the intrinsics (COLMAP ``OPENCV`` / ``RADIAL`` / ``SIMPLE_RADIAL``, JSON ``k1 k2 p1 p2
k3``) the labels, rendered through the pinhole camera, are resampled onto the photo's own distorted pixels
(``geometry.distortion.distort_image``; IGNORE where the pinhole render does not reach).

Resuming (stop 55): a photo whose ``--out/<stem>.png`` exists is kept, not labelled again (every label map is
written whole or not at all, ``io.files.write_atomic``, so one that exists is finished; a label corrected by
hand stays): ``N of M already labelled, kept``. A Ctrl-C says how many are done and kept, and the same
command goes on. ``--overwrite`` labels every photo again. With ``--overlay``, a kept photo without its
overlay (labelled by a run without ``--overlay``) gets one drawn from its kept label map (stop 56: what the
folder holds, a hand correction too, and no render), which the summary line counts (``K missing overlays
drawn from the kept label maps``); a map of another size than its photo is named in a warning.

Refused before any work (``cli.outputs.check_outputs``): an output that is an input (PNG photos and
``--out`` the same folder) and two photos of one stem (``X.JPG``, ``X.png``), which would write one
``X.png``. A label map beside a photo of its stem (``X.png``, palette of the classes or grey class ids,
beside ``X.JPG``: ``--out`` the photos' own folder, ``io.images.label_maps_beside_photos``) is no photo
(stop 56): into that folder it is the photo's kept label map; from another ``--out`` it is left out, with a
note. A write that fails (a full disk, a folder where the file goes) is one line
(``benchmark.runfiles.writing``). One run at a time writes a folder (stop 56): ``label`` holds
``--out/run.lock`` as ``run`` does (``benchmark.runfiles.run_lock``), so a second run into it is refused
naming the first's pid, and a lock a killed run left is taken over.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from semcityloc.benchmark.runfiles import OVERLAYS_DIR, kept_note, remove_stale_temps, run_lock, writing
from semcityloc.citymodel.pose_crs import check_camera_near_model
from semcityloc.classes import IGNORE
from semcityloc.cli.city import add_model_arguments, load_model_from_args
from semcityloc.cli.outputs import check_outputs, same_file
from semcityloc.datasets.photos import (
    APPROXIMATE_INTRINSICS_NOTE,
    INTRINSICS_35MM,
    IntrinsicsFiles,
    PoseFiles,
    list_images,
)
from semcityloc.errors import InputFileError, SemCityLocError, counted, shown_names
from semcityloc.geometry.distortion import distort_image
from semcityloc.io.images import (
    image_size,
    label_maps_beside_photos,
    load_image,
    load_labels_png,
    save_labels_png,
    save_rgb,
)
from semcityloc.perception.autolabel import auto_label_render, label_overlay
from semcityloc.render import Renderer
from semcityloc.render.engine import ENGINES

SHOWN_PROBLEMS = 10  # photos named per problem on stderr; the rest counted


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc label`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    p = sub.add_parser("label", help="automatic label PNGs: project the city model into posed photos")
    add_model_arguments(p, positional=False)
    p.add_argument("--images", required=True, help="folder of photos")
    p.add_argument(
        "--poses",
        required=True,
        help="COLMAP images.txt / images.bin / model folder, or a folder of LoD-Loc <stem>_pose.txt",
    )
    p.add_argument(
        "--intrinsics",
        default=None,
        help="file, COLMAP cameras.txt / cameras.bin, folder of <stem>_intrinsic.txt, or 'exif' (each "
        "photo's DJI calibration tags, else its 35 mm-equivalent focal length: approximate) (with lens "
        "distortion, the labels are resampled onto the photo's distorted pixels)",
    )
    p.add_argument("--out", required=True, help="output folder for <stem>.png label maps")
    p.add_argument(
        "--max-range",
        type=float,
        default=1500.0,
        help="ignore surfaces farther than this (m; default %(default)g)",
    )
    p.add_argument(
        "--min-incidence", type=float, default=10.0, help="ignore rays this close to a surface (deg)"
    )
    p.add_argument(
        "--extent-margin",
        type=float,
        default=25.0,
        help="terrain this far outside the buildings counts (m; default %(default)g)",
    )
    p.add_argument(
        "--boundary-px",
        type=int,
        default=1,
        help="ignore band at class boundaries (px, 0 = off; default %(default)s)",
    )
    p.add_argument("--overlay", action="store_true", help="also write overlays/<stem>.png (photo + labels)")
    p.add_argument("--engine", default="auto", choices=ENGINES, help="render engine (default auto)")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="label every photo again (default: a photo whose <stem>.png exists in --out is kept, so a "
        "stopped run goes on and labels corrected by hand stay)",
    )
    p.set_defaults(func=run)


# ---------------------------------------------------------------------------------------------- run
def named(name: str, why: str) -> str:
    """``why`` a photo was not labelled, led by its ``name`` unless it names it already (a file's path)."""
    return why if name in why else f"{name}: {why}"


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc label`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    images = list_images(Path(args.images))
    out = Path(args.out)
    maps = label_maps_beside_photos(images)
    if maps:  # into the photos' own folder: this command's kept label maps (``_run_locked`` says so)
        images = [i for i in images if i not in maps]
        if not all(same_file(m, out / m.name) for m in maps):
            what = (
                "is a label map beside a photo of its name, not a photo"
                if len(maps) == 1
                else "are label maps beside photos of their names, not photos"
            )
            names = shown_names(sorted(m.name for m in maps))
            print(f"semcityloc: note: {names} in {args.images} {what}: left out", file=sys.stderr)
    outputs = [(image.name, out / f"{image.stem}.png") for image in images]
    if args.overlay:
        outputs += [(image.name, out / OVERLAYS_DIR / f"{image.stem}.png") for image in images]
    check_outputs(outputs, [*images, args.poses, args.intrinsics, args.path])
    with writing(folder=out):
        out.mkdir(parents=True, exist_ok=True)
    with run_lock(out):  # one run at a time writes a folder, as ``run`` and ``benchmark``
        return _run_locked(args, images, out)


def _run_locked(args: argparse.Namespace, images: list[Path], out: Path) -> int:
    """``run`` once it holds ``out``'s lock: what is kept, then the photos to label."""
    remove_stale_temps(out, ("", OVERLAYS_DIR))  # a stopped run's half-written temporary files
    kept = [] if args.overwrite else [i for i in images if (out / f"{i.stem}.png").is_file()]
    finished = set(kept)
    todo = [i for i in images if i not in finished]
    if kept:
        print(f"{len(kept)} of {len(images)} already labelled, kept (--overwrite labels them again)")
    try:
        drawn = _kept_overlays(kept, out) if args.overlay else 0
        if not todo:
            print(f"nothing to label: every photo's label map is in {out}{drawn_note(drawn)}")
            return 0
        model = load_model_from_args(args)
        poses = PoseFiles(args.poses, model.crs)
        intrinsics = IntrinsicsFiles(args.intrinsics, poses)
        renderer = Renderer(model, engine=args.engine)
        return _label(args, images, todo, model, poses, intrinsics, renderer, out, drawn)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: what is kept, and that the same command goes on
        done = sum((out / f"{i.stem}.png").is_file() for i in images)
        print(kept_note(done, len(images), out), file=sys.stderr, flush=True)
        raise


def drawn_note(drawn: int) -> str:
    """What the summary line adds when overlays were drawn from kept label maps (``_kept_overlays``)."""
    return f"; {counted(drawn, 'missing overlay')} drawn from the kept label maps" if drawn else ""


def _draw_overlay(image: Path, labels: np.ndarray | Path, out: Path) -> str | None:
    """Write ``out/overlays/<stem>.png``: the photo ``image`` with ``labels`` over it (or those of the label
    map file ``labels`` names, a kept one). None, or why it could not be drawn: the photo's pixels do not
    decode (its labels need its size only), a kept map that cannot be read or is of another size."""
    try:
        if isinstance(labels, Path):
            labels = load_labels_png(labels)
        photo = load_image(image)
    except InputFileError as exc:
        return str(exc)
    if labels.shape != photo.shape[:2]:  # a map made or corrected by hand at another size
        (h, w), (ph, pw) = labels.shape, photo.shape[:2]
        return f"the kept label map {out / f'{image.stem}.png'} is {w}x{h} pixels, {image.name} {pw}x{ph}"
    path = out / OVERLAYS_DIR / f"{image.stem}.png"
    with writing(path):
        save_rgb(label_overlay(photo, labels), path)
    return None


def _kept_overlays(kept: list[Path], out: Path) -> int:
    """Draw the overlay of each ``kept`` photo that has none (labelled by a run without ``--overlay``; stop
    56) from its kept label map: the labels the folder holds, a hand correction too, without rendering
    again. Warns for those it could not draw; returns how many it drew."""
    drawn, problems = 0, {}
    for image in kept:
        if (out / OVERLAYS_DIR / f"{image.stem}.png").is_file():
            continue
        why = _draw_overlay(image, out / f"{image.stem}.png", out)
        if why is None:
            drawn += 1
        else:
            problems[image.name] = why
    warn("kept, no overlay", problems)
    return drawn


def warn(what: str, problems: dict[str, str]) -> None:
    """One ``semcityloc: warning: WHAT: photo: why`` line for each of the first ``SHOWN_PROBLEMS``
    ``problems`` (photo name: why), then how many more."""
    for name, why in list(problems.items())[:SHOWN_PROBLEMS]:
        print(f"semcityloc: warning: {what}: {named(name, why)}", file=sys.stderr)
    if len(problems) > SHOWN_PROBLEMS:
        print(f"semcityloc: warning: {len(problems) - SHOWN_PROBLEMS} more {what}", file=sys.stderr)


def _label(args, images, todo, model, poses, intrinsics, renderer, out: Path, drawn: int) -> int:
    """Label the photos ``todo`` (of ``images``) into ``out``; the exit code (``run``). ``drawn``: the
    overlays drawn from kept label maps before (``_kept_overlays``), for the summary line."""
    written, skipped, failed, no_overlay = 0, [], {}, {}
    approximate = 0  # photos whose camera is the EXIF's 35 mm-equivalent focal length (--intrinsics exif)
    for image in todo:
        try:  # this photo's own files (its pose, size, intrinsics): its failure, not the run's end
            pose = poses.pose(image)
            if pose is None:
                skipped.append(image.name)
                continue
            check_camera_near_model(model.pose_to_local(pose), model, poses.file_of(image))
            width, height = image_size(image)
            lens = intrinsics.photo_camera(image, width, height)
        except SemCityLocError as exc:
            failed[image.name] = str(exc)
            continue
        approximate += lens.source == INTRINSICS_35MM  # said once, after the photos
        camera = lens.camera
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
        # Rendered through the pinhole camera; a distorting lens moves them onto the photo's own pixels.
        labels = distort_image(res.labels, camera, lens.distortion, fill=IGNORE, nearest=True)
        if args.overlay:  # before the label map: the map's existence says the photo is finished
            why = _draw_overlay(image, labels, out)
            if why is not None:
                no_overlay[image.name] = why
        with writing(out / f"{image.stem}.png"):
            save_labels_png(labels, out / f"{image.stem}.png")
        labelled = float((labels != IGNORE).mean())
        print(json.dumps({"image": image.name, "labelled": round(labelled, 4), "ignored": res.reasons}))
        written += 1
    if approximate:
        print(
            f"semcityloc: note: {counted(approximate, 'photo')}: {APPROXIMATE_INTRINSICS_NOTE}",
            file=sys.stderr,
        )
    if skipped:
        print(
            f"no pose for {len(skipped)} image(s): {', '.join(skipped[:5])}"
            + (" ..." if len(skipped) > 5 else "")
        )
    warn("not labelled", failed)
    warn("labelled, no overlay", no_overlay)
    if written == 0 and len(todo) == len(images):
        if failed:
            first = "; ".join(named(name, why) for name, why in list(failed.items())[:3])
            raise InputFileError(
                f"none of the {len(images)} images in {args.images} could be labelled: {first}"
            )
        raise InputFileError(f"none of the {len(images)} images in {args.images} has a pose in {args.poses}")
    print(f"wrote {written} label map(s) to {out}{drawn_note(drawn)}")
    return 0
