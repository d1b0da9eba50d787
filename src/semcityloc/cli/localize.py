"""``semcityloc localize``: the pose of one image from its semantic mask (+ depth) and a prior."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from semcityloc.benchmark.runfiles import writing
from semcityloc.citymodel.model import crs_label
from semcityloc.citymodel.pose_crs import read_pose_world
from semcityloc.classes import IGNORE
from semcityloc.cli.city import add_model_arguments, load_model_from_args, print_model_warnings
from semcityloc.cli.outputs import check_outputs, same_file
from semcityloc.cli.pose_input import add_pose_name_argument, photo_name, read_lens_for_photo
from semcityloc.datasets.geodesy import check_model_in_crs
from semcityloc.datasets.photos import (
    APPROXIMATE_INTRINSICS_NOTE,
    EXIF,
    INTRINSICS_35MM,
    IntrinsicsFiles,
    PhotoCamera,
    PhotoMissing,
)
from semcityloc.errors import InputFileError, ParameterError, as_flags
from semcityloc.geometry.distortion import undistort_image, unseen_by_photo
from semcityloc.geometry.pose_json import write_pose_json
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.io.files import write_json_atomic
from semcityloc.io.images import (
    check_aspect,
    check_aspect_of_photo,
    exif_orientation,
    image_size,
    load_depth,
    load_image,
    read_mask_file,
    save_depth,
    save_labels_png,
    save_rgb,
)
from semcityloc.localization.config import FLAT_EAVES, PRESET_JOIN, PRESETS, LocalizerConfig, preset_name
from semcityloc.localization.focal_check import focal_scale_used, found_camera
from semcityloc.localization.localize import Localizer
from semcityloc.localization.map_scenes import found_on_flat_eaves
from semcityloc.localization.methods import ABLATIONS
from semcityloc.perception.base import PHOTO_MAX_WIDTH
from semcityloc.perception.files import with_lossy_masks
from semcityloc.perception.registry import (
    available_backends,
    backend_warnings,
    backend_weight_files,
    check_backend_options,
    get_depth_backend,
    get_segmentation_backend,
)
from semcityloc.render.overlay import blend_labels, draw_edges, visible_edges
from semcityloc.render.raster_numba import NumbaEngine


def parse_backend_options(pairs: list[str] | tuple[str, ...]) -> tuple[tuple[str, str], ...]:
    """``--backend-option`` values (``["head=DIR", "threads=2"]``) as (key, value) pairs, in order;
    ``ParameterError`` naming the first one without ``=`` or with a key given twice. Here, not in
    ``perception.registry``: it parses the flag, and its messages name it."""
    out: list[tuple[str, str]] = []
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ParameterError(f"--backend-option must be KEY=VALUE, got {pair!r}")
        if any(k == key.strip() for k, _ in out):
            raise ParameterError(f"--backend-option {key.strip()} is given twice; give each option once")
        out.append((key.strip(), value))
    return tuple(out)


def add_prior_sigma_argument(p: argparse.ArgumentParser, default_text: str | None = None) -> None:
    """``--prior-sigma xy=5,z=15,yaw=5,rp=1``: how far the priors may be off (1 sigma); the search covers
    3 sigma of it."""
    p.add_argument(
        "--prior-sigma",
        default=None,
        metavar="xy=5,z=15,yaw=5,rp=1",
        help=default_text
        or "1-sigma error of the prior (any subset; default xy 5 m, z 10 m, yaw 3 deg, roll/pitch 1 deg: "
        "DJI GNSS + gimbal IMU); the search covers 3 sigma; no compass: yaw=60 searches every heading "
        "(slower)",
    )


class _PresetsAction(argparse.Action):
    """``--preset NAME``: one of ``PRESETS``, several joined by commas, or the option repeated: the presets
    combined (``LocalizerConfig.preset``), kept in their one spelling (``config.preset_name``), which a
    run records. An unknown name is argparse's "invalid choice"; presets that cannot be combined are
    refused when the command builds its config, in one line."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        unknown = [n.strip() for n in values.split(PRESET_JOIN) if n.strip() not in PRESETS]
        if unknown:
            known = ", ".join(repr(n) for n in PRESETS)
            raise argparse.ArgumentError(self, f"invalid choice: {unknown[0]!r} (choose from {known})")
        before = getattr(namespace, self.dest, None)
        joined = values if before in (None, self.default) else f"{before}{PRESET_JOIN}{values}"
        setattr(namespace, self.dest, preset_name(joined))


