"""A prior pose from a DJI image's own metadata: GPS (EXIF / XMP) and gimbal angles (XMP) -> ``Pose``.

Why: a drone image is its own prior. DJI writes the aircraft position and the gimbal's absolute angles
into every photo; this module reads them and puts the camera into the city model's CRS with pyproj, so a
user can localize a flight without any pose file.

What is read (``read_dji_metadata``): the XMP packet (``drone-dji:GpsLatitude``, ``GpsLongitude``,
``AbsoluteAltitude``, ``RelativeAltitude``, ``GimbalYawDegree`` / ``GimbalPitchDegree`` /
``GimbalRollDegree``, ``Flight*Degree``, ``AltitudeType``, ``RtkFlag``, ``RtkStdHgt``, ...), found as
attributes or elements anywhere in the file by a regular expression (no XML parser, no entities), and the
EXIF GPS block as a fallback for position (``GPSLatitude`` etc., via Pillow). The camera model and image
size come from EXIF; ``camera_from_exif`` makes the pinhole camera from DJI's calibration tags when the
photo has them (``CalibratedFocalLength``, ``CalibratedOpticalCenterX`` / ``Y``), else approximately from
the 35 mm-equivalent focal length; ``dewarp_lens`` the camera with its lens distortion from
``DewarpData`` when the camera did not undistort the photo itself (``DewarpFlag`` 0).

Angles (``geometry.conventions.pose_from_dji``): DJI gimbal angles are NED, yaw clockwise from north,
pitch -90 = nadir. They refer to true north; a projected CRS's grid north differs by the meridian
convergence, which is measured numerically here (the grid azimuth of a short step due north) and added
to the yaw. Without that correction a UTM pose is up to ~3 deg off in yaw at the zone edges.

Heights, the part that is easy to get wrong by tens of metres. DJI's ``AbsoluteAltitude`` is:

- the WGS 84 **ellipsoidal** height on RTK aircraft (Matrice 300 / 350 RTK, Phantom 4 RTK, Mavic 3E/3T
  with RTK; recognised by ``AltitudeType`` containing "Rtk" or ``RtkFlag`` >= 34: float or fixed);
- a **barometric** value on the others (zeroed at take-off and drifting with the weather: tens of metres
  wrong). It is used, and flagged with ``BAROMETRIC_UNCERTAINTY_M``.

City models store orthometric heights (above a geoid: NAP, DHHN2016, EGM96 "MSL", ...), which differ from
ellipsoidal heights by the local geoid undulation N (-107 m .. +86 m worldwide; ``H = h - N``). When the
target has a vertical datum (a compound CRS such as ``EPSG:25832+7837`` or ``EPSG:7415``), or the user
says the model's z is orthometric (``target_height="orthometric"``: EGM96 for a 2D CRS), the conversion
runs through pyproj. pyproj applies a geoid only when its grid file is installed (``projsync`` or
``PROJ_NETWORK=ON``); otherwise its "ballpark" operation leaves the height unchanged. That case is never
silent: ``DjiPrior.geoid_applied`` is False, ``vertical_flag`` says what was not done and which grid
would do it, and ``vertical_uncertainty_m`` grows to ``GEOID_UNDULATION_BOUND_M``. A known N can be
given as ``geoid_separation_m``. A 2D target CRS with ``target_height="auto"`` keeps the DJI height as
it is (z of the result = DJI's height reference, stated in ``z_reference``): UAVD4L-LoD's frame is such a
case (its z is DJI's RTK height: measured on the real demo image, GT z - AbsoluteAltitude = 0.68 m).

Frames: ``offset`` is subtracted from the CRS coordinates (in float64) for data sets whose frame is a CRS
minus an offset; bring the result into a ``CityModel``'s local frame with ``model.pose_to_local(pose)``.
"""

from __future__ import annotations

import functools
import math
import os
import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pyproj
from PIL import Image
from pyproj.transformer import TransformerGroup

from semcityloc.citymodel.crs import parse_crs_name
from semcityloc.errors import CameraError, CRSError, InputFileError, ParameterError, PoseError, unknown_choice
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import dji_gimbal_angles, pose_from_dji, wrap_deg
from semcityloc.geometry.distortion import LensDistortion
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.io.images import IMAGE_DECODE_ERRORS

