"""The benchmark over a real data set (``semcityloc benchmark --dataset PATH --format lodloc``).

Why its own module: the simulated benchmark (``benchmark.runner``) makes its queries; here they come from
a user's data set (LoD-Loc layout, ``datasets.lodloc``) with real images, real ground truth and the data
set's own priors. Everything after the queries is shared with the simulated benchmark: the methods
registry, ``results.csv`` rows (``runner.make_row``), ``details/``, ``summary.json``
(``runner.summarize_rows``) and resuming (``runner.prepare_output``), so the numbers mean the same.

Perception (the query mask each method localizes with), ``--perception``:

- ``oracle``: automatic labels at the GT pose (``semcityloc.perception.autolabel.auto_label`` when that
  module exists, else the renderer's labels of the model at GT: ``run.json`` says which in
  ``labels_source``). No depth. This measures the search and the data set's frames, not perception:
  every output (``run.json``, ``summary.json``, each row's ``meta_json``, the printed table) says
  ``oracle``.
- ``oracle-degraded``: the same labels through the simulated segmentation preset ``--seg-quality``
  (default ``trained``, the ≈ 88 % mIoU head; ``benchmark.perception_sim``), seeded per query by
  ``(seed, index)``.
- ``masks``: precomputed or model-predicted masks ``<masks>/<stem>.png`` (class ids 0..5, 255 = ignore,
  as palette indices or grey values: what ``io.images.save_labels_png`` writes) or ``<stem>.npy``;
  optional depth ``<depth>/<stem>.npy`` or a 16-bit depth PNG (any positive scale; NaN / <= 0 invalid).

Frames: queries are moved into the model's local frame (``pose.shift_world(model.origin)``) like the
simulated ones; ``results.csv`` also holds world coordinates (the data set's frame). Oracle labels are
rendered at no more than ``ORACLE_MAX_WIDTH`` pixels wide (the localizer searches at 64 px anyway).
Localizer preset: ``wide-z`` by default (``REAL_PRESETS``): LoD-Loc's priors are up to ±30 m off in
height (``script/Generate_priors.py``), beyond the ±8 m of the ``default`` and ±12 m of the ``wide``
grids. At the end, the estimates are also written as a COLMAP text model (``estimates_colmap/``).
"""

from __future__ import annotations

import importlib.util
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from semcityloc import __version__
from semcityloc.benchmark.methods import BenchmarkError, check_method, get_method
from semcityloc.citymodel.io import file_sha256
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import NUM_CLASSES
from semcityloc.datasets.lodloc import FRAME_AUTO, LodLocDataset, LodLocQuery, read_lodloc
from semcityloc.errors import InputFileError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import CoarseConfig, LocalizerConfig

PERCEPTION_ORACLE, PERCEPTION_DEGRADED, PERCEPTION_MASKS = "oracle", "oracle-degraded", "masks"
PERCEPTIONS = (PERCEPTION_ORACLE, PERCEPTION_DEGRADED, PERCEPTION_MASKS)
FORMATS = ("lodloc",)
ORACLE_MAX_WIDTH = 1024
IGNORE = 255
STREAM_SEG = 3  # same stream number as the simulated benchmark's segmentation noise
ESTIMATES_COLMAP_DIR = "estimates_colmap"
RUN_FORMAT = 1

# Localizer presets for real data sets, on top of ``LocalizerConfig.preset`` names.
REAL_PRESETS: dict[str, LocalizerConfig] = {
    # The default grid (x, y +-16 m, yaw +-9 deg) with LoD-Loc's height range (+-30 m in 5 m steps; 13
    # samples per axis with the default x, y, yaw counts). Measured on the real UAVD4L image (prior 20.7 m
    # off in z), oracle labels: default 6.4 m / 1.3 deg, wide 4.5 m / 1.3 deg, wide-z 0.20 m / 0.02 deg.
    "wide-z": LocalizerConfig(coarse=CoarseConfig(range_z_m=60.0, n_z=13)),
}


def localizer_config(name: str) -> LocalizerConfig:
    """A localizer preset by name: ``LocalizerConfig.preset`` names, then ``REAL_PRESETS``."""
    if name in REAL_PRESETS:
        return REAL_PRESETS[name]
    try:
        return LocalizerConfig.preset(name)
    except KeyError:
        from semcityloc.localization.config import PRESETS

        known = ", ".join([*PRESETS, *REAL_PRESETS])
        raise BenchmarkError(f"unknown localizer preset {name!r}; known: {known}") from None


# ---------------------------------------------------------------------------------------------- perception
def autolabel_available() -> bool:
    try:
        return importlib.util.find_spec("semcityloc.perception.autolabel") is not None
    except ImportError:  # the parent package does not exist yet
        return False


