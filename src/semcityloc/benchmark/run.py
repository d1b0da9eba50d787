"""The one run loop: queries from a source -> a method -> resumable rows, details and a summary.

Why its own module: a benchmark of hundreds of queries runs for hours, so this loop's job is to make a run
reproducible and cheap to restart, whatever makes the queries (``benchmark.sources``) and whatever
localizes them (``localization.methods``). ``run_queries(source, spec, out)`` does resume, rows, details,
summary and progress for every kind of run; ``run_benchmark(spec, out)`` opens the spec's source first.

A spec is a typed object (``benchmark.spec.BenchmarkSpec`` for simulated runs,
``benchmark.dataset_source.DatasetSpec`` for data sets, ``benchmark.photo_spec.PhotoSpec`` for a folder of
photos) with ``method``, ``preset``, ``keep_details``, ``label``, ``localizer_config()``, ``run_config()``
(the ``run.json`` dict), ``open_source(config)`` and ``finish(out, rows, summary)``.
Workers get the spec and the source (with its models) once, never a dict to read settings back from. A
source with a ``tile_store`` (a ``--city`` tile store) gets a ``localization.tiled.TiledMethod``: each query
loads the parts of the city it can see. A source with a ``start_note(todo)`` (a data set's missing files:
``DatasetSource.start_note``) has it said on stderr once it is open, before the first query runs.

Numbers do not depend on ``workers``: every query is made from ``(seed, index)`` alone and the localizer
seeds its own generator per query.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TextIO

import numba

from semcityloc.benchmark.code_version import code_fingerprint
from semcityloc.benchmark.methods import get_method, method_factory
from semcityloc.benchmark.queries import query_id
from semcityloc.benchmark.ray_executor import import_ray, run_ray
from semcityloc.benchmark.results import (
    FAILED,
    REASON_SKIPPED,
    SKIP_REASON,
    SKIPPED,
    SKIPPED_MISS,
    SOURCE_WARNINGS,
    UNFIT_INPUT,
    UNREADABLE_INPUT,
    append_row,
    make_row,
    missing_details,
    missing_details_phrase,
    read_results,
    save_details,
    skipped_miss_result,
    skipped_result,
    summarize_rows,
    unreadable_result,
    write_rows,
)
from semcityloc.benchmark.runfiles import (
    CODE_KEY,
    DETAILS_DIR,
    ESTIMATES_DIR,
    OVERLAYS_DIR,
    POSES_DIR,
    RESULTS_FILE,
    RUN_FILE,
    SUMMARY_FILE,
    Progress,
    code_change_note,
    holds_rows,
    kept_note,
    prepare_output,
    remove_entries,
    remove_stale_temps,
    run_entries,
    run_lock,
    writing,
)
from semcityloc.benchmark.sources import QuerySource
from semcityloc.benchmark.warmup import ensure_compiled, kernel_groups
from semcityloc.errors import (
    ArgumentTypeError,
    BenchmarkError,
    OutputPathError,
    SemCityLocError,
    as_flags,
    parameter,
    unknown_choice,
)
from semcityloc.io.files import write_json_atomic
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.result import LocalizationResult
from semcityloc.localization.tiled import TiledMethod

EXECUTORS = ("local", "ray")  # where queries run: this process / a process pool, or Ray
# Folders of a run where atomic writes leave temporary files (removed on resume when no process owns them).
TEMP_FOLDERS = ("", DETAILS_DIR, ESTIMATES_DIR, POSES_DIR, OVERLAYS_DIR)


class RunSpec(Protocol):
    """What the loop needs of a spec (module docstring)."""

    method: str
    keep_details: int
    label: str

    def localizer_config(self) -> LocalizerConfig:
        """The localizer settings every query of the run uses."""

    def run_config(self) -> dict:
        """The ``run.json`` content: what makes the run what it is, compared on resume."""

    def open_source(self, config: dict) -> QuerySource:
        """The run's query source, from the ``run.json`` content (``config``)."""

    def finish(self, out_dir: Path, rows: list[dict[str, str]], summary: dict) -> None:
        """Add to ``summary`` and write the run's exports once every query has a row."""


@dataclass
class BenchmarkOutcome:
    """What ``run_benchmark`` leaves: the run folder, whether every query has a row (then ``summary.json`` is
    written), how many rows this call wrote, all rows, the summary and the run's config. A killed or
    ``--stop-after`` run is incomplete, not an error. ``summary``'s notes name parameters as a Python caller
    passes them (``errors.parameter``; stop 55: they were in the command line's words), ``summary.json``
    the flags (``errors.as_flags``); the rows are ``results.csv``'s, in the run folder's words.
    """

    out_dir: Path
    complete: bool  # every query has a row (summary.json written)
    new_rows: int  # rows written by this call (a restored query's row replaces its old one)
    rows: list[dict[str, str]]
    summary: dict | None
    config: dict