HEIGHT_AUTO, HEIGHT_ELLIPSOIDAL, HEIGHT_ORTHOMETRIC, HEIGHT_BAROMETRIC = (
    "auto",
    "ellipsoidal",
    "orthometric",
    "barometric",
)
SOURCE_HEIGHTS = (HEIGHT_AUTO, HEIGHT_ELLIPSOIDAL, HEIGHT_ORTHOMETRIC, HEIGHT_BAROMETRIC)
TARGET_HEIGHTS = (HEIGHT_AUTO, HEIGHT_ELLIPSOIDAL, HEIGHT_ORTHOMETRIC)
RTK_MIN_FLAG = 34  # RtkFlag: 0 none, 16 single point, 34..49 float, 50 fixed (DJI XMP list)
RTK_FIXED_FLAG = 50
RTK_FLOAT_FLOOR_M = 1.0  # an RTK float solution: decimetres to a metre, whatever it reports
GEOID_UNDULATION_BOUND_M = 110.0  # |N| <= ~107 m anywhere (EGM2008 extremes: -106.6 / +85.8 m)
BAROMETRIC_UNCERTAINTY_M = 50.0  # DJI non-RTK "absolute altitude": barometric, weather dependent
RTK_DEFAULT_UNCERTAINTY_M = 0.1
GPS_DEFAULT_UNCERTAINTY_M = 5.0
# Said (in the prior's notes) when a 2D CRS gets DJI's ellipsoidal height as its z unchanged: right for
# UAVD4L-like frames, ~40 m wrong for a German LoD2 tile whose heights are DHHN2016.
HEIGHT_AS_IS_NOTE = (
    "the model's CRS names no vertical datum: the photos' WGS 84 ellipsoidal heights are used as its z "
    "unchanged; if the model's heights are orthometric (most city models), pass a compound CRS (--crs "
    "EPSG:xxxx+vvvv) or --target-height orthometric"
)
EGM96 = "EPSG:4326+5773"  # WGS 84 + EGM96 height: DJI's "MSL", the default orthometric system
WGS84_3D = "EPSG:4979"
EGM96_GRID = "us_nga_egm96_15.tif"
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)  # the "35 mm equivalent" is defined on the diagonal
# DJI calibration tags are used only while their optical centre lies within this share of the image size
# of the photo's centre (``calibrated_intrinsics``): farther, the photo was resized or cropped since.
CALIBRATED_CENTRE_TOLERANCE = 0.1
DEWARP_VALUES = 9  # fx, fy, cx, cy, k1, k2, p1, p2, k3
MAX_FILE_BYTES = 256 * 1024 * 1024
AREA_MARGIN_DEG = 2.0  # tolerance around a CRS's area of use (zones are often used a little beyond)
_ATTR = re.compile(rb'([A-Za-z][\w.-]*):([A-Za-z][\w.-]*)\s*=\s*"([^"]*)"')
_ELEM = re.compile(rb"<([A-Za-z][\w.-]*):([A-Za-z][\w.-]*)>([^<]*)</\1:\2>")
# "EPSG:h+v": parse_crs_name keeps only the horizontal code of this form, pyproj reads it whole.
_EPSG_PLUS = re.compile(r"^\s*EPSG:\d+\+\d+\s*$", re.IGNORECASE)


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
        missing = [n for n in names if getattr(self, n) is None]
        if missing:
            raise InputFileError(
                f"the image metadata has no {', '.join(missing)} (is it an original DJI photo?)"
            )


@dataclass
class DjiPrior:
    """A prior pose from DJI metadata and how its height was treated (module docstring)."""

    pose: Pose  # cam_from_world, world = target CRS minus ``offset``
    position_crs: np.ndarray  # (3,) float64 camera centre in the target CRS (before the offset)
    crs: pyproj.CRS
    source_height: str  # reference of the DJI height: ellipsoidal / orthometric / barometric
    z_reference: str  # what the result's z is
    geoid_applied: bool
    geoid_separation_m: float | None  # N = h - H used, when a conversion was done
    vertical_flag: str | None  # set when the height could not be handled as asked
    vertical_uncertainty_m: float
    grid_convergence_deg: float  # grid azimuth of true north (added to the DJI yaw)
    gimbal_ypr_deg: tuple[float, float, float]
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))  # subtracted from the CRS coordinates
    notes: list[str] = field(default_factory=list)
    meta: DjiMetadata | None = None  # what the prior was made from (``prior_uncertainty`` reads its RTK tags)

    def as_dict(self) -> dict:
        return {
            "position_crs": self.position_crs.tolist(),
            "crs": self.crs.to_string(),
            "source_height": self.source_height,
            "z_reference": self.z_reference,
            "geoid_applied": self.geoid_applied,
            "geoid_separation_m": self.geoid_separation_m,
            "vertical_flag": self.vertical_flag,
            "vertical_uncertainty_m": self.vertical_uncertainty_m,
            "grid_convergence_deg": self.grid_convergence_deg,
            "gimbal_yaw_pitch_roll_deg": list(self.gimbal_ypr_deg),
            "offset": self.offset.tolist(),
            "notes": list(self.notes),
        }


