"""Crash-safety soak: a benchmark SIGKILLed at random moments and resumed ends with the rows of an
uninterrupted run — no duplicates, no torn rows, same numbers (timing columns aside).

1. ``semcityloc benchmark`` runs ``--queries N`` without interruption into ``REF`` (timed: start-up until
   its first row, then seconds per query).
2. The same command into ``SOAK`` is started ``--kills`` times and each time SIGKILLed (by its own pid) at a
   random moment: a third during start-up (within the reference run's time to its first row: loading,
   the lock, compiling), the others once that start has written a row, within the next 4 queries' time
   (a query, a row's write, the summary). After
   each kill the script counts the rows, the torn last line (if any) and the lock file left behind; the
   next start must take the stale lock over and resume.
3. The command then runs to its end; ``SOAK/results.csv`` must hold exactly ``REF``'s rows: the same
   query ids once each, every line whole, every non-timing value equal; ``summary.json`` likewise.

``--command run`` does the same with ``semcityloc run`` over a folder of ``--queries`` photos made here (a
box city, LoD-Loc pose and intrinsics files, oracle masks): its rows, and its ``poses/<stem>.json``.

Prints one line per kill and a final JSON line of counts; exit code 1 when anything differs.

    python benchmarks/soak_resume.py [--queries 40] [--kills 10] [--preset fast] [--seed 0] [--command run]
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

import numpy as np
from PIL import Image

from semcityloc.benchmark.dataset_source import oracle_labels
from semcityloc.benchmark.results import COLUMNS, TIMING_COLUMNS
from semcityloc.benchmark.runfiles import LOCK_FILE, POSES_DIR, RESULTS_FILE, SUMMARY_FILE
from semcityloc.benchmark.warmup import box_city_obj
from semcityloc.citymodel.io import load_city_model
from semcityloc.datasets.lodloc import LodLocQuery, write_lodloc_scene
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import save_labels_png

# Summary keys not compared: timings, and a photo run's output paths (the two runs' folders differ).
SUMMARY_TIMING = ("sec_per_image", "sec_per_image_median", "outputs")


def box_flight(root: Path, photos: int, seed: int) -> list[str]:
    """``photos`` photos over the box city (``benchmark.warmup.box_city_obj``): truths, priors 2-4 m off,
    intrinsics in LoD-Loc's layout, oracle masks; the ``semcityloc run`` arguments that read them."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    city = root / "city.obj"
    city.write_text(box_city_obj())
    model = load_city_model(city, cache=False)
    camera = Camera.from_fov(160, 120, 60.0)
    rng = np.random.default_rng(seed)
    queries = []
    for i in range(photos):
        truth = Pose.from_xyz_rpy(
            [rng.uniform(-12, 12), rng.uniform(-10, 10), rng.uniform(85, 95)],
            rng.uniform(-1, 1),
            rng.uniform(5, 20),
            rng.uniform(-180, 180),
        )
        prior = Pose.from_rotation_center(truth.R_world_from_cam, truth.center + rng.uniform(-3, 3, 3))
        name = f"P{i:03d}.JPG"
        queries.append(LodLocQuery(name, "flight", camera, gt_pose_world=truth, prior_pose_world=prior))
        Image.new("RGB", (camera.width, camera.height), (120, 120, 120)).save(root / "images" / name)
        save_labels_png(oracle_labels(model, camera, truth), root / "masks" / f"P{i:03d}.png")
    write_lodloc_scene(root, queries)
    return [
        *("run", str(root / "images"), "--city", str(city), "--priors", str(root / "GPS_pose")),
        *("--intrinsics", str(root / "intrinsic"), "--masks", str(root / "masks")),
        *("--truth", str(root / "GT_pose"), "--no-overlays"),
    ]


def command(out: Path, args) -> list[str]:
    if args.command == "run":
        return [
            sys.executable,
            "-m",
            "semcityloc.cli.main",
            *args.run_argv,
            "--preset",
            args.preset,
            "--out",
            str(out),
        ]
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
    parser.add_argument(
        "--command",
        choices=("benchmark", "run"),
        default="benchmark",
        help="benchmark (simulated queries) or run (a folder of --queries photos over a box city)",
    )
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="semcityloc-soak-") as tmp:
        work = Path(args.work or tmp)
        ref, soak = work / "ref", work / "soak"
        if args.command == "run":
            args.run_argv = box_flight(work / "flight", args.queries, args.seed)
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
            # A third of the kills during start-up (loading, compiling, the lock); the rest among the
            # queries: once this start has written a row, within the next 4 queries' time.
            in_startup = rng.random() < 1 / 3
            at = rng.uniform(0.5, startup) if in_startup else rng.uniform(0, 4 * per_query)
            before = len(rows_of(soak / RESULTS_FILE)[0])
            t_start = time.perf_counter()
            proc = subprocess.Popen(command(soak, args), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            while not in_startup and proc.poll() is None and len(rows_of(soak / RESULTS_FILE)[0]) <= before:
                time.sleep(0.02)
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
            at = time.perf_counter() - t_start
            kills.append({"at_s": round(at, 2), "rows": len(rows), "torn": torn, "finished": finished})
            print(
                f"kill {k + 1}: at {at:.1f} s ({'start-up' if in_startup else 'queries'}), {len(rows)} rows, "
                f"torn last line: {bool(torn)}, lock left: {(soak / LOCK_FILE).exists()}, "
                f"took over a stale lock: {stale}, finished before the kill: {finished}",
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
        if args.command == "run":  # one pose file per photo, the same as the uninterrupted run's
            ref_poses = {
                p.name: json.loads(p.read_text()).get("position") for p in (ref / POSES_DIR).glob("*.json")
            }
            soak_poses = {
                p.name: json.loads(p.read_text()).get("position") for p in (soak / POSES_DIR).glob("*.json")
            }
            counts["pose_files"] = len(soak_poses)
            counts["pose_files_equal"] = ref_poses == soak_poses
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
            and counts.get("pose_files_equal", True)
        )
        return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
