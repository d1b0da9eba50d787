"""DJI metadata -> prior pose: XMP / EXIF reading, grid convergence, heights handled or flagged."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest

from dji_photo import RTK_FIELDS, dji_jpeg, xmp_packet
from semcityloc.citymodel.crs import MetricFrame, parse_crs_name
from semcityloc.citymodel.model import crs_label
from semcityloc.datasets import dji, geodesy
from semcityloc.datasets.dji import (
    BAROMETRIC_UNCERTAINTY_M,
    HEIGHT_AS_IS_NOTE,
    HEIGHT_BAROMETRIC,
    HEIGHT_ELLIPSOIDAL,
    NO_HEADING_NOTE,
    RTK_FLOAT_FLOOR_M,
    dji_geotag,
    dji_prior,
    prior_uncertainty,
)
from semcityloc.datasets.dji_camera import calibrated_intrinsics, camera_from_exif, dewarp_lens
from semcityloc.datasets.dji_metadata import parse_xmp_fields, read_dji_metadata
from semcityloc.datasets.geodesy import GEOID_UNDULATION_BOUND_M, grid_convergence_deg
from semcityloc.datasets.lodloc import read_lodloc
from semcityloc.datasets.photos import PhotoPrior
from semcityloc.errors import CRSError, InputFileError, ParameterError, as_flags
from semcityloc.geometry.distortion import LensDistortion
from semcityloc.geometry.errors import rotation_error_deg
from semcityloc.geometry.uncertainty import NO_HEADING_YAW_DEG, RTK_FLOOR_M, PriorUncertainty

REAL_IMAGE = "real_uav_lodloc/Query_image/DJI_20230513163714_0033_T.JPG"


RTK = RTK_FIELDS


def test_xmp_fields_in_attribute_and_element_form():
    attr = parse_xmp_fields(xmp_packet(GimbalYawDegree="-102.30", AltitudeType="RtkAlt"))
    assert attr["drone-dji:GimbalYawDegree"] == "-102.30" and attr["drone-dji:AltitudeType"] == "RtkAlt"
    assert not any(k.startswith("xmlns:") for k in attr)
    elem = parse_xmp_fields(
        b"<x:xmpmeta><drone-dji:GimbalPitchDegree>-90.0</drone-dji:GimbalPitchDegree></x:xmpmeta>"
    )
    assert elem == {"drone-dji:GimbalPitchDegree": "-90.0"}


def test_rtk_image_gives_a_pose_in_utm_looking_at_true_north(tmp_path):
    """Gimbal yaw 0 = true north. East of the UTM central meridian grid north differs by ~1.9 deg here; the
    optical axis must point at a point 1 km due north (geodesic), not along the grid's +y."""
    image = dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK))
    meta = read_dji_metadata(image)
    assert (meta.latitude, meta.longitude, meta.absolute_altitude_m) == (48.1, 11.5, 612.5)
    assert meta.sources["latitude"] == "xmp:drone-dji:GpsLatitude" and (meta.width, meta.height) == (64, 48)
    prior = dji_prior(meta, "EPSG:25832")
    assert prior.source_height == HEIGHT_ELLIPSOIDAL and prior.z_reference == HEIGHT_ELLIPSOIDAL
    assert prior.vertical_flag is None and prior.vertical_uncertainty_m == pytest.approx(0.021)
    t = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:25832", always_xy=True)
    np.testing.assert_allclose(prior.position_crs, [*t.transform(11.5, 48.1), 612.5], atol=1e-6)
    lon2, lat2, _ = pyproj.Geod(ellps="WGS84").fwd(11.5, 48.1, 0.0, 1000.0)
    target = np.array(t.transform(lon2, lat2)) - prior.position_crs[:2]
    axis = prior.pose.viewing_direction
    angle = math.degrees(math.atan2(axis[0], axis[1]) - math.atan2(target[0], target[1]))
    assert abs(angle) < 0.01 and abs(axis[2]) < 1e-9  # horizontal, at true north
    gamma = prior.grid_convergence_deg
    expected = -math.degrees(math.atan(math.tan(math.radians(11.5 - 9.0)) * math.sin(math.radians(48.1))))
    assert gamma == pytest.approx(expected, abs=0.01)  # true north lies west of grid north, east of the CM


