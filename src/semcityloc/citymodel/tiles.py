"""A tile store: a city published as many CityGML / CityJSON tiles, indexed so a photo loads only its area.

Why: a city's LoD2 comes as hundreds of geoportal tiles (Berlin: about 1,100 tiles of 1 km2). Loading
them whole for every photo costs minutes and gigabytes; a photo sees a few hundred metres. ``build_store``
(``semcityloc tiles build DIR --out STORE``) reads every tile once and writes:

- ``STORE/store.json``: format, the float64 ``origin`` of the whole store (the rounded centre of all
  tiles, the rule of a single file), the CRS, the reading options, and per tile its file name, SHA-256,
  size, format, CRS, building count, world extent and the LoDs its buildings were read at;
- ``STORE/buildings.npz``: per building its tile and its bounding box in the store's local frame, and
  the border ring of the whole city's terrain (``ground.store_ring``: a part of the city rendered for one
  photo gets the same terrain as the whole city);
- ``STORE/tiles/NNNNN.npz``: every tile parsed into the store's origin, in the project's city-model npz
  (``CityModel.save_npz``), so the localizer never parses XML and all tiles share one local frame (float32
  after the float64 origin was subtracted, exactly as a single file of the same buildings).

Every tile must state the same CRS (tiles in different CRSs are refused, naming them: reproject them
first); mixed formats are fine. ``TileStore.tiles_within`` answers "which tiles hold buildings within this
radius" from an STRtree of the buildings' boxes; ``TileStore.load`` merges tiles (store order) through an
LRU of parsed tiles under a byte budget (``TileCache``), reused across the photos of a flight.
``load_city`` opens a model file or a whole store, for every command that takes ``--city``; ``open_store``
opens a store and refuses a ``--lod`` / ``--crs`` it does not hold (``check_store_lod``: the LoD it was
built at, or, built at each building's highest, the one LoD every tile holds).
"""

from __future__ import annotations

import json
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pyproj
import shapely

from semcityloc.citymodel.builder import choose_origin
from semcityloc.citymodel.crs import horizontal_crs, parse_crs_name, same_crs
from semcityloc.citymodel.ground import base_points, store_ring
from semcityloc.citymodel.io import MODEL_SUFFIXES, load_city_model, sniff_format
from semcityloc.citymodel.limits import env_mb
from semcityloc.citymodel.model import CityModel, ParseStats, crs_label
from semcityloc.errors import (
    CRSError,
    EmptyModelError,
    InputFileError,
    LodNotHeldError,
    OutputPathError,
    as_flags,
    counted,
    parameter,
    shown_names,
)
from semcityloc.io.stamps import file_sha256

STORE_FORMAT = 1
INDEX_FILE = "store.json"
BUILDINGS_FILE = "buildings.npz"
TILES_DIR = "tiles"
TILE_FORMATS = ("citygml", "cityjson")
DEFAULT_BUDGET_MB = 1024.0
BUDGET_ENV = "SEMCITYLOC_TILE_BUDGET_MB"


@dataclass(frozen=True)
class TileInfo:
    """One tile of a store (``store.json``)."""

    name: str  # the file's path relative to the folder the store was built from
    sha256: str
    size_bytes: int
    format: str
    crs: str | None
    buildings: int
    extent: tuple[float, ...]  # world xmin, ymin, zmin, xmax, ymax, zmax
    npz: str  # the parsed tile, relative to the store
    # the LoDs its buildings were read at (``CityModel.lods_present``; empty in a store built before stop 56)
    lods: tuple[int, ...] = ()


@dataclass
class BuildReport:
    """What ``build_store`` did: for the CLI's closing line and ``benchmarks/bench_scale.py``."""

    store: TileStore
    tiles: int
    buildings: int
    input_bytes: int
    seconds: float
    skipped: dict[str, str] = field(default_factory=dict)  # tile (relative path) -> why it was left out
    warnings: list[str] = field(default_factory=list)  # e.g. buildings found in more than one tile

    @property
    def mb_per_s(self) -> float:
        """Input MB parsed per second of the build (reported by ``tiles build``)."""
        return self.input_bytes / 1e6 / max(self.seconds, 1e-9)


