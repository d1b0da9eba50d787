"""The resumable benchmark runner: simulated queries -> a localization method -> ``results.csv``.

Why its own module: a benchmark of hundreds of queries runs for hours, so the runner's job is to make a
run reproducible and cheap to restart, not to localize (``methods``) or simulate (``queries``).

Output folder ``DIR``:

- ``run.json``: the run's full configuration (city file and its SHA-256, LoD, method, localizer preset as
  a dict, query config as a dict, ...), written first. A later call with other arguments is refused
  with ``ResumeMismatchError`` unless ``overwrite`` (which deletes the old results).
- ``results.csv``: one row per finished query (``COLUMNS``), appended as ONE ``write`` of a full line
  followed by ``fsync``, by the parent process only. On start the file is read, a torn last line (no
  newline: the process died mid-write) is cut off, and the ids already there are skipped. Rows may be
  in any order (``--workers``); each id appears once.
- ``details/qNNNN.npz`` for the first ``keep_details`` queries (labels, depth, camera, true / prior /
  estimated / coarse poses, the coarse cost volume and its axes) for the report's figures; written
  atomically BEFORE the row, so a row always has its details.
- ``summary.json``: metrics over all rows (``summarize_rows``), rewritten atomically (tmp + rename)
  when every query is done. ``queries`` counts the evaluated queries: a view the simulator could not
  make acceptable (``meta["accepted"] is False``) gets a ``skipped`` row, is not localized and is only
  counted under ``skipped``.

Frames: queries, poses and the cost volume are in the map model's LOCAL frame; the CSV also gives the
world x, y, z (``origin + local``). The reality model the simulator renders is moved into the map's
local frame (its origin may differ when it comes from another file) in float64.

Numbers do not depend on ``workers``: every query is simulated from ``(seed, index)`` alone and the
localizer seeds its own generator per query.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import re
import shutil
import sys
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from semcityloc import __version__
from semcityloc.benchmark.methods import BenchmarkError, check_method, get_method
from semcityloc.citymodel.io import file_sha256
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.errors import InputFileError
from semcityloc.evaluation.metrics import pose_errors, summarize_errors
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.result import LOCALIZED, LocalizationResult

RUN_FILE = "run.json"
RESULTS_FILE = "results.csv"
SUMMARY_FILE = "summary.json"
DETAILS_DIR = "details"
RUN_FORMAT = 1
GENERATED = "generated"  # --city value meaning the embedded generated district

# Keys of run.json that do not change the numbers (not compared on resume).
NOT_IDENTITY = ("city", "keep_details", "semcityloc_version")  # "city": as typed; city_path counts

_POSE_FIELDS = ("x", "y", "z", "roll", "pitch", "yaw")
_TRUE = " ".join(f"true_{k}" for k in _POSE_FIELDS) + " true_world_x true_world_y true_world_z"
_EST = " ".join(f"est_{k}" for k in _POSE_FIELDS) + " est_world_x est_world_y est_world_z"
_PRIOR = " ".join(f"prior_{k}" for k in _POSE_FIELDS)
# One row per query. Poses: local frame of the map (x y z m, roll pitch yaw deg) + world x y z; errors:
# camera-centre distance (m), full rotation angle and yaw (deg), "inf" when not localized; timings in s.
COLUMNS: tuple[str, ...] = tuple(
    f"""query_id index status reason view height_m query_miou {_TRUE} {_EST} {_PRIOR}
    prior_err_m prior_rot_deg prior_yaw_err_deg err_xyz_m err_rot_deg err_yaw_deg
    coarse_err_xyz_m coarse_err_yaw_deg score semantic depth_cost score_margin spread_m spread_deg
    building_iou coarse_hypotheses refine_evaluations t_coarse_s t_refine_s t_total_s meta_json""".split()
)
TIMING_COLUMNS = ("t_coarse_s", "t_refine_s", "t_total_s")


# A query whose simulated view the simulator did not accept (``meta["accepted"] is False``): recorded so a
# resumed run does not redo it, not localized, and left out of every metric (counted as ``skipped``).
SKIPPED = "skipped"
REASON_SKIPPED = "simulator found no acceptable view"


class ResumeMismatchError(BenchmarkError):
    """The output folder holds a run made with other arguments."""


def query_id(index: int) -> str:
    return f"q{index:04d}"


# --------------------------------------------------------------------------------------------- the spec
@dataclass(frozen=True)
class BenchmarkSpec:
    """What to run. ``query``: a ``semcityloc.benchmark.queries.QueryConfig`` (queries, seed, seg quality,
    prior noise); ``city``: a city model file or ``"generated"``; ``lod``: None = the file's highest LoD
    per building, 1 = LoD1 derived from the file (``derive_lod1``) unless the file is LoD1 already."""

    city: str
    query: Any
    lod: int | None = None
    method: str = "semcityloc"
    preset: str = "default"
    crs: str | None = None
    keep_details: int = 3

    def localizer_config(self) -> LocalizerConfig:
        try:
            return LocalizerConfig.preset(self.preset)
        except KeyError as exc:
            raise BenchmarkError(str(exc.args[0])) from exc


def resolve_city(city: str | Path) -> Path:
    """The CityGML / CityJSON file of ``city`` (``"generated"``: the default generated LoD2 district)."""
    if str(city) == GENERATED:
        from semcityloc.citymodel.generator import default_city_path

        return default_city_path(lod=2).resolve()
    path = Path(city).expanduser()
    if not path.is_file():
        raise InputFileError(f"{path}: no such city model file")
    return path.resolve()


_GENERATED_NAME = re.compile(r"^generated_lod([123])\.gml$")


def generated_sibling(path: Path, lod: int) -> Path | None:
    """``generated_lod{lod}.gml`` beside a file named by the generator's scheme, if it exists."""
    if not _GENERATED_NAME.match(path.name):
        return None
    sibling = path.with_name(f"generated_lod{lod}.gml")
    return sibling if sibling.is_file() else None


