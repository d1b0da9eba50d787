"""Generated city models for tests, benchmarks and demos when no real data is at hand.

``synthetic_city`` places flat-roofed boxes and gable houses on a jittered grid, on ground that slopes
gently, with Wall/Roof/Ground semantics, through ``MeshBuilder`` (so exactly the path a reader takes).
``tile_model`` repeats a model side by side (array copies with offsets) to make a bigger city.
"""

from __future__ import annotations

import numpy as np

from semcityloc.citymodel.builder import MeshBuilder
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SemanticClass

# A realistic UTM origin (Berlin, EPSG:25833) so that float64 -> float32 handling is exercised.
DEFAULT_ORIGIN = (391000.0, 5817000.0, 0.0)


def add_house(
    mb: MeshBuilder,
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    z0: float,
    z1: float,
    building_id: str,
    roof_height: float = 0.0,
) -> None:
    """A box [x0, x1] x [y0, y1] x [z0, z1] (world coordinates) with a flat roof, or a gable roof of
    ``roof_height`` whose ridge runs along x. Outward-facing polygons with their semantic class."""
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    for k in range(4):
        (ax, ay), (bx, by) = corners[k], corners[(k + 1) % 4]
        ring = np.array([[ax, ay, z0], [bx, by, z0], [bx, by, z1], [ax, ay, z1]])
        mb.add_polygon(ring, semantic=SemanticClass.WALL, building_id=building_id, lod=2)
    bottom = np.array([[x0, y0, z0], [x0, y1, z0], [x1, y1, z0], [x1, y0, z0]])
    mb.add_polygon(bottom, semantic=SemanticClass.GROUND, building_id=building_id, lod=2)
    if roof_height <= 0:
        top = np.array([[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]])
        mb.add_polygon(top, semantic=SemanticClass.ROOF, building_id=building_id, lod=2)
        return
    ym, zr = 0.5 * (y0 + y1), z1 + roof_height
    roof = SemanticClass.ROOF
    mb.add_polygon(
        np.array([[x0, y0, z1], [x1, y0, z1], [x1, ym, zr], [x0, ym, zr]]),
        semantic=roof,
        building_id=building_id,
        lod=2,
    )
    mb.add_polygon(
        np.array([[x0, ym, zr], [x1, ym, zr], [x1, y1, z1], [x0, y1, z1]]),
        semantic=roof,
        building_id=building_id,
        lod=2,
    )
    wall = SemanticClass.WALL
    mb.add_polygon(
        np.array([[x0, y0, z1], [x0, ym, zr], [x0, y1, z1]]), semantic=wall, building_id=building_id, lod=2
    )
    mb.add_polygon(
        np.array([[x1, y0, z1], [x1, y1, z1], [x1, ym, zr]]), semantic=wall, building_id=building_id, lod=2
    )


def synthetic_city(
    n: int = 8,
    spacing_m: float = 30.0,
    seed: int = 0,
    origin: tuple[float, float, float] = DEFAULT_ORIGIN,
    base_height_m: float = 34.0,
    slope: float = 0.02,
) -> CityModel:
    """An n x n grid of houses (8-22 m footprints, 6-40 m tall, half with gable roofs) on a slope."""
    rng = np.random.default_rng(seed)
    mb = MeshBuilder()
    for i in range(n):
        for j in range(n):
            w, d = rng.uniform(8.0, 22.0, 2)
            h = rng.uniform(6.0, 40.0)
            x0 = origin[0] + i * spacing_m + rng.uniform(0.0, spacing_m - w)
            y0 = origin[1] + j * spacing_m + rng.uniform(0.0, spacing_m - d)
            z0 = base_height_m + slope * i * spacing_m
            gable = rng.uniform(1.0, 6.0) if rng.random() < 0.5 else 0.0
            add_house(mb, x0, y0, x0 + w, y0 + d, z0, z0 + h, f"house_{i}_{j}", roof_height=gable)
    return mb.build(source="synthetic_city")


def tile_model(model: CityModel, nx: int, ny: int = 1, gap_m: float = 0.0) -> CityModel:
    """``model`` repeated nx x ny times side by side (x then y), sharing its origin."""
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