def test_offset_and_nadir_gimbal(tmp_path):
    fields = dict(RTK, GimbalPitchDegree="-90.0", GimbalYawDegree="+45.0")
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**fields)))
    off = np.array([690000.0, 5330000.0, 100.0])
    prior = dji_prior(meta, "EPSG:25832", offset=off)
    np.testing.assert_allclose(prior.pose.center, prior.position_crs - off, atol=1e-6)
    np.testing.assert_allclose(prior.pose.viewing_direction, [0, 0, -1], atol=1e-12)


def test_exif_gps_fills_in_when_xmp_has_no_position(tmp_path):
    xmp = xmp_packet(GimbalYawDegree="10", GimbalPitchDegree="-60", GimbalRollDegree="0")
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp, gps=(-33.5, 151.25, 120.0)))
    assert meta.latitude == pytest.approx(-33.5) and meta.longitude == pytest.approx(151.25)
    assert meta.sources["latitude"] == "exif:GPSLatitude" and meta.absolute_altitude_m == pytest.approx(120.0)
    prior = dji_prior(meta, "EPSG:32756")
    assert prior.source_height == HEIGHT_BAROMETRIC  # no RTK: barometric, flagged
    assert "barometric" in prior.vertical_flag and prior.vertical_uncertainty_m == BAROMETRIC_UNCERTAINTY_M


def test_orthometric_target_applies_the_geoid_or_says_it_did_not(tmp_path):
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK)))
    prior = dji_prior(meta, "EPSG:25832", target_height="orthometric")
    if prior.geoid_applied:  # a machine with the EGM96 grid installed
        assert 40.0 < prior.geoid_separation_m < 55.0  # EGM96 near Munich: ~47 m
        assert prior.position_crs[2] == pytest.approx(612.5 - prior.geoid_separation_m)
        assert prior.vertical_flag is None
    else:
        assert prior.position_crs[2] == 612.5 and "NOT applied" in prior.z_reference
        assert "geoid not applied" in prior.vertical_flag and "us_nga_egm96_15.tif" in prior.vertical_flag
        assert prior.vertical_uncertainty_m == GEOID_UNDULATION_BOUND_M
    compound = dji_prior(meta, "EPSG:25832+7837")  # DHHN2016 heights: orthometric by the CRS itself
    assert compound.geoid_applied or "DHHN2016" in compound.vertical_flag
    given = dji_prior(meta, "EPSG:25832+7837", geoid_separation_m=47.3)
    assert given.geoid_applied and given.position_crs[2] == pytest.approx(612.5 - 47.3)
    assert given.vertical_flag is None and "47.3" in given.z_reference
    for bad in (math.nan, 1e9, -200.0, "47"):  # stop 45's audit: NaN was taken and broke the pose later
        with pytest.raises(ParameterError, match="geoid separation N must be"):
            dji_prior(meta, "EPSG:25832+7837", geoid_separation_m=bad)


def test_the_geoid_not_applied_flag_names_the_python_keyword_the_cli_its_flag(tmp_path, monkeypatch):
    """The flag told CLI users to "pass geoid_separation_m", a keyword they cannot type: it names the
    keyword for the Python API, which the command line prints as ``--geoid-separation`` (``run``,
    ``dataset dji-prior``: ``errors.as_flags``)."""
    monkeypatch.setattr(dji, "geoid_separation", lambda *args: (None, "no geoid grid here"))
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK)))
    flag = dji_prior(meta, "EPSG:25832", target_height="orthometric").vertical_flag
    assert "geoid not applied: no geoid grid here" in flag
    assert "geoid_separation_m=N" in flag and "--" not in flag
    assert "--geoid-separation N" in as_flags(flag)