# ---------------------------------------------------------------------------------------------- reading
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


def camera_from_exif(meta: DjiMetadata) -> Camera:
    """The photo's pinhole camera from its own metadata (principal point at the centre unless calibrated).

    DJI's calibration when the photo carries one (``calibrated_intrinsics``). Otherwise the 35 mm-equivalent
    focal length: ``f_px = f35 / 43.27 mm x image diagonal in pixels`` (the equivalent focal length is
    defined on the diagonal of a 36 x 24 mm frame). Measured on the real DJI H20T thermal demo image (no
    calibration tags): 1098.6 px against LoD-Loc's calibrated 1125 px (2.4 % short), which lowers the
    camera by as much (``docs/your-data.md``, section 4). Use a calibration when there is one.
    """
    calibrated = calibrated_intrinsics(meta)
    if calibrated is not None:
        return calibrated
    if meta.focal_length_35mm is None or meta.width is None or meta.height is None:
        raise CameraError(
            "the image has no 35 mm-equivalent focal length (EXIF FocalLengthIn35mmFilm) or size"
        )
    f = meta.focal_length_35mm / FULL_FRAME_DIAGONAL_MM * math.hypot(meta.width, meta.height)
    return Camera(f, f, meta.width / 2.0, meta.height / 2.0, meta.width, meta.height)


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


def dewarp_lens(meta: DjiMetadata) -> tuple[Camera, LensDistortion] | None:
    """The camera and lens distortion of DJI's ``DewarpData``, or None: no tag, a photo the camera already
    undistorted (``DewarpFlag`` 1), a tag that does not fit the photo's size, or coefficients that cannot be
    inverted over it.

    The tag is in pixels of the image the camera wrote; its principal point is an offset from that image's
    centre. A resized or cropped copy is recognised as in ``calibrated_intrinsics`` when the photo also
    has the calibration tags; without them, by a focal length more than ``CALIBRATED_CENTRE_TOLERANCE``
    off the 35 mm-equivalent one."""
    if meta.dewarp is None or meta.dewarp_flag == 1 or meta.width is None or meta.height is None:
        return None
    fx, fy, dx, dy, k1, k2, p1, p2, k3 = meta.dewarp
    if fx <= 0 or fy <= 0:
        return None
    if meta.calibrated_focal_px is not None and calibrated_intrinsics(meta) is None:
        return None  # the calibration tags say the photo is not the image the camera wrote
    if meta.focal_length_35mm is not None:
        approximate = meta.focal_length_35mm / FULL_FRAME_DIAGONAL_MM * math.hypot(meta.width, meta.height)
        if abs(fx / approximate - 1.0) > CALIBRATED_CENTRE_TOLERANCE:
            return None
    camera = Camera(fx, fy, meta.width / 2.0 + dx, meta.height / 2.0 + dy, meta.width, meta.height)
    distortion = LensDistortion(k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)
    try:
        distortion.check(camera)
    except CameraError:
        return None
    return camera, distortion


def calibrated_intrinsics(meta: DjiMetadata) -> Camera | None:
    """The camera of DJI's calibration tags, or None when the photo has none or they do not fit its size.

    The tags are in pixels of the image the camera wrote. A photo resized or cropped since has its optical
    centre far from where the tags put it; then the tags describe another image and are not used (more
    than ``CALIBRATED_CENTRE_TOLERANCE`` of the image size off its centre)."""
    f, cx, cy = meta.calibrated_focal_px, meta.calibrated_cx_px, meta.calibrated_cy_px
    if f is None or cx is None or cy is None or meta.width is None or meta.height is None or f <= 0:
        return None
    w, h = meta.width, meta.height
    if abs(cx - w / 2) > CALIBRATED_CENTRE_TOLERANCE * w or abs(cy - h / 2) > CALIBRATED_CENTRE_TOLERANCE * h:
        return None
    return Camera(f, f, cx, cy, w, h)