def _plain(value: Any) -> Any:
    """JSON-normalised copy (tuples -> lists, numpy scalars -> Python) for storing and comparing."""
    return json.loads(json.dumps(value, default=_json_default))


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def run_config(spec: BenchmarkSpec) -> dict:
    """The ``run.json`` content of ``spec`` (resolves the city file; loads no model)."""
    if spec.lod not in (None, 1, 2, 3):
        raise BenchmarkError(f"lod must be 1, 2 or 3 (or unset for the file's highest), got {spec.lod!r}")
    if not dataclasses.is_dataclass(spec.query):
        raise BenchmarkError("spec.query must be a QueryConfig")
    check_method(spec.method)
    if int(spec.keep_details) < 0:
        raise BenchmarkError(f"keep_details must be >= 0, got {spec.keep_details}")
    city_path = resolve_city(spec.city)
    if spec.lod in (2, 3):
        map_source = generated_sibling(city_path, spec.lod) or city_path
    else:
        map_source = city_path
    reality_source = generated_sibling(city_path, 3) or city_path
    q = spec.query
    queries = int(q.queries)
    if queries < 1:
        raise BenchmarkError(f"the number of queries must be >= 1, got {queries}")
    return _plain(
        {
            "format": RUN_FORMAT,
            "city": str(spec.city),
            "city_path": str(city_path),
            "city_sha256": file_sha256(city_path),
            "lod": spec.lod,
            "map_source": str(map_source),
            "reality_source": str(reality_source),
            "crs": spec.crs,
            "method": spec.method,
            "seg_quality": q.seg_quality,
            "prior_extra_m": q.prior_extra_m,
            "seed": q.seed,
            "queries": queries,
            "localizer_preset": spec.preset,
            "localizer": spec.localizer_config().as_dict(),
            "query_config": dataclasses.asdict(q),
            "keep_details": int(spec.keep_details),
            "semcityloc_version": __version__,
        }
    )


# ------------------------------------------------------------------------------------------ the models
def in_frame(model: CityModel, origin: np.ndarray) -> CityModel:
    """``model`` re-expressed with local origin ``origin`` (float64 shift before the float32 cast)."""
    origin = np.asarray(origin, dtype=np.float64)
    if np.array_equal(model.origin, origin):
        return model
    shifted = model.vertices.astype(np.float64) + (model.origin - origin)
    return dataclasses.replace(model, origin=origin.copy(), vertices=shifted.astype(np.float32))


def _load(path: Path, config: dict, lod: int | None = None) -> CityModel:
    from semcityloc.citymodel.io import load_city_model

    return load_city_model(path, lod=lod, crs=config.get("crs"))


def _map_from(base: CityModel | None, config: dict) -> CityModel:
    lod = config.get("lod")
    if lod in (2, 3):
        return _load(Path(config["map_source"]), config, lod)
    assert base is not None
    if lod == 1 and max(base.lods_present()) > 1:
        from semcityloc.citymodel.lod1 import derive_lod1

        return derive_lod1(base)
    return base


