"""``semcityloc demo``: the README's main job on the embedded default data (the generated city)."""

from __future__ import annotations

import argparse
from pathlib import Path

from semcityloc.cli.city import format_summary


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on the embedded generated city")
    p.add_argument("--out", default="demo_output", help="output folder")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from semcityloc.citymodel.generator import generate_city
    from semcityloc.citymodel.io import load_city_model

    out = Path(args.out)
    paths = generate_city(out / "city", seed=args.seed)
    for lod, path in sorted(paths.items()):
        model = load_city_model(path, cache=False)
        print(f"== generated LoD{lod} city: {path}")
        print(format_summary(model.summary()))
    return 0
