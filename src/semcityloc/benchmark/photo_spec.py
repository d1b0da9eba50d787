"""``semcityloc run``: a folder of a user's photos localized against a city model, through the one run loop;
``PhotoSpec`` is what such a run is.

Why a spec: as for a simulated run (``benchmark.spec.BenchmarkSpec``) or a data set
(``benchmark.dataset_source.DatasetSpec``), the one typed description of the run from the CLI to the
workers, checked when made (a bad value raises a typed error naming it, before any file is read); its
``run_config`` (``run.json``) is what decides the numbers, compared on resume.

The run: each photo's inputs are found and checked before anything is localized
(``benchmark.photo_inputs``), a camera's approximate focal length is estimated from its flight's oblique
photos (``benchmark.photo_focal``), and the photos are the queries of ``benchmark.photo_source.PhotoSource``
for ``benchmark.run.run_queries``. When no photo is left that can be localized, the run stops in one line
("no photo can be localized") with the first reasons. When every photo is done, the summary counts the
photos and says why any were skipped, and the exports of ``benchmark.photo_exports`` are written (COLMAP
model, geotag CSV, OpenDroneMap ``geo.txt``, GeoJSON), once the finished rows are checked against the files
as they are now (``photo_exports.changed_inputs``: a changed prior, truth, photo, mask or depth is refused
naming the photo, with the one-row remedy). ``resolved`` is read again when a file the spec names changed
(``photo_focal.calibrated_inputs``), and a run whose photos changed while it ran is refused
(``same_photos``), not given another photo's rows.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semcityloc import __version__
from semcityloc.benchmark.methods import searched_map
from semcityloc.benchmark.photo_exports import (
    changed_inputs,
    redo_remedy,
    unfingerprinted,
    write_exports,
)
from semcityloc.benchmark.photo_focal import calibrated_inputs
from semcityloc.benchmark.photo_inputs import Resolved
from semcityloc.benchmark.photo_source import PhotoSource
from semcityloc.benchmark.results import SKIPPED
from semcityloc.benchmark.runfiles import RESULTS_FILE, WEIGHTS_KEY, plain
from semcityloc.benchmark.spec import check_run_options, resolve_city
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.citymodel.tiles import TileStore, city_sha256, is_store, load_city, open_store
from semcityloc.datasets.dji import HEIGHT_AUTO, HEIGHT_ELLIPSOIDAL, TARGET_HEIGHTS
from semcityloc.datasets.geodesy import check_geoid_separation
from semcityloc.datasets.photos import EXIF
from semcityloc.errors import (
    BenchmarkError,
    InputFileError,
    as_flags,
    counted,
    parameter,
    shown_names,
    unknown_choice,
)
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.methods import ABLATIONS
from semcityloc.perception.registry import backend_entry, check_backend_options, weight_fingerprints

RUN_FORMAT = 1
CALIBRATE_FOCAL = ("auto", "on", "off")  # ``PhotoSpec.calibrate_focal``
NO_PERCEPTION = (
    f"no perception source: give {parameter('masks', 'DIR')} (label PNGs by photo stem), or "
    f"{parameter('dinov3')} (the paper's perception: DINOv3 ViT + a DPT head trained on your posed photos "
    f"with {parameter('label')} + {parameter('train_segmenter')}; depth: {parameter('moge2')}); see "
    "docs/your-data.md"
)


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
    recursive: bool = False  # read the photos of the folder's subfolders too (``photo_inputs.photo_paths``)

    label = "photos"  # the progress bar's label

    def __post_init__(self) -> None:
        if not (self.masks or self.seg_backend):
            raise InputFileError(NO_PERCEPTION)
        if self.masks and self.seg_backend:
            raise InputFileError(
                f"give {parameter('masks', 'DIR')} or {parameter('seg_backend', 'NAME')}, not both"
            )
        if self.depth and self.depth_backend:
            raise InputFileError(
                f"give {parameter('depth', 'DIR')} or {parameter('depth_backend', 'NAME')}, not both"
            )
        for kind, name in (("segmentation", self.seg_backend), ("depth", self.depth_backend)):
            if name:
                backend_entry(kind, name)
        check_backend_options(self.seg_backend, self.depth_backend, self.backend_options)
        if self.method not in ABLATIONS:
            raise unknown_choice("method for photos", self.method, ABLATIONS, BenchmarkError)
        if self.target_height not in TARGET_HEIGHTS:
            raise unknown_choice("target height", self.target_height, TARGET_HEIGHTS, BenchmarkError)
        if self.calibrate_focal not in CALIBRATE_FOCAL:
            raise unknown_choice("calibrate_focal", self.calibrate_focal, CALIBRATE_FOCAL, BenchmarkError)
        check_geoid_separation(self.geoid_separation_m)  # refused now, not only once a photo's EXIF needs it
        if self.geoid_separation_m is not None and self.target_height == HEIGHT_ELLIPSOIDAL:
            raise BenchmarkError(
                f"{parameter('geoid_separation', f'{self.geoid_separation_m:g}')} converts the photos' "
                "ellipsoidal heights to the model's orthometric ones, but "
                f"{parameter('target_height', HEIGHT_ELLIPSOIDAL)} says the model's heights are ellipsoidal: "
                "give one or the other"
            )
        self.fixed_uncertainty()
        check_run_options(self)
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
        are loaded once the priors are known (``photo_inputs.resolve_inputs``). The store is opened here only,
        and refused when ``lod`` / ``crs`` are not the ones it was built with (``tiles.open_store``)."""
        lod = int(self.lod) if self.lod is not None and str(self.lod).isdigit() else self.lod
        city = resolve_city(self.city)
        if is_store(city):
            store = open_store(city, lod=lod, crs=self.crs)
            return store.frame(), store
        return load_city(city, lod=lod, crs=self.crs, cache=self.cache), None

    def resolved(self) -> Resolved:
        """The model, the photos that can run (their cameras with the flight's focal-length estimate,
        ``photo_focal``), ``{name: why not}`` of the others and the tile store (None for a file), computed
        once."""
        return calibrated_inputs(self)

    def run_config(self) -> dict:
        """The ``run.json`` of a photo run (what decides the numbers; compared on resume). The backends'
        weight files are found and fingerprinted first (``registry.weight_fingerprints``): a missing head is
        said before the city model loads, and a head retrained at the same path is another run's."""
        weights = weight_fingerprints(self.seg_backend, self.depth_backend, self.backend_options)
        model, inputs, skipped, store = self.resolved()
        if not any(inp.runs for inp in inputs):
            misses = {inp.name: inp.unreadable or inp.skipped for inp in inputs}
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
                # the fingerprints of the backends' weight files (since stop 56; none for masks or files)
                **({WEIGHTS_KEY: weights} if weights else {}),
                "method": self.method,
                "localizer_preset": self.preset,
                "localizer": self.localizer_config().as_dict(),
                "searched_map": searched_map(self.method, self.localizer_config()),
                "overlays": self.overlays,
                "calibrate_focal": self.calibrate_focal,
                "queries": len(inputs),
                "query_names": [i.name for i in inputs],
                "skipped_photos": as_flags(skipped),  # a run folder's words (``results``)
                "keep_details": int(self.keep_details),
                "semcityloc_version": __version__,
                # only when set, so that runs made before the flag existed still resume
                **({"allow_lossy_mask": True} if self.allow_lossy_mask else {}),
                **({"recursive": True} if self.recursive else {}),
            }
        )

    def same_photos(self, inputs: list, config: dict) -> None:
        """Refuse, in one line, inputs that are not the photos of ``config`` (``run.json``'s
        ``query_names``): the folder changed while the run ran (the inputs are read again when their files
        change, ``photo_focal.calibrated_inputs``), so a row's index would name another photo."""
        names = config.get("query_names")
        if names is not None and [inp.name for inp in inputs] != list(names):
            raise InputFileError(
                f"{self.images}: the photos (or the files that decide which can run) changed while this "
                f"run was starting or running ({len(names)} photos to run then, {len(inputs)} now): run "
                "the command again"
            )

    def open_source(self, config: dict) -> PhotoSource:
        model, inputs, _, store = self.resolved()
        self.same_photos(inputs, config)
        source = PhotoSource(self, model, inputs)
        source.tile_store = store
        source.backends()  # weights missing or wrong: said now, before the first photo
        return source

    def finish(self, out_dir: Path, rows: list[dict[str, str]], summary: dict) -> None:
        """The photo counts and reasons in the summary (``skipped_photos``: those skipped before the run
        and those whose files failed when read, ``skipped`` rows); the exports (``photo_exports``)."""
        model, inputs, skipped, _ = self.resolved()
        self.same_photos(inputs, summary.get("config", {}))
        summary["mode"] = "photos"
        summary["perception"] = self.perception()
        summary["photos"] = len(inputs) + len(skipped)
        failed = {inputs[int(r["index"])].name: r["reason"] for r in rows if r["status"] == SKIPPED}
        summary["skipped_photos"] = {**skipped, **failed}
        changed = changed_inputs(rows, inputs, model)
        if changed:
            one = len(changed) == 1
            raise InputFileError(
                f"{counted(len(changed), 'finished photo')} no longer "
                f"{'matches its row' if one else 'match their rows'} "
                f"({shown_names([f'{n}: {why}' for n, why in changed.items()])}): the files changed since; "
                + redo_remedy(len(changed), out_dir / RESULTS_FILE)
            )
        offset = None if self.offset is None else np.asarray(self.offset, dtype=np.float64)
        placed = [inp for inp in inputs if inp.camera is not None and inp.prior is not None]  # exports
        summary["outputs"] = write_exports(
            out_dir, model, placed, offset, self.target_height, self.geoid_separation_m
        )
        if old := unfingerprinted(rows, inputs):  # rows of an earlier version: said, not refused
            summary["outputs"]["notes"].append(
                f"{counted(old, 'finished photo')} {'was' if old == 1 else 'were'} run by an earlier "
                "version that kept no fingerprints of their photo, mask and depth files (before stop 52) or "
                "of their intrinsics file and a files backend's mask and depth (before stop 53), so such a "
                f"file changed since is not noticed for {'it' if old == 1 else 'them'} (a changed prior or "
                "truth is): " + redo_remedy(old, out_dir / RESULTS_FILE)
            )
