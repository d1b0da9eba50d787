"""``make fuzz``: every reader's fuzz target over N mutated inputs (default 10,000), a table of outcomes.

Run as ``python tests/fuzz_run.py [--inputs N] [--targets a,b] [--table docs/reliability.md]``. Each input
is a seed (real files of ../shared/data when present, small generated ones always) with 1-4
structure-aware mutations (``fuzzing.py``), read by the library's reader under a 10 s alarm; the outcome is
``typed`` (a ``SemCityLocError``), ``valid`` (a result) or ``crash`` (any other exception; the input is
saved under ``--crashes`` with its traceback). Prints one row per target (inputs, outcomes, slowest input,
peak RSS of the process) and, with ``--table``, replaces the fuzz table in that Markdown file between its
``<!-- fuzz-table -->`` markers. Exit code 1 when any input crashed or hung.
"""

from __future__ import annotations

import argparse
import json
import random
import resource
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

from fuzzing import CRASH, TARGETS, TYPED, VALID, Fuzzer

HANG_S = 10
MARK = "<!-- fuzz-table -->"


class Hang(BaseException):
    """An input that ran longer than ``HANG_S`` (raised by the alarm; not an ``Exception``)."""


def _alarm(signum, frame):
    raise Hang()


def fuzz_target(name: str, inputs: int, seed: int, work: Path, crashes: Path) -> dict:
    fuzzer = Fuzzer(name, work / name)
    rng = random.Random(f"{seed}-{name}")
    counts = {TYPED: 0, VALID: 0, CRASH: 0, "hang": 0}
    slowest = 0.0
    t_start = time.perf_counter()
    for i in range(inputs):
        fname, data = fuzzer.input(rng)
        t0 = time.perf_counter()
        signal.alarm(HANG_S)
        try:
            outcome, exc = fuzzer.run(fname, data)
        except Hang:
            outcome, exc = "hang", None
        finally:
            signal.alarm(0)
        slowest = max(slowest, time.perf_counter() - t0)
        counts[outcome] += 1
        if outcome in (CRASH, "hang"):
            crashes.mkdir(parents=True, exist_ok=True)
            stem = crashes / f"{name}-{i:06d}-{fname}"
            stem.write_bytes(data)
            text = "".join(traceback.format_exception(exc)) if exc is not None else f"hang > {HANG_S} s"
            stem.with_name(stem.name + ".txt").write_text(text)
            print(f"{name}: {outcome} on input {i} ({stem}): {text.strip().splitlines()[-1]}", flush=True)
    return {
        "target": name,
        "inputs": inputs,
        "seeds": len(fuzzer.seeds),
        **counts,
        "slowest_s": slowest,
        "total_s": time.perf_counter() - t_start,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def atheris_target(name: str, inputs: int, work: Path, crashes: Path) -> dict:
    """The same target under atheris (coverage-guided, ``fuzz_atheris.py``) in its own process."""
    counts_file = work / f"{name}-atheris.json"
    t0 = time.perf_counter()
    script = Path(__file__).with_name("fuzz_atheris.py")
    crashes.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(
        [sys.executable, "-W", "ignore", str(script), name, str(inputs), str(counts_file)],
        capture_output=True,
        text=True,
        cwd=crashes,  # libFuzzer writes crash-* files into the working folder
    )
    counts = json.loads(counts_file.read_text()) if counts_file.is_file() else {TYPED: 0, VALID: 0, CRASH: 0}
    hang = int("timeout" in proc.stderr[-2000:].lower())
    if proc.returncode and not counts[CRASH] and not hang:
        counts[CRASH] = 1  # libFuzzer stopped on something else (an out-of-memory, a signal)
    if proc.returncode:
        (crashes / f"{name}-atheris.log").write_text(proc.stderr[-20000:])
        print(f"{name} (atheris): stopped, exit {proc.returncode}; log in {crashes}", flush=True)
    run = sum(counts.values())
    return {
        "target": f"{name} (atheris)",
        "inputs": run,
        "seeds": "",
        **counts,
        "hang": hang,
        "slowest_s": float("nan"),
        "total_s": time.perf_counter() - t0,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
    }


def markdown(rows: list[dict], command: str) -> str:
    head = ["target", "seeds", "inputs run", "typed error", "valid result", "crash", "hang > 10 s"]
    head += ["slowest input (s)", "time (s)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append(
            f"| {r['target']} | {r['seeds']} | {r['inputs']} | {r[TYPED]} | {r[VALID]} | {r[CRASH]} | "
            f"{r['hang']} | {r['slowest_s']:.2f} | {r['total_s']:.0f} |".replace("| nan |", "| |")
        )
    peak = max(r["peak_rss_mb"] for r in rows)
    lines.append("")
    lines.append(f"Measured with `{command}`; peak RSS of the whole fuzz process {peak:.0f} MB.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inputs", type=int, default=10_000, help="inputs per target (default 10000)")
    parser.add_argument("--targets", default=",".join(TARGETS), help="comma-separated targets")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--crashes", default="fuzz_crashes", help="folder for crashing inputs")
    parser.add_argument("--table", default=None, help="Markdown file whose fuzz table to replace")
    parser.add_argument(
        "--atheris",
        type=int,
        default=0,
        metavar="N",
        help="also N coverage-guided inputs per target with atheris (the optional extra semcityloc[fuzz])",
    )
    args = parser.parse_args(argv)
    signal.signal(signal.SIGALRM, _alarm)
    rows = []
    with tempfile.TemporaryDirectory(prefix="semcityloc-fuzz-") as tmp:
        for name in args.targets.split(","):
            row = fuzz_target(name, args.inputs, args.seed, Path(tmp), Path(args.crashes))
            print(
                f"{name}: {row['inputs']} inputs, {row[TYPED]} typed, {row[VALID]} valid, "
                f"{row[CRASH]} crash, {row['hang']} hang, slowest {row['slowest_s']:.2f} s, "
                f"{row['total_s']:.0f} s",
                flush=True,
            )
            rows.append(row)
            if args.atheris:
                row = atheris_target(name, args.atheris, Path(tmp), Path(args.crashes))
                print(
                    f"{row['target']}: {row['inputs']} inputs, {row[CRASH]} crash, {row['hang']} hang",
                    flush=True,
                )
                rows.append(row)
    command = "python tests/fuzz_run.py " + " ".join(argv if argv is not None else sys.argv[1:])
    table = markdown(rows, command.strip())
    print(table)
    if args.table:
        path = Path(args.table)
        text = path.read_text(encoding="utf-8")
        before, _, rest = text.partition(MARK)
        _, _, after = rest.partition(MARK)
        path.write_text(f"{before}{MARK}\n{table}\n{MARK}{after}", encoding="utf-8")
    return 1 if any(r[CRASH] or r["hang"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
