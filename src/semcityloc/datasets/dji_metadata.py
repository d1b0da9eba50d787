"""A DJI photo's metadata: its XMP packet and EXIF tags, read and checked -> ``DjiMetadata``.

Why: a drone photo carries where it was taken, where the gimbal pointed and the camera's calibration. This
module only reads them (every number finite, latitude / longitude in range, ``DjiMetadata.sources`` naming
the tag each value came from); what they mean for a pose is ``datasets.dji``'s, for a camera
``datasets.dji_camera``'s.

What is read (``read_dji_metadata``): the XMP packet (``drone-dji:GpsLatitude``, ``GpsLongitude``,
``AbsoluteAltitude``, ``RelativeAltitude``, ``GimbalYawDegree`` / ``GimbalPitchDegree`` /
``GimbalRollDegree``, ``Flight*Degree``, ``AltitudeType``, ``RtkFlag``, ``RtkStdHgt``, ...), found as
attributes or elements anywhere in the file by a regular expression (no XML parser, no entities), and the
EXIF GPS block as a fallback for position (``GPSLatitude`` etc., via Pillow). The camera model, image
size and focal lengths come from EXIF; DJI's calibration (``CalibratedFocalLength``,
``CalibratedOpticalCenterX`` / ``Y``) and its lens distortion (``DewarpData``, ``DewarpFlag``) from the XMP.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from PIL import Image

from semcityloc.errors import InputFileError
from semcityloc.io.images import IMAGE_DECODE_ERRORS

DEWARP_VALUES = 9  # fx, fy, cx, cy, k1, k2, p1, p2, k3
MAX_FILE_BYTES = 256 * 1024 * 1024
_ATTR = re.compile(rb'([A-Za-z][\w.-]*):([A-Za-z][\w.-]*)\s*=\s*"([^"]*)"')
_ELEM = re.compile(rb"<([A-Za-z][\w.-]*):([A-Za-z][\w.-]*)>([^<]*)</\1:\2>")


@dataclass
class DjiMetadata:
    """What a DJI image says about where it was taken. ``sources``: field -> the tag it came from."""

    latitude: float | None = None
    longitude: float | None = None
    absolute_altitude_m: float | None = None
    relative_altitude_m: float | None = None
    gimbal_yaw_deg: float | None = None
    gimbal_pitch_deg: float | None = None
    gimbal_roll_deg: float | None = None
    flight_yaw_deg: float | None = None
    flight_pitch_deg: float | None = None
    flight_roll_deg: float | None = None
    altitude_type: str | None = None
    rtk_flag: int | None = None
    rtk_std_height_m: float | None = None
    rtk_std_lon_m: float | None = None  # RtkStdLon / RtkStdLat: metres (east / north), as DJI writes them
    rtk_std_lat_m: float | None = None
    make: str | None = None
    model: str | None = None
    image_source: str | None = None
    width: int | None = None
    height: int | None = None
    focal_length_mm: float | None = None
    focal_length_35mm: float | None = None
    # DJI's per-unit calibration (``drone-dji:CalibratedFocalLength`` / ``CalibratedOpticalCenterX`` /
    # ``Y``, pixels of the full-size image), written by enterprise cameras (P4 RTK, Mavic 3E, Zenmuse P1 ...)
    calibrated_focal_px: float | None = None
    calibrated_cx_px: float | None = None
    calibrated_cy_px: float | None = None
    # ``drone-dji:DewarpData`` "date;fx,fy,cx,cy,k1,k2,p1,p2,k3": the calibration with lens distortion
    # (cx, cy: offsets from the image centre; pixels of the full-size image), and ``DewarpFlag`` (1: the
    # camera already undistorted the photo)
    dewarp: tuple[float, ...] | None = None
    dewarp_flag: int | None = None
    sources: dict[str, str] = field(default_factory=dict)
    xmp: dict[str, str] = field(default_factory=dict)

    def require(self, *names: str) -> None:
        """InputFileError naming the fields among ``names`` the photo's metadata lacks."""
        missing = [n for n in names if getattr(self, n) is None]
        if missing:
            raise InputFileError(
                f"the image metadata has no {', '.join(missing)} (is it an original DJI photo?)"
            )


