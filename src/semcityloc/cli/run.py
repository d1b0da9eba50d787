"""``semcityloc run``: a folder of photos + a city model -> a corrected pose per photo, and the files
photogrammetry tools and GIS read (``benchmark.photo_spec`` / ``photo_exports``; docs/your-data.md).

Resumable like the benchmark: run the same command again after an interruption and it continues; other
arguments on the same ``--out`` are refused unless ``--overwrite`` (which always starts the run again).
Exit status: 0, or ``NONE_LOCALIZED`` (1) for a finished run that localized none of its photos; a run that
cannot be made is one line and 2 (``cli.main``).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from semcityloc.benchmark.photo_inputs import label_maps_left_out, unread_subfolder_photos
from semcityloc.benchmark.photo_spec import CALIBRATE_FOCAL, PhotoSpec
from semcityloc.benchmark.report_tables import summary_markdown
from semcityloc.benchmark.results import SKIPPED, counted_as
from semcityloc.cli.city import add_model_arguments, parse_lod, print_model_warnings
from semcityloc.cli.dataset import parse_floats
from semcityloc.cli.executor import add_executor_arguments, run_from_args
from semcityloc.cli.localize import (
    add_lossy_mask_argument,
    add_map_eaves_arguments,
    add_preset_argument,
    add_prior_sigma_argument,
    parse_backend_options,
)
from semcityloc.datasets.dji import TARGET_HEIGHTS
from semcityloc.datasets.photos import EXIF, check_images_folder
from semcityloc.errors import as_flags, counted, shown_names
from semcityloc.localization.methods import ABLATIONS
from semcityloc.localization.result import LOCALIZED
from semcityloc.perception.registry import available_backends, backend_warnings

SHOWN_PHOTOS = 10  # photos named per reason in the closing lines
# The exit status of a finished run that localized none of its photos (its files are written): as
# ``semcityloc localize`` exits 1 for a photo it did not localize; 2 is a run that could not be made.
NONE_LOCALIZED = 1


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc run`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    p = sub.add_parser(
        "run",
        help="localize a folder of photos against a city model: pose per photo, COLMAP, geotags, GeoJSON",
    )
    p.add_argument("images", help="folder of photos (DJI JPEGs carry their own prior and intrinsics)")
    p.add_argument(
        "--recursive",
        action="store_true",
        help="read the photos of the folder's subfolders too (a DJI card's DCIM/100MEDIA/...); their names "
        "must be unique (outputs are named by them); without it only the top level is read, and the run "
        "says how many photos in subfolders it left out",
    )
    add_model_arguments(p, positional=False)
    p.add_argument(
        "--priors",
        default=EXIF,
        help="exif (default: the photos' DJI GPS + gimbal angles), a geotag .csv (WGS 84 + DJI angles), "
        "a COLMAP images.txt or a folder of LoD-Loc <stem>_pose.txt (in the model's frame)",
    )
    p.add_argument(
        "--intrinsics",
        default=EXIF,
        help="exif (default: DJI's DewarpData with its lens distortion, else DJI's calibration tags, else "
        "the 35 mm-equivalent focal length), a calibration file, COLMAP cameras.txt, or a folder of "
        "<stem>_intrinsic.txt; a lens distortion (COLMAP OPENCV / RADIAL, JSON k1 k2 p1 p2 k3) is undone "
        "on photo, mask and depth",
    )
    p.add_argument(
        "--truth", default=None, help="ground-truth poses (same forms as --priors): errors in the summary"
    )
    add_prior_sigma_argument(
        p,
        "1-sigma error of every prior (default: per photo, from its RTK tags or the geotag accuracy, "
        "else xy 5 m, z 10 m, yaw 3 deg, roll/pitch 1 deg); the search covers 3 sigma",
    )
    p.add_argument(
        "--masks",
        default=None,
        help="folder of precomputed label masks <stem>.png / .npy (or <stem>.JPG.png; <stem>.jpg with "
        "--allow-lossy-mask)",
    )
    add_lossy_mask_argument(p, "--masks (or the files backend's masks)")
    p.add_argument("--depth", default=None, help="folder of precomputed relative depth <stem>.npy / .png")
    p.add_argument(
        "--seg-backend",
        default=None,
        choices=available_backends("segmentation"),
        help="segmentation backend run on each photo instead of --masks (mobilenetv2 / dinov3-dpt need a "
        "trained head: --backend-option head=DIR; docs/perception.md)",
    )
    p.add_argument(
        "--depth-backend",
        default=None,
        choices=available_backends("depth"),
        help="depth backend run on each photo instead of --depth (moge2: --backend-option model=PATH)",
    )
    p.add_argument(
        "--backend-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="option of the perception backends (repeatable): head=DIR, backbone=DIR, model=PATH, device",
    )
    p.add_argument("--offset", default=None, help="x,y,z: the model's frame is its CRS minus this")
    p.add_argument(
        "--target-height",
        default="auto",
        choices=TARGET_HEIGHTS,
        help="what the model's z is (auto: orthometric when its CRS has a vertical datum or "
        "--geoid-separation is given, else DJI's height as it is; orthometric: EGM96 for a 2D CRS)",
    )
    p.add_argument(
        "--geoid-separation",
        type=float,
        default=None,
        help="known geoid undulation N (m) at the site: the model's z = the photos' ellipsoidal height - N",
    )
    p.add_argument("--method", default="semcityloc", choices=ABLATIONS, help="the method or an ablation")
    add_preset_argument(p)
    add_map_eaves_arguments(p)
    p.add_argument("--out", default="semcityloc_run", help="output folder (default semcityloc_run)")
    p.add_argument("--workers", type=int, default=1, help="processes localizing in parallel (default 1)")
    add_executor_arguments(p)
    p.add_argument("--keep-details", type=int, default=3, help="save details of the first N photos")
    p.add_argument(
        "--calibrate-focal",
        default="auto",
        choices=CALIBRATE_FOCAL,
        help="estimate each camera's focal length from the flight's oblique photos (at least 5): auto (the "
        "default) when it is the approximate 35 mm-equivalent EXIF value, on for every camera, off",
    )
    p.add_argument("--no-overlays", action="store_true", help="do not draw overlays/<stem>.png")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="start the run again: delete the results in --out (needed when made with other arguments)",
    )
    p.add_argument("--stop-after", type=int, default=None, metavar="N", help="localize at most N more photos")
    p.set_defaults(func=run)


def spec_from_args(args: argparse.Namespace) -> PhotoSpec:
    """The run's ``PhotoSpec`` from its options; its images folder checked first (``check_images_folder``:
    a photo given instead of its folder is said so, not "no such folder")."""
    check_images_folder(args.images)
    return PhotoSpec(
        images=args.images,
        city=args.path,
        lod=parse_lod(args.lod),
        crs=args.crs,
        priors=args.priors,
        intrinsics=args.intrinsics,
        truth=args.truth,
        masks=args.masks,
        allow_lossy_mask=args.allow_lossy_mask,
        depth=args.depth,
        seg_backend=args.seg_backend,
        depth_backend=args.depth_backend,
        backend_options=parse_backend_options(args.backend_option),
        prior_sigma=args.prior_sigma,
        offset=parse_floats(args.offset, 3, "--offset"),
        target_height=args.target_height,
        geoid_separation_m=args.geoid_separation,
        method=args.method,
        preset=args.preset,
        map_eaves_m=args.map_eaves,
        map_eaves_flat_roofs=args.map_eaves_flat,
        keep_details=args.keep_details,
        overlays=not args.no_overlays,
        calibrate_focal=args.calibrate_focal,
        cache=not args.no_cache,
        recursive=args.recursive,
    )


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc run`` from its parsed arguments; the exit code (typed errors are left to ``cli.main``,
    which prints them as one line).
    """
    spec = spec_from_args(args)
    out = Path(args.out)
    unread = unread_subfolder_photos(spec)
    if unread:  # before the run: a card's DCIM/100MEDIA/ or a flight's sub/ is not left out unsaid
        shown = shown_names([str(p.relative_to(spec.images)) for p in unread], SHOWN_PHOTOS)
        print(
            f"semcityloc: note: {counted(len(unread), 'photo')} in subfolders of {spec.images} "
            f"{'is' if len(unread) == 1 else 'are'} not read ({shown}): only its top level is; pass "
            "--recursive to read them too",
            file=sys.stderr,
        )
    maps = label_maps_left_out(spec)
    if maps:  # what ``semcityloc label --out`` into the photos' folder wrote: not localized as photos
        shown = shown_names([str(p.relative_to(spec.images)) for p in maps], SHOWN_PHOTOS)
        print(
            f"semcityloc: note: {spec.images} holds {counted(len(maps), 'label map')} beside the photo of "
            f"its name ({shown}; semcityloc label's): not photos, left out",
            file=sys.stderr,
        )
    for warning in backend_warnings(spec.seg_backend, spec.backend_options):  # a head without roof or wall
        print(f"semcityloc: warning: {as_flags(warning)}", file=sys.stderr)
    outcome = run_from_args(spec, out, args)
    # The model the run loaded (PhotoSpec.resolved, cached: not loaded again); said after the run, where
    # nothing before its first photo is delayed by it (the run's option checks come first).
    print_model_warnings(spec.resolved().model)
    config = outcome.config
    if not outcome.complete:
        print(
            f"{len(outcome.rows)}/{counted(config['queries'], 'photo')} done in {out}; run again to continue"
        )
        return 0
    s = outcome.summary
    skipped = s["skipped_photos"]  # before the run, or when its files were read (a ``skipped`` row)
    refused: dict[str, list[str]] = {}
    for row in outcome.rows:
        if row["status"] not in (LOCALIZED, SKIPPED):
            name = config["query_names"][int(row["index"])]
            refused.setdefault(row["reason"] or row["status"], []).append(name)
    # photos of the truth skipped before the run: misses, among the not localized (``results``)
    misses = s.get("skipped_counted_as_misses", 0)
    print(
        f"{counted(s['photos'], 'photo')}: {s['localized']} localized, {s['not_localized']} not localized"
        f"{f' ({misses} of them skipped, counted as {counted_as(misses)})' if misses else ''}, "
        f"{len(skipped)} skipped (perception: {s['perception']})"
    )
    for reason, names in refused.items():
        print(f"  not localized ({reason}): {shown_names(names, SHOWN_PHOTOS)}")
    for reason, count in Counter(skipped.values()).most_common():
        names = [n for n, r in skipped.items() if r == reason]
        print(f"  skipped ({count}): {reason}: {shown_names(names, SHOWN_PHOTOS)}")
    if s.get("with_ground_truth"):
        print(summary_markdown([s], [f"{spec.method} [{s['perception']}] vs --truth"]))
    outputs = s["outputs"]
    for note in outputs.get("notes", []):
        print(f"semcityloc: note: {note}", file=sys.stderr)
    for warning in outputs.get("warnings", []):  # photos left out of an export (the others are written)
        print(f"semcityloc: warning: {warning}", file=sys.stderr)
    written = [outputs[k] for k in ("poses", "colmap", "geotags", "geo_txt", "geojson") if outputs.get(k)]
    if spec.overlays:
        written.append(str(out / "overlays"))
    print("wrote " + ", ".join(written))
    print(
        f"look at it: semcityloc report {out} --out {out / 'report'}  (tables and an interactive report.html)"
    )
    if s["localized"] == 0:  # as ``localize`` exits 1 for its photo: a script does not go on as if it ran
        print(
            f"semcityloc: warning: 0 of {counted(s['photos'], 'photo')} localized (the reasons above): "
            f"exit status {NONE_LOCALIZED}",
            file=sys.stderr,
        )
        return NONE_LOCALIZED
    return 0
