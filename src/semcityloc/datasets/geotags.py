"""Geotag files: per-photo WGS 84 positions and camera angles (CSV), OpenDroneMap's ``geo.txt``.

Why: photogrammetry tools take a table of camera positions as "reference" or "geolocation" input in
place of the photos' EXIF, and users bring priors in such tables. One CSV layout is read and written here:

``geotags.csv`` (``GEOTAG_COLUMNS``)::

    image,latitude,longitude,height_m,pix4d_yaw_deg,pix4d_pitch_deg,pix4d_roll_deg,accuracy_xy_m,accuracy_z_m,source,height_reference

- ``latitude`` / ``longitude``: WGS 84 degrees; ``height_m``: in ``height_reference`` (WGS 84 ellipsoidal
  when the model's heights could be converted, else the model's own z: ``datasets.dji.dji_geotag``);
- ``pix4d_yaw_deg`` / ``pix4d_pitch_deg`` / ``pix4d_roll_deg``: the yaw, pitch, roll that Pix4D defines
  and Metashape's reference and OpenDroneMap's ``geo.txt`` use (``pix4d_angles``, the same numbers as
  ``geo.txt``'s: pitch 0 = nadir, 90 = looking at the horizon, yaw the heading of the image top from true
  north, roll the sideways tilt; ``geometry.conventions.odm_angles``), so that a tool's reference import
  takes them as they are. Not DJI's gimbal angles (pitch -90 = nadir): a reference import would read
  those 90 degrees off, and near nadir DJI's split between yaw and roll is arbitrary (a camera 0.7 deg
  off nadir has roll 76 deg), where these stay two small tilts and a heading. Before stop 52 the file held
  DJI's angles as ``yaw_deg`` / ``pitch_deg`` / ``roll_deg``; such files read as they were;
- ``accuracy_xy_m`` / ``accuracy_z_m``: one-sigma accuracy where known (empty otherwise); read back as a
  prior's ``PriorUncertainty``;
- ``source``: what the row is (``semcityloc`` for a corrected pose, ``prior`` for a photo that was not
  localized and keeps its prior).

Reading accepts any column order and these names too: ``name`` / ``label`` / ``filename`` for the image,
``lat`` / ``lon`` / ``long``, ``alt`` / ``altitude`` / ``height`` / ``height_ellipsoidal_m``, and angles
either as the ``pix4d_*`` columns or as DJI gimbal angles: ``yaw_deg`` / ``pitch_deg`` / ``roll_deg`` or
``yaw`` / ``pitch`` / ``roll`` (always DJI's convention, as a DJI photo's XMP holds them: what users
export with exiftool); a file with both is refused (which would be meant?). The yaw may be left out (no
such column, or an empty cell or a missing-value marker, ``MISSING_VALUES``: a drone or a table without a
compass heading): that row's prior has yaw 0 and every heading is searched, as a DJI photo without
``GimbalYawDegree`` (``NO_YAW_NOTE``; stop 54). Pix4D angles without a yaw are converted with yaw 0; the
DJI yaw that gives is dropped for 0 too (in both conventions the yaw is the outermost turn, about the
vertical: the camera's tilt, its roll and pitch, is the same whatever heading is taken, and near nadir
DJI's yaw / roll split is arbitrary anyway). Such a row is no true pose (``benchmark.photo_inputs``); a
run writes a photo's prior without a heading with an empty yaw cell. A row without a pitch (an empty cell
or a ``MISSING_VALUES`` marker) gives no prior, as a DJI photo without ``GimbalPitchDegree`` (no tilt to
search from): its photo is skipped with a reason naming file, line and column (``GeotagRow.unusable``;
stop 55: before, the whole file was refused); a file without a pitch column is refused. A row cut short
(fewer cells than the header: a damaged file) is refused naming file, line and the columns it lacks
(stop 55: before, a row cut before its yaw cell read as a row without a heading).

``geo.txt``: OpenDroneMap's image geolocation file, a projection line (the model's horizontal CRS, so no
height conversion is involved) and one line per image: ``image_name x y z yaw pitch roll``, the angles
those of ``geotags.csv`` (``pix4d_angles``), which is ODM's convention.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj

from semcityloc.citymodel.crs import horizontal_crs
from semcityloc.datasets.dji import HEIGHT_ELLIPSOIDAL, HEIGHT_ORTHOMETRIC, NO_HEADING_SEARCHED, DjiGeotag
from semcityloc.datasets.dji_metadata import finite_number
from semcityloc.errors import CRSError, InputFileError
from semcityloc.geometry.conventions import (
    dji_gimbal_angles,
    dji_world_from_cam,
    odm_angles,
    odm_world_from_cam,
)
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty

GEOTAG_COLUMNS = (
    "image",
    "latitude",
    "longitude",
    "height_m",
    "pix4d_yaw_deg",
    "pix4d_pitch_deg",
    "pix4d_roll_deg",
    "accuracy_xy_m",
    "accuracy_z_m",
    "source",
    "height_reference",
)
_ALIASES = {
    "image": ("image", "name", "label", "filename", "file", "image_name", "photo"),
    "latitude": ("latitude", "lat"),
    "longitude": ("longitude", "lon", "long", "lng"),
    "height_m": ("height_m", "height", "alt", "altitude", "height_ellipsoidal_m", "absolute_altitude"),
    "yaw_deg": ("yaw_deg", "yaw", "gimbal_yaw"),
    "pitch_deg": ("pitch_deg", "pitch", "gimbal_pitch"),
    "roll_deg": ("roll_deg", "roll", "gimbal_roll"),
    "pix4d_yaw_deg": ("pix4d_yaw_deg",),
    "pix4d_pitch_deg": ("pix4d_pitch_deg",),
    "pix4d_roll_deg": ("pix4d_roll_deg",),
    "accuracy_xy_m": ("accuracy_xy_m", "accuracy_xy", "horizontal_accuracy"),
    "accuracy_z_m": ("accuracy_z_m", "accuracy_z", "vertical_accuracy"),
    "source": ("source",),
    "height_reference": ("height_reference",),
}
_REQUIRED = ("image", "latitude", "longitude", "height_m")
DJI_ANGLES = ("yaw_deg", "pitch_deg", "roll_deg")  # ``_ALIASES`` keys of the two angle sets a file may hold
PIX4D_ANGLES = ("pix4d_yaw_deg", "pix4d_pitch_deg", "pix4d_roll_deg")
# Said of a row without a yaw (an empty cell, no yaw column), in its prior's notes and its result's warnings:
# the words of ``dji.NO_HEADING_NOTE`` after what lacked the heading.
NO_YAW_NOTE = f"no yaw in its geotag row: {NO_HEADING_SEARCHED}"


def pix4d_angles(tag: DjiGeotag) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in degrees of a geotag's camera as Pix4D, Metashape's reference and OpenDroneMap
    define them (``geometry.conventions.odm_angles``; module docstring): what ``geotags.csv`` and
    ``geo.txt`` hold."""
    yaw, pitch, roll = odm_angles(dji_world_from_cam(tag.yaw_deg, tag.pitch_deg, tag.roll_deg)).tolist()
    return float(yaw), float(pitch), float(roll)


