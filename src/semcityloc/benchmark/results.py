"""The results of a run: ``results.csv`` rows, the ``details/`` npz files and the summary.

Why its own module: the row format is what the report, resuming and users' scripts read; keeping it in one
place (columns, formatting, append/read/repair, summary) keeps every run's files the same.

``results.csv``: one row per finished query (``COLUMNS``), appended as ONE ``write`` of a full line
followed by ``fsync``, by the parent process only. On start the file is read, a torn last line (no
newline: the process died mid-write) is cut off, and the ids already there are skipped. Rows may be in any
order (``--workers``); each id appears once (a repeated row is dropped, two different rows of one id
refused: ``parse_results``). Poses: the map model's local frame (x y z m, roll pitch yaw
deg) + world x y z (``origin + local``); errors: camera-centre distance (m), full rotation angle and yaw
(deg), "inf" when not localized; timings in s; ``sigma_xy_m`` (per axis) / ``sigma_z_m`` /
``sigma_yaw_deg``: the accepted pose's 1-sigma from its covariance (``localization/covariance.py``; empty
without one);
``warnings``: what the localizer ignored and why (a depth map dropped) or noticed (buildings the map
lacks; ``LocalizationResult.warnings``), joined by `` | ``, empty
when none; ``flat_roof_eaves_used``: 1 where ``map_eaves_flat_roofs="auto"``'s second look took the pose from
the map with eaves on its flat roofs (``Localizer.map_of``), 0 where it kept the first, empty where it made
none (the report draws the map at the estimate from it); ``lookalike_margin``: the pose's final score
minus that of the best look-alike more than 5 m / 5 deg away (``localization/lookalike.py``; empty when
none); ``focal_scale``: the focal scale the returned pose was found with where the focal check's correction
took it (``focal_check.focal_scale_used``: the stated focal lengths times it; empty: the stated ones). A
``results.csv`` written before a column of ``ADDED_COLUMNS`` existed still resumes: it is rewritten with that
column (empty) before rows are appended, so every line matches the header.

``details/qNNNN.npz`` (first ``keep_details`` queries): labels, depth, camera, true / prior / estimated /
coarse poses, the coarse cost volume and its axes, the second look's ``flat_roof_eaves`` record (the map
the pose was found on) and ``focal_scale`` (as the row's: the report draws the estimate with the stated
camera's focal lengths times it, ``focal_check.found_camera``), for the report's figures; written
atomically BEFORE the row, so a row always has its details. One deleted since is made again by a resume
(``missing_details``: the query localized again, its row replaced in place by ``write_rows``). The depth
is kept as float16 (``details_depth``) when its values fit: relative depth is good to a few percent,
float16 to 0.05 %, and the file is less than half the size.

``summary.json``: metrics over all rows (``summarize_rows``). ``queries`` counts the evaluated queries: a
query its source did not accept (a view the simulator could not make acceptable, a photo whose mask or
depth cannot be read in full) gets a ``skipped`` row with the reason, is not localized and is only counted
under ``skipped``. A data-set query whose mask or depth cannot be read is not skipped but a miss
(``unreadable_result``): a ``not_localized`` row in every recall. So is a photo of a run against ground
truth that the run skipped before anything ran (``skipped_miss_result``), counted again apart as
``skipped_counted_as_misses`` (only when there is one).

A run folder speaks the command line's words, whoever started the run: a reason or warning the library
worded with a Python parameter (``errors.parameter``: ``prior_uncertainty=PriorUncertainty.parse('z=8')``)
is kept with its flag (``errors.as_flags``: ``--prior-sigma z=8``) in ``results.csv``, the details, the
photo records and ``summary.json``, as the benchmark's own notes name flags. Why: the folder is what the
command's user reads and acts on, and a resumed run (whose old rows name flags) keeps one wording per reason.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
from collections import Counter
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.benchmark.perception_sim import MIN_PRESENT_PIXELS, MIOU_CLASSES
from semcityloc.benchmark.queries import BenchmarkQuery, query_id
from semcityloc.benchmark.runfiles import (
    DETAILS_DIR,
    RESULTS_FILE,
    plain,
    read_error,
    read_run_file,
    write_all,
    writing,
)
from semcityloc.classes import NUM_CLASSES
from semcityloc.errors import BenchmarkError, as_flags, parameter
from semcityloc.evaluation.metrics import THRESHOLDS, is_right, pose_errors, recall, summarize_errors
from semcityloc.geometry.pose import Pose
from semcityloc.io.files import removed_on_error, write_atomic
from semcityloc.localization.covariance import horizontal_sigma
from semcityloc.localization.focal_check import focal_scale_used
from semcityloc.localization.result import LOCALIZED, NOT_LOCALIZED, LocalizationResult
from semcityloc.perception.metrics import mean_iou

_POSE_FIELDS = ("x", "y", "z", "roll", "pitch", "yaw")
_TRUE = " ".join(f"true_{k}" for k in _POSE_FIELDS) + " true_world_x true_world_y true_world_z"
_EST = " ".join(f"est_{k}" for k in _POSE_FIELDS) + " est_world_x est_world_y est_world_z"
_PRIOR = " ".join(f"prior_{k}" for k in _POSE_FIELDS)
COLUMNS: tuple[str, ...] = tuple(
    f"""query_id index status reason warnings view height_m query_miou {_TRUE} {_EST} {_PRIOR}
    prior_err_m prior_rot_deg prior_yaw_err_deg err_xyz_m err_rot_deg err_yaw_deg
    coarse_err_xyz_m coarse_err_yaw_deg score semantic depth_cost score_margin spread_m spread_deg
    building_iou probability found_err_xyz_m found_err_rot_deg coarse_hypotheses refine_evaluations
    t_coarse_s t_refine_s t_total_s meta_json sigma_xy_m sigma_z_m sigma_yaw_deg
    hypothesis_margin depth_cost_agreed building_fraction prior_distance boundary_distance_px
    unmapped_building_share unseen_building_share flat_roof_eaves_used lookalike_margin focal_scale""".split()
)
TIMING_COLUMNS = ("t_coarse_s", "t_refine_s", "t_total_s")
# The acceptance's other inputs, as ``result.confidence`` holds them (stop 42; empty in earlier runs).
CONFIDENCE_COLUMNS = (
    "hypothesis_margin",
    "depth_cost_agreed",
    "building_fraction",
    "prior_distance",
    "boundary_distance_px",
    "unmapped_building_share",
    "unseen_building_share",
)
# Columns added after runs had been written with the others (module docstring): such a run still resumes.
ADDED_COLUMNS = (
    ("warnings", "sigma_xy_m", "sigma_z_m", "sigma_yaw_deg")
    + CONFIDENCE_COLUMNS
    + ("flat_roof_eaves_used", "lookalike_margin", "focal_scale")
)


def _resumable(header: tuple[str, ...]) -> bool:
    """True for this version's columns with some of ``ADDED_COLUMNS`` left out, in this version's order."""
    return header == tuple(c for c in COLUMNS if c in header) and set(COLUMNS) - set(header) <= set(
        ADDED_COLUMNS
    )


WARNING_SEPARATOR = " | "
# The meta key of what a query's source says of its inputs (a photo whose prior had no heading:
# ``datasets.photos.PhotoPrior.warnings``), added to its result's ``warnings`` (``benchmark.run``).
SOURCE_WARNINGS = "source_warnings"
# The meta key saying whether a query's prior had a heading (False: a photo without one, its yaw taken as 0
# and every heading searched): without one its rotation and yaw errors are left empty (``make_row``).
HEADING_KNOWN = "heading_known"

# A query its source did not accept (``meta["accepted"] is False``): a simulated view the simulator could
# not make acceptable, or a photo whose files could not be read in full (``meta["skip_reason"]`` says why).
# Recorded so a resumed run does not redo it, not localized, and left out of every metric (counted as
# ``skipped``).
SKIPPED = "skipped"
REASON_SKIPPED = "simulator found no acceptable view"
SKIP_REASON = "skip_reason"  # the meta key of a source's own reason for not accepting a query


def skipped_result(reason: str = REASON_SKIPPED) -> LocalizationResult:
    """The result of a query its source did not accept (``SKIPPED``), with the reason."""
    return LocalizationResult(status=SKIPPED, reason=reason)


# A query of a run against ground truth whose own input files cannot be read (a data set's corrupt mask or
# depth map; ``meta[UNREADABLE_INPUT]`` says which and why): not localized, the reason starting with
# ``REASON_UNREADABLE``, so that it is a miss in every recall. Never ``SKIPPED``: a benchmark whose files
# are damaged must not score better than one whose files read (the recall's denominator stays the queries).
# A file that reads but cannot be used with its camera (a mask of another size, a depth map of ids) is
# the same kind of miss, said in its own words (``REASON_UNFIT``, ``meta[UNFIT_INPUT]`` true).
REASON_UNREADABLE = "input file cannot be read"
REASON_UNFIT = "input file does not fit its camera"
UNREADABLE_INPUT = "unreadable_input"  # the meta key of what could not be read (or used)
UNFIT_INPUT = "unfit_input"  # the meta key saying it was read but does not fit


def unreadable_result(problem: str, unfit: bool = False) -> LocalizationResult:
    """The result of a query whose input files cannot be read or used (``UNREADABLE_INPUT``): not localized,
    a miss, the reason naming the file and the problem."""
    return LocalizationResult(
        status=NOT_LOCALIZED, reason=f"{REASON_UNFIT if unfit else REASON_UNREADABLE}: {problem}"
    )


# A photo of a run against ground truth that the run skipped before anything ran for another cause than its
# own file (no usable prior, no intrinsics, a prior off the map, a lossy mask without ``allow_lossy_mask``:
# ``benchmark.photo_inputs``; ``meta[SKIPPED_MISS]`` says why): not localized, the reason starting with
# ``REASON_SKIPPED_MISS`` and keeping the skip's, so that it is a miss in every recall (stop 53). Before, it
# left the recall's denominator: a flight scored better by losing the photos it could not place.
REASON_SKIPPED_MISS = "skipped, counted as a miss"
SKIPPED_MISS = "skipped_miss"  # the meta key of why the photo was skipped


def skipped_miss_result(reason: str) -> LocalizationResult:
    """The result of a photo of the truth its run skipped (``SKIPPED_MISS``): not localized, a miss, the
    reason the skip's."""
    return LocalizationResult(status=NOT_LOCALIZED, reason=f"{REASON_SKIPPED_MISS}: {reason}")