@pytest.mark.parametrize("crs", ["EPSG:25832+7837", "CRS object"])
def test_a_second_photo_reuses_the_crs_transformations_and_gets_the_same_prior(tmp_path, crs):
    """pyproj's CRS and transformation objects (tens of ms a photo, a geoid's operations hundreds) are made
    once per process and taken from the cache for the next photo: the same prior and geotag, bit for bit.
    ``CityModel.crs`` is a CRS object (kept by its WKT), a ``--crs`` a name."""
    if crs == "CRS object":
        crs = pyproj.CRS.from_user_input("EPSG:25832+7837")
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK)))
    caches = (geodesy._transformer_group, geodesy._from_wgs84)
    for cache in caches:
        cache.cache_clear()
    first = dji_prior(meta, crs)
    made = [cache.cache_info() for cache in caches]
    second = dji_prior(meta, crs)
    reused = [cache.cache_info() for cache in caches]
    assert [i.misses for i in reused] == [i.misses for i in made]  # nothing made again
    assert reused[0].hits == made[0].hits + 2 and reused[1].hits == made[1].hits + 1  # geoid, position; north
    for a, b in ((first.pose.R, second.pose.R), (first.pose.t, second.pose.t)):
        assert np.array_equal(a, b)
    assert np.array_equal(first.position_crs, second.position_crs)
    assert (first.grid_convergence_deg, first.z_reference, first.notes, first.vertical_flag) == (
        second.grid_convergence_deg,
        second.z_reference,
        second.notes,
        second.vertical_flag,
    )
    assert dji_geotag(first.pose, crs) == dji_geotag(second.pose, crs)


def test_bad_targets_and_images_are_typed_errors(tmp_path):
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK)))
    with pytest.raises(CRSError, match="outside the area of use"):
        dji_prior(meta, "EPSG:28992")  # Dutch RD New for a Bavarian flight
    with pytest.raises(CRSError, match="metric"):
        dji_prior(meta, "EPSG:4326")
    # an Earth-centred CRS is not geographic either: its prior was made, geocentric x, y with the height as z
    with pytest.raises(CRSError, match=r"must be metric \(projected\), got WGS 84 \(geocentric\)"):
        dji_prior(meta, "EPSG:4978")
    with pytest.raises(InputFileError, match="target_height"):
        dji_prior(meta, "EPSG:25832", target_height="geoid")
    no_gimbal = read_dji_metadata(
        dji_jpeg(tmp_path / "b.jpg", xmp_packet(GpsLatitude="48", GpsLongitude="11"))
    )
    with pytest.raises(InputFileError, match="absolute_altitude_m, gimbal_pitch_deg"):
        dji_prior(no_gimbal, "EPSG:25832")
    (tmp_path / "c.jpg").write_bytes(b"not an image")
    with pytest.raises(InputFileError, match="not a readable image"):
        read_dji_metadata(tmp_path / "c.jpg")
    with pytest.raises(InputFileError, match="no such image"):
        read_dji_metadata(tmp_path / "absent.jpg")
    with pytest.raises(InputFileError, match="GimbalYawDegree is not a number"):
        read_dji_metadata(dji_jpeg(tmp_path / "d.jpg", xmp_packet(GimbalYawDegree="north")))