def dji_angles_of_pix4d(yaw_deg: float, pitch_deg: float, roll_deg: float) -> tuple[float, float, float]:
    """DJI gimbal (yaw, pitch, roll) of the camera whose ``pix4d_angles`` are these: the inverse, through
    the rotation (near nadir DJI's yaw / roll split is arbitrary; the camera is the same)."""
    R = odm_world_from_cam(yaw_deg, pitch_deg, roll_deg)
    yaw, pitch, roll = dji_gimbal_angles(Pose.from_rotation_center(R, np.zeros(3))).tolist()
    return float(yaw), float(pitch), float(roll)


@dataclass(frozen=True)
class GeotagRow:
    """One row of a geotag file: the photo's name, its geotag, accuracies and what the row is.

    ``geotag`` None: the row gives no camera (no pitch), ``unusable`` says why and ``PriorFiles`` skips its
    photo with it (module docstring)."""

    image: str
    geotag: DjiGeotag | None
    accuracy_xy_m: float | None = None
    accuracy_z_m: float | None = None
    source: str = ""
    line: int | None = None  # its line in the file it was read from (messages name it)
    unusable: str = ""  # why the row gives no prior (``geotag`` None): "no pitch_deg: ..."

    def source_height(self) -> str:
        """How ``dji_prior`` must read this row's height (``datasets.dji`` ``HEIGHT_*``): orthometric when
        its ``height_reference`` says so (what a run writes when pyproj had no geoid grid: the model's
        own heights), else ellipsoidal (WGS 84, the CSV's documented height; any other reference, e.g.
        "the model's z as it is" of a 2D CRS, reads back unchanged that way too)."""
        if self.geotag.height_reference.lower().startswith("orthometric"):
            return HEIGHT_ORTHOMETRIC
        return HEIGHT_ELLIPSOIDAL

    def uncertainty(self, base: PriorUncertainty | None = None) -> PriorUncertainty | None:
        """The row's accuracies as a prior uncertainty (orientation from ``base``); None without any."""
        if self.accuracy_xy_m is None and self.accuracy_z_m is None:
            return None
        base = base or PriorUncertainty()
        return PriorUncertainty(
            xy_m=self.accuracy_xy_m if self.accuracy_xy_m is not None else base.xy_m,
            z_m=self.accuracy_z_m if self.accuracy_z_m is not None else base.z_m,
            yaw_deg=base.yaw_deg,
            roll_pitch_deg=base.roll_pitch_deg,
            source="geotag file accuracy columns",
        )


