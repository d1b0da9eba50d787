"""``semcityloc run``: a folder of a user's photos localized against a city model, through the one run loop.

Why its own source: users come with a flight of photos and a CityGML / CityJSON tile, not a data set with
ground truth. Everything after the queries is ``benchmark.run.run_queries`` (resumable rows, progress
with ETA, workers, details), so a run of a thousand photos can be stopped and continued like a benchmark.

Per photo (``datasets.photos`` matches files to photos by name):

- intrinsics: ``exif`` (DJI's calibration with its lens distortion, ``dji_camera.dewarp_lens``, else
  DJI's calibration tags, else the 35 mm-equivalent focal length, ``dji_camera.camera_from_exif``) by
  default, or a calibration (LoD-Loc ``intrinsic/`` folder, COLMAP ``cameras.txt``, one file for all); with
  lens distortion, the photo, its mask and its depth are resampled onto the pinhole camera before anything
  uses them (``PhotoInput.pinhole``); a camera whose focal length is the approximate 35 mm one gets the
  one its flight's oblique photos prefer (``calibrate_focal``, ``localization.focal``; computed with the
  inputs, once per run, and read back on resume or a repeated run: ``benchmark.focal_cache``);
- prior: the photo's DJI EXIF/XMP by default (``dji.dji_prior`` into the model's CRS), or a geotag CSV, a
  COLMAP ``images.txt`` or a LoD-Loc ``GPS_pose/`` folder (in the model's frame);
- how far the prior may be off (``PriorUncertainty``): ``prior_sigma`` when given (the same for every
  photo), else the photo's RTK tags (``dji.prior_uncertainty``) or the geotag file's accuracy columns,
  else the defaults. Kept in each query (``BenchmarkQuery.prior_uncertainty``) and in the outputs;
- perception: precomputed masks (``<masks>/<stem>.png|.npy``, any resolution with the photo's aspect),
  or a segmentation backend run on the photo (shrunk to ``PHOTO_MAX_WIDTH``); optional depth likewise;
- optional ground truth (``truth``, same forms as the priors): rows then carry errors and the summary
  recall.

A photo that lacks any of these, or whose file cannot be read (not a file, empty, truncated, corrupt, a
format Pillow does not read: its pixels are decoded once here, ``_readable_photo``), or whose mask's header
says it cannot be used (a lossy format without ``allow_lossy_mask``, not class ids: ``_mask_file``), is
skipped before anything is localized, with the reason naming the file (``run.json`` ``skipped_photos``, the
summary, the CLI's closing lines); the others run. When none is left, the run stops in one line ("no photo
can be localized") with the first reasons. A mask or depth file that fails only when read in full (a
truncated body, class ids a lossy format made) is found when its photo's turn comes: ``PhotoSource.query``
returns that photo not accepted, with the reason, and the run loop records it as ``skipped`` (its row, its
``poses/<stem>.json`` record, the summary's ``skipped_photos``) and goes on with the others; its row stays
on resume (the file fixed, deleting that line of ``results.csv`` redoes the photo). With ground
truth (``truth``), a photo that has a true pose and whose own input (the photo, its mask or depth) is
missing, cannot be read (not a file, empty, corrupt, truncated, no class ids) or does not fit the photo
(another aspect) is not skipped but a miss of the run, found before the run or at its turn: a
``not_localized`` row with the reason naming the file (``results.unreadable_result``,
``PhotoInput.unreadable``), in every recall's denominator, as in a data-set benchmark, so that recall
is never over the photos that happened to have usable inputs. A photo without a true pose, or one that
lacks a prior or intrinsics, or whose mask is in a lossy format without ``allow_lossy_mask`` (the run's
option, not the file), is skipped as before. Outputs (``runfiles``):
``poses/<stem>.json`` for every photo (the pose in the model's CRS at the top level when localized, in
``geometry.io.pose_to_dict``'s layout, and the result record, prior, uncertainty and perception in
``extra``; the record alone when not localized), ``overlays/<stem>.png`` (the model's edges at the estimate,
on the map it was found on (``found_map``: the map with eaves on its flat roofs, named in its title, where the
localizer took the pose from there), and at the prior over the photo) and, when every photo is done, the
exports of ``benchmark.photo_exports`` (COLMAP model, geotag CSV, OpenDroneMap ``geo.txt``, GeoJSON).
"""

from __future__ import annotations