def test_a_photo_without_a_heading_gets_a_prior_that_searches_every_heading_one_without_a_pitch_none(
    tmp_path,
):
    """No GimbalYawDegree (position and pitch known): a prior with yaw 0 that says so, searched over every
    heading whatever yaw sigma is stated (a larger one kept); without the pitch too: refused as before."""
    fields = dict(GpsLatitude="+48.1", GpsLongitude="+11.5", AbsoluteAltitude="+600", GimbalPitchDegree="-45")
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**fields)))
    prior = dji_prior(meta, "EPSG:25832")
    assert not prior.heading_known and prior.gimbal_ypr_deg[:2] == (0.0, -45.0)
    assert NO_HEADING_NOTE in prior.notes and prior.as_dict()["heading_known"] is False
    photo = PhotoPrior(prior.pose, prior_uncertainty(prior), "exif", heading_known=prior.heading_known)
    assert photo.searched().yaw_deg == NO_HEADING_YAW_DEG and photo.warnings() == [NO_HEADING_NOTE]
    assert "no heading" in photo.searched().source
    assert photo.searched(PriorUncertainty(yaw_deg=3.0)).yaw_deg == NO_HEADING_YAW_DEG
    assert photo.searched(PriorUncertainty(yaw_deg=90.0)).yaw_deg == 90.0
    assert dji_prior(
        read_dji_metadata(dji_jpeg(tmp_path / "b.jpg", xmp_packet(**fields, GimbalYawDegree="10"))),
        "EPSG:25832",
    ).heading_known
    del fields["GimbalPitchDegree"]
    no_tilt = read_dji_metadata(dji_jpeg(tmp_path / "c.jpg", xmp_packet(**fields)))
    with pytest.raises(InputFileError, match="no gimbal_pitch_deg"):
        dji_prior(no_tilt, "EPSG:25832")


def test_grid_convergence_is_zero_on_the_central_meridian():
    crs = pyproj.CRS("EPSG:32632")
    assert abs(grid_convergence_deg(crs, 9.0, 50.0)) < 1e-6
    assert grid_convergence_deg(crs, 7.0, 50.0) > 0 > grid_convergence_deg(crs, 11.0, 50.0)


def test_dji_calibration_tags_give_the_camera_when_they_fit_the_photo(tmp_path):
    calibrated = xmp_packet(
        CalibratedFocalLength="3666.666504", CalibratedOpticalCenterX="33.5", CalibratedOpticalCenterY="23.25"
    )
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", calibrated, size=(64, 48), focal_35mm=24))
    cam = camera_from_exif(meta)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (
        3666.666504,
        3666.666504,
        33.5,
        23.25,
        64,
        48,
    )
    # The same tags on a photo resized to half: they describe another image, the 35 mm focal length is used.
    meta = read_dji_metadata(dji_jpeg(tmp_path / "b.jpg", calibrated, size=(32, 24), focal_35mm=24))
    assert calibrated_intrinsics(meta) is None
    cam = camera_from_exif(meta)
    assert cam.fx == pytest.approx(24 / math.hypot(36, 24) * math.hypot(32, 24)) and cam.cx == 16.0
    # No calibration tags: the 35 mm-equivalent focal length, as before.
    meta = read_dji_metadata(dji_jpeg(tmp_path / "c.jpg", xmp_packet(GimbalYawDegree="1"), focal_35mm=24))
    assert calibrated_intrinsics(meta) is None and camera_from_exif(meta).cx == 32.0
    with pytest.raises(InputFileError, match="CalibratedFocalLength"):
        read_dji_metadata(dji_jpeg(tmp_path / "d.jpg", xmp_packet(CalibratedFocalLength="nan")))


DEWARP = "2022-06-08;190.5,190.2,1.5,-2.0,-0.27,0.11,0.0008,-0.0003,-0.03"


