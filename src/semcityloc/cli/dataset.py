"""``semcityloc dataset``: look at, overlay, export and benchmark a user's data set; DJI priors.

Sub-commands: ``info`` (queries, frame, prior errors), ``overlay`` (model edges at GT and prior over each
image, PNG), ``benchmark`` (the real-data benchmark, ``benchmark.dataset_source``), ``colmap`` (the data
set's GT or prior poses as a COLMAP model), ``dji-prior`` (a prior pose JSON from a DJI photo).
For ``semcityloc benchmark --dataset PATH --format lodloc [--city MODEL]``, ``cli/benchmark.py`` adds
``add_dataset_arguments(p, positional=False)`` and ``add_perception_arguments(p)`` and hands a run with
``--dataset`` to ``run_dataset_benchmark(args)``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from semcityloc.benchmark.dataset_source import FORMATS, PERCEPTIONS, DatasetSpec
from semcityloc.benchmark.methods import available_methods
from semcityloc.benchmark.perception_sim import SEG_PRESETS
from semcityloc.benchmark.report_tables import summary_markdown
from semcityloc.benchmark.results import is_skipped_miss, unreadable_row
from semcityloc.benchmark.runfiles import writing
from semcityloc.benchmark.scenario import DEFAULT_SCENARIO
from semcityloc.cli.executor import run_from_args
from semcityloc.cli.localize import add_lossy_mask_argument, add_preset_argument, add_prior_sigma_argument
from semcityloc.cli.outputs import check_outputs
from semcityloc.datasets.colmap import MODEL_KINDS, ColmapModel, text_unreadable_names, write_model
from semcityloc.datasets.dji import SOURCE_HEIGHTS, TARGET_HEIGHTS, dji_prior
from semcityloc.datasets.lodloc import FRAMES, read_lodloc
from semcityloc.datasets.overlay import gt_vs_prior_figure, read_image, save_png
from semcityloc.errors import InputFileError, ParameterError, as_flags, counted, shown_names
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose_json import pose_to_dict
from semcityloc.io.files import write_atomic
from semcityloc.render import Renderer


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc dataset`` and its options to the command's parser (called by
    ``cli.main.build_parser``, once per sub-command module).
    """
    ds = sub.add_parser(
        "dataset",
        help="a LoD-Loc data set: info, overlay, benchmark, colmap export; dji-prior: a DJI photo's prior",
    )
    ds_sub = ds.add_subparsers(dest="dataset_command", required=True, metavar="ACTION")

    info = ds_sub.add_parser("info", help="queries, model, frame and prior errors of a data set")
    add_dataset_arguments(info)
    info.add_argument("--json", action="store_true", help="print exactly one JSON object")
    info.set_defaults(func=run_info)

    overlay = ds_sub.add_parser("overlay", help="PNG per query: model edges at the GT pose and at the prior")
    add_dataset_arguments(overlay)
    overlay.add_argument("--out", required=True, help="output folder for <stem>_gt_vs_prior.png")
    overlay.add_argument("--name", default=None, help="only this image (file name or stem)")
    overlay.set_defaults(func=run_overlay)

    bench = ds_sub.add_parser("benchmark", help="localize every query of the data set and score it")
    add_dataset_arguments(bench)
    add_dataset_benchmark_arguments(bench)
    bench.set_defaults(func=run_dataset_benchmark)

    colmap = ds_sub.add_parser("colmap", help="write the data set's GT or prior poses as a COLMAP model")
    add_dataset_arguments(colmap)
    colmap.add_argument("--out", required=True, help="output model folder")
    colmap.add_argument(
        "--poses", choices=("gt", "prior"), default="gt", help="which poses (default %(default)s)"
    )
    colmap.add_argument("--binary", action="store_true", help="write .bin files (default .txt)")
    colmap.set_defaults(func=run_colmap)

    dji = ds_sub.add_parser("dji-prior", help="prior pose JSON from a DJI photo's GPS and gimbal angles")
    dji.add_argument("image", help="an original DJI photo (EXIF + XMP)")
    dji.add_argument("--crs", required=True, help="the city model's CRS, e.g. EPSG:25832 or EPSG:25832+7837")
    dji.add_argument("--offset", default=None, help="x,y,z subtracted from the CRS coordinates")
    dji.add_argument(
        "--source-height",
        default="auto",
        choices=SOURCE_HEIGHTS,
        help="what the photo's AbsoluteAltitude is (auto: WGS 84 ellipsoidal on an RTK aircraft, else "
        "barometric, flagged as tens of metres uncertain; default %(default)s)",
    )
    dji.add_argument(
        "--target-height",
        default="auto",
        choices=TARGET_HEIGHTS,
        help="what the model's z is (auto: orthometric when --crs has a vertical datum or "
        "--geoid-separation is given, else the source's; orthometric: EGM96 for a 2D CRS; "
        "default %(default)s)",
    )
    dji.add_argument("--geoid-separation", type=float, default=None, help="known geoid undulation N (m)")
    dji.add_argument("--out", default=None, help="write the pose JSON here (default: print it)")
    dji.set_defaults(func=run_dji_prior)