def parse_xmp_fields(data: bytes) -> dict[str, str]:
    """``{"prefix:Name": value}`` of every XMP property written as ``prefix:Name="value"`` or
    ``<prefix:Name>value</prefix:Name>`` in ``data`` (the first occurrence wins)."""
    out: dict[str, str] = {}
    start = data.find(b"<x:xmpmeta")
    packet = data[start : data.find(b"</x:xmpmeta>", start) + 12] if start >= 0 else data
    for pattern in (_ATTR, _ELEM):
        for prefix, name, value in pattern.findall(packet):
            key = f"{prefix.decode('ascii', 'replace')}:{name.decode('ascii', 'replace')}"
            if key.startswith("xmlns:"):
                continue
            out.setdefault(key, value.decode("utf-8", "replace").strip())
    return out


def finite_number(text: str | None, what: str) -> float | None:
    """``text`` as a finite float (None when empty); ``InputFileError`` naming ``what`` otherwise."""
    if text is None or text.strip() == "":
        return None
    try:
        value = float(text)
    except ValueError:
        raise InputFileError(f"{what} is not a number: {text!r}") from None
    if not math.isfinite(value):
        raise InputFileError(f"{what} is not finite: {text!r}")
    return value


def _dms(values, ref: str | bytes | None, negative: str) -> float:
    """Degrees from EXIF (degrees, minutes, seconds) and the hemisphere letter ``ref`` (negative when it is
    ``negative``); ``TypeError`` / ``ValueError`` when either is not what EXIF holds there."""
    d, m, s = (float(v) for v in values)
    out = d + m / 60.0 + s / 3600.0
    if isinstance(ref, bytes):
        ref = ref.decode("ascii", "replace")
    if ref is not None and not isinstance(ref, str):
        raise TypeError(f"GPS hemisphere {ref!r} is no letter")
    return -out if (ref or "").strip().upper().startswith(negative) else out


def _exif(path: Path) -> dict:
    try:
        with Image.open(path) as im:
            exif = im.getexif()
            out = {"width": im.size[0], "height": im.size[1], "make": exif.get(271), "model": exif.get(272)}
            gps = exif.get_ifd(0x8825)
            sub = exif.get_ifd(0x8769)
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: not a readable image ({exc})") from exc
    try:
        if 2 in gps and 4 in gps:
            out["latitude"] = _dms(gps[2], gps.get(1), "S")
            out["longitude"] = _dms(gps[4], gps.get(3), "W")
        if 6 in gps:
            ref = gps.get(5, b"\x00")
            below = (ref[0] if isinstance(ref, bytes) and ref else ref) == 1
            out["altitude"] = -float(gps[6]) if below else float(gps[6])
    except (TypeError, ValueError, ZeroDivisionError) as exc:
        raise InputFileError(f"{path}: unreadable EXIF GPS block ({exc})") from exc
    try:
        if 37386 in sub:
            out["focal_mm"] = float(sub[37386])
        if 41989 in sub and float(sub[41989]) > 0:
            out["focal_35mm"] = float(sub[41989])
    except (TypeError, ValueError, ZeroDivisionError) as exc:  # a tuple or text where a number belongs
        raise InputFileError(f"{path}: unreadable EXIF focal length ({exc})") from exc
    return out