import functools
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from semcityloc import __version__
from semcityloc.benchmark import focal_cache
from semcityloc.benchmark.found_map import FoundMaps
from semcityloc.benchmark.photo_exports import write_exports
from semcityloc.benchmark.queries import BenchmarkQuery, query_id
from semcityloc.benchmark.results import SKIP_REASON, SKIPPED, UNREADABLE_INPUT, is_unreadable
from semcityloc.benchmark.runfiles import (
    OVERLAYS_DIR,
    POSES_DIR,
    Progress,
    plain,
    write_json_atomic,
    writing,
)
from semcityloc.benchmark.spec import check_run_options, resolve_city
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.citymodel.tiles import TileStore, city_sha256, is_store, load_city, open_store
from semcityloc.classes import IGNORE
from semcityloc.datasets.dji import HEIGHT_AUTO, TARGET_HEIGHTS
from semcityloc.datasets.geodesy import check_geoid_separation
from semcityloc.datasets.overlay import GT_COLOR, PRIOR_COLOR, edges_figure, save_png
from semcityloc.datasets.photos import (
    EXIF,
    INTRINSICS_35MM,
    IntrinsicsFiles,
    PhotoMissing,
    PhotoPrior,
    PriorFiles,
    list_images,
    photo_metadata,
)
from semcityloc.errors import BenchmarkError, InputFileError, LossyMaskError, ShapeError, unknown_choice
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import LensDistortion, undistort_image, unseen_by_photo
from semcityloc.geometry.io import pose_to_dict
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.io.images import (
    check_aspect,
    check_aspect_of_photo,
    check_label_header,
    decoded_size_and_orientation,
    image_size,
    load_image,
    read_depth_file,
    read_mask_file,
)
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.focal import MIN_IMAGES as FOCAL_MIN_IMAGES
from semcityloc.localization.focal import (
    FocalView,
    estimate_focal_scale,
    oblique_subset,
    too_few_obliques,
    with_focal_scale,
)
from semcityloc.localization.localize import Localizer
from semcityloc.localization.methods import ABLATIONS, Method, searched_map
from semcityloc.localization.result import LocalizationResult
from semcityloc.localization.search_reach import MAX_VIEW_RANGE_M
from semcityloc.perception.base import PHOTO_MAX_WIDTH
from semcityloc.perception.files import DEPTH_SUFFIXES, MASK_SUFFIXES, find_file, with_lossy_masks
from semcityloc.perception.registry import backend_entry, get_depth_backend, get_segmentation_backend
from semcityloc.render import Renderer

RUN_FORMAT = 1
CALIBRATE_FOCAL = ("auto", "on", "off")  # ``PhotoSpec.calibrate_focal``
NO_PERCEPTION = (
    "no perception source: give --masks DIR (label PNGs by photo stem), or --seg-backend dinov3-dpt "
    "--backend-option backbone=DINOV3_DIR --backend-option head=HEAD_DIR (the paper's perception: DINOv3 "
    "ViT + a DPT head trained on your posed photos with 'semcityloc label' + 'semcityloc train-segmenter'; "
    "depth: --depth-backend moge2 --backend-option model=MOGE2_MODEL_PT); see docs/your-data.md"
)
ESTIMATE_TITLE, PRIOR_TITLE = "model edges at the semcityloc estimate", "model edges at the prior"


@dataclass
class PhotoInput:
    """One photo's resolved inputs (module docstring); poses in the model's world frame."""

    name: str
    path: Path
    camera: Camera | None  # None: an unreadable photo (``unreadable``) whose camera is in its own file
    prior: PhotoPrior | None  # likewise
    uncertainty: PriorUncertainty
    truth_world: Pose | None = None
    mask: Path | None = None
    depth: Path | None = None
    intrinsics_source: str = ""  # ``PhotoCamera.source``
    distortion: LensDistortion = LensDistortion()  # the photo's lens; zero: pinhole already
    # The flight's focal-length estimate for this camera (``calibrate_focal``; one dict per camera).
    focal_estimate: dict | None = None
    orientation: int = 1  # the photo's EXIF orientation (``io.images.exif_orientation``; 1: as stored)
    # Why a photo with a true pose cannot run: its own file cannot be read or used (checked before the
    # run). Its query is a miss naming the file, not skipped (module docstring); None: it runs.
    unreadable: str | None = None

    @property
    def stem(self) -> str:
        return self.path.stem

    def pinhole(self, image: np.ndarray, fill: float, nearest: bool) -> np.ndarray:
        """An array in the photo's geometry (the photo, a mask, a depth map; any resolution) resampled
        onto the pinhole ``camera`` (``geometry.distortion.undistort_image``)."""
        return undistort_image(image, self.camera, self.distortion, fill=fill, nearest=nearest)


