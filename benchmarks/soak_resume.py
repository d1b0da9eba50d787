"""Crash-safety soak: a benchmark SIGKILLed at random moments and resumed ends with the rows of an
uninterrupted run — no duplicates, no torn rows, same numbers (timing columns aside).

1. ``semcityloc benchmark`` runs ``--queries N`` without interruption into ``REF`` (timed: start-up until
   its first row, then seconds per query).
2. The same command into ``SOAK`` is started ``--kills`` times and each time SIGKILLed (by its own pid) at a
   random moment: a third during start-up (before the reference run's first row: loading, the lock,
   compiling), the others within the next 4 queries' time (a query, a row's write, the summary). After
   each kill the script counts the rows, the torn last line (if any) and the lock file left behind; the
   next start must take the stale lock over and resume.
3. The command then runs to its end; ``SOAK/results.csv`` must hold exactly ``REF``'s rows: the same
   query ids once each, every line whole, every non-timing value equal; ``summary.json`` likewise.

Prints one line per kill and a final JSON line of counts; exit code 1 when anything differs.

    python benchmarks/soak_resume.py [--queries 40] [--kills 10] [--preset fast] [--seed 0]
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from semcityloc.benchmark.results import COLUMNS, TIMING_COLUMNS
from semcityloc.benchmark.runfiles import LOCK_FILE, RESULTS_FILE, SUMMARY_FILE

SUMMARY_TIMING = ("sec_per_image", "sec_per_image_median")  # summary keys that are timings


def command(out: Path, args) -> list[str]:
    return [
        *(sys.executable, "-m", "semcityloc.cli.main", "benchmark", "--city", args.city),
        *("--queries", str(args.queries), "--preset", args.preset, "--seed", str(args.seed)),
        *("--workers", str(args.workers), "--out", str(out)),
    ]


def rows_of(path: Path) -> tuple[list[dict[str, str]], int]:
    """(whole rows, torn lines): a line is torn when it does not end the file with a newline or has the
    wrong number of fields."""
    if not path.is_file():
        return [], 0
    data = path.read_bytes()
    torn = 0 if not data or data.endswith(b"\n") else 1
    lines = data[: data.rfind(b"\n") + 1].decode("utf-8") if data else ""
    reader = csv.reader(io.StringIO(lines))
    header = next(reader, None)
    rows = []
    for values in reader:
        if header is None or len(values) != len(header):
            torn += 1
        else:
            rows.append(dict(zip(header, values, strict=True)))
    return rows, torn


def numbers(rows: list[dict[str, str]]) -> dict[str, dict[str, str]]:
    return {r["query_id"]: {k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows}


def summary_numbers(path: Path) -> dict:
    summary = json.loads(path.read_text())
    return {k: v for k, v in summary.items() if k not in SUMMARY_TIMING}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=40)
    parser.add_argument("--kills", type=int, default=10)
    parser.add_argument("--city", default="generated")
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--work", default=None, help="folder for REF and SOAK (default: a temporary one)")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="semcityloc-soak-") as tmp:
        work = Path(args.work or tmp)
        ref, soak = work / "ref", work / "soak"
        t0, t_first = time.perf_counter(), None
        proc = subprocess.Popen(command(ref, args), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while proc.poll() is None:
            if t_first is None and rows_of(ref / RESULTS_FILE)[0]:
                t_first = time.perf_counter() - t0
            time.sleep(0.05)
        if proc.returncode:
            raise SystemExit(f"the uninterrupted run failed (exit {proc.returncode})")
        t_ref = time.perf_counter() - t0
        startup = t_first or 0.5 * t_ref
        per_query = (t_ref - startup) / max(1, args.queries - 1)
        print(
            f"uninterrupted run: {args.queries} queries in {t_ref:.1f} s (first row after {startup:.1f} s, "
            f"then {per_query:.2f} s per query)",
            flush=True,
        )

        kills = []
        for k in range(args.kills):
            # A third of the kills during start-up (loading, compiling, the lock), the rest among the queries.
            at = (
                rng.uniform(0.5, startup) if rng.random() < 1 / 3 else startup + rng.uniform(0, 4 * per_query)
            )
            proc = subprocess.Popen(command(soak, args), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            try:
                proc.wait(timeout=at)
                finished = True
            except subprocess.TimeoutExpired:
                os.kill(proc.pid, signal.SIGKILL)  # by its own pid
                proc.wait()
                finished = False
            err = proc.stderr.read().decode(errors="replace")
            rows, torn = rows_of(soak / RESULTS_FILE)
            stale = "stale lock" in err
            kills.append({"at_s": round(at, 2), "rows": len(rows), "torn": torn, "finished": finished})
            print(
                f"kill {k + 1}: at {at:.1f} s, {len(rows)} rows, torn last line: {bool(torn)}, "
                f"lock left: {(soak / LOCK_FILE).exists()}, took over a stale lock: {stale}, "
                f"finished before the kill: {finished}",
                flush=True,
            )
        final = subprocess.run(command(soak, args), capture_output=True, text=True)
        ref_rows, ref_torn = rows_of(ref / RESULTS_FILE)
        soak_rows, soak_torn = rows_of(soak / RESULTS_FILE)
        ids = [r["query_id"] for r in soak_rows]
        a, b = numbers(ref_rows), numbers(soak_rows)
        differing = sorted(q for q in set(a) | set(b) if a.get(q) != b.get(q))
        done = (soak / SUMMARY_FILE).is_file()
        same_summary = done and summary_numbers(ref / SUMMARY_FILE) == summary_numbers(soak / SUMMARY_FILE)
        header_ok = (soak / RESULTS_FILE).read_text().split("\n", 1)[0] == ",".join(COLUMNS)
        counts = {
            "queries": args.queries,
            "kills": sum(not k["finished"] for k in kills),
            "rows_after_each_kill": [k["rows"] for k in kills],
            "torn_lines_seen_after_kills": sum(k["torn"] for k in kills),
            "final_exit_code": final.returncode,
            "reference_rows": len(ref_rows),
            "resumed_rows": len(soak_rows),
            "duplicate_rows": len(ids) - len(set(ids)),
            "torn_rows_at_end": soak_torn + ref_torn,
            "rows_differing_from_reference": len(differing),
            "summary_equal": same_summary,
            "header_ok": header_ok,
            "lock_left_at_end": (soak / LOCK_FILE).exists(),
        }
        print(json.dumps(counts))
        ok = (
            final.returncode == 0
            and len(soak_rows) == len(ref_rows) == args.queries
            and counts["duplicate_rows"] == 0
            and counts["torn_rows_at_end"] == 0
            and not differing
            and same_summary
            and header_ok
            and not counts["lock_left_at_end"]
        )
        return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
