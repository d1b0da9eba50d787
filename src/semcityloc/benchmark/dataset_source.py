"""The benchmark over a real data set (``semcityloc benchmark --dataset PATH --format lodloc``).

Why its own module: the simulated benchmark makes its queries; here they come from a user's data set
(LoD-Loc layout, ``datasets.lodloc``) with real images, real ground truth and the data set's own priors.
Everything after the queries is the one run loop (``benchmark.run.run_queries``): the same rows,
``details/``, ``summary.json`` and resuming, so the numbers mean the same.

Perception (the query mask each method localizes with), ``--perception``:

- ``oracle``: automatic labels at the GT pose (``perception.autolabel.auto_label``). No depth. This
  measures the search and the data set's frames, not perception: every output (``run.json``,
  ``summary.json``, each row's ``meta_json``, the printed table) says ``oracle``.
- ``oracle-degraded``: the same labels through the simulated segmentation preset ``--seg-quality``
  (default ``trained``, the ≈ 88 % mIoU head; ``benchmark.perception_sim``), seeded per query by
  ``(seed, index)``.
- ``masks``: precomputed or model-predicted masks ``<masks>/<stem>.png`` (class ids 0..5, 255 = ignore,
  as palette indices or grey values: what ``io.images.save_labels_png`` writes) or ``<stem>.npy``; a mask
  in a lossy format (JPEG) only with ``allow_lossy_mask`` (``--allow-lossy-mask``, kept in ``run.json``
  only when set, so that older runs resume);
  optional depth ``<depth>/<stem>.npy`` or a 16-bit depth PNG (any positive scale; NaN / <= 0 invalid).
  A query whose mask or depth file is missing or cannot be read or used (corrupt, truncated, invalid class
  ids, another aspect: ``read_inputs``) is a miss, not the run's end: its row is ``not_localized`` with the
  reason naming the file (``results.unreadable_result``), in every recall's denominator, and the others
  run. The missing ones are found when the run starts (``DatasetSource.start_note``: a ``stat`` of each
  query's files, one warning naming how many and the first few), not when their turn comes, possibly an
  hour in; a ``--masks`` or ``--depth`` folder holding no query's file (a wrong path), or a lossy mask
  without ``allow_lossy_mask`` (a choice of the whole run), stops the run in one line.

Frames: the data set's poses are world-frame (``LodLocQuery.gt_pose_world``); queries are moved into the
model's local frame at this boundary (``CityModel.pose_to_local``). ``results.csv`` also holds world
coordinates. Each localized estimate is written as ``estimates/<query_id>.json`` in the world frame
(``geometry.io.write_pose_json``) and, when every query is done, all of them as a COLMAP text model
(``estimates_colmap/``) named by image; a localized row whose estimate file is gone or unusable is refused
then, naming it, as a photo run's lost ``poses/`` are (``check_estimates``, stop 55). Oracle labels are
rendered at no more than ``ORACLE_MAX_WIDTH`` pixels wide (the localizer searches at 64 px anyway).
Localizer: the ``default`` preset, whose search covers the prior's stated uncertainty (``prior_sigma``;
default: DJI GNSS, +-30 m in height, which covers LoD-Loc's priors).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc import __version__
from semcityloc.benchmark.methods import searched_map
from semcityloc.benchmark.perception_sim import get_preset, simulate_segmentation
from semcityloc.benchmark.perception_sim import miou as seg_miou
from semcityloc.benchmark.photo_exports import changed_files, redo_remedy, unfingerprinted
from semcityloc.benchmark.photo_inputs import INPUT_FINGERPRINTS
from semcityloc.benchmark.queries import STREAM_SEG, BenchmarkQuery, query_id
from semcityloc.benchmark.results import SKIPPED_MISS, UNFIT_INPUT, UNREADABLE_INPUT
from semcityloc.benchmark.runfiles import (
    ESTIMATES_COLMAP_DIR,
    ESTIMATES_DIR,
    RESULTS_FILE,
    plain,
    writing,
)
from semcityloc.benchmark.spec import check_run_options
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import IGNORE
from semcityloc.datasets.colmap import ColmapModel, text_unreadable_names, write_model
from semcityloc.datasets.lodloc import FRAME_AUTO, LodLocDataset, LodLocQuery, read_lodloc
from semcityloc.errors import (
    BenchmarkError,
    InputFileError,
    LossyMaskError,
    SemCityLocError,
    ShapeError,
    counted,
    parameter,
    shown_names,
    unknown_choice,
)
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.pose_files import read_pose
from semcityloc.geometry.pose_json import focal_scale_of, write_pose_json
from semcityloc.io.files import removed_on_error
from semcityloc.io.images import check_aspect, read_depth_file, read_mask_file, scaled_size
from semcityloc.io.stamps import file_fingerprint, file_sha256
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.covariance import covariance_dict
from semcityloc.localization.focal_check import focal_scale_used, found_camera
from semcityloc.localization.methods import Method
from semcityloc.localization.result import LOCALIZED, LocalizationResult
from semcityloc.perception.autolabel import auto_label
from semcityloc.perception.files import DEPTH_SUFFIXES, LOSSY_MASK_SUFFIXES, first_file, mask_suffixes
from semcityloc.render import Renderer

PERCEPTION_ORACLE, PERCEPTION_DEGRADED, PERCEPTION_MASKS = "oracle", "oracle-degraded", "masks"
PERCEPTIONS = (PERCEPTION_ORACLE, PERCEPTION_DEGRADED, PERCEPTION_MASKS)
FORMATS = ("lodloc",)
ORACLE_MAX_WIDTH = 1024
LABELS_SOURCE = "autolabel"
RUN_FORMAT = 1


def oracle_labels(model: CityModel, camera: Camera, pose_world: Pose, renderer=None) -> np.ndarray:
    """(H, W) uint8 automatic labels (``auto_label``) of ``model`` at a WORLD pose."""
    return np.asarray(auto_label(model, camera, pose_world, renderer=renderer), dtype=np.uint8)


def working_camera(camera: Camera, max_width: int = ORACLE_MAX_WIDTH) -> Camera:
    """``camera`` scaled down to at most ``max_width`` pixels wide (same field of view)."""
    if camera.width <= max_width:
        return camera
    return camera.scaled(*scaled_size(camera.width, camera.height, max_width))


MISSING_SHOWN = 5  # the names of queries without their files in the warning at the start of a run


def _find(folder: Path, stem: str, suffixes: tuple[str, ...]) -> Path:
    """The file of query ``stem`` in ``folder`` (``perception.files.first_file``), or ``InputFileError``
    naming the folder and the names looked for."""
    path = first_file(folder, stem, suffixes)
    if path is None:
        looked = f"{stem}{{{','.join(suffixes)}}}"
        raise InputFileError(
            f"{folder}: no file for query {stem!r} (looked for {looked}){_lossy_hint(folder, stem, suffixes)}"
        )
    return path


def _lossy_hint(folder: Path, stem: str, suffixes: tuple[str, ...]) -> str:
    """When mask ``suffixes`` leave the lossy ones out and a JPEG mask of ``stem`` is there: why it is not
    used and the parameter that uses it (``allow_lossy_mask``; the command line prints its flag)."""
    if suffixes != mask_suffixes(False) or (lossy := first_file(folder, stem, LOSSY_MASK_SUFFIXES)) is None:
        return ""
    return (
        f"; {lossy.name} is there, a lossy format (JPEG) whose compression changes class ids: "
        f"{parameter('allow_lossy_mask')} uses it"
    )


def read_inputs(
    camera: Camera, mask: Path, depth: Path | None, allow_lossy: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """(labels, depth or None) of a query from its files, each checked to show the camera's field of view
    (``io.images.check_aspect``); ``InputFileError`` / ``ShapeError`` naming the file that cannot be read
    or used (``LossyMaskError`` for a lossy mask without ``allow_lossy``)."""
    labels = read_mask_file(mask, allow_lossy, "allow_lossy_mask")  # a refusal names the spec's keyword
    check_aspect(labels.shape, camera.width, camera.height, "mask", mask)
    if depth is None:
        return labels, None
    values = read_depth_file(depth)
    check_aspect(values.shape, camera.width, camera.height, "depth", depth)
    return labels, values


def input_files(spec: DatasetSpec, q: LodLocQuery) -> tuple[Path, Path | None]:
    """(mask, depth or None) files of query ``q`` of a ``masks`` run, found by ``stat`` alone (nothing read);
    ``InputFileError`` naming the folder and the names looked for when one is missing."""
    mask = _find(Path(str(spec.masks)), q.stem, mask_suffixes(spec.allow_lossy_mask))
    depth = _find(Path(spec.depth), q.stem, DEPTH_SUFFIXES) if spec.depth else None
    return mask, depth


def input_fingerprints(spec: DatasetSpec, q: LodLocQuery) -> dict[str, dict | None]:
    """``{"mask": fingerprint, "depth": ...}`` of query ``q``'s files in a ``masks`` run (``depth`` when the
    run has one; ``io.stamps.file_fingerprint``, None where there is no file that reads): what its row is
    made from, kept in its ``meta_json`` and compared when the run finishes (``DatasetSpec.finish``)."""
    folders = {
        "mask": (spec.masks, mask_suffixes(spec.allow_lossy_mask)),
        "depth": (spec.depth, DEPTH_SUFFIXES),
    }
    prints = {}
    for kind, (folder, suffixes) in folders.items():
        if folder:
            path = first_file(Path(folder), q.stem, suffixes) or Path(folder) / f"{q.stem}{suffixes[0]}"
            prints[kind] = file_fingerprint(path)
    return prints


def check_some_inputs(spec: DatasetSpec, queries: list[LodLocQuery]) -> None:
    """``InputFileError`` when the ``masks`` (or ``depth``) folder holds the file of none of the queries: a
    wrong path, said in one line before the run starts instead of a miss for every query."""
    kinds = (
        ("mask", spec.masks, mask_suffixes(spec.allow_lossy_mask)),
        ("depth", spec.depth, DEPTH_SUFFIXES),
    )
    for kind, folder, suffixes in kinds:
        if folder and queries and not any(first_file(Path(folder), q.stem, suffixes) for q in queries):
            looked = f"{queries[0].stem}{{{','.join(suffixes)}}}"  # as _find says it
            hint = _lossy_hint(Path(folder), queries[0].stem, suffixes) if kind == "mask" else ""
            tail = hint or f"; is it the data set's {kind} folder?"
            raise InputFileError(
                f"{folder}: no {kind} file of any of the {counted(len(queries), 'query')} (looked for "
                f"{looked}, ...){tail}"
            )


def perception_label(perception: str, seg_quality: str | None = None) -> str:
    """How a method's row is labelled in printed tables: says ``oracle`` wherever it is."""
    if perception == PERCEPTION_ORACLE:
        return "oracle perception (labels at the GT pose)"
    if perception == PERCEPTION_DEGRADED:
        return f"oracle perception degraded by the '{seg_quality}' segmentation preset"
    return "precomputed masks"