def counted_as(n: int) -> str:
    """``a miss`` or ``misses``: how ``n`` photos skipped with a true pose are counted, in the closing line
    and the report's note."""
    return "a miss" if n == 1 else "misses"


def is_skipped_miss(reason: str | None) -> bool:
    """Whether a result's (or row's) reason is ``skipped_miss_result``'s."""
    return (reason or "").startswith(REASON_SKIPPED_MISS)


def skipped_miss_row(row: dict[str, str]) -> bool:
    """Is this ``results.csv`` row a ``skipped_miss_result`` (nothing searched: the miss kind ``skipped``)?"""
    return row["status"] == NOT_LOCALIZED and is_skipped_miss(row.get("reason"))


def is_unreadable(reason: str | None) -> bool:
    """Whether a result's (or row's) reason is ``unreadable_result``'s."""
    return (reason or "").startswith((REASON_UNREADABLE, REASON_UNFIT))


def unreadable_row(row: dict[str, str]) -> bool:
    """Is this ``results.csv`` row an ``unreadable_result``: a miss because its input could not be read,
    not because anything was searched or refused (the report files it apart: ``miss_kinds``)?"""
    return row["status"] == NOT_LOCALIZED and is_unreadable(row.get("reason"))


# A query whose worker process died on every try (``benchmark.ray_executor``): recorded with the reason,
# not tried again on resume.
FAILED = "failed"


