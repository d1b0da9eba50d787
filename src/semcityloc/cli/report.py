"""``semcityloc report DIR...``: the paper's tables (Markdown + CSV) and plots from benchmark runs, and the
interactive page ``report.html`` (``benchmark.report_html``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from semcityloc.benchmark.report import make_report
from semcityloc.benchmark.report_html import make_html_report
from semcityloc.benchmark.runfiles import REPORT_DIR
from semcityloc.errors import BenchmarkError


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc report`` and its options to the command's parser (called by ``cli.main.build_parser``,
    once per sub-command module).
    """
    p = sub.add_parser("report", help="tables and plots from one or more benchmark output folders")
    p.add_argument("runs", nargs="+", metavar="DIR", help="folders written by 'semcityloc benchmark'")
    p.add_argument(
        "--out",
        default=None,
        help="output folder (default: DIR/report for one run, as a run's closing hint says; "
        "./benchmark_report for several); an earlier report's files there are replaced, other files kept",
    )
    p.add_argument(
        "--overlays",
        type=int,
        default=2,
        help="query figures (overlays and cost-volume slices) per run (default 2)",
    )
    p.add_argument("--no-html", action="store_true", help="do not write the interactive report.html")
    p.add_argument(
        "--html-queries",
        type=int,
        default=None,
        metavar="N",
        help="queries per run in report.html's query browser (default: all)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc report`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    if args.overlays < 0:
        raise BenchmarkError(f"--overlays must be >= 0, got {args.overlays}")
    if args.html_queries is not None and args.html_queries < 0:
        raise BenchmarkError(f"--html-queries must be >= 0, got {args.html_queries}")
    if args.out is None:
        args.out = str(Path(args.runs[0]) / REPORT_DIR) if len(args.runs) == 1 else "benchmark_report"
    report = make_report(args.runs, args.out, overlays=args.overlays)
    for name, (md, csv_path) in report.tables.items():
        print(f"table {name}: {md} {csv_path}")
    print(f"{len(report.plots)} plots in {report.out_dir / 'plots'}")
    for note in report.notes:
        print(f"note: {note}")
    print(f"wrote {report.markdown}")
    if not args.no_html:
        tables = [md for md, _ in report.tables.values()]
        page = make_html_report(args.runs, args.out, tables, report.notes, max_queries=args.html_queries)
        print(f"wrote {page.path} ({page.queries} queries, {page.path.stat().st_size / 1e6:.1f} MB)")
    return 0
