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
"""

from __future__ import annotations

import argparse
from pathlib import Path

from semcityloc.benchmark.methods import available_methods, check_method
from semcityloc.benchmark.report import make_report
from semcityloc.benchmark.report_html import make_html_report
from semcityloc.benchmark.report_tables import summary_markdown
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.citymodel.generator import generate_city
from semcityloc.errors import BenchmarkError


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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc demo`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    # Every method checked before the first one runs (a typo in the last one cost the others' minutes)
    methods = [check_method(m.strip()) for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise BenchmarkError(f"--methods names no method; known: {', '.join(available_methods())}")
    out = Path(args.out)
    city = args.city
    if city == "generated":
        paths = generate_city(out / "city", seed=args.seed)
        city = str(paths[2])
        print(f"generated city: {', '.join(str(p) for p in paths.values())}")
    run_dirs, summaries, labels = [], [], []
    for method in methods:
        spec = BenchmarkSpec(
            city=city,
            query=query_config(args.scenario, queries=args.queries, seed=args.seed),
            method=method,
            keep_details=args.queries,
        )
        outcome = run_benchmark(spec, out / f"run_{method}", progress=True)
        run_dirs.append(outcome.out_dir)
        summaries.append(outcome.summary)
        labels.append(method)
    print()
    print(summary_markdown(summaries, labels))
    report = make_report(run_dirs, out / "report", overlays=2)
    print(f"\nreport: {report.markdown} ({len(report.plots)} figures in {report.out_dir / 'plots'})")
    page = make_html_report(run_dirs, report.out_dir, [md for md, _ in report.tables.values()], report.notes)
    size_mb = page.path.stat().st_size / 1e6
    print(f"interactive report: {page.path.resolve()} ({size_mb:.1f} MB; open it in a browser)")
    return 0
