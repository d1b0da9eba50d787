"""What a simulated benchmark run is: ``BenchmarkSpec``, its ``run.json`` and the models it loads.

Why its own module: the spec is the one typed description of a run, from the CLI to the workers; its
range checks live here and nowhere else, and ``run_config`` is exactly what decides the numbers (what a
resumed run must match).

``city``: a city model file or ``"generated"`` (the embedded generated district); ``lod``: None = the
file's highest LoD per building, 1 = LoD1 derived from the file (``derive_lod1``) unless the file is LoD1
already, 2 / 3 = the generated city's sibling file of that LoD. Reality (what the simulated drone sees):
the city's LoD3 when it has one (the generated city's ``generated_lod3.gml``), else the city file at its
highest LoD per building, moved into the map's local frame in float64 (its origin may differ).
"""

from __future__ import annotations

import dataclasses
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from semcityloc import __version__
from semcityloc.benchmark.methods import check_method, searched_map
from semcityloc.benchmark.queries import QueryConfig
from semcityloc.benchmark.runfiles import plain
from semcityloc.benchmark.sources import SimulatedSource, SimulatorFactory
from semcityloc.citymodel.generator import default_city_path
from semcityloc.citymodel.lod1 import derive_lod1
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.citymodel.tiles import TileStore, city_sha256, is_store, load_city, open_store
from semcityloc.errors import ArgumentTypeError, BenchmarkError, InputFileError, parameter
from semcityloc.geometry.pose import LOCAL_FRAME_REACH_M
from semcityloc.localization.config import LocalizerConfig, preset_name

RUN_FORMAT = 1
GENERATED = "generated"  # --city value meaning the embedded generated district
_GENERATED_NAME = re.compile(r"^generated_lod([123])\.gml$")
# The largest extra prior offset per axis (``QueryConfig.prior_extra_m``): half the local frame's reach, so
# a prior of a camera anywhere in a city stays in the frame the localizer takes priors in
# (``input_checks.check_camera_and_prior``); no search reaches a fraction of it.
PRIOR_EXTRA_MAX_M = LOCAL_FRAME_REACH_M / 2


def resolve_city(city: str | Path) -> Path:
    """The CityGML / CityJSON file or tile store of ``city`` (``"generated"``: the default generated LoD2
    district)."""
    if str(city) == GENERATED:
        return default_city_path(lod=2).resolve()
    path = Path(city).expanduser()
    if path.is_dir() and not is_store(path):
        TileStore.open(path)  # its own one line: a folder of tiles, or a build that stopped
    if not path.is_file() and not is_store(path):
        raise InputFileError(f"{path}: no such city model file or tile store")
    return path.resolve()


def open_tile_store(city_path: str | Path, lod: int | None, crs: str | None = None) -> TileStore | None:
    """The tile store the localizer loads its parts from (``localization.tiled``), or None: ``city_path``
    is a file, or the map is LoD1 derived from the store's LoD2 (then the merged, derived map is used).
    ``lod`` / ``crs`` other than the store's are refused (``tiles.open_store``)."""
    if not is_store(city_path) or lod == 1:
        return None
    return open_store(city_path, lod=lod, crs=crs)


def generated_sibling(path: Path, lod: int) -> Path | None:
    """``generated_lod{lod}.gml`` beside a file named by the generator's scheme, if it exists."""
    if not _GENERATED_NAME.match(path.name):
        return None
    sibling = path.with_name(f"generated_lod{lod}.gml")
    return sibling if sibling.is_file() else None


def check_run_options(spec) -> None:
    """The checks every spec shares: a registered method, a known localizer preset (or presets combined,
    which the frozen ``spec`` then holds in their one spelling, ``config.preset_name``, so that a run of
    ``"focal-correct,lookalikes"`` resumes one of ``"lookalikes,focal-correct"``), ``keep_details >= 0``."""
    check_method(spec.method)
    LocalizerConfig.preset(spec.preset)
    object.__setattr__(spec, "preset", preset_name(spec.preset))
    if int(spec.keep_details) < 0:
        raise BenchmarkError(f"keep_details must be >= 0, got {spec.keep_details}")