def add_preset_argument(p: argparse.ArgumentParser, default: str | None = "default") -> None:
    """``--preset NAME[,NAME...]`` (repeatable): the localizer preset, or presets combined
    (``_PresetsAction``); every command that localizes takes it through here."""
    p.add_argument(
        "--preset",
        default=default,
        action=_PresetsAction,
        metavar="PRESET",
        help=f"localizer preset, one of {', '.join(PRESETS)}; several combine (lookalikes,focal-correct, or "
        "--preset repeated) when they change different settings (default: default)",
    )


def add_map_eaves_arguments(p: argparse.ArgumentParser) -> None:
    """``--map-eaves M`` and ``--map-eaves-flat``: the eaves the localizer adds to the map's roofs
    (``LocalizerConfig.map_eaves_m``, ``map_eaves_flat_roofs``)."""
    p.add_argument(
        "--map-eaves",
        type=float,
        default=None,
        metavar="M",
        help="eaves (m) added to the map's pitched roofs before the search (default: the preset's, 0.5 m; "
        "0 for a model whose roofs already overhang their walls)",
    )
    p.add_argument(
        "--map-eaves-flat",
        nargs="?",
        const="on",
        default=None,
        choices=FLAT_EAVES,
        help="the eaves on the map's flat roofs too: 'auto' (the default) tries them per view and keeps "
        "them where the view fits them better; 'on' (the option alone) always, for a city whose flat roofs "
        "overhang their walls; 'off' never, for flat roofs that end in a parapet "
        '(docs/localization.md, "The map\'s eaves")',
    )


