"""Camera centres and ground footprints of posed photos as GeoJSON, for a GIS (QGIS opens it as it is).

Per photo two features with the same properties (``image``, ``status``, ...): a ``Point`` at the camera
centre and a ``Polygon``, the photo's footprint: the rays through ``FOOTPRINT_SAMPLES`` points along each
image border meet the horizontal plane at ``ground_z`` (the model's ground), rays that never meet it
(above the horizon) are cut at ``max_range_m`` horizontally. Coordinates: WGS 84 longitude, latitude
(RFC 7946; pyproj, ``always_xy``, on whole arrays), so the model's CRS must be known: a model in a local
frame has no GeoJSON (``CRSError``). Why not its own metres: RFC 7946 has no member for another CRS, and
QGIS and GDAL read any GeoJSON's coordinates as longitude, latitude (a camera 466 m west of the origin
lands at longitude -466, off the map).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyproj

from semcityloc.citymodel.crs import horizontal_crs
from semcityloc.citymodel.triangulate import ring_area_xy
from semcityloc.errors import CRSError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.io.files import json_default, write_atomic

FOOTPRINT_SAMPLES = 8  # points per image border
MAX_RANGE_M = 1500.0


@dataclass
class CameraFeature:
    """One photo for the GeoJSON: its camera, pose in the model's frame (CRS minus offset) and properties."""

    name: str
    camera: Camera
    pose_world: Pose
    properties: dict = field(default_factory=dict)


def footprint_xy(camera: Camera, pose_world: Pose, ground_z: float, max_range_m: float = MAX_RANGE_M):
    """(N, 2) float64 x, y of the photo's footprint on the plane z = ``ground_z`` (module docstring), in
    the order of the image border (a closed ring without the repeated first point)."""
    w, h = float(camera.width), float(camera.height)
    t = np.arange(FOOTPRINT_SAMPLES) / FOOTPRINT_SAMPLES
    uv = np.concatenate(
        [
            np.stack([t * w, np.zeros_like(t)], 1),
            np.stack([np.full_like(t, w), t * h], 1),
            np.stack([w - t * w, np.full_like(t, h)], 1),
            np.stack([np.zeros_like(t), h - t * h], 1),
        ]
    )
    rays = pose_world.R_world_from_cam @ camera.unproject(uv).T  # (3, N)
    centre = pose_world.center
    dz = float(ground_z) - centre[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(rays[2] * dz > 0, dz / rays[2], np.inf)
    horizontal = np.maximum(np.linalg.norm(rays[:2], axis=0), 1e-12)
    s = np.minimum(s, max_range_m / horizontal)
    return (centre[:2, None] + rays[:2] * s).T


def _to_output(xy: np.ndarray, crs: pyproj.CRS, offset: np.ndarray) -> np.ndarray:
    """(N, 2) model-frame x, y -> WGS 84 lon, lat."""
    t = pyproj.Transformer.from_crs(horizontal_crs(crs), "EPSG:4326", always_xy=True)
    lon, lat = t.transform(xy[:, 0] + offset[0], xy[:, 1] + offset[1])
    out = np.stack([np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)], 1)
    if not np.all(np.isfinite(out)):
        raise CRSError(f"{crs.name}: a camera lies outside the CRS's area of use")
    return out


def cameras_geojson(
    features: list[CameraFeature],
    crs: pyproj.CRS | None,
    ground_z: float,
    offset: np.ndarray | None = None,
) -> dict:
    """A GeoJSON ``FeatureCollection`` of camera centres and footprints (module docstring); ``CRSError``
    without a CRS (``crs`` None)."""
    if crs is None:
        raise CRSError(
            "cameras_geojson needs the model's CRS: GeoJSON coordinates are WGS 84 longitude, latitude"
        )
    shift = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64)
    out = []
    for f in features:
        centre = f.pose_world.center
        ring = footprint_xy(f.camera, f.pose_world, ground_z)
        xy = _to_output(np.vstack([centre[None, :2], ring]), crs, shift)
        border = xy[1:]
        if ring_area_xy(border) < 0:  # RFC 7946: an exterior ring winds counterclockwise
            border = border[::-1]
        ring_out = np.vstack([border, border[:1]]).tolist()  # closed ring
        props = {"image": f.name, **f.properties}
        out.append(
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": xy[0].tolist()},
                "properties": {**props, "feature": "camera centre"},
            }
        )
        out.append(
            {
                "type": "Feature",
                "geometry": {"type": "Polygon", "coordinates": [ring_out]},
                "properties": {**props, "feature": "footprint", "footprint_ground_z": float(ground_z)},
            }
        )
    return {"type": "FeatureCollection", "features": out}


def write_geojson(collection: dict, path: str | os.PathLike) -> Path:
    """Strict JSON (``allow_nan=False``), written through a temporary file; an ``OSError`` (a full disk)
    names ``path`` and leaves no temporary file."""
    path = Path(path)
    write_atomic(path, json.dumps(collection, default=json_default, allow_nan=False) + "\n")
    return path