def model_nbytes(model: CityModel) -> int:
    """Bytes a parsed model holds in its arrays (what the tile cache's budget counts)."""
    arrays = (model.vertices, model.triangles, model.classes, model.building_index, model.lods)
    return int(sum(a.nbytes for a in arrays))


def is_store(path: str | Path) -> bool:
    """Is ``path`` a tile store (its folder or its ``store.json``)?"""
    p = Path(path)
    return (p.is_dir() and (p / INDEX_FILE).is_file()) or (p.name == INDEX_FILE and p.is_file())


def _root(path: str | Path) -> Path:
    p = Path(path)
    return p.parent if p.name == INDEX_FILE else p


def tile_files(folder: Path) -> list[Path]:
    """The CityGML / CityJSON files below ``folder`` (by content), its ZIP archives (which the build leaves
    out, naming the files to extract) and files named like a model that are empty or unreadable (left out
    with the reason, not passed over), sorted by relative path."""
    out = []
    for p in sorted(folder.rglob("*")):
        if not p.is_file() or p.name.startswith("."):
            continue
        try:
            fmt = sniff_format(p)
        except InputFileError:  # empty or unreadable: a tile by its name is left out by the build, named
            if p.name.lower().endswith(MODEL_SUFFIXES):
                out.append(p)
            continue
        if fmt in TILE_FORMATS or fmt == "zip":  # an archive is left out by the build, saying what it holds
            out.append(p)
    return out