def add_lossy_mask_argument(p: argparse.ArgumentParser, masks: str = "--masks") -> None:
    """``--allow-lossy-mask``: accept masks (``masks``, the option naming them) in a lossy format, which
    ``io.images.load_labels_png`` refuses otherwise."""
    p.add_argument(
        "--allow-lossy-mask",
        action="store_true",
        help=f"accept {masks} in a lossy format (JPEG): their edges carry wrong class ids",
    )


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc localize`` and its options to the command's parser (called by
    ``cli.main.build_parser``, once per sub-command module).
    """
    p = sub.add_parser("localize", help="estimate the 6DoF pose of one image against a city model")
    add_model_arguments(p, positional=False)
    p.add_argument(
        "--intrinsics",
        required=True,
        help="LoD-Loc *_intrinsic.txt, COLMAP line, JSON, fx,fy,cx,cy,w,h, or 'exif' (from --image's EXIF); "
        "with lens distortion (COLMAP OPENCV / RADIAL, JSON k1 k2 p1 p2 k3) the image, mask and depth are "
        "undistorted onto the pinhole camera first",
    )
    p.add_argument(
        "--prior", required=True, help="prior pose in the model's CRS (same forms as render --pose)"
    )
    add_pose_name_argument(p, "--prior")
    p.add_argument("--semantic", default=None, help="query label mask (palette/grey PNG of class ids)")
    add_lossy_mask_argument(p, "a --semantic mask (or the files backend's masks)")
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
        help="option passed to the perception backends (repeatable): head=DIR, backbone=DIR "
        "(segmentation), model=PATH (moge2), device=cpu|cuda",
    )
    add_preset_argument(p)
    add_prior_sigma_argument(p)
    add_map_eaves_arguments(p)
    p.add_argument(
        "--method", default="semcityloc", choices=tuple(ABLATIONS), help="the method or one of its ablations"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--height", type=int, default=None)
    p.add_argument(
        "--out",
        required=True,
        help="output folder: pose.json and overlay.png; with --seg-backend also mask.png (its label map), "
        "with --depth-backend depth.png + depth.npy; those of an earlier localize into it that this one "
        "does not write are removed",
    )
    p.set_defaults(func=run)


def _check_files(args) -> None:
    """Input files that are missing, and options that do not go together, before anything is loaded."""
    for option, value in (("--image", args.image), ("--semantic", args.semantic), ("--depth", args.depth)):
        if value and not Path(value).is_file():
            raise InputFileError(f"{option} {value}: no such file")
    if args.semantic and args.seg_backend:
        raise InputFileError("give --semantic MASK.png or --seg-backend NAME, not both")
    if args.depth and args.depth_backend:
        raise InputFileError("give --depth FILE or --depth-backend NAME, not both")
    if not (args.semantic or args.seg_backend):
        raise InputFileError(
            "give --semantic MASK.png (and optionally --depth), or --image and --seg-backend"
        )
    if (args.seg_backend or args.depth_backend) and not args.image:
        raise InputFileError("--seg-backend / --depth-backend run on the photo: give --image PHOTO")
    if args.intrinsics == EXIF and not args.image:
        raise InputFileError("--intrinsics exif reads the photo's EXIF: give --image PHOTO")
    if args.backend_option and not (args.seg_backend or args.depth_backend):
        raise InputFileError(
            "--backend-option sets options of --seg-backend / --depth-backend: give one of them"
        )
    check_backend_options(args.seg_backend, args.depth_backend, parse_backend_options(args.backend_option))


def _camera(args) -> PhotoCamera:
    """The camera of the query: from ``--image``'s EXIF, or from the ``--intrinsics`` file (at ``--width`` x
    ``--height`` when given, else at ``--image``'s size, else ``read_lens``'s size rules:
    ``read_lens_for_photo``, as ``render``). With ``--image`` the file must describe that photo
    (``geometry.io.check_fits_photo``: its size or resized, a principal point near the centre): another
    camera's intrinsics, or an overlay on another photo's pixels, would be wrong silently."""
    if args.intrinsics == EXIF:
        try:
            lens = IntrinsicsFiles(EXIF).photo_camera(Path(args.image), *image_size(args.image))
        except PhotoMissing as exc:  # "the image has no 35 mm-equivalent focal length": which image
            raise PhotoMissing(str(exc) if str(args.image) in str(exc) else f"{args.image}: {exc}") from None
        if lens.source == INTRINSICS_35MM:
            print(f"semcityloc: note: {APPROXIMATE_INTRINSICS_NOTE}", file=sys.stderr)
        return lens
    camera, distortion = read_lens_for_photo(args.intrinsics, args.width, args.height, args.image)
    return PhotoCamera(camera, distortion, str(args.intrinsics))


def _query_inputs(args, lens: PhotoCamera):
    """The mask and the depth, each from its file or its backend (run on the photo, shrunk to
    ``PHOTO_MAX_WIDTH``), checked to show the camera's field of view (any resolution), and resampled onto
    the pinhole camera when the lens distorts."""
    camera = lens.camera
    given = dict(parse_backend_options(args.backend_option))
    options = with_lossy_masks(given, args.seg_backend, args.allow_lossy_mask)
    image = None
    if args.seg_backend or args.depth_backend:
        image = _pinhole_photo(args.image, lens, max_width=PHOTO_MAX_WIDTH)
    name = Path(args.image).name if args.image else None
    orientation = exif_orientation(args.image) if args.image else 1
    if args.semantic:
        labels = read_mask_file(args.semantic, allow_lossy=args.allow_lossy_mask)
        check_aspect_of_photo(labels.shape, camera.width, camera.height, "mask", args.semantic, orientation)
        labels = undistort_image(labels, camera, lens.distortion, fill=IGNORE, nearest=True)
    else:
        labels = get_segmentation_backend(args.seg_backend, **options).predict(image, name=name).labels
        check_aspect(labels.shape, camera.width, camera.height, "mask", name)
        labels = np.where(unseen_by_photo(labels.shape, camera, lens.distortion), IGNORE, labels)
    depth = None
    if args.depth:
        depth = load_depth(args.depth)
        check_aspect_of_photo(depth.shape, camera.width, camera.height, "depth", args.depth, orientation)
        depth = undistort_image(depth, camera, lens.distortion, fill=np.nan, nearest=True)
    elif args.depth_backend:
        depth = get_depth_backend(args.depth_backend, **options).predict(image, name=name).masked()
        check_aspect(depth.shape, camera.width, camera.height, "depth", name)
        depth = np.where(unseen_by_photo(depth.shape, camera, lens.distortion), np.nan, depth)
    return labels, depth


def _pinhole_photo(path, lens: PhotoCamera, max_width: int | None = None) -> np.ndarray:
    """The photo, resampled onto the pinhole camera when the lens distorts."""
    image = load_image(path, max_width=max_width)
    return undistort_image(image, lens.camera, lens.distortion, fill=0, nearest=False)


# What ``localize`` writes into ``--out`` (the overlay only with a pose); checked against its inputs first.
OVERLAY_FILE = "overlay.png"
OUTPUT_FILES = ("pose.json", OVERLAY_FILE)
# What the backends made of the photo, written beside them when a backend ran (``_write_perception``).
MASK_FILE = "mask.png"  # --seg-backend's label map (``io.images.save_labels_png``)
DEPTH_FILES = ("depth.png", "depth.npy")  # --depth-backend's depth (``io.images.save_depth``)


def output_files(args) -> tuple[str, ...]:
    """The files this ``localize`` writes into ``--out``: ``OUTPUT_FILES`` and what its backends made."""
    made = ((MASK_FILE,) if args.seg_backend else ()) + (DEPTH_FILES if args.depth_backend else ())
    return OUTPUT_FILES + made


def remove_unwritten(out: Path, written: tuple[str, ...], inputs: list) -> list[str]:
    """Remove from ``out`` the files of ``OUTPUT_FILES``, ``MASK_FILE`` and ``DEPTH_FILES`` this run does not
    write (``written``): an earlier ``localize`` into the same ``--out`` left them, and beside this run's
    ``pose.json`` they would read as this run's (an old ``mask.png`` after a run with ``--semantic``, an old
    ``overlay.png`` after a refused pose). Only those names, only in ``out``; a file that is one of this
    run's ``inputs`` (``--semantic out/mask.png``) is kept. The names removed."""
    removed = []
    for name in OUTPUT_FILES + (MASK_FILE,) + DEPTH_FILES:
        path = out / name
        if name in written or not path.is_file():
            continue
        if any(value and same_file(value, path) for value in inputs):
            continue
        path.unlink()
        removed.append(name)
    return removed