# ---------------------------------------------------------------------------------------------- geodesy
def source_height_reference(meta: DjiMetadata) -> tuple[str, str]:
    """(reference, why) of ``meta.absolute_altitude_m`` (module docstring)."""
    kind = (meta.altitude_type or "").lower()
    if "rtk" in kind or (meta.rtk_flag is not None and meta.rtk_flag >= RTK_MIN_FLAG):
        why = f"RTK aircraft (AltitudeType={meta.altitude_type!r}, RtkFlag={meta.rtk_flag}): DJI writes the"
        return HEIGHT_ELLIPSOIDAL, why + " WGS 84 ellipsoidal height"
    return HEIGHT_BAROMETRIC, (
        f"no RTK (AltitudeType={meta.altitude_type!r}, RtkFlag={meta.rtk_flag}): DJI's absolute altitude is "
        "barometric and can be tens of metres off"
    )


def _vertical_datum(crs: pyproj.CRS) -> pyproj.CRS | None:
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if sub.is_vertical:
                return sub
    return None


def _ballpark(group: TransformerGroup) -> bool:
    if not group.transformers:
        return True
    return (not group.best_available) or "ballpark" in group.transformers[0].description.lower()


# pyproj's CRS and transformation objects take 5-500 ms each to make (a geoid's operations the most), and
# a flight's photos all need the same few: made once per process, kept by a hashable name of their CRSs
# (``_crs_key``: a name as given, a CRS object's WKT). pyproj's objects are not changed once made.
_CACHED = 32


def _crs_key(crs: str | pyproj.CRS) -> str:
    """A hashable name of ``crs`` for the caches: a name as given, a CRS object's WKT."""
    return crs.to_wkt() if isinstance(crs, pyproj.CRS) else str(crs)


def _group(source: str | pyproj.CRS, target: str | pyproj.CRS) -> TransformerGroup:
    """pyproj's candidate operations (``always_xy``), made once per pair of CRSs (``_transformer_group``)."""
    return _transformer_group(_crs_key(source), _crs_key(target))