def build_store(
    folder: str | Path,
    out: str | Path,
    lod: int | str | None = None,
    crs: str | None = None,
    progress: Callable[[str], None] | None = None,
    overwrite: bool = False,
) -> BuildReport:
    """Index the tiles of ``folder`` into a store at ``out`` (module docstring); returns what it did.

    Reads every tile twice: once in its own frame for the extents (the store's origin is their centre),
    once into the store's origin for the parsed npz. A tile that cannot be read (malformed, truncated) or
    holds no building (a geoportal's water or forest tile) is left out, named with the reason in the
    report's ``skipped`` and ``store.json``'s ``skipped_tiles``, and the others are built: one bad file of
    hundreds must not cost the city. A tile whose buildings hold no geometry at ``lod`` is no bad file: the
    build is refused (``LodNotHeldError``, naming those tiles and the LoDs they hold), as a single file
    without that LoD is, since left out it would be a hole in the city. Raises ``InputFileError`` (``folder``
    is a file or missing, no tiles, or none readable: the first reasons), ``CRSError`` (tiles in different
    CRSs), ``OutputPathError`` (``out`` holds a store already and ``overwrite`` is false: an hour's build is
    not replaced by a typo; with it, the old store's index goes first, so a build stopped half-way never
    leaves an index naming tiles of two builds; ``out`` a file, or a folder holding anything but a store,
    with ``overwrite`` too).
    """
    t0 = time.perf_counter()
    folder, root = Path(folder), Path(out)
    if folder.is_file():
        raise InputFileError(
            f"{folder}: a file, not a folder of tiles: give the folder that holds the tiles, or pass the "
            f"file itself to any command that takes a city ({parameter('city', folder)})"
        )
    if not folder.is_dir():
        raise InputFileError(f"{folder}: no such folder of tiles")
    if root.resolve() == folder.resolve() or root.resolve() in folder.resolve().parents:
        raise OutputPathError(
            f"{root}: the store's folder would hold the tiles it is built from ({folder}); build it in a "
            f"folder beside the tiles ({parameter('out')})"
        )
    _clear_old_store(root, overwrite)
    inside = root.resolve()
    files = [f for f in tile_files(folder) if inside not in f.resolve().parents]  # not an old store's files
    if not files:
        raise InputFileError(f"{folder}: no CityGML or CityJSON files in it")
    say = progress or (lambda _msg: None)
    extents, crss, boxes, counts = [], [], [], []
    ids: list[set[str]] = []
    skipped: dict[str, str] = {}
    lacking: dict[str, str] = {}  # tile -> the LoDs it holds, when not ``lod``
    lods: list[tuple[int, ...]] = []
    read: list[Path] = []
    for i, path in enumerate(files):
        say(f"indexing {i + 1}/{len(files)} {path.name}")
        try:
            model = load_city_model(path, lod=lod, crs=crs, cache=False)
        except LodNotHeldError as exc:  # buildings, at other LoDs: refused below, not left out
            lacking[str(path.relative_to(folder))] = exc.present
            continue
        except (InputFileError, EmptyModelError) as exc:  # this tile's own trouble: left out, named
            skipped[str(path.relative_to(folder))] = str(exc)
            continue
        read.append(path)
        extents.append(model.bounds_local + model.origin)
        crss.append(model.crs)
        box = _building_boxes(model)
        boxes.append(box + np.concatenate([model.origin, model.origin]))
        counts.append(len(box))
        ids.append(set(model.building_ids))
        lods.append(tuple(model.lods_present()))
    if lacking:
        held = [f"{name}: LoDs {present}" for name, present in lacking.items()]
        verb = "holds" if len(lacking) == 1 else "hold"
        raise LodNotHeldError(
            f"{folder}: {counted(len(lacking), 'tile')} of {len(files)} {verb} no LoD {lod} building "
            f"geometry ({shown_names(held)}): left out they would be holes in the city; build the store at a "
            f"LoD every tile holds ({parameter('store_lod', 'N')}), or at each building's highest LoD (the "
            "default)"
        )
    if not read:
        reasons = "; ".join(list(skipped.values())[:3])  # each names its file
        raise InputFileError(f"{folder}: no tile can be read ({len(skipped)} tried; {reasons})")
    files = read
    _check_one_crs(files, crss, folder)
    warnings = _repeated_buildings(files, ids, folder)
    every = np.concatenate(extents)
    origin = choose_origin(every)
    tiles_dir = root / TILES_DIR
    tiles_dir.mkdir(parents=True, exist_ok=True)
    infos, bases = [], []
    for i, path in enumerate(files):
        say(f"parsing {i + 1}/{len(files)} {path.name} into the store's origin")
        model = load_city_model(path, lod=lod, crs=crs, cache=False, origin=origin)
        npz = f"{TILES_DIR}/{i:05d}.npz"
        model.save_npz(root / npz)
        bases.append(base_points(model))
        e = extents[i]
        infos.append(
            TileInfo(
                name=str(path.relative_to(folder)),
                sha256=file_sha256(path),
                size_bytes=path.stat().st_size,
                format=sniff_format(path),
                crs=crs_label(crss[i]),
                buildings=counts[i],
                extent=tuple(float(v) for v in (*e[0], *e[1])),
                npz=npz,
                lods=lods[i],
            )
        )
    tile_of = np.repeat(np.arange(len(files), dtype=np.int32), counts)
    local_boxes = np.concatenate(boxes) - np.concatenate([origin, origin])
    np.savez(root / BUILDINGS_FILE, tile=tile_of, bbox=local_boxes, terrain_ring=store_ring(bases))
    index = {
        "format": STORE_FORMAT,
        "origin": [float(v) for v in origin],
        "crs": crss[0].to_wkt() if crss[0] is not None else None,
        "crs_label": crs_label(crss[0]),
        "lod": lod,
        "crs_override": crs,
        "source_folder": str(folder.resolve()),
        "tiles": [asdict(t) for t in infos],
        # in the command line's words, as a run folder's files (``benchmark.results``): what a user of
        # ``semcityloc tiles build`` reads in the store; the report (``BuildReport.skipped``) keeps Python's
        "skipped_tiles": as_flags(skipped),
    }
    tmp = root / (INDEX_FILE + ".tmp")
    tmp.write_text(json.dumps(index, indent=1), encoding="utf-8")
    tmp.replace(root / INDEX_FILE)
    total = sum(t.size_bytes for t in infos)
    store = TileStore.open(root)
    return BuildReport(
        store, len(infos), int(sum(counts)), total, time.perf_counter() - t0, skipped, warnings
    )