# What tables write for a missing value (numpy's ``savetxt``, pandas, spreadsheets): in an optional column
# (the yaw, the roll) the same as an empty cell, in the pitch's a row without a prior (``NO_PITCH``); in a
# required one still a refusal naming it.
MISSING_VALUES = frozenset({"nan", "n/a", "na", "-", "none", "null"})
# Why a row without a pitch gives no prior (after "no <its pitch column>"), as a DJI photo without
# ``GimbalPitchDegree`` gives none (``dji.dji_prior``): its photo is skipped, not the file refused.
NO_PITCH = "without a pitch there is no camera tilt to search from (only the yaw may be left out)"


def _number(value: str, what: str, where: str, optional: bool = False) -> float | None:
    if optional and value.strip().lower() in MISSING_VALUES:
        return None
    out = finite_number(value, f"{where}: {what}")
    if out is None and not optional:
        raise InputFileError(f"{where}: no {what}")
    return out


def read_geotags_csv(path: str | os.PathLike) -> dict[str, GeotagRow]:
    """``{image name: GeotagRow}`` of a geotag CSV (module docstring); ``InputFileError`` naming the line
    of a bad value, of a row cut short or the missing columns. A row without a pitch is kept without a
    geotag (``GeotagRow.unusable``): its photo is skipped, not the file refused."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError as exc:
        raise InputFileError(f"{path}: no such geotag file") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: cannot read geotag file ({exc})") from exc
    sample = text[:4096]
    try:
        dialect = csv.Sniffer().sniff(sample, delimiters=",;\t")
    except csv.Error:
        dialect = csv.excel
    reader = csv.reader(io.StringIO(text), dialect)
    header = [h.strip().lower() for h in next(reader, [])]
    where: dict[str, int] = {}
    for key, names in _ALIASES.items():
        for name in names:
            if name in header:
                where[key] = header.index(name)
                break
    pix4d = any(k in where for k in PIX4D_ANGLES)
    if pix4d and any(k in where for k in DJI_ANGLES):
        raise InputFileError(
            f"{path}: the header {header} holds both DJI gimbal angles (yaw/pitch/roll) and Pix4D ones "
            "(pix4d_*): keep one set"
        )
    angles = PIX4D_ANGLES if pix4d else DJI_ANGLES
    missing = [k for k in (*_REQUIRED, angles[1]) if k not in where]
    if missing:
        raise InputFileError(
            f"{path}: a geotag CSV needs the columns {', '.join(_REQUIRED)} and a pitch: pitch_deg (DJI's) "
            "or pix4d_pitch_deg (+ the yaw: without it every heading is searched; the roll, accuracy_xy_m, "
            f"accuracy_z_m); missing {', '.join(missing)} in the header {header}"
        )
    rows: dict[str, GeotagRow] = {}
    columns = [i for i, h in enumerate(header) if h]  # a trailing delimiter of the header names no column
    width = columns[-1] + 1 if columns else 0
    for n, values in enumerate(reader, start=2):
        if not values or all(not v.strip() for v in values) or values[0].lstrip().startswith("#"):
            continue
        line = f"{path}: line {n}"
        if len(values) < width:  # cut short: a damaged file, not a row whose last cells are empty
            lacking = [h for h in header[len(values) : width] if h]
            raise InputFileError(
                f"{line}: {len(values)} cells where the header has {width}: no {', '.join(lacking)} (the "
                "row is cut short; an empty cell keeps its delimiter)"
            )

        def get(key: str, values=values, line=line, optional: bool = False) -> float | None:
            i = where.get(key)
            value = values[i] if i is not None else ""
            named = header[i] if i is not None else key  # the column as the file names it
            return _number(value, named, line, optional=optional or i is None)

        def text(key: str, values=values) -> str:
            i = where.get(key)
            return values[i].strip() if i is not None else ""

        image = text("image")
        if not image:
            raise InputFileError(f"{line}: no image name")
        lat, lon = get("latitude"), get("longitude")
        if not (-90 <= lat <= 90 and -180 <= lon <= 360):
            raise InputFileError(f"{line}: latitude {lat} / longitude {lon} out of range")
        height = get("height_m")
        accuracy = get("accuracy_xy_m", optional=True), get("accuracy_z_m", optional=True)
        yaw, pitch, roll = (get(a, optional=True) for a in angles)
        if pitch is None:  # no prior, as a DJI photo without GimbalPitchDegree: its photo skipped
            why = f"no {header[where[angles[1]]]}: {NO_PITCH}"
            rows[image] = GeotagRow(image, None, *accuracy, text("source"), n, unusable=why)
            continue
        heading_known, roll = yaw is not None, 0.0 if roll is None else roll
        if pix4d:
            yaw, pitch, roll = dji_angles_of_pix4d(yaw if heading_known else 0.0, pitch, roll)
        yaw = yaw if heading_known else 0.0  # module docstring: no heading, yaw 0 (DJI's)
        tag = DjiGeotag(
            latitude=lat,
            longitude=lon,
            height_m=height,
            yaw_deg=yaw,
            pitch_deg=pitch,
            roll_deg=roll,
            height_reference=text("height_reference") or "as given in the geotag file",
            heading_known=heading_known,
        )
        rows[image] = GeotagRow(image, tag, *accuracy, text("source"), n)
    if not rows:
        raise InputFileError(f"{path}: no geotag rows")
    return rows


def _cell(value: float | None, digits: int) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def geotags_csv_text(rows: list[GeotagRow]) -> str:
    """The CSV text of ``rows`` (module docstring): 9 decimals of a degree (0.1 mm), 4 of a metre."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(GEOTAG_COLUMNS)
    for r in rows:
        g = r.geotag
        yaw, pitch, roll = pix4d_angles(g)
        writer.writerow(
            [
                r.image,
                f"{g.latitude:.10f}",
                f"{g.longitude:.10f}",
                f"{g.height_m:.4f}",
                f"{yaw:.6f}" if g.heading_known else "",  # none known: none written (module docstring)
                f"{pitch:.6f}",
                f"{roll:.6f}",
                _cell(r.accuracy_xy_m, 3),
                _cell(r.accuracy_z_m, 3),
                r.source,
                g.height_reference,
            ]
        )
    return buf.getvalue()


