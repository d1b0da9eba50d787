"""``semcityloc demo``: the README's main job, end to end on the embedded generated city.

1. Generate the procedural district (CityGML 2.0, LoD1/LoD2/LoD3 from one set of footprints).
2. Benchmark: simulated UAV queries in the ``realistic`` scenario (``benchmark.scenario``: an LoD3
   reality that differs from the map, trees, cars, structured segmentation errors at the trained quality,
   non-affine relative depth, GNSS/IMU priors with height errors up to ±30 m) localized against the LoD2
   map by the full method and, for contrast, its coarse-only ablation and the LoD-Loc-style wireframe
   baseline. Resumable. ``--scenario clean`` runs the first, easy benchmark instead.
3. Report: the Markdown/CSV tables and the figures (error curves, overlays, cost-volume slices), and the
   interactive page ``report/report.html`` (``benchmark.report_html``; every query's details are kept
   so its query browser shows each query's mask and cost volume).

``--city PATH`` runs the same on any CityGML/CityJSON file instead of the generated district.

Nothing is written before every run is known to be accepted: the city is generated into a temporary
folder first, and ``OUT/city`` is replaced only when no finished run of ``OUT`` was made on the city there
(else refused, naming the runs: ``--overwrite`` starts them again on the new city, or choose another
``--out``); each run's arguments are checked as ``benchmark`` resumes them (``runfiles.check_resumable``)
before the first run starts.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import tempfile
from pathlib import Path

from semcityloc.benchmark.methods import available_methods, check_method
from semcityloc.benchmark.report import make_report
from semcityloc.benchmark.report_html import make_html_report
from semcityloc.benchmark.report_tables import summary_markdown
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.runfiles import RUN_FILE, check_resumable
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.citymodel.generator import generate_city
from semcityloc.errors import BenchmarkError, ResumeMismatchError, counted, parameter
from semcityloc.io.stamps import file_sha256


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc demo`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    p = sub.add_parser(
        "demo", help="generate a city, benchmark the localizer on it, write tables and figures"
    )
    p.add_argument("--out", default="demo_output", help="output folder (default %(default)s)")
    p.add_argument("--city", default="generated", help="city model file (default: the generated city)")
    p.add_argument("--queries", type=int, default=20, help="simulated queries per method (default 20)")
    p.add_argument(
        "--seed", type=int, default=0, help="seed of the city and the queries (default %(default)s)"
    )
    p.add_argument(
        "--scenario", default="realistic", choices=("realistic", "clean"), help="simulation scenario"
    )
    p.add_argument(
        "--methods",
        default="semcityloc,no-refine,lodloc-wireframe",
        help="comma-separated benchmark methods (default %(default)s)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="start the demo again: its runs in --out are deleted and run anew (needed when made with other "
        "arguments)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc demo`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    # Every method checked before the first one runs (a typo in the last one cost the others' minutes);
    # a method named twice is run once
    methods = list(dict.fromkeys(check_method(m.strip()) for m in args.methods.split(",") if m.strip()))
    if not methods:
        raise BenchmarkError(f"--methods names no method; known: {', '.join(available_methods())}")
    if args.queries < 1:  # before the city is generated; the words of BenchmarkSpec's own check
        raise BenchmarkError(f"the number of queries must be >= 1, got {args.queries}")
    out = Path(args.out)
    query = query_config(args.scenario, queries=args.queries, seed=args.seed)
    specs = [BenchmarkSpec(city=args.city, query=query, method=m, keep_details=args.queries) for m in methods]
    run_dirs = [out / f"run_{method}" for method in methods]
    if args.city == "generated":
        city = _generate_city(out / "city", args.seed, run_dirs, args.overwrite)
        specs = [dataclasses.replace(spec, city=city) for spec in specs]
    if not args.overwrite:
        for spec, run_dir in zip(specs, run_dirs, strict=True):
            check_resumable(run_dir, spec.run_config())
    summaries, labels = [], []
    for spec, run_dir in zip(specs, run_dirs, strict=True):
        outcome = run_benchmark(spec, run_dir, overwrite=args.overwrite, progress=True)
        summaries.append(outcome.summary)
        labels.append(spec.method)
    print()
    print(summary_markdown(summaries, labels))
    report = make_report(run_dirs, out / "report", overlays=2)
    print(f"\nreport: {report.markdown} ({len(report.plots)} figures in {report.out_dir / 'plots'})")
    page = make_html_report(run_dirs, report.out_dir, [md for md, _ in report.tables.values()], report.notes)
    size_mb = page.path.stat().st_size / 1e6
    print(f"interactive report: {page.path.resolve()} ({size_mb:.1f} MB; open it in a browser)")
    return 0


def _generate_city(folder: Path, seed: int, run_dirs: list[Path], overwrite: bool) -> str:
    """Generate the demo's city into ``folder`` (its LoD2 file's path), or keep the one there when it is
    the same; a city that would change under finished runs of ``run_dirs`` is refused unless ``overwrite``,
    before anything is written (the city is generated into a temporary folder first)."""
    with tempfile.TemporaryDirectory(prefix="semcityloc-demo-") as tmp:
        made = generate_city(tmp, seed=seed)
        kept = {lod: folder / p.name for lod, p in made.items()}
        same = all(
            kept[lod].is_file() and file_sha256(kept[lod]) == file_sha256(p) for lod, p in made.items()
        )
        if not same:
            runs = [d for d in run_dirs if (d / RUN_FILE).exists()]
            if runs and not overwrite:
                names = ", ".join(d.name for d in runs)
                raise ResumeMismatchError(
                    f"{folder.parent} holds {counted(len(runs), 'demo run')} ({names}) made on another city "
                    f"than the one --seed {seed} generates; pass {parameter('overwrite')} to run them again "
                    f"on it, or choose another {parameter('out_dir')}"
                )
            folder.mkdir(parents=True, exist_ok=True)
            for lod, path in made.items():
                shutil.move(str(path), kept[lod])
    print(f"generated city: {', '.join(str(p) for p in kept.values())}")
    return str(kept[2])