@functools.lru_cache(maxsize=_CACHED)
def _transformer_group(source: str, target: str) -> TransformerGroup:
    """``_group`` of two CRS names; pyproj's warning about missing grids is ours to report (``_ballpark``)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Best transformation is not available")
        return TransformerGroup(source, target, always_xy=True)


@functools.lru_cache(maxsize=_CACHED)
def _from_wgs84(target: str) -> pyproj.Transformer:
    """WGS 84 latitude / longitude -> ``target`` (a CRS name, ``always_xy``), made once per CRS."""
    return pyproj.Transformer.from_crs("EPSG:4326", target, always_xy=True)


def target_crs_of(name: str | pyproj.CRS) -> pyproj.CRS:
    """A CRS from a name: ``parse_crs_name`` forms, and ``EPSG:h+v`` compounds kept whole."""
    if isinstance(name, pyproj.CRS):
        return name
    return _crs_of_name(str(name))


@functools.lru_cache(maxsize=_CACHED)
def _crs_of_name(name: str) -> pyproj.CRS:
    """``target_crs_of`` a name, made once per name (an error is raised again each time)."""
    if _EPSG_PLUS.match(name):
        try:
            return pyproj.CRS.from_user_input(name.strip())
        except pyproj.exceptions.CRSError as exc:
            raise CRSError(f"unknown EPSG code in CRS {name!r}: {exc}") from exc
    return parse_crs_name(name)


def check_geoid_separation(value: float | None) -> None:
    """A stated geoid undulation N (None: none stated) is a number of metres the geoid can lie from the
    ellipsoid; ``ParameterError`` naming it otherwise (NaN too)."""
    if value is not None and not (
        isinstance(value, (int, float)) and abs(value) <= GEOID_UNDULATION_BOUND_M
    ):  # NaN fails the comparison too
        raise ParameterError(
            f"geoid separation N must be a number of metres within +-{GEOID_UNDULATION_BOUND_M:g} (the geoid "
            f"lies -107..+86 m from the ellipsoid anywhere), got {value!r}"
        )


def _geoid_separation(
    lon: float, lat: float, h: float, target_3d: pyproj.CRS | str
) -> tuple[float | None, str]:
    """N = h - H from pyproj (None when it would only use a ballpark, i.e. no geoid grid) and a note."""
    group = _group(WGS84_3D, target_3d)
    if _ballpark(group):
        missing = sorted(
            {g.short_name for op in group.unavailable_operations for g in getattr(op, "grids", []) or []}
        )
        grids = ", ".join(missing) or EGM96_GRID
        return None, (
            f"pyproj has no geoid grid for this conversion (missing: {grids}; install with "
            f"'projsync --file <grid>' or set PROJ_NETWORK=ON)"
        )
    H = group.transformers[0].transform(lon, lat, h)[2]
    if not math.isfinite(H):
        return None, "pyproj's geoid grid does not cover this position"
    return h - H, group.transformers[0].description


def grid_convergence_deg(crs: pyproj.CRS, lon: float, lat: float) -> float:
    """Grid azimuth (clockwise from grid north, degrees) of true north at (lon, lat) in ``crs``."""
    t = _from_wgs84(_crs_key(_horizontal(crs)))
    step = 1e-4 if lat < 89.9 else -1e-4
    e0, n0 = t.transform(lon, lat)
    e1, n1 = t.transform(lon, lat + step)
    if not all(math.isfinite(v) for v in (e0, n0, e1, n1)):
        raise CRSError(f"{crs.name}: the position (lat {lat}, lon {lon}) is outside its area of use")
    angle = math.degrees(math.atan2(e1 - e0, n1 - n0))
    return angle if step > 0 else angle - math.copysign(180.0, angle)


def _check_area(crs: pyproj.CRS, lon: float, lat: float) -> None:
    """``CRSError`` when the image lies more than ``AREA_MARGIN_DEG`` outside the CRS's area of use: the
    projection would still give numbers, metres to kilometres distorted, for a CRS that was never meant."""
    area = crs.area_of_use
    if area is None:
        return
    west, south, east, north = area.bounds
    lon_in = west - AREA_MARGIN_DEG <= lon <= east + AREA_MARGIN_DEG if west <= east else True
    if not (lon_in and south - AREA_MARGIN_DEG <= lat <= north + AREA_MARGIN_DEG):
        raise CRSError(
            f"the image (lat {lat:.6f}, lon {lon:.6f}) is outside the area of use of {crs.name} "
            f"({area.name}): wrong target CRS?"
        )


def horizontal_crs(crs: str | pyproj.CRS) -> pyproj.CRS:
    """The horizontal part of a CRS (a compound's non-vertical part; the CRS itself otherwise)."""
    return _horizontal(target_crs_of(crs))


def _horizontal(crs: pyproj.CRS) -> pyproj.CRS:
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if not sub.is_vertical:
                return sub
    return crs


def dji_prior(
    meta: DjiMetadata | str | os.PathLike,
    target_crs: str | pyproj.CRS,
    offset: np.ndarray | None = None,
    source_height: str = HEIGHT_AUTO,
    target_height: str = HEIGHT_AUTO,
    geoid_separation_m: float | None = None,
) -> DjiPrior:
    """The camera's prior pose in ``target_crs`` (minus ``offset``) from DJI metadata.

    Args:
        meta: ``read_dji_metadata`` output or the image path.
        target_crs: the city model's metric CRS (``CityModel.crs``), e.g. ``"EPSG:25832+7837"``.
        offset: (3,) subtracted from the CRS coordinates (a data set frame = CRS minus offset).
        source_height: reference of DJI's height, ``"auto"`` from RTK status (module docstring).
        target_height: ``"auto"`` (orthometric when the CRS has a vertical datum, else as the source),
            ``"ellipsoidal"`` or ``"orthometric"`` (EGM96 unless the CRS names a vertical datum).
        geoid_separation_m: a known geoid undulation N at the site (H = h - N); overrides pyproj.
    """
    if not isinstance(meta, DjiMetadata):
        meta = read_dji_metadata(meta)
    meta.require("latitude", "longitude", "absolute_altitude_m", "gimbal_yaw_deg", "gimbal_pitch_deg")
    if source_height not in SOURCE_HEIGHTS:
        raise unknown_choice("source_height", source_height, SOURCE_HEIGHTS, InputFileError)
    if target_height not in TARGET_HEIGHTS:
        raise unknown_choice("target_height", target_height, TARGET_HEIGHTS, InputFileError)
    check_geoid_separation(geoid_separation_m)
    crs = target_crs_of(target_crs)
    if _horizontal(crs).is_geographic:
        raise CRSError(f"the target CRS must be metric (projected), got {crs.name}")
    lat, lon, h = float(meta.latitude), float(meta.longitude), float(meta.absolute_altitude_m)
    notes: list[str] = []

    if source_height == HEIGHT_AUTO:
        source_height, why = source_height_reference(meta)
        notes.append(why)
    vertical = _vertical_datum(crs)
    if target_height == HEIGHT_AUTO:
        wanted = HEIGHT_ORTHOMETRIC if vertical is not None else None
        if wanted is None and source_height == HEIGHT_ELLIPSOIDAL:
            notes.append(HEIGHT_AS_IS_NOTE)
    else:
        wanted = target_height

    uncertainty = {
        HEIGHT_ELLIPSOIDAL: meta.rtk_std_height_m or RTK_DEFAULT_UNCERTAINTY_M,
        HEIGHT_ORTHOMETRIC: GPS_DEFAULT_UNCERTAINTY_M,
        HEIGHT_BAROMETRIC: BAROMETRIC_UNCERTAINTY_M,
    }[source_height]
    flag = None
    if source_height == HEIGHT_BAROMETRIC:
        flag = (
            "DJI absolute altitude is barometric (no RTK): z may be tens of metres off; "
            "prefer RelativeAltitude + the take-off point's height when known"
        )
    z, z_reference, applied, n_used = h, source_height, False, None
    target_vertical = vertical if vertical is not None else target_crs_of(EGM96)
    if wanted == HEIGHT_ORTHOMETRIC and source_height in (HEIGHT_ELLIPSOIDAL, HEIGHT_BAROMETRIC):
        vname = target_vertical.name if vertical is not None else "EGM96 height"
        if geoid_separation_m is not None:
            n_used, applied = float(geoid_separation_m), True
            z, z_reference = h - n_used, f"orthometric ({vname}, N = {n_used:g} m given)"
        elif source_height == HEIGHT_ELLIPSOIDAL:
            target_3d = crs if vertical is not None else EGM96
            n_value, how = _geoid_separation(lon, lat, h, target_3d)
            if n_value is not None:
                n_used, applied = n_value, True
                z, z_reference = h - n_value, f"orthometric ({vname}, via {how})"
            else:
                z_reference = "ellipsoidal (geoid NOT applied)"
                flag = (
                    f"geoid not applied: {how}; z is the WGS 84 ellipsoidal height, not {vname}. They differ "
                    f"by the local geoid undulation (up to {GEOID_UNDULATION_BOUND_M:g} m); or pass "
                    "geoid_separation_m (N at the site)"
                )
                uncertainty = max(uncertainty, GEOID_UNDULATION_BOUND_M)
        else:
            notes.append("barometric height taken as orthometric (DJI's 'MSL' estimate), no geoid applied")
            z_reference = "barometric, taken as orthometric"
    elif wanted == HEIGHT_ELLIPSOIDAL and source_height == HEIGHT_ORTHOMETRIC:
        if geoid_separation_m is None:
            n_value, how = _geoid_separation(lon, lat, h, EGM96)
            if n_value is None:
                z_reference = "orthometric (geoid NOT applied)"
                flag = f"geoid not applied: {how}; z is the EGM96 height, not ellipsoidal"
                uncertainty = max(uncertainty, GEOID_UNDULATION_BOUND_M)
            else:
                n_used, applied = n_value, True
        else:
            n_used, applied = float(geoid_separation_m), True
        if applied:
            z, z_reference = h + n_used, "ellipsoidal"

    horizontal = _horizontal(crs)
    group = _group("EPSG:4326", horizontal)
    if not group.transformers:
        raise CRSError(f"pyproj finds no transformation from WGS 84 to {horizontal.name}")
    if _ballpark(group):
        notes.append(f"horizontal datum shift WGS 84 -> {horizontal.name} is approximate (pyproj ballpark)")
    _check_area(horizontal, lon, lat)
    x, y = group.transformers[0].transform(lon, lat)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise CRSError(f"{crs.name}: the position (lat {lat}, lon {lon}) is outside its area of use")
    gamma = grid_convergence_deg(crs, lon, lat)
    position = np.array([x, y, z], dtype=np.float64)
    shift = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64)
    if shift.shape != (3,) or not np.all(np.isfinite(shift)):
        raise InputFileError(f"offset must be 3 finite numbers, got {shift.tolist()}")
    world = position - shift
    roll = meta.gimbal_roll_deg if meta.gimbal_roll_deg is not None else 0.0
    if meta.gimbal_roll_deg is None:
        notes.append("no GimbalRollDegree: roll taken as 0")
    try:
        pose = pose_from_dji(world, meta.gimbal_yaw_deg + gamma, meta.gimbal_pitch_deg, roll)
    except PoseError as exc:
        raise InputFileError(f"DJI gimbal angles give no pose: {exc}") from exc
    return DjiPrior(
        pose=pose,
        position_crs=position,
        crs=crs,
        source_height=source_height,
        z_reference=z_reference,
        geoid_applied=applied,
        geoid_separation_m=n_used,
        vertical_flag=flag,
        vertical_uncertainty_m=float(uncertainty),
        grid_convergence_deg=gamma,
        gimbal_ypr_deg=(float(meta.gimbal_yaw_deg), float(meta.gimbal_pitch_deg), float(roll)),
        offset=shift,
        notes=notes,
        meta=meta,
    )