def test_dewarp_data_gives_the_camera_and_its_lens_distortion(tmp_path):
    """DewarpData "date;fx,fy,cx,cy,k1,k2,p1,p2,k3": cx, cy are offsets from the image centre."""
    f35 = 33  # 33 / 43.27 x 250 px (the diagonal of 200 x 150) = 190.7 px: the same photo
    meta = read_dji_metadata(
        dji_jpeg(
            tmp_path / "a.jpg", xmp_packet(DewarpData=DEWARP, DewarpFlag="0"), size=(200, 150), focal_35mm=f35
        )
    )
    camera, lens = dewarp_lens(meta)
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.size) == (
        190.5,
        190.2,
        101.5,
        73.0,
        (200, 150),
    )
    assert lens == LensDistortion(k1=-0.27, k2=0.11, p1=0.0008, p2=-0.0003, k3=-0.03)
    # The camera undistorted the photo itself: nothing to apply.
    flagged = xmp_packet(DewarpData=DEWARP, DewarpFlag="1")
    assert (
        dewarp_lens(read_dji_metadata(dji_jpeg(tmp_path / "b.jpg", flagged, size=(200, 150), focal_35mm=f35)))
        is None
    )
    # A copy resized to half: the tag describes another image (its focal length twice the photo's).
    half = read_dji_metadata(
        dji_jpeg(tmp_path / "c.jpg", xmp_packet(DewarpData=DEWARP), size=(100, 75), focal_35mm=f35)
    )
    assert dewarp_lens(half) is None
    with pytest.raises(InputFileError, match="DewarpData: expected 'date;fx,fy,cx,cy,k1,k2,p1,p2,k3'"):
        read_dji_metadata(dji_jpeg(tmp_path / "d.jpg", xmp_packet(DewarpData="2022-06-08;190.5,190.2,1.5")))
    with pytest.raises(InputFileError, match="DewarpData is not finite"):
        read_dji_metadata(dji_jpeg(tmp_path / "e.jpg", xmp_packet(DewarpData=DEWARP.replace("0.11", "inf"))))


# ------------------------------------------------------------------------------------------ real image
def test_real_dji_image_metadata(shared):
    meta = read_dji_metadata(shared(REAL_IMAGE))
    assert (meta.make, meta.model, meta.image_source) == ("DJI", "ZH20T", "InfraredCamera")
    assert (meta.latitude, meta.longitude) == (28.2949691, 112.990583)
    assert meta.absolute_altitude_m == 223.893 and meta.relative_altitude_m == 200.038
    assert (meta.gimbal_yaw_deg, meta.gimbal_pitch_deg, meta.gimbal_roll_deg) == (-102.3, -90.0, 0.0)
    assert meta.altitude_type == "RtkAlt" and meta.rtk_flag == 50
    cam = camera_from_exif(meta)  # 58 mm equivalent on a 640x512 frame
    assert (cam.width, cam.height) == (640, 512) and abs(cam.fx / 1125.0 - 1) < 0.03


def test_real_dji_prior_matches_the_ground_truth_rotation_and_height(shared):
    """In UAVD4L's frame (CGCS2000 / 3-degree GK CM 114E minus a hidden x, y offset, z = DJI's RTK height)
    the image's own gimbal angles are 1.1 deg from GT (LoD-Loc's GPS prior: 4.0 deg) and its RTK height is
    0.7 m from GT z. The x, y offset of the frame is not published, so x, y are not compared."""
    ds = read_lodloc(shared("real_uav_lodloc"), frame="z-up")
    gt, lodloc_prior = ds.queries[0].gt_pose_world, ds.queries[0].prior_pose_world
    prior = dji_prior(shared(REAL_IMAGE), "EPSG:4547")
    assert prior.source_height == HEIGHT_ELLIPSOIDAL and prior.vertical_flag is None
    rot = float(rotation_error_deg(prior.pose, gt))
    assert rot < 1.5 and rot < float(rotation_error_deg(lodloc_prior, gt))
    assert abs(prior.position_crs[2] - gt.center[2]) < 1.0
    assert prior.grid_convergence_deg == pytest.approx(0.4785, abs=1e-3)  # west of CM 114E: true north east