@dataclass(frozen=True)
class BenchmarkSpec:
    """A simulated benchmark run (module docstring). Checked when made: a bad value raises
    ``BenchmarkError`` naming it (a ``city`` that is no str or path ``ArgumentTypeError``), before any model
    is loaded."""

    city: str
    query: QueryConfig
    lod: int | None = None
    method: str = "semcityloc"
    preset: str = "default"
    prior_sigma: str | None = (
        None  # "xy=5,z=15,yaw=5,rp=1": the priors' 1-sigma error (default: the preset's)
    )
    crs: str | None = None
    keep_details: int = 3
    simulator_factory: SimulatorFactory | None = None  # default QuerySimulator; not part of run.json
    sweep: tuple[str, Any] | None = None  # (knob, value) when the run is one point of ``semcityloc sweep``

    label = "benchmark"  # the progress bar's label

    def __post_init__(self) -> None:
        if not isinstance(self.city, (str, os.PathLike)):  # pathlib's TypeError at run time otherwise
            raise ArgumentTypeError(
                f"city must be a city model file, a tile store or {GENERATED!r} (a str or a path), "
                f"got {type(self.city).__name__}"
            )
        if self.lod not in (None, 1, 2, 3):
            raise BenchmarkError(f"lod must be 1, 2 or 3 (or unset for the file's highest), got {self.lod!r}")
        if not isinstance(self.query, QueryConfig):
            raise BenchmarkError("spec.query must be a QueryConfig")
        extra = self.query.prior_extra_m
        if extra is not None and extra[1] > PRIOR_EXTRA_MAX_M:
            raise BenchmarkError(
                f"{parameter('prior_extra')}: an extra prior offset of up to {extra[1]:g} m per axis puts "
                "priors outside the map's local frame, where the localizer refuses them; keep it at most "
                f"{PRIOR_EXTRA_MAX_M:g} m (no search reaches a fraction of that)"
            )
        if int(self.query.queries) < 1:
            raise BenchmarkError(f"the number of queries must be >= 1, got {self.query.queries}")
        check_run_options(self)
        self.localizer_config()  # a malformed prior_sigma fails here, before anything loads

    def localizer_config(self) -> LocalizerConfig:
        """The preset with this run's prior sigma; built early so a bad sigma fails before loading."""
        return LocalizerConfig.preset(self.preset).with_prior_sigma(self.prior_sigma)

    def run_config(self) -> dict:
        """The ``run.json`` content (resolves the city file; loads no model)."""
        city_path = resolve_city(self.city)
        if self.lod in (2, 3):
            map_source = generated_sibling(city_path, self.lod) or city_path
        else:
            map_source = city_path
        reality_source = generated_sibling(city_path, 3) or city_path
        q = self.query
        sweep = {} if self.sweep is None else {"sweep_knob": self.sweep[0], "sweep_value": self.sweep[1]}
        return plain(
            {
                "format": RUN_FORMAT,
                "city": str(self.city),
                "city_path": str(city_path),
                "city_sha256": city_sha256(city_path),
                "lod": self.lod,
                "map_source": str(map_source),
                "reality_source": str(reality_source),
                "crs": self.crs,
                "method": self.method,
                "seg_quality": q.seg_quality,
                "prior_extra_m": q.prior_extra_m,
                "seed": q.seed,
                "queries": int(q.queries),
                "localizer_preset": self.preset,
                "localizer": self.localizer_config().as_dict(),
                "searched_map": searched_map(self.method, self.localizer_config()),
                "query_config": dataclasses.asdict(q),
                "seg_preset": dataclasses.asdict(q.seg_preset()),  # a retuned preset is another run
                "keep_details": int(self.keep_details),
                "semcityloc_version": __version__,
                **sweep,
            }
        )

    def open_source(self, config: dict) -> SimulatedSource:
        """The query source of this run (loads the map and reality models of ``config``)."""
        store = open_tile_store(config["city_path"], config.get("lod"), config.get("crs"))
        map_model, reality = load_models(config, store)
        return SimulatedSource(map_model, reality, self.query, self.simulator_factory, tile_store=store)

    def finish(self, out_dir: Path, rows: list[dict[str, str]], summary: dict) -> None:
        """Nothing to export: a simulated run's results are its rows and summary."""
        return None


def _load(path: Path, config: dict, lod: int | None = None, store: TileStore | None = None) -> CityModel:
    """The model at ``path``; merged from ``store`` when that is the store at ``path``, already opened."""
    if store is not None and Path(path).resolve() == store.root.resolve():
        return store.load_all()
    return load_city(path, lod=lod, crs=config.get("crs"))


def _map_from(base: CityModel | None, config: dict, store: TileStore | None = None) -> CityModel:
    lod = config.get("lod")
    if lod in (2, 3):
        return _load(Path(config["map_source"]), config, lod, store)
    if base is None:
        raise BenchmarkError("internal: no base model for the map")  # pragma: no cover - callers load it
    if lod == 1 and max(base.lods_present()) > 1:
        return derive_lod1(base)
    return base


def load_map(config: dict) -> CityModel:
    """The map model of a run configuration (``run_config``): the chosen LoD (module docstring)."""
    base = _load(Path(config["city_path"]), config) if config.get("lod") in (None, 1) else None
    return _map_from(base, config)


def load_models(config: dict, store: TileStore | None = None) -> tuple[CityModel, CityModel]:
    """(map model, reality model in the map's local frame) of a run configuration (``run_config``).
    ``store``: the run's tile store when it already opened it (``open_tile_store``), merged rather than
    opened a second time."""
    city = Path(config["city_path"])
    reality_source = Path(config["reality_source"])
    loads_base = config.get("lod") in (None, 1) or reality_source == city
    base = _load(city, config, store=store) if loads_base else None
    map_model = _map_from(base, config, store)
    if base is not None and reality_source == city:
        reality = base
    else:
        reality = _load(reality_source, config, store=store)
    if map_model.crs is not None and reality.crs is not None and map_model.crs != reality.crs:
        raise BenchmarkError(
            f"map ({crs_label(map_model.crs)}) and reality ({crs_label(reality.crs)}) CRSs differ"
        )
    return map_model, reality.with_origin(map_model.origin)