STORE_NAMES = (INDEX_FILE, BUILDINGS_FILE, TILES_DIR, INDEX_FILE + ".tmp")  # what a build writes in ``out``


def _clear_old_store(root: Path, overwrite: bool) -> None:
    """Refuse (``OutputPathError``) or, with ``overwrite``, remove the store already at ``root``: its
    index first, then its tile and building files (only the names a build writes). A file at ``root``, or
    a folder holding anything a build does not write but hidden files (a user's files, a benchmark run), is
    refused with ``overwrite`` too, naming what it holds: the store's files would mix with them."""
    if root.exists() and not root.is_dir():
        raise OutputPathError(f"{root}: a file, not a folder: give a new or empty folder for the store")
    # hidden files (a file manager's .DS_Store) are no one's work: the tile search passes them over too
    inside = sorted(p.name for p in root.iterdir()) if root.is_dir() else []
    others = [name for name in inside if name not in STORE_NAMES and not name.startswith(".")]
    if others:
        raise OutputPathError(
            f"{root}: not empty and not a tile store (it holds {shown_names(others)}); build the store in a "
            "new or empty folder"
        )
    old = [root / INDEX_FILE, root / BUILDINGS_FILE, root / TILES_DIR]
    if not any(p.exists() for p in old):
        return
    if not overwrite:
        what = "a tile store" if (root / INDEX_FILE).is_file() else "part of a tile store (a build stopped?)"
        raise OutputPathError(
            f"{root}: holds {what} already; build it again with {parameter('overwrite')} or into another "
            "folder"
        )
    (root / INDEX_FILE).unlink(missing_ok=True)
    (root / BUILDINGS_FILE).unlink(missing_ok=True)
    for npz in (root / TILES_DIR).glob("*.npz"):
        npz.unlink()


def _repeated_buildings(files: list[Path], ids: list[set[str]], folder: Path) -> list[str]:
    """A warning when building ids appear in more than one tile: the same area in two formats (a
    geoportal's .json beside its .xml) or a copied tile, whose buildings the store would hold twice."""
    seen: dict[str, int] = {}
    repeated: dict[tuple[int, int], int] = {}
    for i, tile in enumerate(ids):
        for building in tile:
            first = seen.setdefault(building, i)
            if first != i:
                repeated[(first, i)] = repeated.get((first, i), 0) + 1
    if not repeated:
        return []
    (a, b), n = max(repeated.items(), key=lambda kv: kv[1])
    total = sum(repeated.values())
    return [
        f"{total} building ids appear in more than one tile ({n} of them in both "
        f"{files[a].relative_to(folder)} and {files[b].relative_to(folder)}): the same buildings twice "
        "(one area in two formats, a copied tile)? Leave the copies out of the folder"
    ]


def _building_boxes(model: CityModel) -> np.ndarray:
    """(B, 6) float64 local boxes ``xmin ymin zmin xmax ymax zmax`` of the model's buildings (index order;
    NaN for a building without triangles: it is in no query's reach)."""
    nb = len(model.building_ids)
    lo = np.full((nb, 3), np.inf)
    hi = np.full((nb, 3), -np.inf)
    corners = model.vertices[model.triangles].astype(np.float64)  # (T, 3, 3)
    np.minimum.at(lo, model.building_index, corners.min(1))
    np.maximum.at(hi, model.building_index, corners.max(1))
    empty = ~np.isfinite(lo[:, 0])
    lo[empty], hi[empty] = np.nan, np.nan
    return np.concatenate([lo, hi], 1)