def test_dji_prior_cli_writes_a_pose_json_with_the_height_treatment(tmp_path, capsys):
    import argparse
    import json

    from semcityloc.cli import dataset as cli
    from semcityloc.geometry.io import read_pose

    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers(dest="command"))
    image = dji_jpeg(tmp_path / "a.jpg", xmp_packet(**dict(RTK, GimbalPitchDegree="-90")))
    argv = ["dataset", "dji-prior", str(image), "--crs", "EPSG:25832", "--offset", "690000,5330000,0"]
    argv += ["--target-height", "orthometric", "--out", str(tmp_path / "p.json")]
    args = parser.parse_args(argv)
    assert args.func(args) == 0
    data = json.loads((tmp_path / "p.json").read_text())
    assert data["extra"]["offset"] == [690000.0, 5330000.0, 0.0]
    # Shifted coordinates are no EPSG:25832 ones: no CRS label on them (a reader took them for such)
    assert "crs" not in data and data["extra"]["crs"] == "EPSG:25832"
    # ... and since stop 52 its frame says what they are (it said "world")
    assert data["frame"] == "crs_offset" and data["offset_crs"] == "EPSG:25832"
    assert data["crs_offset"] == [690000.0, 5330000.0, 0.0]
    assert data["extra"]["source_height"] == "ellipsoidal"
    assert data["extra"]["geoid_applied"] or "geoid not applied" in capsys.readouterr().err
    pose = read_pose(tmp_path / "p.json")
    np.testing.assert_allclose(
        pose.center[:2], np.array(data["extra"]["position_crs"][:2]) - [690000, 5330000]
    )
    with pytest.raises(InputFileError, match="--offset must be 3"):
        args = parser.parse_args(
            ["dataset", "dji-prior", str(image), "--crs", "EPSG:25832", "--offset", "1,2"]
        )
        args.func(args)


# ------------------------------------------------------------------------------------ uncertainty, geotags
def test_prior_uncertainty_follows_the_rtk_tags(tmp_path):
    fixed = read_dji_metadata(
        dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK, RtkStdLon="0.9", RtkStdLat="0.012"))
    )
    assert (fixed.rtk_std_lon_m, fixed.rtk_std_lat_m) == (0.9, 0.012)
    sigma = prior_uncertainty(fixed)
    assert sigma.xy_m == 0.9 and sigma.z_m == RTK_FLOOR_M  # the larger std; height 0.021 m floored
    assert "RTK fixed" in sigma.source and sigma.yaw_deg == PriorUncertainty().yaw_deg
    float_fix = read_dji_metadata(dji_jpeg(tmp_path / "b.jpg", xmp_packet(**dict(RTK, RtkFlag="34"))))
    assert prior_uncertainty(float_fix).xy_m == RTK_FLOAT_FLOOR_M == prior_uncertainty(float_fix).z_m
    plain = read_dji_metadata(
        dji_jpeg(
            tmp_path / "c.jpg", xmp_packet(GimbalYawDegree="1", GimbalPitchDegree="-60"), gps=(48, 11, 500)
        )
    )
    base = PriorUncertainty(xy_m=7.0, z_m=20.0)
    got = prior_uncertainty(plain, base)
    assert (got.xy_m, got.z_m) == (7.0, 20.0) and "no RTK" in got.source
    # The same RTK photo into a CRS whose heights need a geoid that pyproj lacks (or not, on a machine
    # with the grid): the height uncertainty then covers the undulation.
    prior = dji_prior(fixed, "EPSG:25832+7837")
    if not prior.geoid_applied:
        assert prior_uncertainty(prior).z_m == pytest.approx(GEOID_UNDULATION_BOUND_M / 3)
    as_is = dji_prior(fixed, "EPSG:25832")  # 2D CRS: the ellipsoidal height becomes z, and it says so
    assert prior_uncertainty(as_is).z_m == RTK_FLOOR_M and HEIGHT_AS_IS_NOTE in as_is.notes
    assert HEIGHT_AS_IS_NOTE not in prior.notes
    with pytest.raises(InputFileError, match="DjiMetadata"):
        prior_uncertainty("not metadata")