def recall_summary(results: list[LocalizationResult], queries: list[BenchmarkQuery]) -> dict:
    """Recall at ``THRESHOLDS`` over ``queries`` (a query not localized counts as a miss), how many were
    localized, and the share of those within 5 m / 5 deg: the one-line figures of the experiment scripts
    that localize cached queries themselves (``benchmarks/focal_selfcal.py``, ``flight_prior.py``)."""
    err_m, err_deg = [], []
    accepted_right = accepted = 0
    for r, q in zip(results, queries, strict=True):
        m, d, _ = pose_errors(r.pose_local if r.status == LOCALIZED else None, q.true_pose_local)
        err_m.append(m)
        err_deg.append(d)
        if r.status == LOCALIZED:
            accepted += 1
            accepted_right += is_right(m, d)
    return {
        "recall": [round(recall(err_m, err_deg, m, d), 1) for m, d in THRESHOLDS],
        "localized": accepted,
        "accepted_right_pct": round(100.0 * accepted_right / max(accepted, 1), 1),
    }


ERROR_COLUMNS = ("err_xyz_m", "err_rot_deg", "err_yaw_deg")


def failed_row(index: int, reason: str, has_truth: bool = False) -> dict[str, str]:
    """The ``results.csv`` row of a query that could not be run (every other column empty). With
    ``has_truth`` (the query has a true pose: every simulated or data-set query, a photo given its truth)
    its errors are ``inf``, as a query not localized: a miss in every recall, whose denominator stays the
    number of queries, instead of a query left out."""
    row = dict.fromkeys(COLUMNS, "")
    row.update(query_id=query_id(index), index=str(index), status=FAILED, reason=reason.replace("\n", " "))
    if has_truth:
        row.update(dict.fromkeys(ERROR_COLUMNS, "inf"))
    return row


