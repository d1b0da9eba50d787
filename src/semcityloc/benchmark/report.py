"""The paper's tables and figures from several benchmark run folders (``semcityloc report DIR...``).

Why: every experiment of the paper is one ``semcityloc benchmark`` run; this module puts runs side by
side by what differs in their ``run.json``:

- tables (Markdown + CSV): ``main`` (methods and ablations), ``perception`` (real data: oracle labels,
  degraded, masks, backends), ``prior_noise`` (``prior_extra_m``), ``lod`` (LoD1/LoD2/LoD3 maps),
  ``seg_quality`` (segmentation preset), ``sweep_<knob>`` (one per swept knob), ``acceptance`` (the
  risk-coverage table of the runs with calibrated probabilities) and ``misses`` (each run's kinds of
  miss, ``miss_kinds``). A table of factor F holds the
  runs whose group - runs agreeing on every setting but F - has two or more values of F (so the LoD
  table compares LoD1 with LoD2 at the same method, noise and segmentation); it is skipped when there
  is no such group, except ``main``, which then lists every run. One row per run: F first, then the
  settings that differ between the table's runs, then the metrics. Recall cells show both conventions,
  ``<=`` / ``<`` (see ``evaluation.metrics``);
- runs without ground truth (a user's photos run without ``--truth``, ``report_runs.has_truth``): no
  error columns, curves or misses of them (they would read as 0 %), but a note, and the table ``self``
  and figure ``self_assessment.png``: localized / not localized with the reasons counted, the calibrated
  probability, the stated sigmas and the shift from the prior;
- plots (matplotlib, Agg): cumulative position and rotation error curves (one line per run with ground
  truth, ``not_localized`` never reaches the curve), recall vs prior noise, and per run a figure for its first
  saved queries (``details/``): the query mask with the label boundaries of the map rendered at the
  estimated and true poses (the estimate on the map it was found on: ``found_map``), an xy slice and a
  yaw slice of the coarse cost volume.

Runs are read only (an unfinished run is reported with its finished rows and marked incomplete); a run
named twice is reported once. The output folder holds this report alone: an earlier report's files there
(``REPORT_FILES``: ``report.md``, ``report.html``, ``tables/*.md``, ``tables/*.csv``, ``plots/*.png``) are
removed first, so a reused ``--out`` never mixes two run sets' tables and figures; any other file in it is
kept. The
report's files speak the command line's words, as the run folders they read do (``errors.as_flags``: a
note's ``truth=...`` is ``--truth`` in ``report.md`` and ``report.html``); ``ReportOutput.notes`` keeps a
Python caller's, and the command prints them with the flags.

Its parts: ``report_runs`` (a run folder read, runs described, labelled and grouped), ``report_tables``
(the tables' Markdown and CSV), ``report_plots`` (the figures); this module chooses the tables and
figures a set of runs gets and writes them with ``report.md`` (``make_report``).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from semcityloc.benchmark.report_plots import (
    plot_cumulative,
    plot_details,
    plot_recall_vs_prior,
    plot_recall_vs_sweep,
    plot_risk_coverage,
    plot_self_assessment,
)
from semcityloc.benchmark.report_runs import (
    NO_TRUTH_LINE,
    RunData,
    acceptance_data,
    comparable_runs,
    differing_keys,
    has_truth,
    ignored_note,
    incomplete_note,
    label_runs,
    load_run,
    map_renderer,
    missing_details_note,
    no_truth_note,
    photo_of,
    readable_details,
    skipped_misses_note,
    unique_runs,
)
from semcityloc.benchmark.report_tables import (
    MISSES_NOTE,
    SELF_NOTE,
    build_table,
    misses_table,
    risk_coverage_table,
    self_assessment_table,
)
from semcityloc.benchmark.runfiles import DETAILS_DIR
from semcityloc.errors import BenchmarkError, as_flags

# name -> (config key shown, title). "main" is always written; the others when their key varies.
TABLES: dict[str, tuple[str, str]] = {
    "main": ("method", "Methods and ablations"),
    "perception": ("perception", "Perception (oracle labels, degraded, masks, backends) on real data"),
    "prior_noise": ("prior_extra", "Prior-noise sensitivity"),
    "lod": ("lod", "Map level of detail (LoD1 / LoD2 / LoD3)"),
    "seg_quality": ("seg_quality", "Segmentation-quality sensitivity"),
}


# What a report writes into its folder (``report.md``, ``report.html``, and by pattern in its subfolders):
# removed before a report is written there (module docstring).
REPORT_FILES = ("report.md", "report.html", "tables/*.md", "tables/*.csv", "plots/*.png")

RECALL_LINE = (
    "Recall cells: `≤` convention (LoD-Loc v1) / strict `<`; not_localized queries count as failures."
)


@dataclass
class ReportOutput:
    """What ``make_report`` wrote: the output folder, each table's Markdown and CSV files, the figures,
    ``report.md`` and the notes printed to the user (runs left out and why).
    """

    out_dir: Path
    tables: dict[str, tuple[Path, Path]]  # name -> (markdown, csv)
    plots: list[Path]
    markdown: Path
    notes: list[str]


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text).strip("_")[:60] or "run"


def _write_table(
    out: Path, tables: dict, name: str, title: str, md: str, csv_text: str, preface: str = ""
) -> list[str]:
    """Write ``tables/<name>.md`` and ``.csv``, record them in ``tables``; the report's lines for it."""
    md_path, csv_path = out / "tables" / f"{name}.md", out / "tables" / f"{name}.csv"
    md_path.write_text(f"## {title}\n\n{md}", encoding="utf-8")
    csv_path.write_text(csv_text, encoding="utf-8")
    tables[name] = (md_path, csv_path)
    return [f"## {title}", "", *([preface, ""] if preface else []), md]