def add_dataset_arguments(p: argparse.ArgumentParser, positional: bool = True) -> None:
    """Where the data set is and how to read it (``positional``: ``PATH``, else ``--dataset``)."""
    if positional:
        p.add_argument("dataset", help="LoD-Loc scene folder or a folder of scenes")
    else:
        p.add_argument(
            "--dataset", default=None, help="a real data set (LoD-Loc layout) instead of simulation"
        )
    p.add_argument("--format", default="lodloc", choices=FORMATS, help="data set layout (default lodloc)")
    if positional:  # ``semcityloc benchmark`` has its own --city
        p.add_argument("--city", default=None, help="the LoD model (default: the *.obj beside the data set)")
    p.add_argument("--split", default=None, help="LoD-Loc split JSON: keep only its images")
    p.add_argument("--stage", default=None, help="split stage (default val)")
    p.add_argument(
        "--frame",
        default="auto",
        choices=FRAMES,
        help="auto: test the model; ecef: Swiss-EPFL's shifted-ECEF frame (rotated into ENU)",
    )
    p.add_argument("--ecef-origin", default=None, help="lat,lon,h of the ECEF origin (default Swiss-EPFL's)")


def add_perception_arguments(p: argparse.ArgumentParser) -> None:
    """The real-data benchmark's perception options (none of them exists in ``semcityloc benchmark``)."""
    p.add_argument(
        "--perception",
        default="oracle",
        choices=PERCEPTIONS,
        help="oracle: labels at the GT pose; oracle-degraded: them through --seg-quality; masks: --masks",
    )
    p.add_argument(
        "--masks", default=None, help="folder of <stem>.png / .npy label masks (--perception masks)"
    )
    add_lossy_mask_argument(p)
    p.add_argument("--depth", default=None, help="folder of <stem>.npy / .png relative depth (optional)")


def real_data_defaults() -> dict[str, object]:
    """``{dest: default}`` of the options ``semcityloc benchmark`` takes for a real data set only
    (``add_dataset_arguments`` without the positional path, ``add_perception_arguments``), read off the
    parser that defines them, so that a simulated run can tell which of them were given."""
    p = argparse.ArgumentParser(add_help=False)
    add_dataset_arguments(p, positional=False)
    add_perception_arguments(p)
    return {a.dest: a.default for a in p._actions if a.dest != "dataset"}


def add_dataset_benchmark_arguments(p: argparse.ArgumentParser) -> None:
    """All options of ``semcityloc dataset benchmark`` after the data set ones."""
    add_perception_arguments(p)
    p.add_argument(
        "--seg-quality",
        default="trained",
        choices=tuple(SEG_PRESETS),
        help="segmentation preset of oracle-degraded",
    )
    p.add_argument("--method", default="semcityloc", choices=available_methods(), help="a benchmark method")
    add_preset_argument(p, default=None)
    add_prior_sigma_argument(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the degraded segmentation")
    p.add_argument("--keep-details", type=int, default=3, help="save details of the first N queries")
    p.add_argument("--out", default="benchmark_output", help="output folder (default benchmark_output)")
    p.add_argument("--workers", type=int, default=1, help="processes localizing in parallel (default 1)")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="start the run again: delete the results in --out (needed when made with other arguments)",
    )
    p.add_argument(
        "--stop-after", type=int, default=None, metavar="N", help="localize at most N more queries"
    )


def parse_floats(text: str | None, n: int, what: str) -> tuple[float, ...] | None:
    """``n`` comma-separated finite numbers from an option's text (None: None); an ``InputFileError`` naming
    ``what`` otherwise.
    """
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise InputFileError(f"{what} must be {n} comma-separated numbers, got {text!r}") from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise InputFileError(f"{what} must be {n} finite comma-separated numbers, got {text!r}")
    return values


def _dataset(args: argparse.Namespace):
    return read_lodloc(
        args.dataset,
        city=args.city,
        split=args.split,
        stage=args.stage,
        frame=args.frame,
        ecef_origin_llh=parse_floats(args.ecef_origin, 3, "--ecef-origin"),
    )