class _Worker:
    """A source and a method for one map, built once per process; writes details and estimates."""

    def __init__(self, spec: RunSpec, source: QuerySource, out_dir: Path):
        self.source = source
        store = getattr(source, "tile_store", None)
        if store is not None:  # the parts of the store each query can see (localization.tiled)
            self.method = TiledMethod(
                spec.method, store, spec.localizer_config(), factory=method_factory(spec.method)
            )
        else:
            self.method = get_method(spec.method, source.map_model, spec.localizer_config())
        source.prepare(self.method)
        self.origin = source.map_model.origin
        self.out_dir = out_dir
        self.keep = int(spec.keep_details)

    def run(self, index: int) -> dict[str, str]:
        """The row of query ``index``. One its source did not accept is not localized: skipped with the
        source's reason (``results.SKIPPED``), kept like the others (``save_estimate``: a photo's record);
        one whose input files its source could not read is a miss (``results.unreadable_result``)."""
        q = self.source.query(index)
        refused = _refused_by_source(q.meta or {})
        if refused is not None:
            self.source.save_estimate(self.out_dir, q, refused)
            return make_row(q, refused, self.origin)
        result = self.method.localize(q)
        result.warnings.extend((q.meta or {}).get(SOURCE_WARNINGS, ()))  # e.g. a prior without a heading
        if index < self.keep:
            save_details(self.out_dir / DETAILS_DIR / f"{query_id(index)}.npz", q, result, self.origin)
        self.source.save_estimate(self.out_dir, q, result)
        return make_row(q, result, self.origin)


def _refused_by_source(meta: dict) -> LocalizationResult | None:
    """The result of a query its source could not hand to a method, or None: one whose input files it
    could not read is a miss (``results.unreadable_result``), as is a photo of the truth its run skipped
    (``results.skipped_miss_result``); one it did not accept is skipped (``results.skipped_result``)."""
    if UNREADABLE_INPUT in meta:
        return unreadable_result(str(meta[UNREADABLE_INPUT]), unfit=bool(meta.get(UNFIT_INPUT)))
    if SKIPPED_MISS in meta:
        return skipped_miss_result(str(meta[SKIPPED_MISS]))
    if not meta.get("accepted", True):
        return skipped_result(meta.get(SKIP_REASON, REASON_SKIPPED))
    return None


_PROCESS_WORKER: _Worker | None = None