def make_report(run_dirs: list[str | Path], out_dir: str | Path, overlays: int = 2) -> ReportOutput:
    """Tables, plots and ``report.md`` from benchmark run folders (module docstring)."""
    if not run_dirs:
        raise BenchmarkError("name at least one benchmark run folder")
    runs = [load_run(p) for p in unique_runs(run_dirs)]
    label_runs(runs)
    out = Path(out_dir)
    clear_report(out)
    (out / "tables").mkdir(parents=True, exist_ok=True)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    differ = differing_keys(runs)
    notes: list[str] = [incomplete_note(r) for r in runs if not r.complete]
    notes += [ignored_note(r) for r in runs if r.ignored]
    notes += [n for n in map(missing_details_note, runs) if n is not None]
    truth = [r for r in runs if has_truth(r)]  # errors measured: curves and recall as always
    blind = [r for r in runs if not has_truth(r)]  # a user's photos without --truth: what they say instead
    notes += [no_truth_note(r) for r in blind]
    notes += [n for n in map(skipped_misses_note, truth) if n is not None]
    doc = ["# SemCityLoc benchmark report", "", f"Runs: {len(runs)}", ""]
    doc += [f"- `{r.path}`: {r.label}" for r in runs]
    doc += ["", RECALL_LINE if truth else as_flags(NO_TRUTH_LINE), ""]
    tables: dict[str, tuple[Path, Path]] = {}
    sweep_plots: list[Path] = []
    for name, (factor, title) in TABLES.items():
        if name != "main" and not any(factor in r.settings for r in runs):
            continue  # a setting none of these runs has (perception of simulated runs, LoD of real ones)
        members = comparable_runs(runs, factor)
        if not members and name == "main":
            members = runs  # no methods to compare: the main table lists every run
        if not members:
            why = "all runs share" if factor not in differ else "no two runs differ only in"
            notes.append(f"table {name}: skipped, {why} {factor}")
            continue
        doc += _write_table(out, tables, name, title, *build_table(members, factor))

    for knob in sorted({r.config.get("sweep_knob") for r in runs} - {None}):
        members = [r for r in runs if r.config.get("sweep_knob") == knob]
        table = build_table(members, "sweep_value", hide=("q.",))
        doc += _write_table(out, tables, f"sweep_{_slug(knob)}", f"Sweep of `{knob}`", *table)
        sweep_plots.append(
            plot_recall_vs_sweep(members, knob, out / "plots" / f"recall_vs_{_slug(knob)}.png")
        )

    plots = _error_plots(truth, out / "plots") + sweep_plots
    acceptance = [r for r in runs if acceptance_data(r) is not None]
    if acceptance:
        title = "Acceptance: coverage and precision by probability threshold"
        doc += _write_table(out, tables, "acceptance", title, *risk_coverage_table(acceptance))
        plots.append(plot_risk_coverage(acceptance, out / "plots" / "risk_coverage.png"))
    with_truth = [r for r in runs if any(row.get("err_xyz_m", "") != "" for row in r.rows)]
    if with_truth:
        title = "Misses at 2 m / 2°, by kind, and the map's agreement with the world at the truth"
        doc += _write_table(out, tables, "misses", title, *misses_table(with_truth), preface=MISSES_NOTE)
    if blind:
        title = "Without ground truth: what the runs say of themselves"
        doc += _write_table(out, tables, "self", title, *self_assessment_table(blind), preface=SELF_NOTE)
        plots.append(plot_self_assessment(blind, out / "plots" / "self_assessment.png"))
    plots += _detail_figures(runs, out / "plots", overlays, notes)
    doc += ["## Figures", ""] + [f"![{p.stem}](plots/{p.name})" for p in plots]
    if notes:
        doc += ["", "## Notes", ""] + [f"- {as_flags(n)}" for n in notes]
    md_file = out / "report.md"
    md_file.write_text("\n".join(doc) + "\n", encoding="utf-8")
    return ReportOutput(out, tables, plots, md_file, notes)