@dataclass(frozen=True)
class PhotoSpec:
    """A run over a folder of photos (module docstring). Checked when made: a bad value raises a typed error
    naming it, before any file is read."""

    images: str
    city: str
    lod: int | str | None = None
    crs: str | None = None
    priors: str = EXIF
    intrinsics: str = EXIF
    truth: str | None = None
    masks: str | None = None
    allow_lossy_mask: bool = False  # accept --masks in a lossy format (JPEG): their edges carry wrong ids
    depth: str | None = None
    seg_backend: str | None = None
    depth_backend: str | None = None
    backend_options: tuple[tuple[str, str], ...] = ()
    prior_sigma: str | None = None  # "xy=5,z=15,yaw=5,rp=1" for every photo; None: per photo
    offset: tuple[float, float, float] | None = None  # the model's frame = its CRS minus this
    target_height: str = HEIGHT_AUTO
    geoid_separation_m: float | None = None
    method: str = "semcityloc"
    preset: str = "default"
    map_eaves_m: float | None = None  # eaves added to the map's pitched roofs; None: the preset's (0.5 m)
    # and to its flat roofs: "auto", "on", "off" (``LocalizerConfig.map_eaves_flat_roofs``); None: preset's
    map_eaves_flat_roofs: str | None = None
    keep_details: int = 3
    overlays: bool = True
    # Estimate each camera's focal length from the flight's oblique photos (``localization.focal``):
    # "auto" when the intrinsics are the approximate 35 mm-equivalent ones, "on" for every camera, "off".
    calibrate_focal: str = "auto"
    cache: bool = True  # parse cache of the city model (not part of the run's identity)

    label = "photos"  # the progress bar's label

    def __post_init__(self) -> None:
        if not (self.masks or self.seg_backend):
            raise InputFileError(NO_PERCEPTION)
        if self.masks and self.seg_backend:
            raise InputFileError("give --masks DIR or --seg-backend NAME, not both")
        if self.depth and self.depth_backend:
            raise InputFileError("give --depth DIR or --depth-backend NAME, not both")
        for kind, name in (("segmentation", self.seg_backend), ("depth", self.depth_backend)):
            if name:
                backend_entry(kind, name)
        if self.method not in ABLATIONS:
            raise unknown_choice("method for photos", self.method, ABLATIONS, BenchmarkError)
        if self.target_height not in TARGET_HEIGHTS:
            raise unknown_choice("target height", self.target_height, TARGET_HEIGHTS, BenchmarkError)
        if self.calibrate_focal not in CALIBRATE_FOCAL:
            raise unknown_choice("calibrate_focal", self.calibrate_focal, CALIBRATE_FOCAL, BenchmarkError)
        check_geoid_separation(self.geoid_separation_m)  # refused now, not only once a photo's EXIF needs it
        self.fixed_uncertainty()
        check_run_options(self.method, self.preset, self.keep_details)
        self.localizer_config()  # a bad eaves value fails here, before anything loads

    # ------------------------------------------------------------------ what the run is
    def fixed_uncertainty(self) -> PriorUncertainty | None:
        return PriorUncertainty.parse(self.prior_sigma) if self.prior_sigma else None

    def perception(self) -> str:
        """How the masks (and depth) are made, for labels: ``masks``, ``dinov3-dpt + moge2``, ..."""
        seg = "masks" if self.masks else str(self.seg_backend)
        depth = "depth files" if self.depth else self.depth_backend
        return f"{seg} + {depth}" if depth else seg

    def localizer_config(self) -> LocalizerConfig:
        return LocalizerConfig.preset(self.preset).with_map_eaves(self.map_eaves_m, self.map_eaves_flat_roofs)

    def load_model(self) -> tuple[CityModel, TileStore | None]:
        """(the city model, None) for a file; for a tile store (its frame, the store): the flight's tiles
        are loaded once the priors are known (``_resolve``). The store is opened here only, and refused
        when ``lod`` / ``crs`` are not the ones it was built with (``tiles.open_store``)."""
        lod = int(self.lod) if self.lod is not None and str(self.lod).isdigit() else self.lod
        city = resolve_city(self.city)
        if is_store(city):
            store = open_store(city, lod=lod, crs=self.crs)
            return store.frame(), store
        return load_city(city, lod=lod, crs=self.crs, cache=self.cache), None

    def resolved(self) -> Resolved:
        """The model, the photos that can run (their cameras with the flight's focal-length estimate,
        ``calibrate_focal``), ``{name: why not}`` of the others and the tile store (None for a file),
        computed once."""
        return _calibrated(self)

    def run_config(self) -> dict:
        """The ``run.json`` of a photo run (what decides the numbers; compared on resume)."""
        model, inputs, skipped, store = self.resolved()
        if not any(inp.unreadable is None for inp in inputs):
            misses = {inp.name: inp.unreadable for inp in inputs}
            reasons = "; ".join(f"{k}: {v}" for k, v in list({**misses, **skipped}.items())[:3])
            raise InputFileError(f"{self.images}: no photo can be localized ({reasons})")
        city = resolve_city(self.city)
        return plain(
            {
                "format": RUN_FORMAT,
                "mode": "photos",
                "images": str(Path(self.images).resolve()),
                "city": str(self.city),
                "city_path": str(city),
                "city_sha256": store.sha256 if store is not None else city_sha256(city),
                "lod": self.lod,
                "crs": self.crs,
                "model_crs": crs_label(model.crs),
                "priors": self.priors,
                "intrinsics": self.intrinsics,
                "truth": self.truth,
                "prior_sigma": self.prior_sigma,
                "offset": self.offset,
                "target_height": self.target_height,
                "geoid_separation_m": self.geoid_separation_m,
                "perception": self.perception(),
                "masks": self.masks,
                "depth": self.depth,
                "seg_backend": self.seg_backend,
                "depth_backend": self.depth_backend,
                "backend_options": [list(kv) for kv in self.backend_options],
                "method": self.method,
                "localizer_preset": self.preset,
                "localizer": self.localizer_config().as_dict(),
                "searched_map": searched_map(self.method, self.localizer_config()),
                "overlays": self.overlays,
                "calibrate_focal": self.calibrate_focal,
                "queries": len(inputs),
                "query_names": [i.name for i in inputs],
                "skipped_photos": skipped,
                "keep_details": int(self.keep_details),
                "semcityloc_version": __version__,
                # only when set, so that runs made before the flag existed still resume
                **({"allow_lossy_mask": True} if self.allow_lossy_mask else {}),
            }
        )

    def open_source(self, config: dict) -> PhotoSource:
        model, inputs, _, store = self.resolved()
        source = PhotoSource(self, model, inputs)
        source.tile_store = store
        source.backends()  # weights missing or wrong: said now, before the first photo
        return source

    def finish(self, out_dir: Path, rows: list[dict[str, str]], summary: dict) -> None:
        """The photo counts and reasons in the summary (``skipped_photos``: those skipped before the run
        and those whose files failed when read, ``skipped`` rows); the exports (``photo_exports``)."""
        model, inputs, skipped, _ = self.resolved()
        summary["mode"] = "photos"
        summary["perception"] = self.perception()
        summary["photos"] = len(inputs) + len(skipped)
        failed = {inputs[int(r["index"])].name: r["reason"] for r in rows if r["status"] == SKIPPED}
        summary["skipped_photos"] = {**skipped, **failed}
        offset = None if self.offset is None else np.asarray(self.offset, dtype=np.float64)
        placed = [inp for inp in inputs if inp.camera is not None and inp.prior is not None]  # exports
        summary["outputs"] = write_exports(out_dir, model, placed, offset, self.target_height)