def load_map(config: dict) -> CityModel:
    """The map model of a run configuration (``run_config``): the chosen LoD (see ``BenchmarkSpec``)."""
    base = _load(Path(config["city_path"]), config) if config.get("lod") in (None, 1) else None
    return _map_from(base, config)


def load_models(config: dict) -> tuple[CityModel, CityModel]:
    """(map model, reality model in the map's local frame) of a run configuration (``run_config``).

    Reality (what the simulated drone sees): the city's LoD3 when it has one (the generated city's
    ``generated_lod3.gml``), else the city file at its highest LoD per building.
    """
    city = Path(config["city_path"])
    reality_source = Path(config["reality_source"])
    base = _load(city, config) if config.get("lod") in (None, 1) or reality_source == city else None
    map_model = _map_from(base, config)
    reality = base if base is not None and reality_source == city else _load(reality_source, config)
    if map_model.crs is not None and reality.crs is not None and map_model.crs != reality.crs:
        raise BenchmarkError(
            f"map ({crs_label(map_model.crs)}) and reality ({crs_label(reality.crs)}) CRSs differ"
        )
    return map_model, in_frame(reality, map_model.origin)


def make_simulator(map_model: CityModel, query_config: Any, reality_model: CityModel | None):
    """The default simulator factory: ``QuerySimulator(map_model, query_config, reality_model)``."""
    from semcityloc.benchmark.queries import QuerySimulator

    return QuerySimulator(map_model, query_config, reality_model)


SimulatorFactory = Callable[[CityModel, Any, "CityModel | None"], Any]


# ----------------------------------------------------------------------------------------- the results
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


def _pose_values(prefix: str, pose: Pose | None, origin: np.ndarray, world: bool = True) -> dict:
    keys = [f"{prefix}_{k}" for k in _POSE_FIELDS]
    if world:
        keys += [f"{prefix}_world_{k}" for k in "xyz"]
    if pose is None:
        return dict.fromkeys(keys)
    values = list(pose.to_xyz_rpy())
    if world:
        values += list(pose.center + origin)
    return dict(zip(keys, values, strict=True))


def make_row(index: int, q: Any, result: LocalizationResult, origin: np.ndarray) -> dict[str, str]:
    """One ``results.csv`` row (all values formatted) from a query and its result."""
    est = None
    if result.localized:
        est = result.pose_local if result.pose_local is not None else result.pose
    err = pose_errors(est, q.true_pose)
    prior_err = pose_errors(q.prior_pose, q.true_pose)
    coarse = result.coarse_pose_local
    coarse_err = pose_errors(coarse, q.true_pose) if coarse is not None else (None, None, None)
    meta = dict(q.meta or {})
    conf, counts, timings = result.confidence or {}, result.counts or {}, result.timings or {}
    row: dict[str, Any] = {
        "query_id": query_id(index),
        "index": index,
        "status": result.status,
        "reason": result.reason,
        "view": meta.get("view"),
        "height_m": meta.get("height_m"),
        "query_miou": q.query_miou,
        **_pose_values("true", q.true_pose, origin),
        **_pose_values("est", est, origin),
        **_pose_values("prior", q.prior_pose, origin, world=False),
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
        "coarse_hypotheses": counts.get("coarse_hypotheses"),
        "refine_evaluations": counts.get("refine_evaluations"),
        "t_coarse_s": timings.get("coarse_s"),
        "t_refine_s": timings.get("refine_s"),
        "t_total_s": timings.get("total_s"),
        "meta_json": json.dumps(_plain(meta), sort_keys=True),
    }
    return {c: _fmt(row.get(c)) for c in COLUMNS}


def _csv_line(row: dict[str, str]) -> bytes:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([row.get(c, "") for c in COLUMNS])
    return buf.getvalue().encode("utf-8")


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def append_row(path: Path, row: dict[str, str]) -> None:
    """Append one row as a single full-line write, then fsync (a crash loses at most this line)."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        _write_all(fd, _csv_line(row))
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(path: Path, data: bytes | str) -> None:
    """Write ``path`` through a temporary file in the same folder and ``os.replace`` (never half-written)."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def read_results(path: Path) -> list[dict[str, str]]:
    """Rows of ``results.csv``, repairing it first: a torn last line is cut off, a missing or torn header is
    rewritten. Rows with an id seen before are ignored (the first one counts)."""
    data = path.read_bytes() if path.exists() else b""
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
    return parse_results(data, path)