def oracle_labels(
    model: CityModel, camera: Camera, pose_world: Pose, renderer=None
) -> tuple[np.ndarray, str]:
    """((H, W) uint8 labels, source) at a WORLD pose: ``auto_label`` when available ("autolabel"),
    else the renderer's labels ("render")."""
    if autolabel_available():
        from semcityloc.perception.autolabel import auto_label

        return np.asarray(
            auto_label(model, camera, pose_world, renderer=renderer), dtype=np.uint8
        ), "autolabel"
    if renderer is None:
        from semcityloc.render import Renderer

        renderer = Renderer(model, engine="numba")
    return renderer.render(camera, pose_world.shift_world(model.origin)).labels[0], "render"


def labels_source() -> str:
    return "autolabel" if autolabel_available() else "render"


def working_camera(camera: Camera, max_width: int = ORACLE_MAX_WIDTH) -> Camera:
    """``camera`` scaled down to at most ``max_width`` pixels wide (same field of view)."""
    if camera.width <= max_width:
        return camera
    return camera.scaled(max_width, max(1, round(camera.height * max_width / camera.width)))


def read_mask(path: str | Path) -> np.ndarray:
    """(H, W) uint8 class ids (0..5, 255 = ignore) from a ``.npy`` or a label PNG (palette or grey image
    whose values are class ids, ``io.images.load_labels_png``)."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        try:
            labels = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise InputFileError(f"{path}: not a readable .npy mask ({exc})") from exc
    else:
        from semcityloc.io.images import load_labels_png

        labels = load_labels_png(path)
    labels = np.asarray(labels)
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer):
        raise ShapeError(
            f"{path}: a mask must be an (H, W) array of class ids, got {labels.shape} {labels.dtype}"
        )
    bad = (labels != IGNORE) & ((labels < 0) | (labels >= NUM_CLASSES))
    if bad.any():
        raise InputFileError(
            f"{path}: class ids must be 0..{NUM_CLASSES - 1} or 255, found {int(labels[bad][0])}"
        )
    return labels.astype(np.uint8)


def read_depth(path: str | Path) -> np.ndarray:
    """(H, W) float64 relative depth from a ``.npy`` or a 16-bit depth PNG (``io.images.load_depth``);
    NaN / <= 0 = invalid."""
    from semcityloc.io.images import load_depth

    if not Path(path).is_file():
        raise InputFileError(f"{path}: no such depth file")
    depth = load_depth(path)
    if not np.issubdtype(depth.dtype, np.number):
        raise ShapeError(f"{path}: depth must be numeric, got {depth.dtype}")
    return depth.astype(np.float64)


def _find(folder: Path, stem: str, suffixes: tuple[str, ...]) -> Path:
    for suffix in suffixes:
        for candidate in (folder / f"{stem}{suffix}", folder / f"{stem}{suffix.upper()}"):
            if candidate.is_file():
                return candidate
    raise InputFileError(f"{folder}: no file for query {stem!r} (looked for {stem}{{{','.join(suffixes)}}})")


# ---------------------------------------------------------------------------------------------- the spec
@dataclass(frozen=True)
class RealBenchmarkSpec:
    """What to run over a real data set (module docstring)."""

    dataset: str
    format: str = "lodloc"
    city: str | None = None
    perception: str = PERCEPTION_ORACLE
    masks: str | None = None
    depth: str | None = None
    seg_quality: str = "trained"
    method: str = "semcityloc"
    preset: str = "wide-z"
    seed: int = 0
    split: str | None = None
    stage: str | None = None
    frame: str = FRAME_AUTO
    ecef_origin_llh: tuple[float, float, float] | None = None  # frame="ecef": default Swiss-EPFL's
    keep_details: int = 3

    def check(self) -> None:
        if self.format not in FORMATS:
            raise BenchmarkError(f"unknown data set format {self.format!r}; known: {', '.join(FORMATS)}")
        if self.perception not in PERCEPTIONS:
            raise BenchmarkError(f"unknown --perception {self.perception!r}; known: {', '.join(PERCEPTIONS)}")
        if self.perception == PERCEPTION_MASKS and not self.masks:
            raise BenchmarkError("--perception masks needs --masks DIR (one <stem>.png / .npy per image)")
        if self.perception != PERCEPTION_MASKS and (self.masks or self.depth):
            raise BenchmarkError("--masks / --depth are only used with --perception masks")
        if self.perception == PERCEPTION_DEGRADED:
            from semcityloc.benchmark.perception_sim import get_preset

            try:
                get_preset(self.seg_quality)
            except Exception as exc:  # PerceptionSimError: report it as a benchmark option error
                raise BenchmarkError(str(exc)) from exc
        check_method(self.method)
        localizer_config(self.preset)
        if int(self.keep_details) < 0:
            raise BenchmarkError(f"keep_details must be >= 0, got {self.keep_details}")


def load_dataset(spec: RealBenchmarkSpec) -> LodLocDataset:
    return read_lodloc(
        spec.dataset,
        city=spec.city,
        split=spec.split,
        stage=spec.stage,
        frame=spec.frame,
        ecef_origin_llh=spec.ecef_origin_llh,
    )


def evaluable(dataset: LodLocDataset) -> tuple[list[LodLocQuery], list[str]]:
    """(queries with both a GT pose and a prior, names of the others)."""
    keep = [q for q in dataset.queries if q.gt_pose is not None and q.prior_pose is not None]
    return keep, [q.name for q in dataset.queries if q.gt_pose is None or q.prior_pose is None]


def run_config(spec: RealBenchmarkSpec, dataset: LodLocDataset) -> dict:
    """The ``run.json`` of a real-data run (what decides the numbers; compared on resume)."""
    from semcityloc.benchmark.runner import _plain

    spec.check()
    queries, skipped = evaluable(dataset)
    if not queries:
        raise BenchmarkError(f"{dataset.root}: no query has both a ground-truth pose and a prior")
    if dataset.model_path is None:
        raise BenchmarkError(f"{dataset.root}: no LoD model found beside the data set; pass --city")
    return _plain(
        {
            "format": RUN_FORMAT,
            "mode": "dataset",
            "dataset": str(Path(spec.dataset).resolve()),
            "dataset_format": spec.format,
            "city": str(dataset.model_path),
            "city_path": str(dataset.model_path.resolve()),
            "city_sha256": file_sha256(dataset.model_path),
            "frame": dataset.frame,
            "frame_note": dataset.frame_note,
            "ecef_origin_llh": dataset.ecef_origin_llh,
            "split": spec.split,
            "stage": spec.stage,
            "method": spec.method,
            "perception": spec.perception,
            "labels_source": labels_source() if spec.perception != PERCEPTION_MASKS else "masks",
            "masks": spec.masks,
            "depth": spec.depth,
            "seg_quality": spec.seg_quality if spec.perception == PERCEPTION_DEGRADED else None,
            "seed": spec.seed,
            "queries": len(queries),
            "query_names": [q.name for q in queries],
            "skipped_no_gt_or_prior": skipped,
            "localizer_preset": spec.preset,
            "localizer": localizer_config(spec.preset).as_dict(),
            "keep_details": int(spec.keep_details),
            "semcityloc_version": __version__,
        }
    )


# ---------------------------------------------------------------------------------------------- queries
class RealQuerySource:
    """``BenchmarkQuery`` objects of a data set's queries, in the model's local frame (module docstring)."""

    def __init__(self, spec: RealBenchmarkSpec, dataset: LodLocDataset, model: CityModel, renderer=None):
        self.spec = spec
        self.model = model
        self.queries, _ = evaluable(dataset)
        self._renderer = renderer

    @property
    def renderer(self):
        if self._renderer is None:
            from semcityloc.render import Renderer

            self._renderer = Renderer(self.model, engine="numba")
        return self._renderer

    def __len__(self) -> int:
        return len(self.queries)

    def __iter__(self) -> Iterator[Any]:
        return (self.query(i) for i in range(len(self)))

    def query(self, index: int):
        from semcityloc.benchmark.queries import BenchmarkQuery, query_id

        q = self.queries[index]
        spec = self.spec
        camera = working_camera(q.camera)
        meta: dict[str, Any] = {"name": q.name, "scene": q.scene, "perception": spec.perception}
        depth = None
        miou = float("nan")
        if spec.perception == PERCEPTION_MASKS:
            camera = q.camera
            labels = read_mask(_find(Path(spec.masks), q.stem, (".png", ".npy")))
            if spec.depth:
                depth = read_depth(_find(Path(spec.depth), q.stem, (".npy", ".png")))
            meta["labels_source"] = "masks"
        else:
            labels, source = oracle_labels(self.model, camera, q.gt_pose, self.renderer)
            meta["labels_source"] = source
            miou = 100.0
            if spec.perception == PERCEPTION_DEGRADED:
                from semcityloc.benchmark.perception_sim import miou as seg_miou
                from semcityloc.benchmark.perception_sim import simulate_segmentation

                clean = np.where(labels == IGNORE, 0, labels).astype(np.uint8)
                rng = np.random.default_rng([spec.seed, index, STREAM_SEG])
                noisy = simulate_segmentation(clean, spec.seg_quality, rng)
                noisy[labels == IGNORE] = IGNORE
                miou = seg_miou(np.where(noisy == IGNORE, 0, noisy), clean)
                labels = noisy
                meta["seg_quality"] = spec.seg_quality
        pitch = float(q.gt_pose.to_xyz_rpy()[4])
        meta["view"] = "nadir" if abs(pitch) < 15.0 else "oblique"
        return BenchmarkQuery(
            query_id=query_id(index),
            index=index,
            camera=camera,
            true_pose=q.gt_pose.shift_world(self.model.origin),
            prior_pose=q.prior_pose.shift_world(self.model.origin),
            labels=labels,
            depth=depth,
            query_miou=miou,
            meta=meta,
        )


# ---------------------------------------------------------------------------------------------- the run
def perception_label(perception: str, seg_quality: str | None = None) -> str:
    """How a method's row is labelled in printed tables: says ``oracle`` wherever it is."""
    if perception == PERCEPTION_ORACLE:
        return "oracle perception (labels at the GT pose)"
    if perception == PERCEPTION_DEGRADED:
        return f"oracle perception degraded by the '{seg_quality}' segmentation preset"
    return "precomputed masks"