def read_dji_metadata(path: str | os.PathLike) -> DjiMetadata:
    """GPS, heights, gimbal / flight angles and camera facts of an image (module docstring)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise InputFileError(f"{path}: {size} bytes is too large for an image")
        data = path.read_bytes()
    except FileNotFoundError as exc:
        raise InputFileError(f"{path}: no such image") from exc
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    xmp = parse_xmp_fields(data)
    exif = _exif(path)
    meta = DjiMetadata(xmp=xmp, width=exif.get("width"), height=exif.get("height"))

    def dji(key: str) -> str | None:
        return xmp.get(f"drone-dji:{key}")

    for attr, key in (
        ("latitude", "GpsLatitude"),
        ("longitude", "GpsLongitude"),
        ("absolute_altitude_m", "AbsoluteAltitude"),
        ("relative_altitude_m", "RelativeAltitude"),
        ("gimbal_yaw_deg", "GimbalYawDegree"),
        ("gimbal_pitch_deg", "GimbalPitchDegree"),
        ("gimbal_roll_deg", "GimbalRollDegree"),
        ("flight_yaw_deg", "FlightYawDegree"),
        ("flight_pitch_deg", "FlightPitchDegree"),
        ("flight_roll_deg", "FlightRollDegree"),
        ("rtk_std_height_m", "RtkStdHgt"),
        ("rtk_std_lon_m", "RtkStdLon"),
        ("rtk_std_lat_m", "RtkStdLat"),
    ):
        value = finite_number(dji(key), f"DJI metadata {key}")
        if value is None and key == "GpsLongitude":
            value = finite_number(
                dji("GpsLongtitude"), f"DJI metadata {key}"
            )  # a misspelling some firmware writes
        if value is not None:
            setattr(meta, attr, value)
            meta.sources[attr] = f"xmp:drone-dji:{key}"
    for attr, key in (
        ("latitude", "latitude"),
        ("longitude", "longitude"),
        ("absolute_altitude_m", "altitude"),
    ):
        if getattr(meta, attr) is None and key in exif:
            setattr(meta, attr, exif[key])
            meta.sources[attr] = f"exif:GPS{key.capitalize()}"
    rtk = finite_number(dji("RtkFlag"), "DJI metadata RtkFlag")
    meta.rtk_flag = int(rtk) if rtk is not None else None
    meta.altitude_type = dji("AltitudeType")
    meta.image_source = dji("ImageSource")
    meta.make = exif.get("make") or xmp.get("tiff:Make")
    meta.model = exif.get("model") or xmp.get("tiff:Model")
    meta.focal_length_mm = exif.get("focal_mm")
    meta.focal_length_35mm = exif.get("focal_35mm")
    meta.calibrated_focal_px = finite_number(
        dji("CalibratedFocalLength"), "DJI metadata CalibratedFocalLength"
    )
    meta.calibrated_cx_px = finite_number(
        dji("CalibratedOpticalCenterX"), "DJI metadata CalibratedOpticalCenterX"
    )
    meta.calibrated_cy_px = finite_number(
        dji("CalibratedOpticalCenterY"), "DJI metadata CalibratedOpticalCenterY"
    )
    meta.dewarp = _dewarp_data(dji("DewarpData"))
    flag = finite_number(dji("DewarpFlag"), "DJI metadata DewarpFlag")
    meta.dewarp_flag = int(flag) if flag is not None else None
    if meta.latitude is not None and not -90 <= meta.latitude <= 90:
        raise InputFileError(f"{path}: latitude {meta.latitude} is out of range")
    if meta.longitude is not None and not -180 <= meta.longitude <= 360:
        raise InputFileError(f"{path}: longitude {meta.longitude} is out of range")
    return meta


def _dewarp_data(text: str | None) -> tuple[float, ...] | None:
    """The nine numbers of a ``DewarpData`` tag (``DjiMetadata.dewarp``), None when absent."""
    if text is None or not text.strip():
        return None
    values = text.split(";", 1)[-1].split(",")
    if len(values) != DEWARP_VALUES:
        raise InputFileError(
            f"DJI metadata DewarpData: expected 'date;fx,fy,cx,cy,k1,k2,p1,p2,k3', got {text[:80]!r}"
        )
    return tuple(finite_number(v, "DJI metadata DewarpData") for v in values)