# ------------------------------------------------------------------------------------------------ rows
def _fmt(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool | np.bool_):
        return "1" if value else "0"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return repr(float(value))
    return str(value).replace("\r", " ").replace("\n", " ")


def _pose_values(prefix: str, pose_local: Pose | None, origin_world: np.ndarray, world: bool = True) -> dict:
    keys = [f"{prefix}_{k}" for k in _POSE_FIELDS]
    if world:
        keys += [f"{prefix}_world_{k}" for k in "xyz"]
    if pose_local is None:
        return dict.fromkeys(keys)
    values = list(pose_local.to_xyz_rpy())
    if world:
        values += list(pose_local.center + origin_world)
    return dict(zip(keys, values, strict=True))


def row_pose(row: dict[str, str], prefix: str) -> Pose | None:
    """The local pose in a row's columns ``<prefix>_x ... <prefix>_yaw`` (what ``_pose_values`` wrote), or
    None when any is empty or not a finite number."""
    try:
        values = [float(row.get(f"{prefix}_{k}") or "nan") for k in _POSE_FIELDS]
    except ValueError:
        return None
    if not np.all(np.isfinite(values)):
        return None
    x, y, z, roll, pitch, yaw = values
    return Pose.from_xyz_rpy(np.array([x, y, z]), roll, pitch, yaw)