@pytest.mark.parametrize("crs", ["EPSG:25832", "EPSG:32632", "EPSG:25832+7837"])
@pytest.mark.parametrize("gimbal", [(33.0, -50.0, 0.0), (-150.0, -90.0, 0.0), (10.0, -20.0, 2.5)])
def test_geotag_of_a_prior_gives_the_photo_back(tmp_path, crs, gimbal):
    """``dji_geotag`` inverts ``dji_prior``: latitude / longitude to 1e-9 deg, height to 1 mm, and the
    rotation (gimbal angles are gimbal-locked at nadir, so the rotation is compared, not the angles)."""
    yaw, pitch, roll = gimbal
    fields = dict(RTK, GimbalYawDegree=yaw, GimbalPitchDegree=pitch, GimbalRollDegree=roll)
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**fields)))
    off = np.array([690000.0, 5330000.0, 0.0])
    n = 47.0 if "+" in crs else None  # a geoid separation given: the geotag adds back what the prior took
    prior = dji_prior(meta, crs, offset=off, geoid_separation_m=n)
    tag = dji_geotag(prior.pose, crs, offset=off, geoid_separation_m=n)
    assert tag.latitude == pytest.approx(48.1, abs=1e-9) and tag.longitude == pytest.approx(11.5, abs=1e-9)
    assert tag.height_m == pytest.approx(612.5, abs=1e-3) and tag.vertical_flag is None
    assert ("N = 47 m given" if "+" in crs else "as it is") in tag.height_reference
    back = dji_prior(tag.metadata(), crs, offset=off, source_height="ellipsoidal", geoid_separation_m=n)
    assert float(rotation_error_deg(back.pose, prior.pose)) < 1e-7
    np.testing.assert_allclose(back.pose.center, prior.pose.center, atol=1e-3)
    if pitch > -89:
        assert (tag.yaw_deg, tag.pitch_deg, tag.roll_deg) == pytest.approx(gimbal, abs=1e-7)


def test_geotag_needs_a_metric_crs_and_a_valid_offset():
    from semcityloc.geometry.pose import Pose

    pose = Pose.from_xyz_rpy(np.array([690000.0, 5330000.0, 600.0]), 0.0, 30.0, 0.0)
    with pytest.raises(CRSError, match="metric"):
        dji_geotag(pose, "EPSG:4326")
    with pytest.raises(CRSError, match="geocentric"):
        dji_geotag(pose, "EPSG:4978")
    with pytest.raises(InputFileError, match="offset"):
        dji_geotag(pose, "EPSG:25832", offset=np.array([1.0, 2.0]))
    with pytest.raises(InputFileError, match="target_height"):
        dji_geotag(pose, "EPSG:25832", target_height="geoid")


@pytest.mark.parametrize(
    "crs, centre, inside",
    [
        ("EPSG:32649", (-466.0, 286.0), False),  # a local frame read as UTM 49N: the Equator
        ("EPSG:32649", (695_206.0, 3_131_485.0), True),
        ("EPSG:25833", (391_000.0, 5_817_000.0), True),  # Berlin
        ("EPSG:7415", (85_000.0, 447_000.0), True),  # RD + NAP (a compound CRS)
        ("EPSG:7415", (100.0, 50.0), False),
        ("EPSG:31468", (4_424_500.0, 5_482_500.0), True),  # Gauss-Krueger zone 4 (Fuerth)
        ("EPSG:31468", (24_500.0, 82_500.0), False),
        ("EPSG:6677", (-10_000.0, -30_000.0), True),  # a Japanese plane zone: near 0 is its own origin
    ],
)
def test_a_models_coordinates_outside_its_crs_are_told(crs, centre, inside):
    """``model_outside_crs``: coordinates beyond a CRS's area of use (in its own metres) are no coordinates
    of it, most often a local frame given a CRS without its offset; real ones (a national grid's origin
    included) pass."""
    reason = geodesy.model_outside_crs(pyproj.CRS(crs), centre)
    assert (reason is None) == inside, reason
    if not inside:
        assert "its area of use spans x" in reason and "a local frame?" in reason


