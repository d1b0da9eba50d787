"""A prior pose from a DJI image's own metadata (GPS and gimbal angles -> ``Pose``), and the way back.

Why: a drone image is its own prior. DJI writes the aircraft position and the gimbal's absolute angles
into every photo (read by ``datasets.dji_metadata``); this module puts the camera into the city model's
CRS with pyproj (``datasets.geodesy``), so a user can localize a flight without any pose file.
``prior_uncertainty`` says how far such a prior may be off, from the photo's RTK tags; ``dji_geotag``
turns a pose in the model's CRS back into a photo's geotag.

Angles (``geometry.conventions.pose_from_dji``): DJI gimbal angles are NED, yaw clockwise from north,
pitch -90 = nadir. They refer to true north; a projected CRS's grid north differs by the meridian
convergence (``geodesy.grid_convergence_deg``), which is added to the yaw.

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
given as ``geoid_separation_m`` (with ``target_height="auto"`` it says the model's z is orthometric, for a
2D CRS too: ``model_heights_orthometric``). A 2D target CRS with ``target_height="auto"`` and no N keeps
the DJI height as it is (z of the result = DJI's height reference, stated in ``z_reference``):
UAVD4L-LoD's frame is such a case (its z is DJI's RTK height: measured on the real demo image, GT z -
AbsoluteAltitude = 0.68 m).

Frames: ``offset`` is subtracted from the CRS coordinates (in float64) for data sets whose frame is a CRS
minus an offset; bring the result into a ``CityModel``'s local frame with ``model.pose_to_local(pose)``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace

import numpy as np
import pyproj

from semcityloc.citymodel.crs import check_projected, horizontal_crs, vertical_datum
from semcityloc.datasets.dji_metadata import DjiMetadata, read_dji_metadata
from semcityloc.datasets.geodesy import (
    EGM96,
    GEOID_UNDULATION_BOUND_M,
    WGS84_3D,
    check_area_of_use,
    check_geoid_separation,
    geoid_separation,
    grid_convergence_deg,
    is_ballpark,
    target_crs_of,
    transformer_group,
)
from semcityloc.errors import CRSError, InputFileError, PoseError, parameter, unknown_choice
from semcityloc.geometry.conventions import dji_gimbal_angles, pose_from_dji, wrap_deg
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty

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
BAROMETRIC_UNCERTAINTY_M = 50.0  # DJI non-RTK "absolute altitude": barometric, weather dependent
RTK_DEFAULT_UNCERTAINTY_M = 0.1
GPS_DEFAULT_UNCERTAINTY_M = 5.0
# A position of exactly 0, 0: what DJI aircraft write before their GNSS has a fix (no photo of a city model
# is taken at "Null Island"); projected, it would be a prior thousands of kilometres from the model.
NO_GNSS_FIX = "no GNSS fix (latitude 0, longitude 0: taken before the drone had a GPS position)"
# Said of a photo whose tags have its position and gimbal pitch but no heading (``GimbalYawDegree``): its
# prior's yaw is taken as 0 and its search covers every heading (``photos.PhotoPrior.searched``; stop 53).
# Without the pitch too there is no tilt to search from: ``dji_prior`` refuses it. ``NO_HEADING_SEARCHED``
# is what every prior without a heading says after what lacked it (a geotag row's: ``geotags.NO_YAW_NOTE``);
# ``NO_HEADING_TRUTH`` why such tags are no true pose (``benchmark.photo_inputs``).
NO_HEADING_SEARCHED = "the heading is unknown, yaw taken as 0 and every heading searched (slower)"
NO_HEADING_NOTE = f"no GimbalYawDegree: {NO_HEADING_SEARCHED}"
NO_HEADING_TRUTH = "its tags have no heading (GimbalYawDegree)"
# Said (in the prior's notes) when a 2D CRS gets DJI's ellipsoidal height as its z unchanged: right for
# UAVD4L-like frames, ~40 m wrong for a German LoD2 tile whose heights are DHHN2016.
HEIGHT_AS_IS_NOTE = (
    "the model's CRS names no vertical datum: the photos' WGS 84 ellipsoidal heights are used as its z "
    "unchanged; if the model's heights are orthometric (most city models), pass a compound CRS "
    f"({parameter('target_crs', 'EPSG:xxxx+vvvv')}) or {parameter('target_height', 'orthometric')}"
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
    heading_known: bool = True  # False: no GimbalYawDegree (no yaw in a geotag row), yaw taken as 0 (notes)

    @property
    def height_unconverted(self) -> bool:
        """Whether the height could not be brought into the model's reference (a geoid needed and not
        applied: ``vertical_uncertainty_m`` grown to ``GEOID_UNDULATION_BOUND_M``); ``height_widened``."""
        return self.vertical_uncertainty_m >= GEOID_UNDULATION_BOUND_M

    def as_dict(self) -> dict:
        """How the prior was derived (CRS, heights, geoid, convergence, notes), for pose files."""
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
            "heading_known": self.heading_known,
        }


# Said when a geoid separation was given but no height conversion needed it: the heights were of one kind
# on both sides (``target_height="ellipsoidal"`` with ellipsoidal photo heights, orthometric ones for an
# orthometric model); nothing else would show that it did not apply. (With ``"auto"`` a given N is always
# applied: ``model_heights_orthometric``.)
GEOID_UNUSED_NOTE = (
    f"the geoid separation given ({parameter('geoid_separation')}) was not used: the heights needed no "
    "conversion between ellipsoidal and orthometric "
    f"({parameter('target_height', 'ellipsoidal')} with ellipsoidal photo heights, or orthometric photo "
    "heights for an orthometric model)"
)


def model_heights_orthometric(
    crs: pyproj.CRS, target_height: str, geoid_separation_m: float | None = None
) -> bool:
    """Whether the model's z is taken as orthometric (so that a GNSS ellipsoidal height is converted to it,
    ``H = h - N``, and back in ``dji_geotag``): ``target_height="orthometric"``; with ``"auto"`` when its CRS
    has a vertical datum, or when a geoid separation N is given (a stated N says the model's heights are
    the geoid's; before stop 52 it was ignored for a 2D CRS); never with ``"ellipsoidal"``."""
    if target_height == HEIGHT_AUTO:
        return vertical_datum(crs) is not None or geoid_separation_m is not None
    return target_height == HEIGHT_ORTHOMETRIC


def _height_system_name(crs: pyproj.CRS, geoid_separation_m: float | None) -> str:
    """What the model's orthometric heights are called in a height reference: its CRS's vertical datum,
    else "the model's heights" for a stated N (any geoid), else EGM96 (DJI's "MSL")."""
    vertical = vertical_datum(crs)
    if vertical is not None:
        return vertical.name
    return "the model's heights" if geoid_separation_m is not None else "EGM96 height"


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


def dji_prior(
    meta: DjiMetadata | str | os.PathLike,
    target_crs: str | pyproj.CRS,
    offset: np.ndarray | None = None,
    source_height: str = HEIGHT_AUTO,
    target_height: str = HEIGHT_AUTO,
    geoid_separation_m: float | None = None,
    no_heading_note: str = NO_HEADING_NOTE,
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
        no_heading_note: what the notes say when ``meta`` has no gimbal yaw (yaw taken as 0,
            ``heading_known`` False): ``NO_HEADING_NOTE``, or a geotag row's ``geotags.NO_YAW_NOTE``.
    """
    if not isinstance(meta, DjiMetadata):
        meta = read_dji_metadata(meta)
    meta.require("latitude", "longitude", "absolute_altitude_m", "gimbal_pitch_deg")
    if source_height not in SOURCE_HEIGHTS:
        raise unknown_choice("source_height", source_height, SOURCE_HEIGHTS, InputFileError)
    if target_height not in TARGET_HEIGHTS:
        raise unknown_choice("target_height", target_height, TARGET_HEIGHTS, InputFileError)
    check_geoid_separation(geoid_separation_m)
    crs = target_crs_of(target_crs)
    check_projected(crs, "the target CRS", "target_crs")
    lat, lon, h = float(meta.latitude), float(meta.longitude), float(meta.absolute_altitude_m)
    if lat == 0.0 and lon == 0.0:
        raise InputFileError(NO_GNSS_FIX)
    notes: list[str] = []

    if source_height == HEIGHT_AUTO:
        source_height, why = source_height_reference(meta)
        notes.append(why)
    vertical = vertical_datum(crs)
    if model_heights_orthometric(crs, target_height, geoid_separation_m):
        wanted = HEIGHT_ORTHOMETRIC
    elif target_height == HEIGHT_AUTO:
        wanted = None
        if source_height == HEIGHT_ELLIPSOIDAL:
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
    if wanted == HEIGHT_ORTHOMETRIC and source_height in (HEIGHT_ELLIPSOIDAL, HEIGHT_BAROMETRIC):
        vname = _height_system_name(crs, geoid_separation_m)
        if geoid_separation_m is not None:
            n_used, applied = float(geoid_separation_m), True
            z, z_reference = h - n_used, f"orthometric ({vname}, N = {n_used:g} m given)"
        elif source_height == HEIGHT_ELLIPSOIDAL:
            target_3d = crs if vertical is not None else EGM96
            n_value, how = geoid_separation(lon, lat, h, target_3d)
            if n_value is not None:
                n_used, applied = n_value, True
                z, z_reference = h - n_value, f"orthometric ({vname}, via {how})"
            else:
                z_reference = "ellipsoidal (geoid NOT applied)"
                flag = (
                    f"geoid not applied: {how}; z is the WGS 84 ellipsoidal height, not {vname}. They differ "
                    f"by the local geoid undulation (up to {GEOID_UNDULATION_BOUND_M:g} m); or give N at the "
                    f"site: {parameter('geoid_separation', 'N')}"
                )
                uncertainty = max(uncertainty, GEOID_UNDULATION_BOUND_M)
        else:
            notes.append("barometric height taken as orthometric (DJI's 'MSL' estimate), no geoid applied")
            z_reference = "barometric, taken as orthometric"
    elif wanted == HEIGHT_ELLIPSOIDAL and source_height == HEIGHT_ORTHOMETRIC:
        if geoid_separation_m is None:
            n_value, how = geoid_separation(lon, lat, h, EGM96)
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
    if geoid_separation_m is not None and not applied:
        notes.append(GEOID_UNUSED_NOTE)

    horizontal = horizontal_crs(crs)
    group = transformer_group("EPSG:4326", horizontal)
    if not group.transformers:
        raise CRSError(f"pyproj finds no transformation from WGS 84 to {horizontal.name}")
    if is_ballpark(group):
        notes.append(f"horizontal datum shift WGS 84 -> {horizontal.name} is approximate (pyproj ballpark)")
    check_area_of_use(horizontal, lon, lat)
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
    yaw = meta.gimbal_yaw_deg if meta.gimbal_yaw_deg is not None else 0.0
    if meta.gimbal_yaw_deg is None:
        notes.append(no_heading_note)
    try:
        pose = pose_from_dji(world, yaw + gamma, meta.gimbal_pitch_deg, roll)
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
        gimbal_ypr_deg=(float(yaw), float(meta.gimbal_pitch_deg), float(roll)),
        offset=shift,
        notes=notes,
        meta=meta,
        heading_known=meta.gimbal_yaw_deg is not None,
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
    a ``DjiPrior`` whose height could not be brought into the model's reference, ``height_widened``. (One
    without a heading: ``photos.PhotoPrior.searched``.)
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
    return height_widened(out, prior) if isinstance(prior, DjiPrior) else out


def height_widened(uncertainty: PriorUncertainty, prior: DjiPrior) -> PriorUncertainty:
    """``uncertainty`` of a prior made by ``dji_prior`` (from a photo's EXIF, a geotag file's row: any
    source), its height sigma grown to a third of ``GEOID_UNDULATION_BOUND_M`` (the search covers 3 sigma:
    +-110 m) when the height could not be brought into the model's reference
    (``DjiPrior.height_unconverted``: no geoid grid, no N given), and the reason added to its ``source``;
    ``uncertainty`` as it is otherwise. The one rule of "height not converted: search the whole geoid
    range", whatever gave the prior or its other sigmas (RTK tags, a geotag file's accuracy columns, the
    defaults)."""
    if not prior.height_unconverted:
        return uncertainty
    return replace(
        uncertainty,
        z_m=max(uncertainty.z_m, GEOID_UNDULATION_BOUND_M / 3.0),
        source=f"{uncertainty.source}; height reference not converted ({prior.z_reference})",
    )


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
    heading_known: bool = True  # False: a geotag row without a yaw (``yaw_deg`` 0, taken; no heading written)

    def metadata(self) -> DjiMetadata:
        """The geotag as ``DjiMetadata`` (what ``dji_prior`` reads): a prior from a geotag file; without a
        heading no gimbal yaw, as a DJI photo without ``GimbalYawDegree`` (yaw 0, every heading searched)."""
        return DjiMetadata(
            latitude=self.latitude,
            longitude=self.longitude,
            absolute_altitude_m=self.height_m,
            gimbal_yaw_deg=self.yaw_deg if self.heading_known else None,
            gimbal_pitch_deg=self.pitch_deg,
            gimbal_roll_deg=self.roll_deg,
            sources={"latitude": "geotag"},
        )


def dji_geotag(
    pose_world: Pose,
    target_crs: str | pyproj.CRS,
    offset: np.ndarray | None = None,
    target_height: str = HEIGHT_AUTO,
    geoid_separation_m: float | None = None,
) -> DjiGeotag:
    """The geotag of a camera pose in a model's CRS (minus ``offset``): the inverse of ``dji_prior``.

    Position: the CRS's horizontal part -> WGS 84 latitude / longitude with pyproj (``always_xy``).
    Height, as ``dji_prior`` brought heights in: an orthometric model (``model_heights_orthometric``: a CRS
    with a vertical datum, ``target_height="orthometric"``, EGM96 for a 2D CRS, or a given N) -> WGS 84
    ellipsoidal height through pyproj or N (``vertical_flag`` set and the height left as it is when
    pyproj has no geoid grid); a 2D CRS with ``target_height`` ``"auto"`` (no N) or ``"ellipsoidal"`` ->
    the model's z as it is (``dji_prior`` took DJI's height as z, so a
    prior read back gives the photo's own height). Angles: ``dji_gimbal_angles`` minus the grid
    convergence (grid north -> true north). ``dji_prior(geotag.metadata(), crs, offset, "ellipsoidal")``
    gives the pose back. ``geoid_separation_m``: the N the priors were brought in with (h = H + N, the
    inverse of ``dji_prior``'s H = h - N): a run's exports must give an unmoved photo its own EXIF height
    back, with the same options.
    """
    if target_height not in TARGET_HEIGHTS:
        raise unknown_choice("target_height", target_height, TARGET_HEIGHTS, InputFileError)
    check_geoid_separation(geoid_separation_m)
    crs = target_crs_of(target_crs)
    horizontal = check_projected(crs, "the model's CRS", "target_crs")
    shift = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64)
    if shift.shape != (3,) or not np.all(np.isfinite(shift)):
        raise InputFileError(f"offset must be 3 finite numbers, got {shift.tolist()}")
    x, y, z = (np.asarray(pose_world.center, dtype=np.float64) + shift).tolist()
    group = transformer_group(horizontal, "EPSG:4326")
    if not group.transformers:
        raise CRSError(f"pyproj finds no transformation from {horizontal.name} to WGS 84")
    lon, lat = group.transformers[0].transform(x, y)
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise CRSError(f"{crs.name}: the position ({x}, {y}) is outside its area of use")

    vertical = vertical_datum(crs)
    flag = None
    if model_heights_orthometric(crs, target_height, geoid_separation_m):
        source_3d = crs if vertical is not None else EGM96
        vname = _height_system_name(crs, geoid_separation_m)
        heights = transformer_group(source_3d, WGS84_3D)
        if geoid_separation_m is not None:
            h = z + float(geoid_separation_m)
            reference = f"ellipsoidal (WGS 84; {vname} + N = {float(geoid_separation_m):g} m given)"
        elif is_ballpark(heights):
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
