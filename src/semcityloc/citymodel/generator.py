"""Procedural city district: the embedded default city of semcityloc, as CityGML 2.0 files or a ``CityModel``.

Why: the demo and every test that must run without ``../shared`` need a realistic semantic city with
known ground truth. ``generate_city`` writes ``generated_lod1.gml``, ``generated_lod2.gml`` and
``generated_lod3.gml`` from the SAME footprints (same building ids), deterministically for a seed (the
files are byte-identical across runs).

The parts, one module each:
- the district's layout (street grid, blocks, footprints, heights, roofs, terrain):
  ``generator_footprints.generate_footprints``;
- a building's polygons at LoD 1, 2 or 3 (ground, walls, roofs, windows, doors):
  ``generator_surfaces.building_surfaces``;
- the CityGML 2.0 file of one LoD: ``citygml_writer.write_citygml``.

Here, what the library uses: ``generate_city`` (the files); ``footprints_to_model`` turns the same
surfaces straight into a ``CityModel`` (no XML round trip) -- the one generated city of the library
(tests, benchmarks, demo); ``tile_model`` repeats a model side by side for a bigger one;
``default_city_path`` generates the default district once into a user cache directory.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from semcityloc.cache import cache_root
from semcityloc.citymodel.builder import MeshBuilder
from semcityloc.citymodel.citygml_writer import srs_name, write_citygml
from semcityloc.citymodel.crs import metric_crs
from semcityloc.citymodel.generator_footprints import (
    DEFAULT_BLOCKS,
    DEFAULT_CRS,
    DEFAULT_ORIGIN,
    DEFAULT_SEED,
    Footprint,
    check_blocks,
    generate_footprints,
    generated_crs_what,
)
from semcityloc.citymodel.generator_surfaces import check_lod, city_surfaces
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SURFACE_CLASS
from semcityloc.errors import InputFileError, ParameterError

GENERATOR_VERSION = 1  # bump whenever the output of the same parameters changes (cache key)
DEFAULT_LODS = (1, 2, 3)


def footprints_to_model(footprints: list[Footprint], lod: int = 2, crs: str = DEFAULT_CRS) -> CityModel:
    """The generated surfaces straight into a ``CityModel`` (no XML). LoD1 surfaces go in unlabelled
    (classified by normals, as a reader of the LoD1 file would), LoD2/3 with their CityGML semantics."""
    lod = check_lod(lod)
    metric = metric_crs(crs, generated_crs_what(crs))
    builder = MeshBuilder()
    for fp, surfaces in city_surfaces(footprints, lod):
        for s in surfaces:
            sem = None if lod == 1 else int(SURFACE_CLASS[s.kind])
            builder.add_polygon(s.exterior, s.interiors, sem, fp.id, lod)
            for o in s.openings:
                builder.add_polygon(o.exterior, (), int(SURFACE_CLASS[o.kind]), fp.id, lod)
    return builder.build(crs=metric, source_crs=metric, source=f"generated LoD{lod}")


def tile_model(model: CityModel, nx: int, ny: int = 1, gap_m: float = 0.0) -> CityModel:
    """``model`` repeated nx x ny times side by side (x then y), ``gap_m`` apart, sharing its origin: a
    bigger city for scaling tests and benchmarks (array copies with offsets)."""
    ext = model.extent_m
    verts, tris, extras = [], [], []
    nv = len(model.vertices)
    nb = len(model.building_ids)
    ids: list[str] = []
    for a in range(ny):
        for b in range(nx):
            k = a * nx + b
            off = np.array([b * (ext[0] + gap_m), a * (ext[1] + gap_m), 0.0])
            verts.append(model.vertices.astype(np.float64) + off)
            tris.append(model.triangles + k * nv)
            extras.append(model.building_index + k * nb)
            ids.extend(f"{bid}#{k}" for bid in model.building_ids)
    reps = nx * ny
    return CityModel(
        origin=model.origin.copy(),
        vertices=np.concatenate(verts).astype(np.float32),
        triangles=np.concatenate(tris),
        classes=np.tile(model.classes, reps),
        building_index=np.concatenate(extras),
        lods=np.tile(model.lods, reps),
        building_ids=ids,
        crs=model.crs,
        source_crs=model.source_crs,
        source=f"{model.source} x{reps}",
    )


def generate_city(
    out_dir: str | Path,
    seed: int = DEFAULT_SEED,
    blocks: tuple[int, int] = DEFAULT_BLOCKS,
    lods: tuple[int, ...] = DEFAULT_LODS,
    crs: str = DEFAULT_CRS,
    origin: tuple[float, float] = DEFAULT_ORIGIN,
) -> dict[int, Path]:
    """Write ``out_dir/generated_lod{N}.gml`` for each LoD in ``lods`` from the same footprints.

    ``origin``: world x, y of the district's south-west corner (in ``crs``, which must be projected).
    Returns {lod: path}. Deterministic: the same arguments give byte-identical files.
    """
    lods = (lods,) if isinstance(lods, (int, np.integer)) else lods
    lod_list = sorted({check_lod(v) for v in lods}) if lods else []
    if not lod_list:
        raise ParameterError("lods must name at least one of 1, 2, 3")
    srs_name(crs)  # fail on a bad CRS before any work
    footprints = generate_footprints(seed, blocks, origin)
    nx, ny = check_blocks(blocks)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = f"semcityloc generated district (v{GENERATOR_VERSION}, seed {int(seed)}, blocks {nx}x{ny})"
    return {
        lod: write_citygml(footprints, lod, out / f"generated_lod{lod}.gml", crs, f"{name} LoD{lod}")
        for lod in lod_list
    }


def default_cache_root() -> Path:
    """``cache.cache_root()`` / ``generated``."""
    return cache_root() / "generated"


def default_city_path(lod: int = 2, cache_dir: str | Path | None = None) -> Path:
    """The default district's CityGML file at ``lod``, generated once (all three LoDs) into
    ``cache_dir`` (default ``default_cache_root()``) under a folder keyed by the generator version and
    the default parameters."""
    lod = check_lod(lod)
    root = Path(cache_dir) if cache_dir is not None else default_cache_root()
    key = (
        f"v{GENERATOR_VERSION}-seed{DEFAULT_SEED}-blocks{DEFAULT_BLOCKS[0]}x{DEFAULT_BLOCKS[1]}-"
        f"{DEFAULT_CRS.replace(':', '')}-{DEFAULT_ORIGIN[0]:.0f}-{DEFAULT_ORIGIN[1]:.0f}"
    )
    target = root / key
    path = target / f"generated_lod{lod}.gml"
    if path.exists():
        return path
    try:
        root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key}-", dir=root))
    except OSError as exc:
        raise InputFileError(f"cannot write the generated city into {root}: {exc.strerror or exc}") from exc
    try:
        generate_city(tmp)
        try:
            tmp.rename(target)  # atomic: a reader never sees a half-written folder
        except OSError:  # another process won the race, or an incomplete folder is in the way
            for f in sorted(tmp.iterdir()):
                if not (target / f.name).exists():
                    os.replace(f, target / f.name)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return path
