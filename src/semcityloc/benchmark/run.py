"""The one run loop: queries from a source -> a method -> resumable rows, details and a summary.

Why its own module: a benchmark of hundreds of queries runs for hours, so this loop's job is to make a run
reproducible and cheap to restart, whatever makes the queries (``benchmark.sources``) and whatever
localizes them (``localization.methods``). ``run_queries(source, spec, out)`` does resume, rows, details,
summary and progress for every kind of run; ``run_benchmark(spec, out)`` opens the spec's source first.

A spec is a typed object (``benchmark.spec.BenchmarkSpec`` for simulated runs,
``benchmark.dataset_source.DatasetSpec`` for data sets) with ``method``, ``preset``, ``keep_details``,
``label``, ``localizer_config()``, ``run_config()`` (the ``run.json`` dict), ``open_source(config)`` and
``finish(out, rows, summary)``.
Workers get the spec and the source (with its models) once, never a dict to read settings back from. A
source with a ``tile_store`` (a ``--city`` tile store) gets a ``localization.tiled.TiledMethod``: each query
loads the parts of the city it can see.

Numbers do not depend on ``workers``: every query is made from ``(seed, index)`` alone and the localizer
seeds its own generator per query.
"""

from __future__ import annotations

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

import semcityloc.baselines  # noqa: F401  (registers the baselines' methods)
from semcityloc.benchmark.code_version import code_fingerprint
from semcityloc.benchmark.queries import query_id
from semcityloc.benchmark.ray_executor import import_ray, run_ray
from semcityloc.benchmark.results import (
    REASON_SKIPPED,
    SKIP_REASON,
    append_row,
    make_row,
    read_results,
    save_details,
    skipped_result,
    summarize_rows,
)
from semcityloc.benchmark.runfiles import (
    CODE_KEY,
    DETAILS_DIR,
    ESTIMATES_DIR,
    OVERLAYS_DIR,
    POSES_DIR,
    RESULTS_FILE,
    SUMMARY_FILE,
    Progress,
    code_change_note,
    prepare_output,
    remove_stale_temps,
    run_lock,
    write_json_atomic,
    writing,
)
from semcityloc.benchmark.sources import QuerySource
from semcityloc.benchmark.warmup import ensure_compiled, kernel_groups
from semcityloc.errors import BenchmarkError, OutputPathError, unknown_choice
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.methods import get_method
from semcityloc.localization.tiled import TiledMethod

EXECUTORS = ("local", "ray")  # where queries run: this process / a process pool, or Ray
# Folders of a run where atomic writes leave temporary files (removed on resume when no process owns them).
TEMP_FOLDERS = ("", DETAILS_DIR, ESTIMATES_DIR, POSES_DIR, OVERLAYS_DIR)


class RunSpec(Protocol):
    """What the loop needs of a spec (module docstring)."""

    method: str
    keep_details: int
    label: str

    def localizer_config(self) -> LocalizerConfig: ...

    def run_config(self) -> dict: ...

    def open_source(self, config: dict) -> QuerySource: ...

    def finish(self, out_dir: Path, rows: list[dict[str, str]], summary: dict) -> None:
        """Add to ``summary`` and write the run's exports once every query has a row."""


@dataclass
class BenchmarkOutcome:
    out_dir: Path
    complete: bool  # every query has a row (summary.json written)
    new_rows: int  # rows added by this call
    rows: list[dict[str, str]]
    summary: dict | None
    config: dict


class _Worker:
    """A source and a method for one map, built once per process; writes details and estimates."""

    def __init__(self, spec: RunSpec, source: QuerySource, out_dir: Path):
        self.source = source
        store = getattr(source, "tile_store", None)
        if store is not None:  # the parts of the store each query can see (localization.tiled)
            self.method = TiledMethod(spec.method, store, spec.localizer_config())
        else:
            self.method = get_method(spec.method, source.map_model, spec.localizer_config())
        source.prepare(self.method)
        self.origin = source.map_model.origin
        self.out_dir = out_dir
        self.keep = int(spec.keep_details)

    def run(self, index: int) -> dict[str, str]:
        """The row of query ``index``. One its source did not accept is not localized: skipped with the
        source's reason (``results.SKIPPED``), kept like the others (``save_estimate``: a photo's record)."""
        q = self.source.query(index)
        meta = q.meta or {}
        if not meta.get("accepted", True):
            skipped = skipped_result(meta.get(SKIP_REASON, REASON_SKIPPED))
            self.source.save_estimate(self.out_dir, q, skipped)
            return make_row(q, skipped, self.origin)
        result = self.method.localize(q)
        if index < self.keep:
            save_details(self.out_dir / DETAILS_DIR / f"{query_id(index)}.npz", q, result, self.origin)
        self.source.save_estimate(self.out_dir, q, result)
        return make_row(q, result, self.origin)