def evaluable(dataset: LodLocDataset) -> tuple[list[LodLocQuery], list[str]]:
    """(queries with both a GT pose and a prior, names of the others)."""
    keep = [q for q in dataset.queries if q.gt_pose_world is not None and q.prior_pose_world is not None]
    return keep, [q.name for q in dataset.queries if q.gt_pose_world is None or q.prior_pose_world is None]


# ---------------------------------------------------------------------------------------------- the spec
@dataclass(frozen=True)
class DatasetSpec:
    """A benchmark run over a real data set (module docstring). Checked when made: a bad value raises
    ``BenchmarkError`` naming it, before the data set is read."""

    dataset: str
    format: str = "lodloc"
    city: str | None = None
    perception: str = PERCEPTION_ORACLE
    masks: str | None = None
    allow_lossy_mask: bool = False  # accept masks in a lossy format (JPEG): their edges carry wrong ids
    depth: str | None = None
    seg_quality: str = "trained"
    method: str = "semcityloc"
    preset: str = "default"
    prior_sigma: str | None = (
        None  # "xy=5,z=15,yaw=5,rp=1": the priors' 1-sigma error (default: the preset's)
    )
    seed: int = 0
    split: str | None = None
    stage: str | None = None
    frame: str = FRAME_AUTO
    ecef_origin_llh: tuple[float, float, float] | None = None  # frame="ecef": default Swiss-EPFL's
    keep_details: int = 3

    label = "dataset"  # the progress bar's label

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise unknown_choice("data set format", self.format, FORMATS, BenchmarkError)
        if self.perception not in PERCEPTIONS:
            raise unknown_choice("perception", self.perception, PERCEPTIONS, BenchmarkError)
        if self.perception == PERCEPTION_MASKS and not self.masks:
            raise BenchmarkError(
                f"{parameter('perception', PERCEPTION_MASKS)} needs {parameter('masks', 'DIR')} (one "
                "<stem>.png / .npy per image)"
            )
        if self.perception != PERCEPTION_MASKS and (self.masks or self.depth or self.allow_lossy_mask):
            raise BenchmarkError(
                f"{parameter('masks')} / {parameter('depth')} / {parameter('allow_lossy_mask')} are only "
                f"used with {parameter('perception', PERCEPTION_MASKS)}"
            )
        if self.perception == PERCEPTION_DEGRADED:
            get_preset(self.seg_quality)
        check_run_options(self)
        self.localizer_config()  # a malformed prior_sigma fails here, before anything loads

    def localizer_config(self) -> LocalizerConfig:
        """The preset with this run's prior sigma; built early so a bad sigma fails before loading."""
        return LocalizerConfig.preset(self.preset).with_prior_sigma(self.prior_sigma)

    def load_dataset(self) -> LodLocDataset:
        """The LoD-Loc data set this spec names (split, stage, frame), read but its model not loaded."""
        return read_lodloc(
            self.dataset,
            city=self.city,
            split=self.split,
            stage=self.stage,
            frame=self.frame,
            ecef_origin_llh=self.ecef_origin_llh,
        )

    def run_config(self) -> dict:
        """The ``run.json`` of a data-set run (what decides the numbers; compared on resume)."""
        dataset = self.load_dataset()
        queries, skipped = evaluable(dataset)
        if not queries:
            raise BenchmarkError(f"{dataset.root}: no query has both a ground-truth pose and a prior")
        if dataset.model_path is None:
            raise BenchmarkError(
                f"{dataset.root}: no LoD model found beside the data set; pass {parameter('city')}"
            )
        if self.perception == PERCEPTION_MASKS:
            check_some_inputs(self, queries)
        return plain(
            {
                "format": RUN_FORMAT,
                "mode": "dataset",
                "dataset": str(Path(self.dataset).resolve()),
                "dataset_format": self.format,
                "city": str(dataset.model_path),
                "city_path": str(dataset.model_path.resolve()),
                "city_sha256": file_sha256(dataset.model_path),
                "frame": dataset.frame,
                "frame_note": dataset.frame_note,
                "ecef_origin_llh": dataset.ecef_origin_llh,
                "split": self.split,
                "stage": self.stage,
                "method": self.method,
                "perception": self.perception,
                "labels_source": LABELS_SOURCE if self.perception != PERCEPTION_MASKS else "masks",
                "masks": self.masks,
                "depth": self.depth,
                "seg_quality": self.seg_quality if self.perception == PERCEPTION_DEGRADED else None,
                "seed": self.seed,
                "queries": len(queries),
                "query_names": [q.name for q in queries],
                "skipped_no_gt_or_prior": skipped,
                "localizer_preset": self.preset,
                "localizer": self.localizer_config().as_dict(),
                "searched_map": searched_map(self.method, self.localizer_config()),
                "keep_details": int(self.keep_details),
                "semcityloc_version": __version__,
                # only when set, so that runs made before the flag existed still resume
                **({"allow_lossy_mask": True} if self.allow_lossy_mask else {}),
            }
        )

    def open_source(self, config: dict) -> DatasetSource:
        """The query source of this run: the data set with its city model loaded."""
        dataset = self.load_dataset()
        return DatasetSource(self, dataset, dataset.load_model())

    def finish(self, out_dir: Path, rows: list[dict[str, str]], summary: dict) -> None:
        """Perception fields in the summary; the estimates as a COLMAP text model, once the finished rows of
        a ``masks`` run are checked against its mask and depth files as they are now (``input_fingerprints``:
        a file changed since its query finished is refused naming the query and the file, as a photo run
        does, ``photo_exports.changed_files``; rows of an earlier version, without fingerprints, are said)."""
        summary["perception"] = self.perception
        summary["perception_label"] = perception_label(self.perception, self.seg_quality)
        summary["labels_source"] = summary["config"]["labels_source"]
        queries, _ = evaluable(self.load_dataset())
        if self.perception == PERCEPTION_MASKS:
            self._check_files(out_dir, rows, queries, summary)
        check_estimates(out_dir, rows, queries)
        write_estimates_colmap(queries, out_dir, out_dir / ESTIMATES_COLMAP_DIR)

    def _check_files(
        self, out_dir: Path, rows: list[dict[str, str]], queries: list[LodLocQuery], summary: dict
    ) -> None:
        """Refuse finished rows whose mask or depth file changed since (``finish``); a note in the summary
        (``notes``) for rows that kept no fingerprints (written before stop 53)."""
        changed = {}
        for row in rows:
            index = int(row["index"])
            if index < len(queries):
                why = changed_files(row, input_fingerprints(self, queries[index]))
                if why:
                    changed[queries[index].name] = why
        if changed:
            one = len(changed) == 1
            raise InputFileError(
                f"{counted(len(changed), 'finished query', 'finished queries')} no longer "
                f"{'matches its row' if one else 'match their rows'} "
                f"({shown_names([f'{n}: {why}' for n, why in changed.items()])}): the files changed since; "
                + redo_remedy(len(changed), out_dir / RESULTS_FILE, "query")
            )
        if old := unfingerprinted(rows):
            summary.setdefault("notes", []).append(
                f"{counted(old, 'finished query', 'finished queries')} {'was' if old == 1 else 'were'} run "
                "by an earlier version that kept no fingerprints of their mask and depth files (before stop "
                f"53), so a file changed since is not noticed for {'it' if old == 1 else 'them'}: "
                + redo_remedy(old, out_dir / RESULTS_FILE, "query")
            )