def test_a_geoid_separation_applies_with_auto_heights(tmp_path):
    """``--geoid-separation 36.7`` with the default ``--target-height auto`` over a model whose CRS names no
    vertical datum was not applied, only said unused (stop 51), and a PLATEAU photo 36.7 m above the
    model's z was refused at the search volume's edge (user audit, stop 52): a stated N now says the
    model's z is orthometric, for a 2D CRS too (``model_heights_orthometric``), and ``dji_geotag`` adds it
    back; only where no conversion needs it (``target_height="ellipsoidal"`` with an RTK photo) is it
    said unused."""
    meta = read_dji_metadata(dji_jpeg(tmp_path / "a.jpg", xmp_packet(**RTK)))
    plain = dji_prior(meta, "EPSG:25832", geoid_separation_m=47.0)
    assert plain.pose.center[2] == pytest.approx(612.5 - 47.0) and plain.geoid_applied
    assert dji.GEOID_UNUSED_NOTE not in plain.notes and dji.HEIGHT_AS_IS_NOTE not in plain.notes
    assert plain.z_reference == "orthometric (the model's heights, N = 47 m given)"
    back = dji.dji_geotag(plain.pose, "EPSG:25832", geoid_separation_m=47.0)
    assert back.height_m == pytest.approx(612.5) and back.height_reference.startswith("ellipsoidal")
    compound = dji_prior(meta, "EPSG:25832+7837", geoid_separation_m=47.0)
    assert dji.GEOID_UNUSED_NOTE not in compound.notes
    assert compound.pose.center[2] == pytest.approx(612.5 - 47.0)
    unused = dji_prior(meta, "EPSG:25832", target_height="ellipsoidal", geoid_separation_m=47.0)
    assert dji.GEOID_UNUSED_NOTE in unused.notes and unused.pose.center[2] == pytest.approx(612.5)


def test_a_geographic_compound_model_crs_keeps_its_height_system(tmp_path):
    """PLATEAU's CityGML declares EPSG:6697 (JGD2011 latitude / longitude + JGD2011 vertical height). It was
    projected to plain EPSG:32654, and a run over it said "the model's CRS names no vertical datum" and took
    an RTK photo's ellipsoidal height, 36.7 m above the model's z, as z: refused at the search volume's
    edge (user audit, stop 52). The metric CRS now keeps the height system (``with_heights_of``), so the
    height is converted, or said not to be and searched over the geoid's range; a given N applies."""
    source = parse_crs_name("http://www.opengis.net/def/crs/EPSG/0/6697")
    sample = np.array([[35.6746, 139.7118], [35.6836, 139.7250]])  # latitude first, as the file writes it
    frame = MetricFrame.for_source(source, sample)
    assert crs_label(frame.target) == "EPSG:32654+6695"
    assert frame.to_metric(np.array([[35.678, 139.718, 40.0]]))[0, 2] == 40.0  # heights as they are
    fields = dict(RTK, GpsLatitude="+35.678", GpsLongitude="+139.718", AbsoluteAltitude="+186.700")
    meta = read_dji_metadata(dji_jpeg(tmp_path / "t.jpg", xmp_packet(**fields)))
    prior = dji_prior(meta, frame.target)
    assert HEIGHT_AS_IS_NOTE not in prior.notes
    if not prior.geoid_applied:  # no jp_gsi_gsigeo2011 grid installed: said, and the whole range searched
        assert (
            "JGD2011 (vertical) height" in prior.vertical_flag and "jp_gsi_gsigeo2011" in prior.vertical_flag
        )
        assert prior_uncertainty(prior).z_m == pytest.approx(GEOID_UNDULATION_BOUND_M / 3.0)
    given = dji_prior(meta, frame.target, geoid_separation_m=36.7)
    assert given.pose.center[2] == pytest.approx(150.0) and prior_uncertainty(given).z_m == RTK_FLOOR_M
    # A target of its own with another height system would name heights that are not converted: refused.
    with pytest.raises(CRSError, match="height system"):
        MetricFrame.for_source(source, sample, parse_crs_name("EPSG:32654+5773"))
    plain = MetricFrame.for_source(source, sample, parse_crs_name("EPSG:6691"))  # JGD2011 / UTM 54N
    assert crs_label(plain.target) == "EPSG:6691+6695"