def _check_one_crs(files: list[Path], crss: list[pyproj.CRS | None], folder: Path) -> None:
    first = crss[0]
    for path, crs in zip(files, crss, strict=True):
        if (crs is None) != (first is None) or (crs is not None and not crs.equals(first)):
            raise CRSError(
                f"{folder}: tiles in different CRSs ({files[0].name}: {crs_label(first) or 'none'}, "
                f"{path.name}: {crs_label(crs) or 'none'}); a store holds one CRS: reproject the tiles "
                f"first, or give {parameter('crs')} when the files name a wrong one"
            )


class TileCache:
    """Parsed tiles by index, least recently used first out, holding at most ``budget_bytes``.

    A single tile larger than the budget is still returned (the caller needs it) but not kept.
    """

    def __init__(self, budget_bytes: int):
        if budget_bytes <= 0:
            raise InputFileError(f"the tile cache budget must be > 0 bytes, got {budget_bytes}")
        self.budget_bytes = int(budget_bytes)
        self._models: OrderedDict[int, CityModel] = OrderedDict()
        self.held_bytes = 0
        self.loads = 0  # tiles read from disk (misses)

    def get(self, index: int, load: Callable[[int], CityModel]) -> CityModel:
        """Tile ``index`` from the cache, else ``load``-ed and kept, evicting the least recently used."""
        if index in self._models:
            self._models.move_to_end(index)
            return self._models[index]
        model = load(index)
        self.loads += 1
        size = model_nbytes(model)
        while self._models and self.held_bytes + size > self.budget_bytes:
            _, old = self._models.popitem(last=False)
            self.held_bytes -= model_nbytes(old)
        if size <= self.budget_bytes:
            self._models[index] = model
            self.held_bytes += size
        return model

    def __contains__(self, index: int) -> bool:
        return index in self._models

    def __len__(self) -> int:
        return len(self._models)


def tile_budget_mb() -> float:
    """The tile cache's budget in MB: ``SEMCITYLOC_TILE_BUDGET_MB`` when set, else ``DEFAULT_BUDGET_MB``
    (an environment variable, so that it reaches every command and every worker process alike)."""
    return env_mb(BUDGET_ENV, DEFAULT_BUDGET_MB)