def run_info(args: argparse.Namespace) -> int:
    """Run ``semcityloc dataset info`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    ds = _dataset(args)
    model = ds.load_model() if ds.model_path is not None else None
    rows = []
    for q in ds.queries:
        far = q.far_pose(model) if model is not None else None
        if far is not None:  # a pose in another CRS: its prior error below is the CRSs' distance
            ds.warnings.append(far)
        row = {"name": q.name, "scene": q.scene, "camera": q.camera.as_dict()}
        row["gt"] = q.gt_pose_world is not None
        row["prior"] = q.prior_pose_world is not None
        if q.gt_pose_world is not None and q.prior_pose_world is not None:
            row["prior_err_m"] = float(center_error_m(q.prior_pose_world, q.gt_pose_world))
            row["prior_rot_deg"] = float(rotation_error_deg(q.prior_pose_world, q.gt_pose_world))
        rows.append(row)
    info = {
        "root": str(ds.root),
        "queries": len(ds.queries),
        "model": str(ds.model_path) if ds.model_path else None,
        "frame": ds.frame,
        "frame_note": ds.frame_note,
        "warnings": ds.warnings,
        "images": rows,
    }
    if args.json:
        print(json.dumps(info))
        return 0
    print(f"data set:  {info['root']}\nqueries:   {info['queries']}\nmodel:     {info['model']}")
    print(f"frame:     {ds.frame} ({ds.frame_note})")
    for w in ds.warnings:
        print(f"warning:   {w}")
    for r in rows[:20]:
        err = (
            f"prior {r['prior_err_m']:.2f} m / {r['prior_rot_deg']:.2f} deg"
            if "prior_err_m" in r
            else "no GT/prior"
        )
        print(f"  {r['name']}  {r['camera']['width']}x{r['camera']['height']}  {err}")
    if len(rows) > 20:
        print(f"  ... {len(rows) - 20} more")
    return 0


def run_overlay(args: argparse.Namespace) -> int:
    """Run ``semcityloc dataset overlay`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    ds = _dataset(args)
    queries = [ds.query(args.name)] if args.name else ds.queries
    out = Path(args.out)
    check_outputs(  # two scenes' queries of one stem would write one file; an input is never overwritten
        [(f"{q.scene}/{q.name}" if q.scene else q.name, out / f"{q.stem}_gt_vs_prior.png") for q in queries],
        [ds.model_path, *(q.image_path for q in queries)],
    )
    model = ds.load_model()
    renderer = Renderer(model, engine="numba")
    written = 0
    for q in queries:
        if q.image_path is None or q.gt_pose_world is None or q.prior_pose_world is None:
            print(f"skipped {q.name}: needs the image, a GT pose and a prior")
            continue
        far = q.far_pose(model)
        if far is not None:  # a pose in another CRS: said in its file's words, the others drawn
            print(f"semcityloc: warning: skipped {far}", file=sys.stderr)
            continue
        image = read_image(q.image_path)
        figure = gt_vs_prior_figure(image, model, q.camera, q.gt_pose_world, q.prior_pose_world, renderer)
        path = save_png(figure, out / f"{q.stem}_gt_vs_prior.png")
        print(f"wrote {path}")
        written += 1
    return 0 if written else 2


def run_colmap(args: argparse.Namespace) -> int:
    """Run ``semcityloc dataset colmap`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    ds = _dataset(args)
    entries = {}
    for q in ds.queries:
        pose = q.gt_pose_world if args.poses == "gt" else q.prior_pose_world
        if pose is not None:
            entries[q.name] = (q.camera, pose)
    if not entries:
        raise InputFileError(f"{ds.root}: no query has a {args.poses} pose")
    unreadable = [] if args.binary else text_unreadable_names(entries)
    if unreadable:  # COLMAP would read them back as other names (up to their first space)
        print(
            f"semcityloc: warning: {counted(len(unreadable), 'image')} left out of images.txt (COLMAP's text "
            f"reader cuts a name at its first space): {shown_names(unreadable)}; --binary keeps them",
            file=sys.stderr,
        )
        entries = {name: entry for name, entry in entries.items() if name not in unreadable}
    ext = ".bin" if args.binary else ".txt"
    out = Path(args.out)
    check_outputs(
        [(kind, out / f"{kind}{ext}") for kind in MODEL_KINDS],
        [ds.model_path, args.split, *(q.image_path for q in ds.queries)],
    )
    folder = write_model(ColmapModel.from_poses(entries), out, ext=ext)
    print(f"wrote {len(entries)} {args.poses} poses to {folder}")
    return 0