class Resolved(NamedTuple):
    """What a ``PhotoSpec`` resolves to (``PhotoSpec.resolved``)."""

    model: CityModel  # the city file, or the tiles of a store within a camera's range of the flight
    inputs: list[PhotoInput]  # the photos that can run
    skipped: dict[str, str]  # {name: why not} of the others
    store: TileStore | None  # the ``--city`` tile store, opened once: the localizer's parts per photo


@functools.lru_cache(maxsize=2)
def _calibrated(spec: PhotoSpec) -> Resolved:
    """``_resolve`` with each camera's focal length times its flight estimate (``calibrate_focal``)."""
    resolved = _resolve(spec)
    if spec.calibrate_focal == "off" or not resolved.inputs:
        return resolved
    groups: dict[tuple[Camera, str], list[int]] = {}
    for i, inp in enumerate(resolved.inputs):
        if inp.unreadable is None:  # an unreadable photo's miss needs no camera
            groups.setdefault((inp.camera, inp.intrinsics_source), []).append(i)
    inputs = list(resolved.inputs)
    for (camera, source), members in groups.items():
        if spec.calibrate_focal == "auto" and source != INTRINSICS_35MM:
            continue
        estimate = _flight_focal(spec, resolved.model, inputs, members)
        scaled = camera if estimate.scale is None else with_focal_scale(camera, estimate.scale)
        record = estimate.as_dict()
        for i in members:
            inputs[i] = replace(inputs[i], camera=scaled, focal_estimate=record)
    return resolved._replace(inputs=inputs)