def make_row(q: BenchmarkQuery, result: LocalizationResult, origin_world: np.ndarray) -> dict[str, str]:
    """One ``results.csv`` row (all values formatted) from a query and its result (poses local)."""
    est_local = result.pose_local if result.localized else None
    true_local = q.true_pose_local
    none = (None, None, None)  # no ground truth (a user's photo): no error
    err = pose_errors(est_local, true_local) if true_local is not None else none
    prior_local = q.prior_pose_local  # None: an unreadable photo's (``photo_inputs.PhotoInput.unreadable``)
    prior_err = (
        pose_errors(prior_local, true_local) if true_local is not None and prior_local is not None else none
    )
    coarse_local = result.coarse_pose_local
    coarse_err = (
        pose_errors(coarse_local, true_local) if coarse_local is not None and true_local is not None else none
    )
    # The pose the search found, accepted or refused: what the acceptance's risk-coverage curve needs.
    found_local = result.found_pose_local
    found_err = (
        pose_errors(found_local, true_local) if found_local is not None and true_local is not None else none
    )
    meta = dict(q.meta or {})
    if not meta.get(HEADING_KNOWN, True):  # its yaw was taken, not known: no error of it, nor of its rotation
        prior_err = (prior_err[0], None, None)
    conf, counts, timings = result.confidence or {}, result.counts or {}, result.timings or {}
    row: dict[str, Any] = {
        "query_id": query_id(q.index),
        "index": q.index,
        "status": result.status,
        "reason": as_flags(result.reason),
        "warnings": as_flags(WARNING_SEPARATOR.join(result.warnings)),
        "view": meta.get("view"),
        "height_m": meta.get("height_m"),
        "query_miou": q.query_miou,
        **_pose_values("true", q.true_pose_local, origin_world),
        **_pose_values("est", est_local, origin_world),
        **_pose_values("prior", q.prior_pose_local, origin_world, world=False),
        "prior_err_m": prior_err[0],
        "prior_rot_deg": prior_err[1],
        "prior_yaw_err_deg": prior_err[2],
        "err_xyz_m": err[0],
        "err_rot_deg": err[1],
        "err_yaw_deg": err[2],
        "coarse_err_xyz_m": coarse_err[0],
        "coarse_err_yaw_deg": coarse_err[2],
        "score": result.score,
        "semantic": result.semantic,
        "depth_cost": result.depth_cost,
        "score_margin": conf.get("score_margin"),
        "spread_m": conf.get("spread_m"),
        "spread_deg": conf.get("spread_deg"),
        "building_iou": conf.get("building_iou"),
        "probability": conf.get("probability"),
        "found_err_xyz_m": found_err[0],
        "found_err_rot_deg": found_err[1],
        "coarse_hypotheses": counts.get("coarse_hypotheses"),
        "refine_evaluations": counts.get("refine_evaluations"),
        "t_coarse_s": timings.get("coarse_s"),
        "t_refine_s": timings.get("refine_s"),
        "t_total_s": timings.get("total_s"),
        "meta_json": json.dumps(plain(meta), sort_keys=True),
        **_sigmas(result.covariance if est_local is not None else None),
        **{c: conf.get(c) for c in CONFIDENCE_COLUMNS},
        "flat_roof_eaves_used": flat_roof_eaves_used(result),
        "lookalike_margin": conf.get("lookalike_margin"),
        "focal_scale": focal_scale_used(result.search or {}),
    }
    return {c: _fmt(row.get(c)) for c in COLUMNS}


def flat_roof_eaves_used(result: LocalizationResult) -> bool | None:
    """Did ``map_eaves_flat_roofs="auto"``'s second look take the result's pose from the map with eaves on
    its flat roofs (``Localizer.map_of``)? None when it made no look; drawings of the map at the estimate
    read it back (``benchmark.found_map``)."""
    look = result.search.get("flat_roof_eaves")
    return None if look is None else bool(look.get("used"))


def _sigmas(covariance: np.ndarray | None) -> dict[str, float | None]:
    """1-sigma of the accepted pose from its covariance: horizontal per axis (``horizontal_sigma``), height
    and yaw; None without a covariance."""
    if covariance is None:
        return {"sigma_xy_m": None, "sigma_z_m": None, "sigma_yaw_deg": None}
    sigma = np.sqrt(np.diag(covariance))
    return {
        "sigma_xy_m": horizontal_sigma(sigma[0], sigma[1]),
        "sigma_z_m": float(sigma[2]),
        "sigma_yaw_deg": float(sigma[5]),
    }


def _csv_line(row: dict[str, str]) -> bytes:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([row.get(c, "") for c in COLUMNS])
    return buf.getvalue().encode("utf-8")


def append_row(path: Path, row: dict[str, str]) -> None:
    """Append one row as a single full-line write, then fsync (a crash loses at most this line). A write
    that fails (a full disk) is cut off again, so the file keeps whole lines only; the error is
    ``runfiles.write_error`` naming the file."""
    with writing(path):
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            size = os.fstat(fd).st_size
            try:
                write_all(fd, _csv_line(row))
                os.fsync(fd)
            except OSError:
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, size)
                raise
        finally:
            os.close(fd)