def run_dji_prior(args: argparse.Namespace) -> int:
    """Run ``semcityloc dataset dji-prior`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    offset = parse_floats(args.offset, 3, "--offset")
    if args.out:  # ``--out DJI_0001.JPG`` would replace the photo by its prior
        check_outputs([(args.image, Path(args.out))], [args.image])
    prior = dji_prior(
        args.image,
        args.crs,
        offset=None if offset is None else np.array(offset),
        source_height=args.source_height,
        target_height=args.target_height,
        geoid_separation_m=args.geoid_separation,
    )
    # With an offset the position is the CRS's minus it: frame crs_offset, no CRS label on the numbers (a
    # reader would take them for CRS coordinates).
    data = as_flags(
        pose_to_dict(pose_world=prior.pose, crs=prior.crs, crs_offset=prior.offset, extra=prior.as_dict())
    )
    text = json.dumps(data, indent=2)
    if args.out:
        with writing(args.out):  # whole or not at all; a failure is one line
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            write_atomic(Path(args.out), text + "\n")
        print(f"wrote {args.out}")
    else:
        print(text)
    if prior.vertical_flag:
        print(f"semcityloc: warning: {prior.vertical_flag}", file=sys.stderr)
    return 0


def warn_unreadable(rows: list[dict[str, str]], config: dict) -> None:
    """One line on stderr per query whose input files could not be read (``results.REASON_UNREADABLE``) or
    that was skipped (``results.REASON_SKIPPED_MISS``: a pose far from the model, ``LodLocQuery.far_pose``):
    the run went on without it, and the recall counts it as a miss."""
    for row in sorted(rows, key=lambda r: int(r["index"])):
        if unreadable_row(row) or is_skipped_miss(row.get("reason")):
            name = config["query_names"][int(row["index"])]
            line = f"semcityloc: warning: {row['query_id']} ({name}) is a miss: {row['reason']}"
            print(line, file=sys.stderr)


# Options of a simulated benchmark that a data-set run has no use for, with their defaults
# (``cli.benchmark.add_simulation_arguments``): given, they were ignored without a word.
SIMULATION_ONLY = {
    "queries": ("--queries", 100),
    "settings": ("--set", []),
    "scenario": ("--scenario", DEFAULT_SCENARIO),
    "prior_extra": ("--prior-extra", None),
    "lod": ("--lod", None),
}


def check_dataset_options(args: argparse.Namespace) -> None:
    """``ParameterError`` naming the simulation-only options given to a data-set run (its queries are its
    images, its perception ``--perception``'s), and ``--seg-quality`` without ``oracle-degraded``."""
    given = [
        flag for key, (flag, default) in SIMULATION_ONLY.items() if getattr(args, key, default) != default
    ]
    if getattr(args, "seg_quality", "trained") != "trained" and args.perception != "oracle-degraded":
        given.append("--seg-quality (only with --perception oracle-degraded)")
    if given:
        raise ParameterError(
            f"{', '.join(given)}: options of a simulated benchmark, not of a data set's (--dataset), whose "
            "queries are its images; leave them out"
        )


def run_dataset_benchmark(args: argparse.Namespace) -> int:
    """Run ``semcityloc dataset benchmark`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    check_dataset_options(args)
    if args.ecef_origin is not None and args.frame != "ecef":
        raise InputFileError("--ecef-origin needs --frame ecef")
    spec = DatasetSpec(
        dataset=args.dataset,
        format=args.format,
        city=args.city,
        perception=args.perception,
        masks=args.masks,
        allow_lossy_mask=args.allow_lossy_mask,
        depth=args.depth,
        seg_quality=args.seg_quality,
        method=args.method,
        preset=args.preset or "default",
        prior_sigma=args.prior_sigma,
        seed=args.seed,
        split=args.split,
        stage=args.stage,
        frame=args.frame,
        ecef_origin_llh=parse_floats(args.ecef_origin, 3, "--ecef-origin"),
        keep_details=args.keep_details,
    )
    outcome = run_from_args(spec, args.out, args)
    out = Path(args.out)
    warn_unreadable(outcome.rows, outcome.config)
    if not outcome.complete:
        total = counted(outcome.config["queries"], "query")
        print(f"{len(outcome.rows)}/{total} done in {out}; run again to continue")
        return 0
    label = f"{args.method} [{outcome.summary['perception_label']}]"
    print(summary_markdown([outcome.summary], [label]))
    for note in outcome.summary.get("notes", []):  # rows of an earlier version (``DatasetSpec.finish``)
        print(f"semcityloc: note: {note}", file=sys.stderr)
    print(f"wrote {out / 'results.csv'} and {out / 'summary.json'}")
    return 0