def _focal_scale(path: Path) -> float:
    """An estimate file's ``focal_scale`` (``pose_json.focal_scale_of``; 1 where the file cannot be read:
    ``read_pose`` says what is wrong with it)."""
    try:
        return focal_scale_of(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError):
        return 1.0


def _estimate_problem(path: Path, name: str) -> str | None:
    """Why ``path`` is no usable estimate of query ``name`` (None: it is): missing, unreadable, another
    image's (a copied file)."""
    if not path.is_file():
        return "no estimate file"
    try:
        image = json.loads(path.read_text(encoding="utf-8")).get("extra", {}).get("image", name)
        read_pose(path)
    except (OSError, ValueError, AttributeError, SemCityLocError) as exc:
        return f"unreadable ({exc})"
    return None if image == name else f"is the estimate of {image!r}"


def check_estimates(out_dir: Path, rows: list[dict[str, str]], queries: list[LodLocQuery]) -> None:
    """Refuse (one line, before any export is written) a run whose localized rows lack a usable
    ``estimates/<query_id>.json``: the COLMAP export is written from those files, so it would hold fewer
    images than the summary counts localized, without a word (stop 55; a photo run's ``poses/``,
    ``photo_exports.check_records``, stop 51). Deleting the row redoes that query."""
    problems = {}
    for row in rows:
        index = int(row["index"])
        if row.get("status") != LOCALIZED or index >= len(queries):
            continue
        why = _estimate_problem(out_dir / ESTIMATES_DIR / f"{row['query_id']}.json", queries[index].name)
        if why:
            problems[f"{row['query_id']}.json of {queries[index].name}"] = why
    if problems:
        shown = shown_names([f"{name}: {why}" for name, why in problems.items()])
        count = f"{len(problems)} localized {'query has' if len(problems) == 1 else 'queries have'}"
        raise InputFileError(
            f"{out_dir / ESTIMATES_DIR}: {count} no usable estimate file ({shown}), so no exports were "
            "written; " + redo_remedy(len(problems), out_dir / RESULTS_FILE, "query")
        )