_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _die_with_parent(parent: int) -> None:
    """Make this pool worker end with the process that started it (``parent``), even when that one is
    killed (SIGKILL, SIGTERM): else each worker, hundreds of MB, would live on as an orphan. On Linux the
    kernel sends SIGTERM when the parent dies (``prctl(PR_SET_PDEATHSIG)``); elsewhere that is skipped.
    A parent that died before this ran (the worker already adopted by another) ends the worker now.
    Ray's workers need none: Ray ends them with the driver (``ray_executor``, "The driver's death")."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - a libc without prctl
            pass
    if os.getppid() != parent:
        os._exit(1)


def _init_process(parent: int, threads: int, spec: RunSpec, source: QuerySource, out_dir: Path) -> None:
    global _PROCESS_WORKER
    _die_with_parent(parent)
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    _PROCESS_WORKER = _Worker(spec, source, out_dir)


def _run_in_process(index: int) -> dict[str, str]:
    if _PROCESS_WORKER is None:  # pragma: no cover - the pool's initializer always runs first
        raise RuntimeError("worker process not initialised")
    return _PROCESS_WORKER.run(index)


def run_queries(
    source: QuerySource | None,
    spec: RunSpec,
    out_dir: str | Path,
    workers: int = 1,
    overwrite: bool = False,
    limit: int | None = None,
    progress: bool | TextIO = True,
    config: dict | None = None,
    executor: str = "local",
    ray_address: str | None = None,
) -> BenchmarkOutcome:
    """Run (or resume) ``spec`` over ``source`` into ``out_dir`` (``benchmark.runfiles`` has the files).

    Args:
        source: the queries; None = ``spec.open_source(config)``, opened only when a query is left to do
            (a finished run is summarised without loading a model).
        workers: processes localizing queries in parallel (each builds its method once).
        overwrite: start afresh (the run's own files in ``out_dir`` removed), whatever ``out_dir`` holds.
        limit: process at most this many new queries in this call, then stop (a later call resumes).
        progress: True for the bar on stderr, False for none, or a stream.
        config: ``spec.run_config()`` when the caller has it already.
        executor: ``local`` (this process, or a process pool for ``workers > 1``) or ``ray``
            (``benchmark.ray_executor``: a local Ray runtime of ``workers`` CPUs, or the cluster at
            ``ray_address``).
    """
    workers = int(workers)
    if workers < 1:
        raise BenchmarkError(f"workers must be >= 1, got {workers}")
    if executor not in EXECUTORS:
        raise unknown_choice("executor", executor, EXECUTORS, BenchmarkError)
    if executor == "ray":
        import_ray()  # missing: the install hint now, before any file is written
    if limit is not None and int(limit) < 0:
        raise BenchmarkError(f"{parameter('limit')} must be >= 0, got {limit}")
    if not isinstance(out_dir, (str, os.PathLike)):  # pathlib's TypeError otherwise
        raise ArgumentTypeError(
            f"out_dir must be the run's folder (a str or a path), got {type(out_dir).__name__}"
        )
    out = Path(out_dir)
    config = config if config is not None else spec.run_config()
    config = {**config, CODE_KEY: code_fingerprint()}
    made = not out.exists()
    try:
        with run_lock(out):  # one run at a time writes a folder
            return _run_locked(
                source, spec, out, config, workers, overwrite, limit, progress, executor, ray_address
            )
    except BaseException as exc:
        if made:  # a folder this call made and left empty (a run that failed at setup): not kept
            with contextlib.suppress(OSError):
                out.rmdir()
        if isinstance(exc, KeyboardInterrupt):  # Ctrl-C or SIGTERM: what is kept, and how to go on
            _say_kept(out, int(config["queries"]), progress)
        raise


def _say_kept(out: Path, total: int, progress: bool | TextIO) -> None:
    """After an interruption: how many finished rows ``out`` keeps and that the same command continues."""
    with contextlib.suppress(SemCityLocError, OSError):  # the interruption is the news, not a damaged file
        done = len(read_results(out / RESULTS_FILE)) if (out / RESULTS_FILE).is_file() else 0
        if done:
            print(
                kept_note(done, total, out),
                file=sys.stderr if isinstance(progress, bool) else progress,
                flush=True,
            )


def _run_locked(
    source, spec, out: Path, config: dict, workers, overwrite, limit, progress, executor, ray_address
) -> BenchmarkOutcome:
    """``run_queries`` once it holds the folder's lock."""
    with writing(folder=out):  # run.json, a repaired results.csv
        found = run_entries(out)
        resumed = prepare_output(out, config, overwrite)
        # What the folder held that is not this call's: run.json when resumed, outputs not cleared.
        theirs = (found & run_entries(out)) - (set() if resumed is not None else {RUN_FILE})
        remove_stale_temps(out, TEMP_FOLDERS)  # we hold the lock: no other run writes here
        wanted = {query_id(i) for i in range(int(config["queries"]))}
        rows = [r for r in read_results(out / RESULTS_FILE) if r["query_id"] in wanted]
    try:
        return _run_rows(
            source, spec, out, config, rows, resumed, workers, limit, progress, executor, ray_address
        )
    except BaseException:
        _undo_setup(out, theirs)
        raise


def _undo_setup(out: Path, theirs: set[str]) -> None:
    """After a run that failed (or was interrupted) before the folder held any result row (a backend whose
    weights are missing, a Ctrl-C while compiling): remove what this call made (``run.json``, an empty
    ``results.csv``, ``details/``), so that the corrected command is not refused as "another run". What the
    folder held before (``theirs``: a resumed run's files) stays; a folder holding any row is left whole."""
    if holds_rows(out / RESULTS_FILE):
        return
    with contextlib.suppress(OSError):  # the failure that got here is the one to tell
        remove_entries(out, run_entries(out) - theirs)


def _run_rows(
    source, spec, out: Path, config: dict, rows, resumed, workers, limit, progress, executor, ray_address
) -> BenchmarkOutcome:
    """The queries left to do, localized and their rows kept; the summary and exports once all are done."""
    total = int(config["queries"])
    done = {r["query_id"] for r in rows}
    missing = missing_details(out, rows, min(int(spec.keep_details), total))  # made again, first
    todo = missing + [i for i in range(total) if query_id(i) not in done]
    if limit is not None:
        todo = todo[: int(limit)]
    redo = [i for i in missing if i in todo]
    kept = len(done) - len(redo)  # finished queries not made again
    for note in (code_change_note(out, resumed, config, kept, len(todo)), redo_note(out, missing)):
        if note is not None:
            print(note, file=sys.stderr if isinstance(progress, bool) else progress)

    if any(i < int(spec.keep_details) for i in todo):
        (out / DETAILS_DIR).mkdir(exist_ok=True)
    written = 0
    if todo:
        stream = None if progress is True else progress or None
        ensure_compiled(kernel_groups(spec.method), stream)
        source = source if source is not None else spec.open_source(config)
        start_note = getattr(source, "start_note", None)  # a source's word before its first query
        note = start_note(todo) if start_note is not None else None
        if note is not None:
            print(note, file=sys.stderr if isinstance(progress, bool) else progress, flush=True)
        bar = Progress(total, kept, stream, label=spec.label) if progress is not False else None
        if executor == "ray":
            finished = run_ray(todo, workers, _Worker, (spec, source, out), ray_address, source.has_truth)
        elif workers == 1 or len(todo) == 1:
            finished = _run_serial(todo, (spec, source, out))
        else:
            finished = _run_pool(todo, workers, (spec, source, out))
        try:
            rows, written = _keep_rows(finished, out / RESULTS_FILE, rows, {query_id(i) for i in redo}, bar)
        finally:
            finished.close()  # stops the pool at once when the loop ends by an error
            if bar:
                bar.close()
    complete = len(rows) == total
    summary = None
    if complete:
        summary = summarize_rows(rows, config)
        try:
            with writing(folder=out):  # the exports and summary.json (names the file that failed)
                spec.finish(out, rows, summary)
                # The file in a run folder's words (``results``: its notes name flags); the summary returned
                # keeps the library's (a Python caller passed no flag; the command line prints flags).
                write_json_atomic(out / SUMMARY_FILE, as_flags(summary))
        except OutputPathError as exc:
            raise OutputPathError(f"{exc}: all {total} rows are kept") from exc
    return BenchmarkOutcome(out, complete, written, rows, summary, config)


def redo_note(out: Path, redo: list[int]) -> str | None:
    """What a resume that restores missing details files (``missing_details``) says on stderr; None when
    none are missing."""
    if not redo:
        return None
    return (
        f"{missing_details_phrase(out, redo)}, so the report would draw no figure of them; localizing them "
        "again to restore them (each row is kept until its new one replaces it)"
    )


def _keep_rows(
    finished: Iterator[dict[str, str]],
    path: Path,
    rows: list[dict[str, str]],
    redo: set[str],
    bar: Progress | None,
) -> tuple[list[dict[str, str]], int]:
    """Write each finished row (the parent alone writes ``results.csv``): a new query's row appended (one
    fsync'd line), a restored query's (``redo``) replacing its old row in the file (rewritten atomically).
    The old row stays when the new one is ``skipped`` or ``failed`` (no details made; finished work is
    never traded for nothing). Returns every row and how many were written; a write that fails (a full
    disk, a folder made read-only) is an ``OutputPathError`` saying how many finished rows are kept."""
    by_id = {r["query_id"]: r for r in rows}  # the file's order
    written = 0
    try:
        for row in finished:
            qid = row["query_id"]
            if qid not in redo:
                append_row(path, row)
            elif row["status"] in (SKIPPED, FAILED):
                continue
            by_id[qid] = row
            if qid in redo:
                write_rows(path, by_id.values())
            written += 1
            if bar:
                bar.update()
    except OutputPathError as exc:
        raise OutputPathError(f"{exc}: the {len(by_id)} finished rows are kept") from exc
    return list(by_id.values()), written


def run_benchmark(
    spec: RunSpec,
    out_dir: str | Path,
    workers: int = 1,
    overwrite: bool = False,
    limit: int | None = None,
    progress: bool | TextIO = True,
    executor: str = "local",
    ray_address: str | None = None,
) -> BenchmarkOutcome:
    """Run (or resume) the benchmark of ``spec`` (simulated or data set) into ``out_dir``."""
    return run_queries(
        None, spec, out_dir, workers, overwrite, limit, progress, executor=executor, ray_address=ray_address
    )


def _run_serial(todo: list[int], worker_args: tuple) -> Iterator[dict[str, str]]:
    """Rows of ``todo`` localized in this process, in order."""
    worker = _Worker(*worker_args)
    for i in todo:
        yield worker.run(i)


def _run_pool(todo: list[int], workers: int, worker_args: tuple) -> Iterator[dict[str, str]]:
    """Rows of ``todo`` from ``workers`` processes, in the order they finish."""
    threads = max(1, (os.cpu_count() or 1) // workers)
    ctx = multiprocessing.get_context("spawn")  # numba's thread pools are not fork-safe
    pool = ProcessPoolExecutor(
        workers, mp_context=ctx, initializer=_init_process, initargs=(os.getpid(), threads, *worker_args)
    )
    try:
        pending = {pool.submit(_run_in_process, i) for i in todo}
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                yield fut.result()
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