def run_real_benchmark(
    spec: RealBenchmarkSpec,
    out_dir: str | Path,
    overwrite: bool = False,
    limit: int | None = None,
    progress: bool | TextIO = True,
) -> Any:
    """Run (or resume) the benchmark of ``spec`` into ``out_dir``; returns a ``runner.BenchmarkOutcome``.

    Same files as the simulated benchmark (``benchmark.runner``); ``summary.json`` adds ``perception``,
    ``perception_label`` and ``labels_source``; ``estimates_colmap/`` holds the localized poses.
    """
    from semcityloc.benchmark.runner import (
        DETAILS_DIR,
        RESULTS_FILE,
        SUMMARY_FILE,
        BenchmarkOutcome,
        Progress,
        append_row,
        json_safe,
        make_row,
        prepare_output,
        query_id,
        read_results,
        save_details,
        summarize_rows,
        write_atomic,
    )

    if limit is not None and int(limit) < 0:
        raise BenchmarkError(f"limit must be >= 0, got {limit}")
    dataset = load_dataset(spec)
    config = run_config(spec, dataset)
    out = Path(out_dir)
    prepare_output(out, config, overwrite)
    results_path = out / RESULTS_FILE
    wanted = {query_id(i) for i in range(config["queries"])}
    rows = [r for r in read_results(results_path) if r["query_id"] in wanted]
    done = {r["query_id"] for r in rows}
    todo = [i for i in range(config["queries"]) if query_id(i) not in done]
    if limit is not None:
        todo = todo[: int(limit)]

    model = dataset.load_model()
    source = RealQuerySource(spec, dataset, model)
    new_rows = []
    if todo:
        if any(i < config["keep_details"] for i in todo):
            (out / DETAILS_DIR).mkdir(exist_ok=True)
        method = get_method(spec.method, model, localizer_config(spec.preset))
        stream = None if progress is True else progress or None
        bar = (
            Progress(config["queries"], len(done), stream, label="dataset") if progress is not False else None
        )
        try:
            for i in todo:
                q = source.query(i)
                result = method.localize(q)
                if i < config["keep_details"]:
                    save_details(out / DETAILS_DIR / f"{query_id(i)}.npz", q, result, model.origin)
                row = make_row(i, q, result, model.origin)
                append_row(results_path, row)
                new_rows.append(row)
                if bar:
                    bar.update()
        finally:
            if bar:
                bar.close()
    rows += new_rows
    complete = len(rows) == config["queries"]
    summary = None
    if complete:
        summary = summarize_rows(rows, config)
        summary["perception"] = spec.perception
        summary["perception_label"] = perception_label(spec.perception, spec.seg_quality)
        summary["labels_source"] = config["labels_source"]
        write_atomic(out / SUMMARY_FILE, json.dumps(json_safe(summary), indent=2) + "\n")
        write_estimates_colmap(rows, source, out / ESTIMATES_COLMAP_DIR)
    return BenchmarkOutcome(out, complete, len(new_rows), rows, summary, config)


def _f(text: str) -> float:
    return float(text) if text not in ("", None) else math.nan


def write_estimates_colmap(rows: list[dict[str, str]], source: RealQuerySource, folder: Path) -> Path:
    """The localized estimates as a COLMAP text model in the data set's (world) frame, named by image."""
    from semcityloc.datasets.colmap import ColmapModel, write_model

    entries: dict[str, tuple[Camera, Pose]] = {}
    for row in sorted(rows, key=lambda r: int(r["index"])):
        if row["status"] != "localized":
            continue
        q = source.queries[int(row["index"])]
        xyz = [_f(row[f"est_world_{k}"]) for k in "xyz"]
        angles = [_f(row[f"est_{k}"]) for k in ("roll", "pitch", "yaw")]
        if not all(math.isfinite(v) for v in xyz + angles):
            continue
        entries[q.name] = (q.camera, Pose.from_xyz_rpy(np.array(xyz), *angles))
    return write_model(ColmapModel.from_poses(entries), folder, ext=".txt")
