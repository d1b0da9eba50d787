"""``semcityloc city info|convert``: inspect and convert city models."""

from __future__ import annotations

import argparse
import json

from semcityloc.citymodel.export import export_model
from semcityloc.citymodel.generator import default_city_path
from semcityloc.citymodel.tiles import load_city


def register(sub: argparse._SubParsersAction) -> None:
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
    p.add_argument("--lod", default=None, help="LoD to read (default: the highest per building)")
    p.add_argument("--crs", default=None, help="override the file's CRS, e.g. EPSG:25832")
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="compute again instead of using the caches (parsed city models; photo runs: focal estimates)",
    )


def load_model_from_args(args: argparse.Namespace):
    """The ``CityModel`` named by ``add_model_arguments`` options (``generated`` = the embedded city)."""
    lod = args.lod
    if lod is not None and str(lod).isdigit():
        lod = int(lod)
    path = args.path
    if path == "generated":
        path = default_city_path(lod=lod if isinstance(lod, int) else 2)
    return load_city(path, lod=lod, crs=args.crs, cache=not args.no_cache)


_load = load_model_from_args


def run_info(args: argparse.Namespace) -> int:
    summary = _load(args).summary()
    if args.json:
        print(json.dumps(summary))
        return 0
    print(format_summary(summary))
    return 0


def format_summary(s: dict) -> str:
    dx, dy, dz = s["extent_m"]
    lines = [
        f"source:     {s['source']}",
        f"buildings:  {s['buildings']}",
        f"triangles:  {s['triangles']}",
        f"CRS:        {s['crs'] or 'none (local metric frame)'}"
        + (f"  (file: {s['source_crs']})" if s["source_crs"] != s["crs"] else ""),
        f"LoDs:       {', '.join(map(str, s['lods']))}",
        f"extent:     {dx:.1f} x {dy:.1f} x {dz:.1f} m",
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
    return "\n".join(lines)


def run_convert(args: argparse.Namespace) -> int:
    model = _load(args)
    out = export_model(model, args.out)
    print(f"wrote {out} ({model.num_triangles} triangles)")
    return 0