class TileStore:
    """An opened store (module docstring): its index, the STRtree of building boxes, the tile cache."""

    def __init__(
        self,
        root: Path,
        index: dict,
        tile_of: np.ndarray,
        bbox: np.ndarray,
        terrain_ring: np.ndarray,
        budget_mb: float,
    ):
        self.root = root
        self.index = index
        self.origin = np.asarray(index["origin"], dtype=np.float64)
        self.crs = pyproj.CRS.from_wkt(index["crs"]) if index.get("crs") else None
        self.lod = index.get("lod")
        self.tiles = [
            TileInfo(**{**t, "extent": tuple(t["extent"]), "lods": tuple(t.get("lods", ()))})
            for t in index["tiles"]
        ]
        self.tile_of = tile_of
        self.bbox = bbox
        self.terrain_ring = terrain_ring  # the whole city's terrain border (``ground.store_ring``)
        self.budget_mb = float(budget_mb)
        self.cache = TileCache(int(budget_mb * 1e6))
        self._tree: shapely.STRtree | None = None

    @classmethod
    def open(cls, path: str | Path, budget_mb: float | None = None) -> TileStore:
        """The store at ``path``; ``budget_mb``: the tile cache's budget (None: ``tile_budget_mb()``)."""
        budget_mb = tile_budget_mb() if budget_mb is None else budget_mb
        root = _root(path)
        if not is_store(root) and (root / TILES_DIR).is_dir():
            raise InputFileError(
                f"{path}: a tile store whose build stopped before its {INDEX_FILE}: build it again with "
                f"{parameter('store_again')}"
            )
        if not is_store(root):
            raise InputFileError(
                f"{path}: not a tile store (no {INDEX_FILE}; make one with {parameter('store_build')})"
            )
        try:
            index = json.loads((root / INDEX_FILE).read_text(encoding="utf-8"))
            with np.load(root / BUILDINGS_FILE, allow_pickle=False) as z:
                tile_of, bbox = z["tile"].astype(np.int32), z["bbox"].astype(np.float64)
                ring = z["terrain_ring"].astype(np.float64)
        except (OSError, ValueError, KeyError) as exc:
            raise InputFileError(f"{root}: a damaged tile store ({exc}); build it again") from exc
        if index.get("format") != STORE_FORMAT:
            raise InputFileError(
                f"{root}: store format {index.get('format')!r}, this version reads {STORE_FORMAT}"
            )
        store = cls(root, index, tile_of, bbox, ring, budget_mb)
        missing = [f"{t.npz} of {t.name}" for t in store.tiles if not (root / t.npz).is_file()]
        if missing:
            raise _damaged(root, f"{counted(len(missing), 'tile file')} missing ({shown_names(missing)})")
        return store

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_tree"] = None  # rebuilt where it is used
        state["cache"] = TileCache(self.cache.budget_bytes)
        return state

    @property
    def sha256(self) -> str:
        """The store's identity: the SHA-256 of its index (which holds every tile's hash)."""
        return file_sha256(self.root / INDEX_FILE)

    @property
    def num_buildings(self) -> int:
        """How many buildings the store holds, over all its tiles."""
        return len(self.tile_of)

    @property
    def tree(self) -> shapely.STRtree:
        """STRtree of the buildings' xy boxes, built on first use, to find tiles near a point."""
        if self._tree is None:
            b = self.bbox
            boxes = np.full(len(b), None, dtype=object)  # None: a building without triangles, never found
            valid = np.isfinite(b).all(1)
            boxes[valid] = shapely.box(b[valid, 0], b[valid, 1], b[valid, 3], b[valid, 4])
            self._tree = shapely.STRtree(boxes)
        return self._tree

    def buildings_within(self, xy: Sequence[float], radius_m: float) -> np.ndarray:
        """Indices of the buildings whose box comes within ``radius_m`` of local point ``xy``."""
        disc = shapely.Point(float(xy[0]), float(xy[1])).buffer(float(radius_m), quad_segs=16)
        return np.sort(self.tree.query(disc, predicate="intersects"))

    def tiles_within(self, xy: Sequence[float], radius_m: float) -> tuple[int, ...]:
        """The tiles holding a building within ``radius_m`` of local point ``xy`` (store order)."""
        return tuple(int(t) for t in np.unique(self.tile_of[self.buildings_within(xy, radius_m)]))

    def tiles_around(self, xy: np.ndarray, radius_m: float) -> tuple[int, ...]:
        """The tiles holding a building within ``radius_m`` of any of the local points ``xy`` (N, 2)."""
        points = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return tuple(sorted({t for p in points for t in self.tiles_within(p, radius_m)}))

    def frame(self) -> CityModel:
        """A model without buildings in the store's frame (origin, CRS): for what needs only the frame."""
        return CityModel(
            origin=self.origin.copy(),
            vertices=np.zeros((0, 3), np.float32),
            triangles=np.zeros((0, 3), np.int32),
            classes=np.zeros(0, np.uint8),
            building_index=np.zeros(0, np.int32),
            lods=np.zeros(0, np.uint8),
            building_ids=[],
            crs=self.crs,
            source_crs=self.crs,
            source=str(self.root),
        )

    def tiles_near(self, xy: Sequence[float]) -> tuple[int, ...]:
        """The tile of the building nearest to local point ``xy``."""
        nearest = self.tree.nearest(shapely.Point(float(xy[0]), float(xy[1])))
        return (int(self.tile_of[int(nearest)]),)

    def ground_z_near(self, xy: Sequence[float], radius_m: float) -> float | None:
        """The lowest building bottom within ``radius_m`` (local z), None when no building is that close."""
        near = self.buildings_within(xy, radius_m)
        return float(self.bbox[near, 2].min()) if len(near) else None

    def tile_model(self, index: int) -> CityModel:
        """Tile ``index`` parsed (through the cache)."""
        return self.cache.get(index, self._read_tile)

    def _read_tile(self, index: int) -> CityModel:
        tile = self.tiles[index]
        if not (self.root / tile.npz).is_file():  # removed since the store was opened
            raise _damaged(self.root, f"tile file {tile.npz} of {tile.name} is missing")
        try:
            model = CityModel.load_npz(self.root / tile.npz)
        except InputFileError as exc:
            raise _damaged(self.root, f"tile {tile.name}: {exc}") from exc
        if not np.array_equal(model.origin, self.origin):
            raise InputFileError(f"{self.root}: tile {self.tiles[index].name} is not in the store's origin")
        return model

    def load(self, tiles: Sequence[int]) -> CityModel:
        """The tiles ``tiles`` as one model in the store's local frame (buildings in store order)."""
        if not len(tiles):
            raise EmptyModelError(f"{self.root}: no tile selected")
        models = [self.tile_model(int(t)) for t in sorted(set(int(t) for t in tiles))]
        return merge_models(models, source=str(self.root))

    def load_all(self) -> CityModel:
        """Every tile merged into one model (the whole city, in the store's origin)."""
        return self.load(range(len(self.tiles)))

    def summary(self) -> dict:
        """Tiles, buildings, CRS, origin, extent and input size, for ``tiles info`` and ``city info``."""
        lo = np.array([t.extent[:3] for t in self.tiles]).min(0)
        hi = np.array([t.extent[3:] for t in self.tiles]).max(0)
        return {
            "store": str(self.root),
            "tiles": len(self.tiles),
            "buildings": self.num_buildings,
            "crs": self.index.get("crs_label"),
            "origin": [float(v) for v in self.origin],
            "extent_m": [round(float(v), 3) for v in hi - lo],
            "input_mb": round(sum(t.size_bytes for t in self.tiles) / 1e6, 3),
            "formats": sorted({t.format for t in self.tiles}),
            "lod": self.lod,  # None: each building's highest
            "lods": self.lods_held(),
            "skipped_tiles": sorted(
                self.index.get("skipped_tiles") or {}
            ),  # left out by the build (why: there)
        }

    def lods_held(self) -> list[int] | None:
        """The LoDs the store's buildings were read at, over all tiles (None: a store built before stop 56,
        which did not record them)."""
        if any(not t.lods for t in self.tiles):
            return None
        return sorted({v for t in self.tiles for v in t.lods})