# ---------------------------------------------------------------------------------------------- uncertainty
def prior_uncertainty(
    prior: DjiPrior | DjiMetadata, base: PriorUncertainty | None = None
) -> PriorUncertainty:
    """How far a DJI prior may be off (``geometry.uncertainty.PriorUncertainty``), from the image's tags.

    - RTK fixed (``RtkFlag`` 50, or ``AltitudeType`` RTK with reported standard deviations and no flag):
      ``PriorUncertainty.rtk`` of the reported ``RtkStdLon`` / ``RtkStdLat`` (the larger) and
      ``RtkStdHgt``, floored at ``RTK_FLOOR_M`` (a map is good to about a metre);
    - RTK float (``RtkFlag`` 34..49): the same, floored at ``RTK_FLOAT_FLOOR_M``;
    - anything else (single-point GNSS, barometric height): ``base`` (default: ``PriorUncertainty()``,
      whose numbers are those of a DJI drone on plain GNSS).

    Orientation (yaw, roll / pitch) always comes from ``base``: DJI writes no accuracy for the gimbal. Given
    a ``DjiPrior`` whose height could not be brought into the model's reference (``geoid_applied`` False
    where a geoid was needed: ``vertical_uncertainty_m`` = ``GEOID_UNDULATION_BOUND_M``), the height
    uncertainty grows to a third of that bound (the search covers 3 sigma).
    """
    meta = prior.meta if isinstance(prior, DjiPrior) else prior
    if not isinstance(meta, DjiMetadata):
        raise InputFileError("prior_uncertainty needs DjiMetadata or a DjiPrior made from it")
    base = base or PriorUncertainty()
    flag = meta.rtk_flag
    stds = [v for v in (meta.rtk_std_lon_m, meta.rtk_std_lat_m) if v is not None]
    std_xy = max(stds) if stds else None
    rtk_type = "rtk" in (meta.altitude_type or "").lower()
    if (flag is not None and flag >= RTK_FIXED_FLAG) or (
        flag is None and rtk_type and (std_xy is not None or meta.rtk_std_height_m is not None)
    ):
        out = PriorUncertainty.rtk(std_xy, meta.rtk_std_height_m, base)
    elif flag is not None and flag >= RTK_MIN_FLAG:
        rtk = PriorUncertainty.rtk(std_xy, meta.rtk_std_height_m, base)
        out = replace(
            rtk,
            xy_m=max(rtk.xy_m, RTK_FLOAT_FLOOR_M),
            z_m=max(rtk.z_m, RTK_FLOAT_FLOOR_M),
            source="RTK float (image metadata)",
        )
    else:
        out = replace(base, source=f"no RTK fix (RtkFlag={flag}): {base.source}")
    if isinstance(prior, DjiPrior) and prior.vertical_uncertainty_m >= GEOID_UNDULATION_BOUND_M:
        out = replace(
            out,
            z_m=max(out.z_m, GEOID_UNDULATION_BOUND_M / 3.0),
            source=f"{out.source}; height reference not converted ({prior.z_reference})",
        )
    return out