def parse_results(data: bytes, path: Path | str = RESULTS_FILE) -> list[dict[str, str]]:
    """Rows of the bytes of a ``results.csv`` (read-only; a torn last line is ignored)."""
    data = data[: data.rfind(b"\n") + 1]
    if not data:
        return []
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BenchmarkError(f"{path}: not a results file of this runner ({exc}); use --overwrite") from exc
    reader = csv.reader(io.StringIO(text))
    if tuple(next(reader)) != COLUMNS:
        raise BenchmarkError(
            f"{path}: its columns differ from this version's; use --overwrite or another --out"
        )
    rows: dict[str, dict[str, str]] = {}
    for n, values in enumerate(reader, start=2):
        if len(values) != len(COLUMNS):
            raise BenchmarkError(
                f"{path}: line {n} has {len(values)} fields, not {len(COLUMNS)}; use --overwrite"
            )
        row = dict(zip(COLUMNS, values, strict=True))
        rows.setdefault(row["query_id"], row)
    return list(rows.values())


# ------------------------------------------------------------------------------------------ the details
def _pose_matrix(pose: Pose | None) -> np.ndarray:
    return pose.cam_from_world if pose is not None else np.full((4, 4), np.nan)


def save_details(path: Path, q: Any, result: LocalizationResult, origin: np.ndarray) -> None:
    """The npz the report's figures need (module docstring), written atomically."""
    cam = q.camera
    volume = result.cost_volume
    est = result.pose_local if result.localized else None
    meta = {
        "query_id": path.stem,
        "status": result.status,
        "reason": result.reason,
        "query_miou": q.query_miou,
        "query_meta": q.meta,
        "cost_volume": volume.as_dict() if volume is not None else None,
        "camera": cam.as_dict(),
    }
    arrays = {
        "labels": np.asarray(q.labels, dtype=np.uint8),
        "depth": np.asarray(q.depth, dtype=np.float32)
        if q.depth is not None
        else np.zeros((0, 0), np.float32),
        "camera": np.array([cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height], dtype=np.float64),
        "origin": np.asarray(origin, dtype=np.float64),
        "true_cam_from_world": _pose_matrix(q.true_pose),
        "prior_cam_from_world": _pose_matrix(q.prior_pose),
        "est_cam_from_world": _pose_matrix(est),
        "coarse_cam_from_world": _pose_matrix(result.coarse_pose_local),
        "cost_scores": (
            volume.scores.astype(np.float32) if volume is not None else np.zeros((0, 0, 0, 0), np.float32)
        ),
        "meta": np.frombuffer(json.dumps(_plain(meta)).encode("utf-8"), dtype=np.uint8),
    }
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def load_details(path: Path) -> dict:
    """The arrays of a details npz plus ``meta`` decoded (``cost_volume`` axes, camera, status...)."""
    with np.load(path, allow_pickle=False) as z:
        out = {k: z[k] for k in z.files}
    out["meta"] = json.loads(bytes(out["meta"]).decode("utf-8"))
    return out


# ---------------------------------------------------------------------------------------- the summary
def _float(text: str) -> float:
    return float(text) if text not in ("", None) else float("nan")


def summarize_rows(rows: list[dict[str, str]], config: dict) -> dict:
    """``summary.json``: the metrics of ``evaluation.metrics`` over the rows (``skipped`` rows left out
    and counted), timings, query mIoU, a per-view breakdown and the run's config."""
    skipped = sum(r["status"] == SKIPPED for r in rows)
    ordered = sorted((r for r in rows if r["status"] != SKIPPED), key=lambda r: int(r["index"]))
    err = {c: np.array([_float(r[c]) for r in ordered]) for c in ("err_xyz_m", "err_rot_deg", "err_yaw_deg")}
    localized = np.array([r["status"] == LOCALIZED for r in ordered], dtype=bool)

    def errors_of(sel: np.ndarray) -> dict:
        return summarize_errors(
            err["err_xyz_m"][sel], err["err_rot_deg"][sel], err["err_yaw_deg"][sel], localized[sel]
        )

    s: dict[str, Any] = {"method": config.get("method")}
    s.update(errors_of(np.ones(len(ordered), dtype=bool)))
    s["skipped"] = skipped
    miou = np.array([_float(r["query_miou"]) for r in ordered])
    total = np.array([_float(r["t_total_s"]) for r in ordered])
    s["mean_query_miou"] = float(np.nanmean(miou)) if np.isfinite(miou).any() else float("nan")
    s["sec_per_image"] = float(np.nanmean(total)) if np.isfinite(total).any() else float("nan")
    s["sec_per_image_median"] = float(np.nanmedian(total)) if np.isfinite(total).any() else float("nan")
    s["not_localized_reasons"] = dict(Counter(r["reason"] for r in ordered if r["status"] != LOCALIZED))
    views = np.array([r["view"] or "unknown" for r in ordered])
    s["by_view"] = {
        v: {k: x for k, x in errors_of(views == v).items() if k != "convention"} for v in sorted(set(views))
    }
    s["config"] = config
    return s