def _write_perception(args, out: Path, labels: np.ndarray, depth: np.ndarray | None) -> None:
    """The mask and depth the backends made of the photo (on the pinhole camera, at the size the backend
    ran at), so that what the localizer was given can be looked at: ``mask.png``, ``depth.png`` + ``.npy``."""
    if args.seg_backend:
        save_labels_png(labels, out / MASK_FILE)
    if args.depth_backend and depth is not None:
        save_depth(depth, out / DEPTH_FILES[0])


def _inputs(args) -> list:
    """The files ``localize`` reads (None for an option not given)."""
    return [args.prior, args.image, args.semantic, args.depth, args.intrinsics, args.path]


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc localize`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    uncertainty = PriorUncertainty.parse(args.prior_sigma) if args.prior_sigma else None
    config = replace(LocalizerConfig.preset(args.preset).with_ablation(args.method), seed=args.seed)
    config = config.with_map_eaves(args.map_eaves, args.map_eaves_flat)  # checked here, before anything loads
    _check_files(args)
    out = Path(args.out)
    check_outputs(  # ``--prior out/pose.json`` would be replaced by the pose found from it
        [(name, out / name) for name in output_files(args)], _inputs(args)
    )
    if config.no_depth and (args.depth or args.depth_backend):
        print(
            f"semcityloc: warning: --method {args.method} localizes without depth: the depth is not used",
            file=sys.stderr,
        )
    lens = _camera(args)  # before the model loads: intrinsics that do not fit the photo stop at once
    camera = lens.camera
    # the backends' weight files (a missing head, a MoGe-2 model.pt) before the model loads too
    options = parse_backend_options(args.backend_option)
    backend_weight_files(args.seg_backend, args.depth_backend, options)
    for warning in backend_warnings(args.seg_backend, options):  # a head without roof or wall
        print(f"semcityloc: warning: {as_flags(warning)}", file=sys.stderr)
    model = load_model_from_args(args)
    check_model_in_crs(
        model,
        None,
        "leave out --crs (the pose is then written in the model's own frame; `semcityloc run` "
        "takes an --offset that places it)",
    )
    print_model_warnings(model)
    prior_world = read_pose_world(
        args.prior, model.crs, "prior", args.pose_name, photo=photo_name(args.image)
    )
    labels, depth = _query_inputs(args, lens)
    localizer = Localizer(model, config)
    result = localizer.localize(
        camera, model.pose_to_local(prior_world), labels, depth, prior_uncertainty=uncertainty
    )
    for warning in result.warnings:
        print(f"semcityloc: warning: {warning}", file=sys.stderr)

    with writing(folder=out):  # a full disk, a file where the folder goes: one line, naming it
        out.mkdir(parents=True, exist_ok=True)
        drawn = result.pose_local is not None  # the overlay is drawn at a pose found
        written = tuple(n for n in output_files(args) if drawn or n != OVERLAY_FILE)
        remove_unwritten(out, written, _inputs(args))
        _write_perception(args, out, labels, depth)
        return _write_result(args, out, model, localizer, result, config, camera, lens, labels)


def _write_result(args, out: Path, model, localizer, result, config, camera, lens, labels) -> int:
    """``pose.json`` (and with a pose ``overlay.png``) into ``out``, the summary printed; the exit code."""
    crs = crs_label(model.crs)
    record = result.to_dict(model.origin, crs)  # the pose, if any, in CRS coordinates
    # The map searched: its eaves, and whether the pose was found with them on the flat roofs too.
    flat = found_on_flat_eaves(config.map_eaves_flat_roofs, result.search.get("flat_roof_eaves"))
    record["map_eaves"] = {
        "m": config.map_eaves_m,
        "flat_roofs": config.map_eaves_flat_roofs,
        "flat_roofs_used": flat,
    }
    if not lens.distortion.is_zero:
        record["lens_distortion"] = lens.distortion.as_dict()  # the inputs were undistorted with it
    record = as_flags(record)  # its reason and warnings in the command line's words, as printed
    # The camera the pose holds with: the stated one, its focal lengths times focal_scale where the focal
    # check's correction re-found the pose (pose.json's "focal_scale" and extra "intrinsics" then).
    scale = focal_scale_used(result.search or {})
    found = found_camera(camera, scale)
    if scale is not None:
        record.update(intrinsics=found.as_dict(), intrinsics_stated=camera.as_dict())
    if result.pose_local is not None:
        # pose.json: the pose at the top level (read_pose reads it), the whole result record in "extra".
        data = write_pose_json(
            out / "pose.json",
            pose_local=result.pose_local,
            origin_world=model.origin,
            crs=crs,
            extra=record,
            focal_scale=scale,
        )

        scene = localizer.map_of(result).scene  # the map the pose was found on (flat roofs' eaves too?)
        view = NumbaEngine(scene).render(
            found, result.pose_local.R[None], result.pose_local.t[None], depth=True, face_ids=True
        )
        background = (
            _pinhole_photo(args.image, lens)
            if args.image
            else blend_labels(np.zeros(labels.shape + (3,), np.uint8) + 40, labels, alpha=0.8)
        )
        edges = visible_edges(view.face_ids[0], view.depth[0], scene)
        save_rgb(draw_edges(background, edges), out / OVERLAY_FILE)
        summary = {
            "status": result.status,
            "position": data["position"],
            "roll": data["roll"],
            "pitch": data["pitch"],
            "yaw": data["yaw"],
            "crs": data.get("crs"),
            "focal_scale": scale,  # null: the pose holds with the stated focal lengths
            "timings_s": result.timings,
        }
        if "covariance" in record:  # 1-sigma per component (m, deg); the whole matrix is in pose.json
            cov = record["covariance"]
            summary["sigma"] = dict(zip(cov["order"], cov["sigma"], strict=True))
        print(json.dumps(summary))
        return 0
    write_json_atomic(out / "pose.json", record)  # strict JSON: a refused pose's NaN scores are null
    print(json.dumps({"status": result.status, "reason": result.reason}))
    return 1