def _flight_focal(spec: PhotoSpec, model: CityModel, inputs: list[PhotoInput], members: list[int]):
    """The focal-length estimate of the photos ``members`` (one camera) from their oblique ones."""
    # Only the photos the estimate uses go through perception.
    priors = [model.pose_to_local(inputs[i].prior.pose_world) for i in members]
    oblique = [members[k] for k in oblique_subset(priors)]
    if len(oblique) < FOCAL_MIN_IMAGES:
        return too_few_obliques(len(oblique))
    camera = inputs[members[0]].camera
    key = None
    if spec.cache:
        key = focal_cache.estimate_key(_focal_settings(spec), [inputs[i] for i in oblique])
    cached = focal_cache.read_estimate(key) if key else None
    if cached is not None:
        print(
            f"semcityloc: the focal length of {len(members)} photos' camera from an earlier run's estimate "
            f"({focal_cache.cache_file(key)})",
            file=sys.stderr,
            flush=True,
        )
        return cached
    print(
        f"semcityloc: estimating the focal length of {len(members)} photos' camera "
        f"({camera.width} x {camera.height}, fx {camera.fx:.1f}) from {len(oblique)} oblique ones ...",
        file=sys.stderr,
        flush=True,
    )
    source = PhotoSource(spec, model, inputs)
    views = []
    for i in oblique:
        q = source.query(i)
        if not q.meta.get("accepted", True) or UNREADABLE_INPUT in q.meta:  # its file: recorded by the run
            continue
        views.append(FocalView(q.camera, q.prior_pose_local, q.labels, q.depth, q.prior_uncertainty))
    bar = Progress(len(views), label="focal estimate")  # views: the oblique subset already
    estimate = estimate_focal_scale(Localizer(model, spec.localizer_config()), views, progress=bar.update)
    bar.close()
    if key:
        focal_cache.write_estimate(key, estimate)
    return estimate


def _focal_settings(spec: PhotoSpec) -> dict:
    """What of the run decides a focal estimate besides its photos (``focal_cache.estimate_key``)."""
    return {
        "city_sha256": city_sha256(resolve_city(spec.city)),
        "lod": spec.lod,
        "crs": spec.crs,
        "localizer": spec.localizer_config().as_dict(),
        "seg_backend": spec.seg_backend,
        "depth_backend": spec.depth_backend,
        "backend_options": [list(kv) for kv in spec.backend_options],
        "allow_lossy_mask": spec.allow_lossy_mask,
    }


@functools.lru_cache(maxsize=1)
def _load_backends(spec: PhotoSpec) -> tuple[Any, Any]:
    """``spec``'s (segmentation, depth) backends, built once per process: the focal estimate's photos and
    the run's go through the same ones instead of loading the weights twice."""
    options = with_lossy_masks(dict(spec.backend_options), spec.seg_backend, spec.allow_lossy_mask)
    seg = get_segmentation_backend(spec.seg_backend, **options) if spec.seg_backend else None
    dep = get_depth_backend(spec.depth_backend, **options) if spec.depth_backend else None
    return seg, dep


@functools.lru_cache(maxsize=2)
def _resolve(spec: PhotoSpec) -> Resolved:
    model, store = spec.load_model()
    offset = None if spec.offset is None else np.asarray(spec.offset, dtype=np.float64)
    priors = PriorFiles(spec.priors, model.crs, offset, spec.target_height, spec.geoid_separation_m)
    truth = None
    if spec.truth:
        truth = PriorFiles(spec.truth, model.crs, offset, spec.target_height, spec.geoid_separation_m)
    intrinsics = IntrinsicsFiles(spec.intrinsics, priors.files)
    fixed = spec.fixed_uncertainty()
    inputs: list[PhotoInput] = []
    skipped: dict[str, str] = {}
    for path in list_images(spec.images, every_entry=True):
        lens = prior = meta = None
        try:
            width, height, orientation = _readable_photo(path)
            # Read once when both the camera and the prior come from it (each would read the whole file).
            meta = photo_metadata(path) if intrinsics.exif and priors.exif else None
            lens = intrinsics.photo_camera(path, width, height, meta)
            camera = lens.camera
            prior = priors.prior(path, meta)
            mask = _mask_file(spec, path, camera, orientation)
            depth = _input_file(spec.depth, path, DEPTH_SUFFIXES, "depth", camera, orientation)
        except PhotoMissing as exc:
            true_pose = _true_pose(truth, path, meta) if isinstance(exc, PhotoUnreadable) else None
            if true_pose is None:
                skipped[path.name] = str(exc)
                continue
            # A photo of the truth whose own file cannot be read: a miss of the run (module docstring),
            # with its prior when that is not in the photo itself (a pose file, a geotag CSV).
            prior = prior if prior is not None or lens is not None else _prior_or_none(priors, path)
            sigma = fixed or (prior.uncertainty if prior is not None else None) or PriorUncertainty()
            known = {} if lens is None else {"intrinsics_source": lens.source, "distortion": lens.distortion}
            camera = lens.camera if lens is not None else None
            inputs.append(
                PhotoInput(path.name, path, camera, prior, sigma, true_pose, unreadable=str(exc), **known)
            )
            continue
        true_pose = _true_pose(truth, path, meta)
        sigma = fixed or prior.uncertainty or PriorUncertainty()
        inputs.append(
            PhotoInput(
                path.name,
                path,
                camera,
                prior,
                sigma,
                true_pose,
                mask,
                depth,
                intrinsics_source=lens.source,
                distortion=lens.distortion,
                orientation=orientation,
            )
        )
    placed = [inp for inp in inputs if inp.prior is not None]
    if store is not None and placed:
        model = flight_area(store, model, placed)
    return Resolved(model, inputs, skipped, store)