def clear_report(out: Path) -> None:
    """Remove an earlier report's files (``REPORT_FILES``) from ``out``; other files are kept."""
    for pattern in REPORT_FILES:
        for path in out.glob(pattern):
            if path.is_file() or path.is_symlink():
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()


def _error_plots(runs: list[RunData], plot_dir: Path) -> list[Path]:
    """The cumulative error curves and recall against the prior noise of the runs with ground truth; none
    when no run has it (curves at 0 % would read as a run that failed)."""
    if not runs:
        return []
    return [
        plot_cumulative(
            runs, "err_xyz_m", "camera-centre error (m)", plot_dir / "cumulative_translation.png"
        ),
        plot_cumulative(runs, "err_rot_deg", "rotation error (deg)", plot_dir / "cumulative_rotation.png"),
        plot_recall_vs_prior(runs, plot_dir / "recall_vs_prior_noise.png"),
    ]


def _detail_figures(runs: list[RunData], plot_dir: Path, overlays: int, notes: list[str]) -> list[Path]:
    figures: list[Path] = []
    cache: dict[str, Any] = {}
    for n, run in enumerate(runs):
        files = sorted((run.path / DETAILS_DIR).glob("q*.npz"))[: max(0, overlays)]
        if not files:
            continue
        pair = map_renderer(run, cache, notes, "no query figures")
        if pair is None:
            continue
        model, maps = pair
        for f in files:
            details = readable_details(f, notes, f"no figure of {f.stem}")
            if details is None:
                continue
            photo = photo_of(run.config, details["meta"].get("query_meta") or {})
            name = f"query_{n:02d}_{_slug(run.path.name)}_{f.stem}.png"
            title = f"{run.label} {f.stem}"
            figures.append(plot_details(details, model, plot_dir / name, title, photo, maps, run.config))
    return figures
