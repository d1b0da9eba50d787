"""``semcityloc city info|convert``: inspect and convert city models."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from semcityloc.benchmark.runfiles import writing
from semcityloc.citymodel.cityjson import lod_key
from semcityloc.citymodel.export import export_model, export_paths
from semcityloc.citymodel.generator import default_city_path
from semcityloc.citymodel.model import CityModel
from semcityloc.citymodel.tiles import load_city
from semcityloc.cli.outputs import check_outputs
from semcityloc.errors import ParameterError


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc city`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    city = sub.add_parser("city", help="inspect or convert a city model")
    city_sub = city.add_subparsers(dest="city_command", required=True, metavar="ACTION")

    info = city_sub.add_parser("info", help="buildings, triangles, classes, CRS, LoDs and extent")
    _common(info)
    info.add_argument("--json", action="store_true", help="print exactly one JSON object")
    info.set_defaults(func=run_info)

    convert = city_sub.add_parser("convert", help="write the semantic mesh as .ply, .obj or .npz")
    _common(convert)
    convert.add_argument("out", help="output file: .ply (face class property), .obj (+.mtl) or .npz")
    convert.set_defaults(func=run_convert)


def _common(p: argparse.ArgumentParser) -> None:
    add_model_arguments(p, positional=True)


LOD_HELP = "LoD to read: 0 to 4 (CityJSON also a refinement, e.g. 2.2; default: the highest per building)"


def add_model_arguments(p: argparse.ArgumentParser, positional: bool) -> None:
    """The city-model options every command shares: the file (``PATH`` or ``--city``), LoD, CRS, cache."""
    help_text = (
        "CityGML (1.0/2.0/3.0), CityJSON, OBJ, semcityloc .npz, a tile store (semcityloc tiles build), "
        "or 'generated' (embedded city)"
    )
    if positional:
        p.add_argument("path", help=help_text)
    else:
        p.add_argument("--city", dest="path", required=True, help=help_text)
    p.add_argument("--lod", default=None, help=LOD_HELP)
    p.add_argument("--crs", default=None, help="override the file's CRS, e.g. EPSG:25832")
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="compute again instead of using the caches (parsed city models; photo runs: focal estimates)",
    )


def parse_lod(text: str | None) -> int | str | None:
    """``--lod``'s value for the readers: None, a whole number as an int (``"2"`` -> 2), or a CityJSON
    refinement as written (``"2.2"``: the CityGML reader refuses it, ``citygml_lod_choice.citygml_lod``).

    Anything that is no LoD (``foo``, ``-1``, ``7``) is a ``ParameterError`` here, for every format, before
    a file is read (it was a ``TypeError`` traceback from the CityGML reader)."""
    if text is None:
        return None
    stripped = str(text).strip()
    if stripped.isdigit() and int(stripped) <= 4:
        return int(stripped)
    if lod_key(stripped) is None:
        raise ParameterError(
            f"--lod {text!r} is not a LoD: give a whole number 0 to 4 (a CityJSON file also takes a "
            "refinement such as 2.2)"
        )
    return stripped


def load_model_from_args(args: argparse.Namespace):
    """The ``CityModel`` named by ``add_model_arguments`` options (``generated`` = the embedded city)."""
    lod = parse_lod(args.lod)
    path = args.path
    if path == "generated":
        path = default_city_path(lod=lod if isinstance(lod, int) else 2)
    return load_city(path, lod=lod, crs=args.crs, cache=not args.no_cache)


def print_model_warnings(model: CityModel) -> None:
    """The reader's warnings about ``model`` (polygons it skipped, a CRS it did not find), once each on
    stderr, for the commands that localize against it (``localize``, ``run``): a dropped roof or a
    model in degrees taken as metres changes every pose, so it must not pass without a word.
    ``city info`` shows them in its summary instead (``format_summary``, ``--json``)."""
    for warning in model.stats.warnings:
        print(f"semcityloc: warning: {Path(model.source).name or 'city model'}: {warning}", file=sys.stderr)


_load = load_model_from_args


def run_info(args: argparse.Namespace) -> int:
    """Run ``semcityloc city info`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    summary = _load(args).summary()
    if args.json:
        print(json.dumps(summary))
        return 0
    print(format_summary(summary))
    return 0


def _bounds_lines(bounds: list | None) -> list[str]:
    """``city info``'s line of the model's world bounding box (its z range too), none for an empty one."""
    if not bounds:
        return []
    (x0, y0, z0), (x1, y1, z1) = bounds
    return [f"bounds:     x {x0:.1f} .. {x1:.1f}, y {y0:.1f} .. {y1:.1f}, z {z0:.1f} .. {z1:.1f} (world)"]


def format_summary(s: dict) -> str:
    """``city info``'s text: a model summary (source, buildings, triangles, CRS, LoDs, extent, the local
    frame's origin, its world bounding box, per-class triangles and areas, skipped polygons, warnings) as
    aligned lines.
    """
    dx, dy, dz = s["extent_m"]
    lines = [
        f"source:     {s['source']}",
        f"buildings:  {s['buildings']}",
        f"triangles:  {s['triangles']}",
        f"CRS:        {s['crs'] or 'none (local metric frame)'}"
        + (f"  (file: {s['source_crs']})" if s["source_crs"] != s["crs"] else ""),
        f"LoDs:       {', '.join(map(str, s['lods']))}",
        f"extent:     {dx:.1f} x {dy:.1f} x {dz:.1f} m",
        "origin:     " + " ".join(f"{v:.3f}" for v in s["origin"]) + "  (world = origin + local)",
        *_bounds_lines(s.get("bounds_world")),
        "classes:    name        triangles       area m2",
    ]
    for name, count in s["class_triangles"].items():
        if count:
            lines.append(f"            {name:<10} {count:>10} {s['class_area_m2'][name]:>13.1f}")
    skipped = {k: v for k, v in s["skipped"].items() if v}
    if skipped:
        lines.append("skipped:    " + ", ".join(f"{k}={v}" for k, v in skipped.items()))
    if s["classified_by_normal"]:
        lines.append(f"classified by normals: {s['classified_by_normal']} polygons without semantics")
    lines += [f"warning:    {w}" for w in s.get("warnings", [])]
    return "\n".join(lines)


def run_convert(args: argparse.Namespace) -> int:
    """Run ``semcityloc city convert`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    check_outputs([(args.path, path) for path in export_paths(args.out)], [args.path], flag="OUT")
    model = _load(args)
    with writing(folder=Path(args.out).parent):  # a full disk, a folder in its place: one line, naming it
        out = export_model(model, args.out)
    print(f"wrote {out} ({model.num_triangles} triangles)")
    return 0