def merge_models(models: Sequence[CityModel], source: str = "") -> CityModel:
    """One model of ``models`` (all in the same origin and CRS): vertices, triangles and buildings
    concatenated in the given order; their readers' counts summed and their warnings kept, each prefixed
    with the file it is about (a skipped roof in one tile must show like one in a single file)."""
    first = models[0]
    v_off = np.cumsum([0] + [len(m.vertices) for m in models[:-1]])
    b_off = np.cumsum([0] + [len(m.building_ids) for m in models[:-1]])
    stats = ParseStats()
    for m in models:
        for key, value in m.stats.as_dict().items():
            if isinstance(value, int):
                setattr(stats, key, getattr(stats, key) + value)
        name = Path(m.source).name if m.source else ""
        stats.warnings.extend(f"{name}: {w}" if name else w for w in m.stats.warnings)
    return CityModel(
        origin=first.origin.copy(),
        vertices=np.concatenate([m.vertices for m in models]),
        triangles=np.concatenate([m.triangles + o for m, o in zip(models, v_off, strict=True)]),
        classes=np.concatenate([m.classes for m in models]),
        building_index=np.concatenate([m.building_index + o for m, o in zip(models, b_off, strict=True)]),
        lods=np.concatenate([m.lods for m in models]),
        building_ids=[b for m in models for b in m.building_ids],
        crs=first.crs,
        source_crs=first.source_crs,
        source=source,
        stats=stats,
    )


