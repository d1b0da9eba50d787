"""A photo run's focal length per camera, estimated from its flight's oblique photos (``calibrate_focal``).

Why: the approximate 35 mm-equivalent focal length (``dji_camera.camera_from_exif``,
``datasets.photos.INTRINSICS_35MM``) may be a few percent off, which moves the camera as much along its
axis; the photos of a flight share their camera, and its oblique ones tell the focal length the localizer's
score prefers (``localization.focal``). ``PhotoSpec.calibrate_focal``: ``auto`` (the cameras with that
focal length), ``on`` (every camera) or ``off``.

``calibrated_inputs`` is the run's resolved inputs (``benchmark.photo_inputs``) with each camera's focal
length times its estimate and the estimate, or why there is none, in each photo's record
(``PhotoInput.focal_estimate``). Computed with the inputs, once per process while their files are unchanged
(``calibrated_inputs``), only the photos the estimate uses going through perception, with the backends the
run then uses (``benchmark.photo_source``); read back on resume or a repeated run (``benchmark.focal_cache``).
"""

from __future__ import annotations

import functools
import sys
from dataclasses import replace
from typing import TYPE_CHECKING

from semcityloc.benchmark import focal_cache
from semcityloc.benchmark.photo_inputs import PhotoInput, Resolved, inputs_stamp, resolve_inputs
from semcityloc.benchmark.photo_source import PhotoSource
from semcityloc.benchmark.results import UNREADABLE_INPUT
from semcityloc.benchmark.runfiles import Progress
from semcityloc.benchmark.spec import resolve_city
from semcityloc.citymodel.model import CityModel
from semcityloc.citymodel.tiles import city_sha256
from semcityloc.datasets.photos import INTRINSICS_35MM
from semcityloc.geometry.camera import Camera
from semcityloc.localization.focal import MIN_IMAGES as FOCAL_MIN_IMAGES
from semcityloc.localization.focal import (
    FocalView,
    estimate_focal_scale,
    oblique_subset,
    too_few_obliques,
)
from semcityloc.localization.focal_check import with_focal_scale
from semcityloc.localization.localize import Localizer

if TYPE_CHECKING:
    # for annotations only: ``photo_spec`` imports this module, so importing it back would be a cycle
    from semcityloc.benchmark.photo_spec import PhotoSpec


def calibrated_inputs(spec: PhotoSpec) -> Resolved:
    """``resolve_inputs`` with each camera's focal length times its flight estimate (``calibrate_focal``),
    computed once per process while the files ``spec`` names are unchanged: cached by the spec and their
    stamps (``photo_inputs.inputs_stamp``, taken before they are read), so that a run's ``run.json``, its
    source and its exports see the same inputs, and a file changed between two runs in one process (a
    corrected truth or mask) is read again. Why a cache: each call checks that every photo decodes and
    reads its metadata (40 copies of a 4 MP DJI photo: 7.3 s) and may estimate the focal length, and a run
    asks three or four times; the stamps cost a ``stat`` per file (6.5 ms for those 40)."""
    return _calibrated(spec, inputs_stamp(spec))


@functools.lru_cache(maxsize=2)
def _calibrated(spec: PhotoSpec, stamp: tuple) -> Resolved:
    """``calibrated_inputs`` of ``spec`` whose files have the stamp ``stamp``."""
    resolved = resolve_inputs(spec)
    if spec.calibrate_focal == "off" or not resolved.inputs:
        return resolved
    groups: dict[tuple[Camera, str], list[int]] = {}
    for i, inp in enumerate(resolved.inputs):
        if inp.runs:  # a miss decided before the run (an unreadable photo's, say) needs no camera
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


def _camera_of(n: int) -> str:
    """``"1 photo's camera"`` / ``"3 photos' camera"``: the camera of ``n`` photos, in the progress lines."""
    return f"{n} photo's camera" if n == 1 else f"{n} photos' camera"


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
            f"semcityloc: the focal length of {_camera_of(len(members))} from an earlier run's estimate "
            f"({focal_cache.cache_file(key)})",
            file=sys.stderr,
            flush=True,
        )
        return cached
    print(
        f"semcityloc: estimating the focal length of {_camera_of(len(members))} "
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