# ---------------------------------------------------------------------------------------------- geotags
@dataclass(frozen=True)
class DjiGeotag:
    """A camera as drone photos describe it: WGS 84 position and DJI gimbal angles (``dji_geotag``).

    ``height_m`` is in ``height_reference`` (the WGS 84 ellipsoid when the model's heights could be
    converted, else the model's own z, said so); angles in DJI's convention (NED, yaw clockwise from
    TRUE north, pitch -90 = nadir, roll about the optical axis; ``geometry.conventions.pose_from_dji``).
    """

    latitude: float
    longitude: float
    height_m: float
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    height_reference: str
    vertical_flag: str | None = None  # set when a height conversion the model's CRS asks for was not done

    def metadata(self) -> DjiMetadata:
        """The geotag as ``DjiMetadata`` (what ``dji_prior`` reads): a prior from a geotag file."""
        return DjiMetadata(
            latitude=self.latitude,
            longitude=self.longitude,
            absolute_altitude_m=self.height_m,
            gimbal_yaw_deg=self.yaw_deg,
            gimbal_pitch_deg=self.pitch_deg,
            gimbal_roll_deg=self.roll_deg,
            sources={"latitude": "geotag"},
        )


def dji_geotag(
    pose_world: Pose,
    target_crs: str | pyproj.CRS,
    offset: np.ndarray | None = None,
    target_height: str = HEIGHT_AUTO,
) -> DjiGeotag:
    """The geotag of a camera pose in a model's CRS (minus ``offset``): the inverse of ``dji_prior``.

    Position: the CRS's horizontal part -> WGS 84 latitude / longitude with pyproj (``always_xy``).
    Height, as ``dji_prior`` brought heights in: a CRS with a vertical datum (or ``target_height=
    "orthometric"``: EGM96 for a 2D CRS) -> WGS 84 ellipsoidal height through pyproj (``vertical_flag``
    set and the height left as it is when pyproj has no geoid grid); a 2D CRS with ``target_height``
    ``"auto"`` or ``"ellipsoidal"`` -> the model's z as it is (``dji_prior`` took DJI's height as z, so a
    prior read back gives the photo's own height). Angles: ``dji_gimbal_angles`` minus the grid
    convergence (grid north -> true north). ``dji_prior(geotag.metadata(), crs, offset, "ellipsoidal")``
    gives the pose back.
    """
    if target_height not in TARGET_HEIGHTS:
        raise unknown_choice("target_height", target_height, TARGET_HEIGHTS, InputFileError)
    crs = target_crs_of(target_crs)
    horizontal = _horizontal(crs)
    if horizontal.is_geographic:
        raise CRSError(f"the model's CRS must be metric (projected), got {crs.name}")
    shift = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64)
    if shift.shape != (3,) or not np.all(np.isfinite(shift)):
        raise InputFileError(f"offset must be 3 finite numbers, got {shift.tolist()}")
    x, y, z = (np.asarray(pose_world.center, dtype=np.float64) + shift).tolist()
    group = _group(horizontal, "EPSG:4326")
    if not group.transformers:
        raise CRSError(f"pyproj finds no transformation from {horizontal.name} to WGS 84")
    lon, lat = group.transformers[0].transform(x, y)
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise CRSError(f"{crs.name}: the position ({x}, {y}) is outside its area of use")

    vertical = _vertical_datum(crs)
    flag = None
    if vertical is not None or target_height == HEIGHT_ORTHOMETRIC:
        source_3d = crs if vertical is not None else EGM96
        vname = vertical.name if vertical is not None else "EGM96 height"
        heights = _group(source_3d, WGS84_3D)
        if _ballpark(heights):
            h, reference = z, f"orthometric ({vname}; geoid NOT applied: not ellipsoidal)"
            flag = (
                f"geoid not applied: pyproj has no geoid grid for {vname} -> WGS 84 (install one with "
                "'projsync --file <grid>' or set PROJ_NETWORK=ON); heights are the model's, not ellipsoidal"
            )
        else:
            xy_in = (lon, lat) if vertical is None else (x, y)
            h = float(heights.transformers[0].transform(*xy_in, z)[2])
            reference = "ellipsoidal (WGS 84)"
    else:
        h, reference = z, "the model's z as it is (2D CRS: no vertical datum)"
    yaw, pitch, roll = dji_gimbal_angles(pose_world).tolist()
    gamma = grid_convergence_deg(crs, lon, lat)
    return DjiGeotag(
        latitude=float(lat),
        longitude=float(lon),
        height_m=float(h),
        yaw_deg=float(wrap_deg(yaw - gamma)),
        pitch_deg=float(pitch),
        roll_deg=float(roll),
        height_reference=reference,
        vertical_flag=flag,
    )