def json_safe(value: Any) -> Any:
    """Non-finite floats -> None (strict JSON), recursively."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


# ----------------------------------------------------------------------------------------- the progress
class Progress:
    """One-line ``\\r`` progress bar with ETA on a TTY; elsewhere silent except a final line."""

    def __init__(self, total: int, done: int = 0, stream: TextIO | None = None, label: str = "benchmark"):
        self.total, self.done, self.start_done = total, done, done
        self.stream = stream if stream is not None else sys.stderr
        self.label = label
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.monotonic()
        self._last = 0.0
        if self.tty:
            self._draw()

    def update(self, n: int = 1) -> None:
        self.done += n
        now = time.monotonic()
        if self.tty and (now - self._last > 0.2 or self.done >= self.total):
            self._draw()
            self._last = now

    def _draw(self) -> None:
        width = 30
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(frac * width)
        new = self.done - self.start_done
        elapsed = time.monotonic() - self.t0
        eta = _duration(elapsed / new * (self.total - self.done)) if new else "?"
        self.stream.write(f"\r{self.label} [{bar:<{width}}] {self.done}/{self.total} ETA {eta}   ")
        self.stream.flush()

    def close(self) -> None:
        new = self.done - self.start_done
        elapsed = time.monotonic() - self.t0
        rate = f", {elapsed / new:.2f} s/query" if new else ""
        if self.tty:
            self._draw()
            self.stream.write("\n")
        self.stream.write(
            f"{self.label}: {self.done}/{self.total} queries done ({new} new in {_duration(elapsed)}{rate})\n"
        )
        self.stream.flush()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"


# ----------------------------------------------------------------------------------------- the running
@dataclass
class BenchmarkOutcome:
    out_dir: Path
    complete: bool  # every query has a row (summary.json written)
    new_rows: int  # rows added by this call
    rows: list[dict[str, str]]
    summary: dict | None
    config: dict


def prepare_output(out_dir: Path, config: dict, overwrite: bool = False) -> None:
    """Create ``out_dir`` and its ``run.json``; refuse a folder holding a run with other arguments."""
    out_dir.mkdir(parents=True, exist_ok=True)
    run_file, results = out_dir / RUN_FILE, out_dir / RESULTS_FILE
    mismatch = None
    if run_file.exists():
        try:
            old = json.loads(run_file.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            old = None
            mismatch = f"its {RUN_FILE} is unreadable ({exc})"
        if old is not None:
            differ = [
                f"{k}: {old.get(k)!r} -> {config.get(k)!r}"
                for k in sorted(set(old) | set(config))
                if k not in NOT_IDENTITY and old.get(k) != config.get(k)
            ]
            if differ:
                mismatch = (
                    "arguments differ (" + "; ".join(differ[:4]) + ("; ..." if len(differ) > 4 else "") + ")"
                )
    elif results.exists():
        mismatch = f"it has a {RESULTS_FILE} but no {RUN_FILE}"
    if mismatch and not overwrite:
        raise ResumeMismatchError(
            f"{out_dir} holds another benchmark run: {mismatch}; pass --overwrite or choose another --out"
        )
    if mismatch:
        for name in (RESULTS_FILE, SUMMARY_FILE):
            (out_dir / name).unlink(missing_ok=True)
        shutil.rmtree(out_dir / DETAILS_DIR, ignore_errors=True)
    if mismatch or not run_file.exists():
        write_atomic(run_file, json.dumps(config, indent=2) + "\n")


class _Worker:
    """A simulator and a method for one map, built once per process."""

    def __init__(self, map_model, reality, config: dict, spec_query, factory, details: Path):
        self.sim = factory(map_model, spec_query, reality)
        self.method = get_method(
            config["method"], map_model, LocalizerConfig.preset(config["localizer_preset"])
        )
        # Baselines that simulate their own query input (the wireframe's edge map) draw it from the same
        # perturbed reality the query labels come from, not from the exact map.
        attach = getattr(self.method, "attach_reality", None)
        reality = getattr(self.sim, "reality", None)
        if attach is not None and reality is not None:
            attach(reality)
        self.origin = map_model.origin
        self.details = details
        self.keep = int(config["keep_details"])

    def run(self, index: int) -> dict[str, str]:
        q = self.sim.query(index)
        if not (q.meta or {}).get("accepted", True):
            return make_row(index, q, LocalizationResult(status=SKIPPED, reason=REASON_SKIPPED), self.origin)
        result = self.method.localize(q)
        if index < self.keep:
            save_details(self.details / f"{query_id(index)}.npz", q, result, self.origin)
        return make_row(index, q, result, self.origin)


_PROCESS_WORKER: _Worker | None = None


def _init_process(threads: int, *args) -> None:
    global _PROCESS_WORKER
    try:
        import numba

        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    except ImportError:  # pragma: no cover - numba is a dependency
        pass
    _PROCESS_WORKER = _Worker(*args)


def _run_in_process(index: int) -> dict[str, str]:
    assert _PROCESS_WORKER is not None, "worker process not initialised"
    return _PROCESS_WORKER.run(index)


def run_benchmark(
    spec: BenchmarkSpec,
    out_dir: str | Path,
    workers: int = 1,
    overwrite: bool = False,
    limit: int | None = None,
    progress: bool | TextIO = True,
    simulator_factory: SimulatorFactory | None = None,
) -> BenchmarkOutcome:
    """Run (or resume) a benchmark into ``out_dir`` (module docstring).

    Args:
        workers: processes localizing queries in parallel (each builds its simulator and method once).
        overwrite: start afresh when ``out_dir`` holds a run with other arguments.
        limit: process at most this many new queries in this call, then stop (a later call resumes).
        progress: True for the bar on stderr, False for none, or a stream.
        simulator_factory: ``(map_model, query_config, reality_model) -> simulator`` (default
            ``QuerySimulator``); must be picklable by reference for ``workers > 1``.
    """
    workers = int(workers)
    if workers < 1:
        raise BenchmarkError(f"workers must be >= 1, got {workers}")
    if limit is not None and int(limit) < 0:
        raise BenchmarkError(f"limit must be >= 0, got {limit}")
    out = Path(out_dir)
    config = run_config(spec)
    prepare_output(out, config, overwrite)
    results_path = out / RESULTS_FILE
    rows = read_results(results_path)
    wanted = {query_id(i) for i in range(config["queries"])}
    rows = [r for r in rows if r["query_id"] in wanted]
    done = {r["query_id"] for r in rows}
    todo = [i for i in range(config["queries"]) if query_id(i) not in done]
    if limit is not None:
        todo = todo[: int(limit)]

    details = out / DETAILS_DIR
    if any(i < config["keep_details"] for i in todo):
        details.mkdir(exist_ok=True)
    factory = simulator_factory or make_simulator
    new_rows: list[dict[str, str]] = []
    if todo:
        map_model, reality = load_models(config)
        stream = None if progress is True else progress or None
        bar = Progress(config["queries"], len(done), stream) if progress is not False else None
        worker_args = (map_model, reality, config, spec.query, factory, details)
        try:
            if workers == 1 or len(todo) == 1:
                worker = _Worker(*worker_args)
                for i in todo:
                    row = worker.run(i)
                    append_row(results_path, row)
                    new_rows.append(row)
                    if bar:
                        bar.update()
            else:
                new_rows = _run_pool(todo, workers, worker_args, results_path, bar)
        finally:
            if bar:
                bar.close()
    rows += new_rows
    complete = len(rows) == config["queries"]
    summary = None
    if complete:
        summary = summarize_rows(rows, config)
        write_atomic(out / SUMMARY_FILE, json.dumps(json_safe(summary), indent=2) + "\n")
    return BenchmarkOutcome(out, complete, len(new_rows), rows, summary, config)


def _run_pool(todo, workers, worker_args, results_path: Path, bar: Progress | None) -> list[dict[str, str]]:
    import multiprocessing

    threads = max(1, (os.cpu_count() or 1) // workers)
    ctx = multiprocessing.get_context("spawn")  # numba's thread pools are not fork-safe
    new_rows: list[dict[str, str]] = []
    pool = ProcessPoolExecutor(
        workers, mp_context=ctx, initializer=_init_process, initargs=(threads, *worker_args)
    )
    try:
        pending = {pool.submit(_run_in_process, i) for i in todo}
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                row = fut.result()
                append_row(results_path, row)
                new_rows.append(row)
                if bar:
                    bar.update()
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    return new_rows