_PROCESS_WORKER: _Worker | None = None


_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _die_with_parent(parent: int) -> None:
    """Make this pool worker end with the process that started it (``parent``), even when that one is
    killed (SIGKILL, SIGTERM): else each worker, hundreds of MB, would live on as an orphan. On Linux the
    kernel sends SIGTERM when the parent dies (``prctl(PR_SET_PDEATHSIG)``); elsewhere that is skipped.
    A parent that died before this ran (the worker already adopted by another) ends the worker now."""
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
        raise BenchmarkError(f"limit must be >= 0, got {limit}")
    out = Path(out_dir)
    config = config if config is not None else spec.run_config()
    config = {**config, CODE_KEY: code_fingerprint()}
    with run_lock(out):  # one run at a time writes a folder
        return _run_locked(
            source, spec, out, config, workers, overwrite, limit, progress, executor, ray_address
        )


def _run_locked(
    source, spec, out: Path, config: dict, workers, overwrite, limit, progress, executor, ray_address
) -> BenchmarkOutcome:
    """``run_queries`` once it holds the folder's lock."""
    with writing(folder=out):  # run.json, a repaired results.csv
        resumed = prepare_output(out, config, overwrite)
        remove_stale_temps(out, TEMP_FOLDERS)  # we hold the lock: no other run writes here
        results_path = out / RESULTS_FILE
        total = int(config["queries"])
        wanted = {query_id(i) for i in range(total)}
        rows = [r for r in read_results(results_path) if r["query_id"] in wanted]
    done = {r["query_id"] for r in rows}
    todo = [i for i in range(total) if query_id(i) not in done]
    if limit is not None:
        todo = todo[: int(limit)]
    note = code_change_note(out, resumed, config, len(done), len(todo))
    if note is not None:
        print(note, file=sys.stderr if isinstance(progress, bool) else progress)

    if any(i < int(spec.keep_details) for i in todo):
        (out / DETAILS_DIR).mkdir(exist_ok=True)
    new_rows: list[dict[str, str]] = []
    if todo:
        stream = None if progress is True else progress or None
        ensure_compiled(kernel_groups(spec.method), stream)
        source = source if source is not None else spec.open_source(config)
        bar = Progress(total, len(done), stream, label=spec.label) if progress is not False else None
        if executor == "ray":
            finished = run_ray(todo, workers, _Worker, (spec, source, out), ray_address)
        elif workers == 1 or len(todo) == 1:
            finished = _run_serial(todo, (spec, source, out))
        else:
            finished = _run_pool(todo, workers, (spec, source, out))
        try:
            for row in finished:  # the parent alone appends, one fsync'd line per query
                append_row(results_path, row)
                new_rows.append(row)
                if bar:
                    bar.update()
        except OutputPathError as exc:  # a full disk, a folder made read-only: what is finished is kept
            kept = len(done) + len(new_rows)
            raise OutputPathError(f"{exc}: the {kept} finished rows are kept") from exc
        finally:
            finished.close()  # stops the pool at once when the loop ends by an error
            if bar:
                bar.close()
    rows += new_rows
    complete = len(rows) == total
    summary = None
    if complete:
        summary = summarize_rows(rows, config)
        try:
            with writing(folder=out):  # the exports and summary.json (names the file that failed)
                spec.finish(out, rows, summary)
                write_json_atomic(out / SUMMARY_FILE, summary)
        except OutputPathError as exc:
            raise OutputPathError(f"{exc}: all {total} rows are kept") from exc
    return BenchmarkOutcome(out, complete, len(new_rows), rows, summary, config)


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
