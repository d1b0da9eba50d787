"""Load any supported city model file into a ``CityModel``, with a parse cache.

Formats are recognised by content, not only by extension: CityGML (XML, also ``.gml.gz``), CityJSON
(JSON with ``"type": "CityJSON"``, also a CityJSONSeq stream), Wavefront OBJ, and our own ``.npz`` cache
files. Parsed models are cached as npz keyed by the file's SHA-256 and the reading options, so a 24 MB
CityGML is parsed once.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import zipfile
from pathlib import Path

import numpy as np

from semcityloc.cache import cache_root
from semcityloc.citymodel.citygml import read_citygml
from semcityloc.citymodel.cityjson import read_cityjson
from semcityloc.citymodel.crs import (
    check_projected,
    ground_scale_problem,
    metric_crs,
    overridden_warning,
    parse_crs_name,
)
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.citymodel.obj import OBJ_LOD, read_obj
from semcityloc.errors import CRSError, InputFileError, ParameterError, UnsupportedFormatError, parameter
from semcityloc.io.stamps import file_sha256

# Part of every parse-cache key: raised when the readers' output changes, so that no cached parse made
# before is returned (2: a geographic CityGML's UTM zone no longer comes from a stale Envelope; 3: the stats
# count every skipped polygon, with a warning each; 4: CityJSON's JSON-true vertex indices and non-list
# semantic values no longer pass silently; 5: an AdV srsName's height system kept, a compound CRS; 6: an
# OBJ's class-named materials and semcityloc's own frame header read; 7: a geographic compound CRS's height
# system kept in the metric CRS, PLATEAU's EPSG:6697 -> EPSG:32654+6695).
CACHE_VERSION = 7


def default_cache_dir() -> Path:
    """Where parsed models are cached: ``models/`` under ``cache.cache_root()``, so every cache moves with one
    setting.
    """
    return cache_root() / "models"


ZIP_MAGIC = b"PK\x03\x04"
# What a geoportal's archive may hold that the readers take (``__MACOSX/`` resource forks left out).
MODEL_SUFFIXES = (".gml", ".xml", ".gml.gz", ".json", ".jsonl", ".obj")


def zip_message(path: Path) -> str:
    """Why a ZIP archive is refused, naming the city model files it holds (its central directory only: the
    members are not decompressed, so a hostile archive costs nothing here)."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = [
                n
                for n in archive.namelist()
                if n.lower().endswith(MODEL_SUFFIXES) and not n.startswith("__MACOSX/")
            ]
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        return f"{path}: a damaged ZIP archive ({exc}), not a city model file"
    if not names:
        return f"{path}: a ZIP archive without a CityGML, CityJSON or OBJ file in it"
    shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    return (
        f"{path}: a ZIP archive, not a city model file; it holds {shown}: extract it and pass one of them "
        f"(several tiles of a city: their folder to {parameter('store_build')})"
    )


def sniff_format(path: Path) -> str:
    """``citygml``, ``cityjson``, ``obj``, ``npz`` or ``zip`` (an archive, which ``load_city_model`` refuses
    naming what it holds), from the first bytes of the file."""
    name = path.name.lower()
    if name.endswith(".npz"):
        return "npz"
    opener = gzip.open if name.endswith(".gz") else open
    try:
        with opener(path, "rb") as fh:
            head = fh.read(4096)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if head.startswith(ZIP_MAGIC):
        return "zip"
    text = head.lstrip(b"\xef\xbb\xbf").lstrip()
    if text.startswith(b"<"):
        return "citygml"
    if text.startswith(b"{"):
        return "cityjson"
    if name.endswith(".obj") or any(
        line.startswith((b"v ", b"o ", b"f ", b"g ")) for line in text.splitlines()
    ):
        return "obj"
    if not text:
        raise InputFileError(f"{path}: the file is empty")
    if text.startswith(b"ply"):  # what `city convert` writes for viewers: written, never read
        raise UnsupportedFormatError(
            f"{path}: a PLY mesh, which semcityloc writes for viewers but does not read; convert the "
            "source to .npz (exact) or .obj instead"
        )
    raise UnsupportedFormatError(f"{path}: not CityGML, CityJSON or OBJ (starts with {head[:40]!r})")