def read_results(path: Path) -> list[dict[str, str]]:
    """Rows of ``results.csv``, repairing it first: a torn last line is cut off, a missing or torn header is
    rewritten. A row repeated word for word is dropped and the file rewritten without it; two different rows
    of one id are refused (``parse_results``)."""
    data = read_run_file(path)
    if data and not data.endswith(b"\n"):
        cut = data.rfind(b"\n") + 1
        with open(path, "r+b") as fh:
            fh.truncate(cut)
            fh.flush()
            os.fsync(fh.fileno())
        data = data[:cut]
    if not data:
        write_atomic(path, ",".join(COLUMNS) + "\n")
        return []
    rows, repeated = _parse_results(data, path, strict=True)
    if repeated or not data.startswith((",".join(COLUMNS) + "\n").encode()):  # an earlier layout, repeats
        write_rows(path, rows)
    return rows


def write_rows(path: Path, rows: Iterable[dict[str, str]]) -> None:
    """``results.csv`` holding exactly ``rows`` under this version's header, written atomically (a kill or
    a full disk leaves the old file whole; the error is ``runfiles.write_error`` naming the file)."""
    with writing(path):
        write_atomic(path, (",".join(COLUMNS) + "\n").encode() + b"".join(_csv_line(r) for r in rows))


def parse_results(data: bytes, path: Path | str = RESULTS_FILE, strict: bool = True) -> list[dict[str, str]]:
    """Rows of the bytes of a ``results.csv`` (read-only; a torn last line is ignored). ``strict``: the
    columns must be this version's, or this version's but ``ADDED_COLUMNS`` (a run to resume); else a file
    of an earlier version is read by its own header. Columns of this version that a file lacks are empty.
    A row repeated word for word counts once; two different rows of one id (another run's row among ours)
    are a ``BenchmarkError`` naming the id and both lines, never one of them chosen silently."""
    return _parse_results(data, path, strict)[0]


def _parse_results(data: bytes, path: Path | str, strict: bool) -> tuple[list[dict[str, str]], int]:
    """``parse_results``'s rows and how many rows repeated an earlier one word for word."""
    data = data[: data.rfind(b"\n") + 1]
    if not data:
        return [], 0
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise read_error(path, exc) from exc
    reader = csv.reader(io.StringIO(text))
    header = tuple(next(reader))
    if not _resumable(header) and (strict or "query_id" not in header):
        raise BenchmarkError(
            f"{path}: its columns differ from this version's; pass {parameter('overwrite')} to start the run "
            f"again, or choose another {parameter('out_dir')}"
        )
    rows: dict[str, dict[str, str]] = {}
    first: dict[str, tuple[int, list[str]]] = {}
    repeated = 0
    for values in reader:
        n = reader.line_num  # the file's line (a quoted field may hold a newline)
        if not "".join(values).strip():  # a blank line (an editor's, a concatenation's): no row, nothing lost
            continue
        if len(values) != len(header):
            raise BenchmarkError(
                f"{path}: line {n} has {len(values)} fields, not {len(header)}: delete that line to keep "
                f"the other rows, or pass {parameter('overwrite')} to start the run again"
            )
        row = {c: "" for c in COLUMNS} | dict(zip(header, values, strict=True))
        qid = row["query_id"]
        if qid in first:
            if first[qid][1] != values:
                raise BenchmarkError(
                    f"{path}: query {qid} has 2 different rows (lines {first[qid][0]} and {n}): delete the "
                    "one not of this run to keep the other rows, or pass "
                    f"{parameter('overwrite')} to start the run again"
                )
            repeated += 1
            continue
        first[qid] = (n, values)
        rows[qid] = row
    return list(rows.values()), repeated


# --------------------------------------------------------------------------------------------- details
def _pose_matrix(pose_local: Pose | None) -> np.ndarray:
    return pose_local.cam_from_world if pose_local is not None else np.full((4, 4), np.nan)


FLOAT16_SAFE_MAX = 60_000.0  # float16's largest finite value is 65,504


