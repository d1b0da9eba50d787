"""``semcityloc tiles build|info``: index a folder of CityGML / CityJSON tiles into a store
(``citymodel.tiles``; docs/scale.md), which every ``--city`` then accepts."""

from __future__ import annotations

import argparse
import json
import sys

from semcityloc.citymodel.tiles import TileStore, build_store
from semcityloc.cli.city import LOD_HELP, parse_lod
from semcityloc.errors import counted, shown_names

SHOWN_SKIPPED = 10  # tiles left out named one per line; the rest counted


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc tiles`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    tiles = sub.add_parser("tiles", help="index a folder of city-model tiles into a store for --city")
    tiles_sub = tiles.add_subparsers(dest="tiles_command", required=True, metavar="ACTION")
    build = tiles_sub.add_parser("build", help="index a folder of CityGML / CityJSON tiles into a store")
    build.add_argument("folder", help="folder of tiles (searched recursively; formats may be mixed)")
    build.add_argument("--out", required=True, help="the store's folder")
    build.add_argument("--lod", default=None, help=LOD_HELP)
    build.add_argument("--crs", default=None, help="override the tiles' CRS, e.g. EPSG:25832")
    build.add_argument(
        "--overwrite", action="store_true", help="replace the store already in --out (default: refuse)"
    )
    build.set_defaults(func=run_build)
    info = tiles_sub.add_parser("info", help="tiles, buildings, CRS, origin and extent of a store")
    info.add_argument("store", help="a store made by 'semcityloc tiles build'")
    info.add_argument("--json", action="store_true", help="print exactly one JSON object")
    info.set_defaults(func=run_info)


def run_build(args: argparse.Namespace) -> int:
    """Run ``semcityloc tiles build`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """

    shown = []

    def progress(message: str) -> None:
        shown.append(True)
        print(f"\r{message[:100]:<100}", end="", file=sys.stderr, flush=True)

    try:
        report = build_store(
            args.folder,
            args.out,
            lod=parse_lod(args.lod),
            crs=args.crs,
            progress=progress,
            overwrite=args.overwrite,
        )
    finally:  # the progress line ends, whatever ends the build (an error, a Ctrl-C: their line follows)
        if shown:
            print(file=sys.stderr)
    for why in list(report.skipped.values())[:SHOWN_SKIPPED]:
        print(f"semcityloc: warning: tile left out: {why}", file=sys.stderr)
    if len(report.skipped) > SHOWN_SKIPPED:
        print(
            f"semcityloc: warning: {counted(len(report.skipped) - SHOWN_SKIPPED, 'more tile')} left out "
            f"(all named in {report.store.root}/store.json, skipped_tiles)",
            file=sys.stderr,
        )
    for warning in report.warnings:
        print(f"semcityloc: warning: {warning}", file=sys.stderr)
    print(
        f"{counted(report.tiles, 'tile')}, {counted(report.buildings, 'building')}, "
        f"{report.input_bytes / 1e6:.1f} MB in "
        f"{report.seconds:.1f} s ({report.mb_per_s:.2f} MB/s): wrote {report.store.root}"
        + (
            f"; {counted(len(report.skipped), 'tile')} left out (store.json, skipped_tiles)"
            if report.skipped
            else ""
        )
    )
    return 0


def run_info(args: argparse.Namespace) -> int:
    """Run ``semcityloc tiles info`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    summary = TileStore.open(args.store).summary()
    if args.json:
        print(json.dumps(summary))
        return 0
    width = max(len(key) for key in summary) + 2
    for key, value in summary.items():
        if key == "lod" and value is None:
            value = "each building's highest"
        elif key == "lods" and value is None:
            value = "not recorded (built before stop 56)"
        elif key == "skipped_tiles":
            value = f"{len(value)} ({shown_names(value)})" if value else 0
        elif isinstance(value, list) and key in ("lods", "formats"):
            value = ", ".join(map(str, value))
        print(f"{key + ':':<{width}}{value}")
    return 0
