"""The query source of a photo run (``semcityloc run``): each photo as a query of the one run loop, and its
pose record and overlay once it is localized.

Why its own source: users come with a flight of photos and a CityGML / CityJSON tile, not a data set with
ground truth. Everything after the queries is ``benchmark.run.run_queries`` (resumable rows, progress
with ETA, workers, details), so a run of a thousand photos can be stopped and continued like a benchmark.

A query is a photo's resolved inputs (``benchmark.photo_inputs``) with its mask and depth read, or made by
the run's segmentation and depth backends (built once per process), on the pinhole camera. A mask or depth
file that fails only when read in full (a truncated body, class ids a lossy format made) is found when its
photo's turn comes: ``PhotoSource.query`` returns that photo not accepted, with the reason, and the run loop
records it as ``skipped`` (its row, its ``poses/<stem>.json`` record, the summary's ``skipped_photos``) and
goes on with the others; its row stays on resume (the file fixed, the run refuses that row when it
finishes, ``photo_exports.changed_inputs``; deleting that line of ``results.csv`` redoes the photo). A
photo with a true pose is a miss of the run instead, as is one whose own input was found unreadable before
the run (``PhotoInput.unreadable``) or that was skipped before it (``PhotoInput.skipped``: no usable prior,
say). Every query's meta holds the fingerprints of the photo's files, taken
before they are read (``PhotoInput.fingerprints``): its row's ``meta_json`` and its record keep them.

Outputs (``runfiles``): ``poses/<stem>.json`` for every photo (the pose in the model's CRS at the top level
when localized, in ``geometry.io.pose_to_dict``'s layout, and the result record, prior, uncertainty and
perception in ``extra``; the record alone when not localized), ``overlays/<stem>.png`` (the model's edges at
the estimate, on the map it was found on (``found_map``: the map with eaves on its flat roofs, named in its
title, where the localizer took the pose from there), and at the prior over the photo).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from semcityloc.benchmark.found_map import FoundMaps
from semcityloc.benchmark.photo_inputs import INPUT_FINGERPRINTS, PhotoInput
from semcityloc.benchmark.queries import BenchmarkQuery, query_id
from semcityloc.benchmark.results import (
    HEADING_KNOWN,
    SKIP_REASON,
    SKIPPED,
    SKIPPED_MISS,
    SOURCE_WARNINGS,
    UNFIT_INPUT,
    UNREADABLE_INPUT,
    is_skipped_miss,
    is_unreadable,
)
from semcityloc.benchmark.runfiles import OVERLAYS_DIR, POSES_DIR, writing
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.citymodel.tiles import TileStore
from semcityloc.classes import IGNORE
from semcityloc.datasets.overlay import GT_COLOR, PRIOR_COLOR, edges_figure, save_png
from semcityloc.errors import InputFileError, ShapeError, as_flags
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import unseen_by_photo
from semcityloc.geometry.pose_json import pose_to_dict
from semcityloc.io.files import write_json_atomic
from semcityloc.io.images import check_aspect, load_image, read_depth_file, read_mask_file
from semcityloc.localization.focal_check import focal_scale_used, found_camera
from semcityloc.localization.methods import Method
from semcityloc.localization.result import LocalizationResult
from semcityloc.perception.base import PHOTO_MAX_WIDTH
from semcityloc.perception.files import with_lossy_masks
from semcityloc.perception.registry import get_depth_backend, get_segmentation_backend
from semcityloc.render import Renderer

if TYPE_CHECKING:
    # for annotations only: ``photo_spec`` imports this module, so importing it back would be a cycle
    from semcityloc.benchmark.photo_spec import PhotoSpec

ESTIMATE_TITLE, PRIOR_TITLE = "model edges at the semcityloc estimate", "model edges at the prior"


@functools.lru_cache(maxsize=1)
def _load_backends(spec: PhotoSpec) -> tuple[Any, Any]:
    """``spec``'s (segmentation, depth) backends, built once per process: the focal estimate's photos and
    the run's go through the same ones instead of loading the weights twice."""
    options = with_lossy_masks(dict(spec.backend_options), spec.seg_backend, spec.allow_lossy_mask)
    seg = get_segmentation_backend(spec.seg_backend, **options) if spec.seg_backend else None
    dep = get_depth_backend(spec.depth_backend, **options) if spec.depth_backend else None
    return seg, dep


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
        # What the row is made from, fingerprinted before it is read (a file changed while it is read is
        # then one that changed since: refused when the run finishes, ``photo_exports.changed_inputs``).
        files = {INPUT_FINGERPRINTS: inp.fingerprints()}
        if inp.unreadable is not None:  # checked before the run: a miss of the truth (module docstring)
            return self._query(index, None, None, {**files, UNREADABLE_INPUT: inp.unreadable})
        if inp.skipped is not None:  # skipped before the run with a true pose: a miss all the same
            return self._query(index, None, None, {**files, SKIPPED_MISS: inp.skipped})
        seg, dep = self.backends()
        try:
            photo, labels, depth = self._read_files(inp, seg is not None or dep is not None)
        except (InputFileError, ShapeError) as exc:  # this photo's own file: its result, not the run's end
            blank = np.full((cam.height, cam.width), IGNORE, dtype=np.uint8)
            # unreadable or unfit with a true pose: a miss of the run, else skipped (module docstring)
            if inp.truth_world is not None:
                unfit = isinstance(exc, ShapeError)
                return self._query(
                    index, blank, None, {**files, UNREADABLE_INPUT: str(exc), UNFIT_INPUT: unfit}
                )
            return self._query(index, blank, None, {**files, "accepted": False, SKIP_REASON: str(exc)})
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
        return self._query(index, labels, depth, files)

    def _read_files(
        self, inp: PhotoInput, need_photo: bool
    ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """(photo when ``need_photo`` (a backend's input), mask, depth) of ``inp`` as stored, None where it
        has none; ``InputFileError`` / ``ShapeError`` naming the file when one cannot be read in full."""
        cam = inp.camera
        photo = load_image(inp.path, max_width=PHOTO_MAX_WIDTH) if need_photo else None
        labels = depth = None
        if inp.mask is not None:
            labels = read_mask_file(inp.mask, self.spec.allow_lossy_mask, "allow_lossy_mask")
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
            SOURCE_WARNINGS: inp.prior.warnings() if inp.prior is not None else [],
            HEADING_KNOWN: inp.prior.heading_known if inp.prior is not None else True,
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

    def pose_frame(self) -> dict:
        """The world frame of the pose files' numbers as ``geometry.io.pose_to_dict`` takes it: the model's
        CRS, minus ``--offset`` when one is given (frame ``crs_offset``: no ``crs`` label, which would place
        the camera the offset away); a model without a CRS: none (frame ``model``)."""
        crs = crs_label(self.map_model.crs)
        return {"crs": crs, "crs_offset": self.spec.offset if crs is not None else None}

    def record(self, inp: PhotoInput, result: LocalizationResult, files: dict | None = None) -> dict:
        """What ``poses/<stem>.json`` says besides the pose: the result, the prior, its uncertainty, and the
        fingerprints of the photo's files it was made from (``files``: ``PhotoInput.fingerprints``)."""
        model = self.map_model
        frame = self.pose_frame()
        record = result.to_dict(model.origin, **frame)
        if self.spec.offset is not None:  # the numbers + crs_offset are coordinates in offset_crs
            record.update(crs_offset=[float(v) for v in self.spec.offset], offset_crs=crs_label(model.crs))
        prior = inp.prior  # None: an unreadable photo's (``PhotoInput.unreadable``), and its camera too
        scale = focal_scale_used(result.search or {})
        camera = found_camera(inp.camera, scale) if inp.camera is not None else None
        if camera is not None and camera != inp.camera:  # re-found with the focal length scaled
            record["intrinsics_stated"] = inp.camera.as_dict()
        record.update(
            image=inp.name,
            perception=self.spec.perception(),
            intrinsics=camera.as_dict() if camera is not None else None,  # the one the pose holds with
            intrinsics_source=inp.intrinsics_source,
            focal_estimate=inp.focal_estimate,
            lens_distortion=None if inp.distortion.is_zero else inp.distortion.as_dict(),
            prior=(
                pose_to_dict(pose_world=prior.pose_world, **frame, extra=prior.details)
                if prior is not None
                else None
            ),
            prior_source=prior.source if prior is not None else None,
            prior_uncertainty=inp.uncertainty.as_dict(),  # what the localizer searched
            input_fingerprints=files,
        )
        return as_flags(record)  # a run folder's words (``results``): its reason, warnings, notes name flags

    def save_estimate(self, out_dir: Path, q: BenchmarkQuery, result: LocalizationResult) -> None:
        """``poses/<stem>.json`` and ``overlays/<stem>.png`` of a finished photo (module docstring); a skipped
        one (its files could not be read) gets its record alone."""
        inp = self.inputs[q.index]
        model = self.map_model
        record = self.record(inp, result, (q.meta or {}).get(INPUT_FINGERPRINTS))
        folder = out_dir / POSES_DIR
        folder.mkdir(exist_ok=True)
        estimate = result.pose_local if result.localized else None
        if estimate is not None:
            data = pose_to_dict(
                pose_local=estimate,
                origin_world=model.origin,
                **self.pose_frame(),
                extra=record,
                focal_scale=focal_scale_used(result.search or {}),  # extra.intrinsics: the stated times it
            )
        else:
            data = record
        with writing(folder / f"{inp.stem}.json"):
            write_json_atomic(folder / f"{inp.stem}.json", data)
        drawn = (
            result.status != SKIPPED
            and not is_unreadable(result.reason)
            and not is_skipped_miss(result.reason)
        )
        if self.spec.overlays and drawn:
            photo = inp.pinhole(load_image(inp.path, max_width=PHOTO_MAX_WIDTH), fill=0, nearest=False)
            camera = inp.camera.scaled(photo.shape[1], photo.shape[0])
            panels = [(inp.prior.pose_world, PRIOR_COLOR, PRIOR_TITLE)]
            renderers: list[Renderer | None] = [self.maps.searched()]
            cameras: list[Camera | None] = [None]  # the prior: the stated camera
            if estimate is not None:
                found_on, found_map = self.maps.for_estimate(result.search.get("flat_roof_eaves"))
                title = ESTIMATE_TITLE if found_map is None else f"{ESTIMATE_TITLE}, on {found_map}"
                scale = focal_scale_used(result.search or {})
                if scale is not None:  # re-found with the focal lengths scaled: drawn with that camera
                    title += f", focal length x {scale:.3f}"
                panels.insert(0, (model.pose_to_world(estimate), GT_COLOR, title))
                renderers.insert(0, found_on)
                cameras.insert(0, found_camera(camera, scale))
            figure = edges_figure(photo, model, camera, panels, self.renderer, renderers, cameras)
            png = out_dir / OVERLAYS_DIR / f"{inp.stem}.png"
            with writing(png):
                png.parent.mkdir(exist_ok=True)
                save_png(figure, png)