def load_city_model(
    path: str | Path,
    lod: int | str | None = None,
    crs: str | None = None,
    target_crs: str | None = None,
    cache: bool | str | Path = True,
    origin=None,
) -> CityModel:
    """Read a city model file.

    Args:
        path: CityGML (1.0/2.0/3.0), CityJSON, OBJ or a semcityloc ``.npz``.
        lod: LoD to keep (None: the highest each building has). Ignored for OBJ (with a warning); an
            ``.npz`` that holds other LoDs is refused (``ParameterError``).
        crs: override of the CRS the file states (or states nothing about), e.g. ``"EPSG:25832"``; an
            override of another CRS is warned of (``model.stats.warnings``), for every format.
        target_crs: metric CRS to project a geographic source to (default: its UTM zone).
        cache: True for the default cache dir, a path for another, False to parse every time.
        origin: float64 (3,) origin of the local frame (default: the data's rounded centre); a tile store
            parses all its tiles into its one origin. Ignored for OBJ and npz.
    """
    path = Path(path)
    if path.is_dir():
        raise InputFileError(
            f"{path}: a folder, not a city model file (a folder of tiles: {parameter('store_build')} makes "
            "a store of them)"
        )
    if not path.is_file():
        raise InputFileError(f"{path}: no such file")
    fmt = sniff_format(path)
    if fmt == "zip":
        raise UnsupportedFormatError(zip_message(path))
    if fmt == "npz":
        return _checked_frame(_npz_options(CityModel.load_npz(path), path, lod, crs), path, crs)

    cache_file = None
    if cache:
        cache_dir = default_cache_dir() if cache is True else Path(cache)
        options = json.dumps([CACHE_VERSION, fmt, lod, crs, target_crs], sort_keys=True, default=_key_value)
        if origin is not None:  # appended only when given: the keys of existing caches stay valid
            options += json.dumps([float(v) for v in np.asarray(origin, dtype=np.float64).reshape(3)])
        key = hashlib.sha256((file_sha256(path) + options).encode()).hexdigest()[:32]
        cache_file = cache_dir / f"{path.stem}-{key}.npz"
        if cache_file.exists():
            try:
                model = CityModel.load_npz(cache_file)
                model.source = str(path)
                return _checked_frame(model, path, crs)
            except InputFileError:
                cache_file.unlink(missing_ok=True)

    model = _checked_frame(_read(path, fmt, lod, crs, target_crs, origin), path, crs)
    if cache_file is not None:
        try:
            cache_file.parent.mkdir(parents=True, exist_ok=True)
            model.save_npz(cache_file)
        except OSError:
            pass  # a read-only cache never stops a parse
    return model


def _checked_frame(model: CityModel, path: Path, crs_given: str | None = None) -> CityModel:
    """``model``, unless its CRS is no metric frame at the model: not projected (an Earth-centred or a
    vertical-only CRS), not in metres (``crs.check_projected``), or with a point scale factor far from 1
    (``crs.ground_scale_problem``: Web Mercator, whose metres are 0.61 m in Berlin); then a ``CRSError``
    naming the file and who named the CRS (``crs_given``: the ``crs`` option, --crs)."""
    if model.crs is not None:
        check_projected(model.crs, f"{path}: the model's CRS")
    centre = model.origin[:2] + model.bounds_local.mean(axis=0)[:2]
    named_by = parameter("crs", crs_given) if crs_given else "the CRS the file states"
    problem = ground_scale_problem(model.crs, float(centre[0]), float(centre[1]), named_by)
    if problem is not None:
        raise CRSError(f"{path}: {problem}")
    return model


def _npz_options(model: CityModel, path: Path, lod, crs: str | None) -> CityModel:
    """A semcityloc ``.npz`` with the ``lod`` and ``crs`` options applied as far as they can be, as the
    CityGML reader applies them: a ``crs`` labels a model that names none, and overrides another with the
    reader's warning (``crs.overridden_warning``); a ``lod`` it does not hold alone is refused, since the
    LoD was chosen when it was converted (they were ignored without a word)."""
    if lod is not None and model.lods_present() != [lod]:
        held = ", ".join(f"LoD{v}" for v in model.lods_present()) or "no triangles"
        raise ParameterError(
            f"{path}: a semcityloc .npz holds the LoD it was converted with ({held}), so "
            f"{parameter('lod', lod)} cannot be applied to it: leave it out, or convert the CityGML / "
            "CityJSON file again with it"
        )
    if crs is None:
        return model
    given = metric_crs(crs, f"the CRS {crs!r}")
    stated = crs_label(model.crs)
    if stated is not None:
        said = overridden_warning(crs, stated)
        if said is None:  # the same place: the model's own CRS (with its height system) is kept
            return model
        model.stats.warnings.append(said)
    model.crs = model.source_crs = given
    return model


def _obj_lod_warning(model: CityModel, lod) -> CityModel:
    """``model`` read from an OBJ, with a warning when a ``lod`` was asked for: an OBJ names none."""
    if lod is not None:
        model.stats.warnings.append(
            f"{parameter('lod', lod)} is ignored for an OBJ, which names no LoD (every triangle is read as "
            f"LoD{OBJ_LOD})"
        )
    return model


def _key_value(value):
    """A cache-key option JSON does not write itself (a numpy integer LoD): its plain value or its text."""
    return value.item() if hasattr(value, "item") else str(value)


def _read(path: Path, fmt: str, lod, crs, target_crs, origin=None) -> CityModel:
    target = parse_crs_name(target_crs) if target_crs else None
    if fmt == "citygml":
        return read_citygml(path, lod=lod, target_crs=target, crs_override=crs, origin=origin)
    if fmt == "cityjson":
        return read_cityjson(path, lod=lod, target_crs=target, crs_override=crs, origin=origin)

    return _obj_lod_warning(read_obj(path, crs=crs), lod)