class PhotoUnreadable(PhotoMissing):
    """A photo's own input (the photo, its mask or depth) is missing, cannot be read or does not fit the
    photo: skipped, or with a true pose a miss (module docstring)."""


def _prior_or_none(priors: PriorFiles | None, path: Path, meta=None) -> PhotoPrior | None:
    """``priors.prior`` of the photo ``path``, None when there is none it can give (ground truth is optional
    per photo; an unreadable photo's prior may be in the photo itself)."""
    if priors is None:
        return None
    try:
        return priors.prior(path, meta)
    except InputFileError:  # PhotoMissing among them
        return None


def _true_pose(truth: PriorFiles | None, path: Path, meta) -> Pose | None:
    """The true pose of the photo ``path`` (world frame), None without one."""
    given = _prior_or_none(truth, path, meta)
    return given.pose_world if given is not None else None


def _readable_photo(path: Path) -> tuple[int, int, int]:
    """(width, height, EXIF orientation) of a photo whose pixels decode (``io.images.check_decodes``, here
    with the size and orientation from the same opening: ``decoded_size_and_orientation``);
    ``PhotoMissing`` naming the file when it is not a file, is empty, truncated, corrupt or of a format
    Pillow does not read: that photo is skipped with the reason, the others run."""
    if not path.is_file():
        raise PhotoUnreadable(f"{path}: not a file (named like a photo)")
    try:
        if path.stat().st_size == 0:
            raise InputFileError(f"{path}: cannot read photo (empty file)")
        return decoded_size_and_orientation(path, "photo")
    except (InputFileError, OSError) as exc:
        raise PhotoUnreadable(str(exc)) from None


def flight_area(store: TileStore, frame: CityModel, inputs: list[PhotoInput]) -> CityModel:
    """The tiles of a store within a camera's range of any photo's prior: the map of the run's overlays
    and exports (the localizer loads its own per photo, ``localization.tiled``)."""
    xy = np.array([frame.pose_to_local(inp.prior.pose_world).center[:2] for inp in inputs])
    tiles = store.tiles_around(xy, MAX_VIEW_RANGE_M) or store.tiles_near(xy[0])
    return store.load(tiles)


def _mask_file(spec: PhotoSpec, photo: Path, camera: Camera, orientation: int) -> Path | None:
    """``_input_file`` of the photo's mask, its header checked too (``io.images.check_label_header``: a lossy
    format without ``allow_lossy_mask``, ``PhotoMissing``; not class ids, ``PhotoUnreadable``) saying why."""
    path = _input_file(spec.masks, photo, MASK_SUFFIXES, "mask", camera, orientation)
    if path is not None and path.suffix.lower() != ".npy":
        try:
            check_label_header(path, spec.allow_lossy_mask)
        except LossyMaskError as exc:  # the run's --allow-lossy-mask, not this file
            raise PhotoMissing(str(exc)) from None
        except InputFileError as exc:
            raise PhotoUnreadable(str(exc)) from None
    return path


def _array_shape(path: Path) -> tuple[int, int]:
    """(H, W) of a mask / depth file from its header (PNG) or array header (``.npy``)."""
    if path.suffix.lower() == ".npy":
        try:
            shape = np.load(path, mmap_mode="r", allow_pickle=False).shape
        except (OSError, ValueError) as exc:
            raise PhotoUnreadable(f"{path}: not a readable .npy array ({exc})") from None
        return tuple(int(v) for v in shape)
    width, height = image_size(path, "mask or depth image")
    return height, width