def save_details(path: Path, q: BenchmarkQuery, result: LocalizationResult, origin_world: np.ndarray) -> None:
    """The npz the report's figures need (module docstring), written atomically."""
    cam = q.camera
    volume = result.cost_volume
    est_local = result.pose_local if result.localized else None
    meta = {
        "query_id": path.stem,
        "status": result.status,
        "reason": as_flags(result.reason),
        "query_miou": q.query_miou,
        "query_meta": as_flags(q.meta),
        "cost_volume": volume.as_dict() if volume is not None else None,
        "camera": cam.as_dict(),
        "flat_roof_eaves": result.search.get("flat_roof_eaves"),  # the map the pose was found on
        # the camera it holds with: ``camera`` times this where the focal check's correction re-found it
        "focal_scale": focal_scale_used(result.search or {}),
    }
    arrays = {
        "labels": np.asarray(q.labels, dtype=np.uint8),
        "depth": details_depth(q.depth),
        "camera": np.array([cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height], dtype=np.float64),
        "origin": np.asarray(origin_world, dtype=np.float64),
        "true_cam_from_world": _pose_matrix(q.true_pose_local),
        "prior_cam_from_world": _pose_matrix(q.prior_pose_local),
        "est_cam_from_world": _pose_matrix(est_local),
        "coarse_cam_from_world": _pose_matrix(result.coarse_pose_local),
        "cost_scores": (
            volume.scores.astype(np.float32) if volume is not None else np.zeros((0, 0, 0, 0), np.float32)
        ),
        "meta": np.frombuffer(json.dumps(plain(meta)).encode("utf-8"), dtype=np.uint8),
    }
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    with writing(path), removed_on_error(tmp):
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)


def missing_details(out_dir: Path, rows: list[dict[str, str]], keep: int) -> list[int]:
    """The indices of a run's finished queries below ``keep`` whose ``details/qNNNN.npz`` is gone (a
    deleted ``details/``): the report would draw no figure of them. A resume localizes them again
    (``benchmark.run``), the report names them. Rows that never had details (``skipped``, ``failed``, a
    data-set query whose files cannot be read: ``unreadable_result``) are left out."""
    ids = {query_id(i): i for i in range(keep)}
    return sorted(
        ids[r["query_id"]]
        for r in rows
        if r["query_id"] in ids
        and r["status"] not in (SKIPPED, FAILED)
        and not unreadable_row(r)
        and not (out_dir / DETAILS_DIR / f"{r['query_id']}.npz").is_file()
    )


def missing_details_phrase(out_dir: Path, missing: list[int]) -> str:
    """ "OUT/details: the details files of 2 finished queries are missing (q0000, q0001)": the start of
    what the run and the report say about ``missing_details`` (the first five ids named)."""
    ids = [query_id(i) for i in missing]
    shown = ", ".join(ids[:5]) + (", ..." if len(ids) > 5 else "")
    finished = f"{len(ids)} finished {'queries' if len(ids) != 1 else 'query'}"
    return f"{out_dir / DETAILS_DIR}: the details files of {finished} are missing ({shown})"


def details_depth(depth: np.ndarray | None) -> np.ndarray:
    """The query depth as a details file keeps it: float16 when every finite value fits (< 60,000 in
    magnitude), else float32; NaN stays NaN; (0, 0) when there is none."""
    if depth is None:
        return np.zeros((0, 0), np.float16)
    depth = np.asarray(depth, dtype=np.float32)
    finite = depth[np.isfinite(depth)]
    fits = finite.size == 0 or float(np.abs(finite).max()) < FLOAT16_SAFE_MAX
    return depth.astype(np.float16) if fits else depth


def load_details(path: Path) -> dict:
    """The arrays of a details npz plus ``meta`` decoded (``cost_volume`` axes, camera, status...)."""
    with np.load(path, allow_pickle=False) as z:
        out = {k: z[k] for k in z.files}
    out["meta"] = json.loads(bytes(out["meta"]).decode("utf-8"))
    return out