def write_estimates_colmap(queries: list[LodLocQuery], out_dir: Path, folder: Path) -> Path:
    """The localized estimates of a run (``estimates/qNNNN.json``, world frame) as a COLMAP text model
    named by image (``queries``: the run's queries in index order)."""
    entries: dict[str, tuple[Camera, Pose]] = {}
    for index, q in enumerate(queries):
        path = out_dir / ESTIMATES_DIR / f"{query_id(index)}.json"
        if path.is_file():
            entries[q.name] = (found_camera(q.camera, _focal_scale(path)), read_pose(path))
    unreadable = text_unreadable_names(entries)
    if unreadable:  # COLMAP's text reader would cut them at their first space; estimates/ holds them
        print(
            f"semcityloc: warning: {counted(len(unreadable), 'estimate')} left out of "
            f"{folder.name}/images.txt (a name with a space): {shown_names(unreadable)}; {ESTIMATES_DIR}/ "
            "holds every estimate",
            file=sys.stderr,
        )
    kept = {name: entry for name, entry in entries.items() if name not in unreadable}
    return write_model(ColmapModel.from_poses(kept), folder, ext=".txt")


# ---------------------------------------------------------------------------------------------- queries
class DatasetSource:
    """``BenchmarkQuery`` objects of a data set's queries, in the model's local frame (module docstring)."""

    def __init__(self, spec: DatasetSpec, dataset: LodLocDataset, model: CityModel, renderer=None):
        self.spec = spec
        self.map_model = model
        self.queries, _ = evaluable(dataset)
        self._renderer = renderer

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_renderer"] = None  # rebuilt in each process
        return state

    @property
    def renderer(self) -> Renderer:
        """The map's renderer, built on first use (and anew in each worker process)."""
        if self._renderer is None:
            self._renderer = Renderer(self.map_model, engine="numba")
        return self._renderer

    def __len__(self) -> int:
        return len(self.queries)

    def has_truth(self, index: int) -> bool:
        """Every evaluable query of a data set has a true pose (``evaluable``)."""
        return True

    def query(self, index: int) -> BenchmarkQuery:
        """Query ``index``: given masks, or oracle labels (degraded on request), with its prior."""
        q = self.queries[index]
        spec = self.spec
        camera = working_camera(q.camera)
        meta: dict[str, Any] = {"name": q.name, "scene": q.scene, "perception": spec.perception}
        depth = None
        miou = float("nan")
        far = q.far_pose(self.map_model)
        if far is not None:  # a pose in another CRS: a miss said in its file's words, not the run's end
            labels = np.full((camera.height, camera.width), IGNORE, dtype=np.uint8)
            meta[SKIPPED_MISS] = far
        elif spec.perception == PERCEPTION_MASKS:
            camera = q.camera
            # What the row is made from, fingerprinted before it is read (as a photo run's: ``finish``).
            meta[INPUT_FINGERPRINTS] = input_fingerprints(spec, q)
            try:
                mask, depth_file = input_files(spec, q)
                labels, depth = read_inputs(camera, mask, depth_file, spec.allow_lossy_mask)
            except LossyMaskError:
                raise  # the run's --allow-lossy-mask, not this file: refused in one line naming the flag
            except (InputFileError, ShapeError) as exc:  # this query's file: its miss, not the run's end
                labels = np.full((camera.height, camera.width), IGNORE, dtype=np.uint8)
                meta[UNREADABLE_INPUT] = str(exc)
                meta[UNFIT_INPUT] = isinstance(exc, ShapeError)
            meta["labels_source"] = "masks"
        else:
            labels = oracle_labels(self.map_model, camera, q.gt_pose_world, self.renderer)
            meta["labels_source"] = LABELS_SOURCE
            miou = 100.0
            if spec.perception == PERCEPTION_DEGRADED:
                clean = np.where(labels == IGNORE, 0, labels).astype(np.uint8)
                rng = np.random.default_rng([spec.seed, index, STREAM_SEG])
                noisy = simulate_segmentation(clean, spec.seg_quality, rng)
                noisy[labels == IGNORE] = IGNORE
                miou = seg_miou(np.where(noisy == IGNORE, 0, noisy), clean)
                labels = noisy
                meta["seg_quality"] = spec.seg_quality
        pitch = float(q.gt_pose_world.to_xyz_rpy()[4])
        meta["view"] = "nadir" if abs(pitch) < 15.0 else "oblique"
        return BenchmarkQuery(
            query_id=query_id(index),
            index=index,
            camera=camera,
            true_pose_local=self.map_model.pose_to_local(q.gt_pose_world),
            prior_pose_local=self.map_model.pose_to_local(q.prior_pose_world),
            labels=labels,
            depth=depth,
            query_miou=miou,
            meta=meta,
        )

    def start_note(self, todo: list[int]) -> str | None:
        """The warning the run says before its first query (``benchmark.run``): one line per query of
        ``todo`` whose GT pose or prior lies far from the model (``LodLocQuery.far_pose``), then the queries
        whose mask or depth file is missing, found by ``stat`` alone, how many and the first
        ``MISSING_SHOWN``; each is a miss at its turn (``query``). None when every file is there."""
        far = [why for index in todo if (why := self.queries[index].far_pose(self.map_model))]
        lines = [f"semcityloc: warning: skipped, counted as a miss: {why}" for why in far]
        missing_note = self._missing_note(todo)
        return "\n".join(lines + ([missing_note] if missing_note else [])) or None

    def _missing_note(self, todo: list[int]) -> str | None:
        if self.spec.perception != PERCEPTION_MASKS:
            return None
        missing = []
        for index in todo:
            try:
                input_files(self.spec, self.queries[index])
            except InputFileError:
                missing.append(self.queries[index].name)
        if not missing:
            return None
        shown = ", ".join(missing[:MISSING_SHOWN]) + (", ..." if len(missing) > MISSING_SHOWN else "")
        folders = " or ".join(str(f) for f in (self.spec.masks, self.spec.depth) if f)
        return (
            f"semcityloc: warning: {len(missing)} of the {counted(len(todo), 'query')} to run "
            f"{'has' if len(missing) == 1 else 'have'} no mask or depth "
            f"file in {folders} ({shown}): each will be a miss (in every recall), the others run"
        )

    def prepare(self, method: Method) -> None:
        """Nothing to give: a data set's inputs come from its files, not from a simulated reality."""
        return None

    def save_estimate(self, out_dir: Path, q: BenchmarkQuery, result: LocalizationResult) -> None:
        """``estimates/<query_id>.json``: the localized pose in the data set's world frame, with its
        covariance when it has one (``extra.covariance``, ``docs/data-formats.md``)."""
        if result.localized and result.pose_local is not None:
            folder = out_dir / ESTIMATES_DIR
            folder.mkdir(exist_ok=True)
            path = folder / f"{q.query_id}.json"
            tmp = folder / f".{q.query_id}.tmp.json"
            extra = {"image": self.queries[q.index].name}
            if result.covariance is not None:
                extra["covariance"] = covariance_dict(result.covariance)
            with writing(path), removed_on_error(tmp):
                write_pose_json(
                    tmp,
                    pose_local=result.pose_local,
                    origin_world=self.map_model.origin,
                    extra=extra,
                    focal_scale=focal_scale_used(result.search or {}),
                )
                tmp.replace(path)