def city_sha256(path: str | Path) -> str:
    """The identity of a city model file or of a store (its index: ``TileStore.sha256``, read without
    opening the store), for run provenance."""
    return file_sha256(_root(path) / INDEX_FILE) if is_store(path) else file_sha256(path)


def open_store(path: str | Path, lod: int | str | None = None, crs: str | None = None) -> TileStore:
    """The store at ``path``, refused in one line when ``lod`` / ``crs`` are given and the store does not
    hold them (``check_store_lod``; a ``crs`` other than the one it was built with): they were fixed when
    its tiles were parsed, so another value would silently be ignored."""
    store = TileStore.open(path)
    check_store_lod(store, lod, path)
    if crs is not None and not _same_crs(crs, store.crs):
        built = store.index.get("crs_override") or (store.crs.name if store.crs is not None else None)
        raise _built_with(path, f"crs={built}", parameter("store_crs", crs))
    return store


def _damaged(root: Path, what: str) -> InputFileError:
    """A store whose files no longer match its index: what is wrong, and the command that builds it again."""
    again = parameter("store_again")
    return InputFileError(f"{root}: a damaged tile store: {what}; build it again with {again}")


def check_store_lod(store: TileStore, lod: int | str | None, path: str | Path | None = None) -> None:
    """Refuse in one line a ``lod`` the store does not hold; the one rule of every command that opens a
    store with a ``--lod`` (``open_store``). Held: the LoD it was built at; or, built at each building's
    highest LoD (``lod=None``), a whole-number LoD that is every tile's only one (reading the tiles at it
    gives the same buildings). A LoD no tile holds is refused as a single file without it is
    (``LodNotHeldError``: ``no LoD N building geometry; LoDs present: ...``); a LoD held beside others, a
    refinement (2.2) of a store built at each building's highest, or another LoD than the one it was built
    at asks for the store to be built again at it (``InputFileError``)."""
    where = store.root if path is None else path
    if isinstance(lod, str) and lod.strip().isdigit():
        lod = int(lod)
    if lod is None or str(lod) == str(store.lod):
        return
    held = store.lods_held()
    if store.lod is None and held is not None:
        if isinstance(lod, int) and held == [lod]:
            return
        whole = int(str(lod).split(".")[0])
        if whole not in held:
            present = ", ".join(map(str, held))
            raise LodNotHeldError(
                f"{where}: no LoD {lod} building geometry; LoDs present: {present} (the store was built with "
                "each building's highest LoD)",
                present=present,
            )
    built = "each building's highest LoD" if store.lod is None else f"LoD {store.lod}"
    if held is not None:
        built += f" (its tiles hold LoDs {', '.join(map(str, held))})"
    raise _built_with(where, built, parameter("store_lod", lod))


def _built_with(path: str | Path, built: str, again: str) -> InputFileError:
    return InputFileError(f"{path}: the store was built with {built}; build it again with {again}")


def _same_crs(given: str, store_crs: pyproj.CRS | None) -> bool:
    """Does the user's ``--crs`` name the store's CRS (or its horizontal part; ``crs.same_crs``, axis order
    aside)? Then it changes nothing."""
    if store_crs is None:
        return False
    wanted = parse_crs_name(given)
    return any(same_crs(wanted, c, ignore_axis_order=True) for c in (store_crs, horizontal_crs(store_crs)))


def load_city(
    path: str | Path, lod: int | str | None = None, crs: str | None = None, cache: bool = True
) -> CityModel:
    """A city model file (``citymodel.io.load_city_model``) or a whole store, merged (``lod`` / ``crs``
    must then be the store's own or unset: ``open_store``). A store whose build stopped before its index is
    named as such (``TileStore.open``), not as "a folder"."""
    if Path(path).is_dir() and (Path(path) / TILES_DIR).is_dir() and not is_store(path):
        TileStore.open(path)  # raises, saying the build stopped and how to finish it
    if not is_store(path):
        return load_city_model(path, lod=lod, crs=crs, cache=cache)
    return open_store(path, lod=lod, crs=crs).load_all()