# --------------------------------------------------------------------------------------------- summary
def map_miou(rows: list[dict[str, str]]) -> dict[str, float]:
    """The query masks' mIoU measured the paper's way: against the map's own labels at the true pose
    (``meta["map_confusion"]``, written when ``score_against_map``), pooled over the rows (one confusion
    summed over every query) and as the mean of the per-image values. Empty when no row has it."""
    confs = []
    for r in rows:
        counts = json.loads(r["meta_json"] or "{}").get("map_confusion")
        if counts is not None:
            confs.append(np.asarray(counts, dtype=np.int64).reshape(NUM_CLASSES, NUM_CLASSES))
    if not confs:
        return {}
    per_image = [
        mean_iou(c, classes=MIOU_CLASSES, min_pixels=MIN_PRESENT_PIXELS, percent_of_mean=True) for c in confs
    ]
    pooled = mean_iou(np.sum(confs, axis=0), classes=MIOU_CLASSES, min_pixels=1, percent_of_mean=True)
    finite = [v for v in per_image if np.isfinite(v)]
    return {
        "map_miou_pooled": float(pooled),
        "map_miou_per_image": float(np.mean(finite)) if finite else float("nan"),
    }


def cell_float(text: str | None) -> float:
    """A numeric ``results.csv`` cell as a float, NaN where it is empty."""
    return float(text) if text not in ("", None) else float("nan")


def summarize_rows(rows: list[dict[str, str]], config: dict) -> dict:
    """``summary.json``: the metrics of ``evaluation.metrics`` over the rows (``skipped`` rows left out
    and counted), timings, query mIoU, the accepted poses' median stated sigma (``median_sigma_xy_m``,
    ``median_sigma_z_m``), a per-view breakdown and the run's config.

    Errors need a true pose: rows without one (a user's photos) count in ``queries`` / ``localized`` /
    ``not_localized`` but not in the error metrics, which cover the ``with_ground_truth`` rows only."""
    skipped = sum(r["status"] == SKIPPED for r in rows)
    every = sorted((r for r in rows if r["status"] != SKIPPED), key=lambda r: int(r["index"]))
    ordered = [r for r in every if r["err_xyz_m"] != ""]  # rows with a true pose have an error
    err = {c: np.array([cell_float(r[c]) for r in ordered]) for c in ERROR_COLUMNS}
    localized = np.array([r["status"] == LOCALIZED for r in ordered], dtype=bool)

    def errors_of(sel: np.ndarray) -> dict:
        return summarize_errors(
            err["err_xyz_m"][sel], err["err_rot_deg"][sel], err["err_yaw_deg"][sel], localized[sel]
        )

    s: dict[str, Any] = {"method": config.get("method")}
    s.update(errors_of(np.ones(len(ordered), dtype=bool)))
    s["with_ground_truth"] = len(ordered)
    if len(ordered) < len(every):
        n_loc = sum(r["status"] == LOCALIZED for r in every)
        s.update(queries=len(every), localized=n_loc, not_localized=len(every) - n_loc)
    s["skipped"] = skipped
    if counted_misses := sum(skipped_miss_row(r) for r in ordered):  # said apart from ``skipped``
        s["skipped_counted_as_misses"] = counted_misses
    miou = np.array([cell_float(r["query_miou"]) for r in every])
    total = np.array([cell_float(r["t_total_s"]) for r in every])
    s["mean_query_miou"] = float(np.nanmean(miou)) if np.isfinite(miou).any() else float("nan")
    s["sec_per_image"] = float(np.nanmean(total)) if np.isfinite(total).any() else float("nan")
    s["sec_per_image_median"] = float(np.nanmedian(total)) if np.isfinite(total).any() else float("nan")
    s.update(map_miou(ordered))
    for column in ("sigma_xy_m", "sigma_z_m"):  # the accepted poses' stated 1-sigma (covariance)
        values = np.array([cell_float(r.get(column, "")) for r in every if r["status"] == LOCALIZED])
        finite = values[np.isfinite(values)]
        s[f"median_{column}"] = float(np.median(finite)) if finite.size else float("nan")
    s["not_localized_reasons"] = dict(Counter(r["reason"] for r in every if r["status"] != LOCALIZED))
    views = np.array([r["view"] or "unknown" for r in ordered])
    s["by_view"] = {
        v: {k: x for k, x in errors_of(views == v).items() if k != "convention"} for v in sorted(set(views))
    }
    s["config"] = config
    return s