def _input_file(
    folder: str | None, photo: Path, suffixes, what: str, camera: Camera, orientation: int
) -> Path | None:
    """The photo's mask / depth file in ``folder`` (None without a folder), checked to show the photo's
    field of view (``orientation``: the photo's EXIF one); ``PhotoUnreadable`` when absent, when its
    header cannot be read or when it is of another aspect."""
    if not folder:
        return None
    try:
        path = find_file(Path(folder), photo.name, suffixes, what)
    except InputFileError as exc:
        raise PhotoUnreadable(str(exc)) from None
    try:
        shape = _array_shape(path)
    except InputFileError as exc:  # PhotoUnreadable (a .npy) among them
        raise PhotoUnreadable(str(exc)) from None
    try:
        check_aspect_of_photo(shape, camera.width, camera.height, what, path, orientation)
    except (InputFileError, ValueError) as exc:
        raise PhotoUnreadable(str(exc)) from None
    return path


class PhotoSource:
    """``BenchmarkQuery`` objects of a user's photos, in the model's local frame (module docstring)."""

    def __init__(self, spec: PhotoSpec, model: CityModel, inputs: list[PhotoInput]):
        self.spec = spec
        self.map_model = model
        self.tile_store: TileStore | None = None  # a store's parts per photo (``localization.tiled``)
        self.inputs = inputs
        self._backends: tuple[Any, Any] | None = None
        self._renderer: Renderer | None = None
        self._maps: FoundMaps | None = None

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_backends"] = state["_renderer"] = state["_maps"] = None  # rebuilt in each process
        return state

    def __len__(self) -> int:
        return len(self.inputs)

    def has_truth(self, index: int) -> bool:
        """A photo has a true pose when the run was given its truth (``truth``) and it names this photo."""
        return self.inputs[index].truth_world is not None

    def backends(self) -> tuple[Any, Any]:
        """(segmentation backend or None, depth backend or None), built once per process."""
        if self._backends is None:
            self._backends = _load_backends(self.spec)
        return self._backends

    @property
    def renderer(self) -> Renderer:
        if self._renderer is None:
            self._renderer = Renderer(self.map_model, engine="numba")
        return self._renderer

    @property
    def maps(self) -> FoundMaps:
        """The overlays' maps: the map the run searched, the one an estimate was found on (``found_map``)."""
        if self._maps is None:
            cfg = self.spec.localizer_config()
            self._maps = FoundMaps.of_method(self.map_model, self.renderer, self.spec.method, cfg)
        return self._maps

    def query(self, index: int) -> BenchmarkQuery:
        """Photo ``index`` with its mask and depth on the pinhole camera; not accepted (``meta["accepted"]``
        False, the reason naming the file in ``meta[SKIP_REASON]``) when one of its files cannot be read in
        full, so that the run records it and goes on (module docstring)."""
        inp = self.inputs[index]
        cam = inp.camera
        if inp.unreadable is not None:  # checked before the run: a miss of the truth (module docstring)
            return self._query(index, None, None, {UNREADABLE_INPUT: inp.unreadable})
        seg, dep = self.backends()
        try:
            photo, labels, depth = self._read_files(inp, seg is not None or dep is not None)
        except (InputFileError, ShapeError) as exc:  # this photo's own file: its result, not the run's end
            blank = np.full((cam.height, cam.width), IGNORE, dtype=np.uint8)
            # unreadable or unfit with a true pose: a miss of the run, else skipped (module docstring)
            if inp.truth_world is not None:
                return self._query(index, blank, None, {UNREADABLE_INPUT: str(exc)})
            return self._query(index, blank, None, {"accepted": False, SKIP_REASON: str(exc)})
        if photo is not None:
            photo = inp.pinhole(photo, fill=0, nearest=False)
        if labels is not None:
            labels = inp.pinhole(labels, fill=IGNORE, nearest=True)
        else:
            labels = seg.predict(photo, name=inp.name).labels
            check_aspect(labels.shape, cam.width, cam.height, "mask", inp.name)
            labels = np.where(unseen_by_photo(labels.shape, cam, inp.distortion), IGNORE, labels)
        if depth is not None:
            depth = inp.pinhole(depth, fill=np.nan, nearest=True)
        elif dep is not None:
            depth = dep.predict(photo, name=inp.name).masked()
            check_aspect(depth.shape, cam.width, cam.height, "depth", inp.name)
            depth = np.where(unseen_by_photo(depth.shape, cam, inp.distortion), np.nan, depth)
        return self._query(index, labels, depth)

    def _read_files(
        self, inp: PhotoInput, need_photo: bool
    ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """(photo when ``need_photo`` (a backend's input), mask, depth) of ``inp`` as stored, None where it
        has none; ``InputFileError`` / ``ShapeError`` naming the file when one cannot be read in full."""
        cam = inp.camera
        photo = load_image(inp.path, max_width=PHOTO_MAX_WIDTH) if need_photo else None
        labels = depth = None
        if inp.mask is not None:
            labels = read_mask_file(inp.mask, allow_lossy=self.spec.allow_lossy_mask)
            check_aspect(labels.shape, cam.width, cam.height, "mask", inp.mask)
        if inp.depth is not None:
            depth = read_depth_file(inp.depth)
            check_aspect(depth.shape, cam.width, cam.height, "depth", inp.depth)
        return photo, labels, depth

    def _query(
        self, index: int, labels: np.ndarray | None, depth: np.ndarray | None, extra: dict | None = None
    ) -> BenchmarkQuery:
        """The ``BenchmarkQuery`` of photo ``index`` (local frame) with these labels and depth; ``extra``
        added to its meta. An unreadable photo's (``PhotoInput.unreadable``) may have no camera or prior."""
        inp = self.inputs[index]
        prior = inp.prior.pose_world if inp.prior is not None else None
        view = inp.truth_world if prior is None else prior
        pitch = float(view.to_xyz_rpy()[4]) if view is not None else 0.0
        meta = {
            "name": inp.name,
            "image": str(inp.path.absolute()),
            "perception": self.spec.perception(),
            "prior_source": inp.prior.source if inp.prior is not None else None,
            "prior_uncertainty": inp.uncertainty.as_dict(),
            "view": "nadir" if abs(pitch) < 15.0 else "oblique",
            **(extra or {}),
        }
        model = self.map_model
        return BenchmarkQuery(
            query_id=query_id(index),
            index=index,
            camera=inp.camera,
            true_pose_local=model.pose_to_local(inp.truth_world) if inp.truth_world is not None else None,
            prior_pose_local=model.pose_to_local(prior) if prior is not None else None,
            labels=labels,
            depth=depth,
            query_miou=math.nan,
            meta=meta,
            prior_uncertainty=inp.uncertainty,
        )

    def prepare(self, method: Method) -> None:
        return None

    def record(self, inp: PhotoInput, result: LocalizationResult) -> dict:
        """What ``poses/<stem>.json`` says besides the pose: the result, the prior, its uncertainty."""
        model = self.map_model
        crs = crs_label(model.crs)
        record = result.to_dict(model.origin, crs)
        prior = inp.prior  # None: an unreadable photo's (``PhotoInput.unreadable``), and its camera too
        record.update(
            image=inp.name,
            perception=self.spec.perception(),
            intrinsics=inp.camera.as_dict() if inp.camera is not None else None,
            intrinsics_source=inp.intrinsics_source,
            focal_estimate=inp.focal_estimate,
            lens_distortion=None if inp.distortion.is_zero else inp.distortion.as_dict(),
            prior=pose_to_dict(prior.pose_world, crs=crs, extra=prior.details) if prior is not None else None,
            prior_source=prior.source if prior is not None else None,
            prior_uncertainty=inp.uncertainty.as_dict(),  # what the localizer searched
        )
        return record

    def save_estimate(self, out_dir: Path, q: BenchmarkQuery, result: LocalizationResult) -> None:
        """``poses/<stem>.json`` and ``overlays/<stem>.png`` of a finished photo (module docstring); a skipped
        one (its files could not be read) gets its record alone."""
        inp = self.inputs[q.index]
        model = self.map_model
        record = self.record(inp, result)
        folder = out_dir / POSES_DIR
        folder.mkdir(exist_ok=True)
        estimate = result.pose_local if result.localized else None
        if estimate is not None:
            data = pose_to_dict(estimate, origin=model.origin, crs=crs_label(model.crs), extra=record)
        else:
            data = record
        with writing(folder / f"{inp.stem}.json"):
            write_json_atomic(folder / f"{inp.stem}.json", data)
        if self.spec.overlays and result.status != SKIPPED and not is_unreadable(result.reason):
            photo = inp.pinhole(load_image(inp.path, max_width=PHOTO_MAX_WIDTH), fill=0, nearest=False)
            camera = inp.camera.scaled(photo.shape[1], photo.shape[0])
            panels = [(inp.prior.pose_world, PRIOR_COLOR, PRIOR_TITLE)]
            renderers: list[Renderer | None] = [self.maps.searched()]
            if estimate is not None:
                found_on, found_map = self.maps.for_estimate(result.search.get("flat_roof_eaves"))
                title = ESTIMATE_TITLE if found_map is None else f"{ESTIMATE_TITLE}, on {found_map}"
                panels.insert(0, (model.pose_to_world(estimate), GT_COLOR, title))
                renderers.insert(0, found_on)
            figure = edges_figure(photo, model, camera, panels, self.renderer, renderers)
            png = out_dir / OVERLAYS_DIR / f"{inp.stem}.png"
            with writing(png):
                png.parent.mkdir(exist_ok=True)
                save_png(figure, png)