def odm_geo_text(
    crs: pyproj.CRS | str,
    rows: list[tuple[str, tuple[float, float, float], DjiGeotag]],
    accuracies: list[tuple[float, float] | None] | None = None,
) -> str:
    """OpenDroneMap's ``geo.txt``: the projection of the model's horizontal CRS, then per image
    ``name x y z yaw pitch roll`` (``rows``: (name, position in that CRS, geotag for the angles), the
    angles in ODM's own convention, ``geometry.conventions.odm_angles``: pitch 0 = nadir; ODM reads
    ``geo.txt`` angles as they are, adding DJI's 90 degrees only to angles from DJI's XMP),
    followed by ``horizontal_accuracy vertical_accuracy`` (m, one sigma; ODM weights the positions by
    them) where ``accuracies`` gives them for that row."""
    horizontal = horizontal_crs(crs)
    code = horizontal.to_epsg()
    if code is None:
        raise CRSError(f"{horizontal.name}: no EPSG code for OpenDroneMap's geo.txt projection line")
    lines = [f"EPSG:{code}"]
    accuracies = accuracies if accuracies is not None else [None] * len(rows)
    for (name, (x, y, z), g), accuracy in zip(rows, accuracies, strict=True):
        if any(c.isspace() for c in name):
            raise InputFileError(f"{name!r}: geo.txt cannot hold image names with spaces")
        yaw, pitch, roll = pix4d_angles(g)
        line = f"{name} {x:.4f} {y:.4f} {z:.4f} {yaw:.6f} {pitch:.6f} {roll:.6f}"
        if accuracy is not None:
            line += f" {accuracy[0]:.3f} {accuracy[1]:.3f}"
        lines.append(line)
    return "\n".join(lines) + "\n"
