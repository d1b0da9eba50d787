"""A user's photos and their files: geotag CSVs, OpenDroneMap geo.txt, priors / intrinsics by photo,
camera footprints as GeoJSON."""

from __future__ import annotations

import json
import re

import numpy as np
import pyproj
import pytest

from dji_photo import RTK_FIELDS, dji_jpeg, xmp_packet
from semcityloc.datasets.dji import NO_HEADING_NOTE, DjiGeotag, dji_geotag
from semcityloc.datasets.geojson import CameraFeature, cameras_geojson, footprint_xy
from semcityloc.datasets.geotags import (
    GEOTAG_COLUMNS,
    NO_YAW_NOTE,
    GeotagRow,
    geotags_csv_text,
    odm_geo_text,
    read_geotags_csv,
)
from semcityloc.datasets.photos import (
    EXIF,
    INTRINSICS_35MM,
    INTRINSICS_DJI_CALIBRATION,
    INTRINSICS_DJI_DEWARP,
    IntrinsicsFiles,
    PhotoMissing,
    PhotoNotListed,
    PriorFiles,
    list_images,
)
from semcityloc.errors import CRSError, InputFileError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import dji_gimbal_angles, dji_world_from_cam, odm_world_from_cam
from semcityloc.geometry.distortion import LensDistortion
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import NO_HEADING_YAW_DEG, PriorUncertainty

RTK = dict(RTK_FIELDS, GimbalYawDegree="+30.00", GimbalPitchDegree="-60.00", RtkStdLon="0.8", RtkStdLat="0.7")
RTK["RtkStdHgt"] = "1.5"


def tag(lat=48.1, lon=11.5, h=612.5, ypr=(30.0, -60.0, 0.0)) -> DjiGeotag:
    return DjiGeotag(lat, lon, h, *ypr, height_reference="ellipsoidal (WGS 84)")


# ------------------------------------------------------------------------------------------ geotag files
def test_geotag_csv_round_trip_keeps_a_tenth_of_a_millimetre(tmp_path):
    rows = [
        GeotagRow("a.JPG", tag(48.123456789012, 11.987654321098, 612.34567), source="semcityloc"),
        GeotagRow("b.JPG", tag(ypr=(-179.5, -90.0, 0.0)), 5.0, 10.0, "prior (not localized: x)"),
    ]
    text = geotags_csv_text(rows)
    assert text.splitlines()[0] == ",".join(GEOTAG_COLUMNS)
    path = tmp_path / "g.csv"
    path.write_text(text)
    back = read_geotags_csv(path)
    a, b = back["a.JPG"], back["b.JPG"]
    geod = pyproj.Geod(ellps="WGS84")
    _, _, dist = geod.inv(11.987654321098, 48.123456789012, a.geotag.longitude, a.geotag.latitude)
    assert dist < 1e-4 and abs(a.geotag.height_m - 612.34567) < 1e-4
    assert a.uncertainty() is None and a.source == "semcityloc"
    sigma = b.uncertainty()
    assert (sigma.xy_m, sigma.z_m, b.geotag.yaw_deg) == (5.0, 10.0, -179.5)


def test_geotag_csv_accepts_other_headers_and_refuses_bad_rows(tmp_path):
    path = tmp_path / "g.csv"
    path.write_text("Label;Lat;Lon;Alt;Yaw;Pitch\nx.jpg;48.1;11.5;600;10;-45\n")
    row = read_geotags_csv(path)["x.jpg"]
    assert (row.geotag.latitude, row.geotag.roll_deg, row.geotag.pitch_deg) == (48.1, 0.0, -45.0)
    path.write_text("image,latitude,longitude\nx.jpg,1,2\n")
    with pytest.raises(InputFileError, match="missing height_m, pitch_deg"):  # no yaw: every heading
        read_geotags_csv(path)
    path.write_text("image,latitude,longitude,height_m,yaw_deg,pitch_deg\nx.jpg,95,2,3,4,5\n")
    with pytest.raises(InputFileError, match="line 2: latitude 95"):
        read_geotags_csv(path)
    path.write_text("image,latitude,longitude,height_m,yaw_deg,pitch_deg\nx.jpg,45,2,high,4,5\n")
    with pytest.raises(InputFileError, match="line 2: height_m is not a number"):
        read_geotags_csv(path)
    with pytest.raises(InputFileError, match="no such geotag file"):
        read_geotags_csv(tmp_path / "absent.csv")


def test_odm_geo_txt_is_in_the_horizontal_crs():
    text = odm_geo_text("EPSG:25833+7837", [("a.JPG", (392000.12345, 5819000.5, 80.25), tag())])
    lines = text.splitlines()
    assert lines[0] == "EPSG:25833"
    name, x, y, z, yaw, pitch, roll = lines[1].split()
    assert (name, float(x), float(y), float(z)) == ("a.JPG", 392000.1235, 5819000.5, 80.25)
    assert (float(yaw), float(pitch), float(roll)) == (30.0, 30.0, 0.0)  # ODM's pitch: 0 = nadir
    with pytest.raises(InputFileError, match="spaces"):
        odm_geo_text("EPSG:25833", [("a b.JPG", (0.0, 0.0, 0.0), tag())])
    # With accuracies (one sigma, m): ODM's 8th and 9th columns, on the rows that have them.
    rows = [("a.JPG", (1.0, 2.0, 3.0), tag()), ("b.JPG", (4.0, 5.0, 6.0), tag())]
    lines = odm_geo_text("EPSG:25833", rows, [(0.41234, 0.9), None]).splitlines()
    assert lines[1].split()[7:] == ["0.412", "0.900"] and len(lines[2].split()) == 7


# ------------------------------------------------------------------------------------------ photos
def test_priors_from_exif_csv_and_pose_files_agree(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    dji_jpeg(folder / "a.JPG", xmp_packet(**RTK), focal_35mm=24, size=(80, 60))
    (folder / "notes.txt").write_text("not a photo")
    images = list_images(folder)
    assert [p.name for p in images] == ["a.JPG"]
    exif = PriorFiles(EXIF, pyproj.CRS("EPSG:25832"))
    prior = exif.prior(images[0])
    assert prior.source == "exif" and prior.uncertainty.xy_m == 0.8 and prior.uncertainty.z_m == 1.5
    assert prior.details["source_height"] == "ellipsoidal"
    # The same camera as a geotag row, then as a COLMAP pose line in the CRS: the same prior.
    g = dji_geotag(prior.pose_world, "EPSG:25832")
    (tmp_path / "g.csv").write_text(geotags_csv_text([GeotagRow("a.JPG", g, 2.0, 3.0)]))
    from_csv = PriorFiles(tmp_path / "g.csv", pyproj.CRS("EPSG:25832")).prior(images[0])
    assert center_error_m(from_csv.pose_world, prior.pose_world) < 1e-3
    assert rotation_error_deg(from_csv.pose_world, prior.pose_world) < 1e-5
    assert (from_csv.uncertainty.xy_m, from_csv.uncertainty.z_m) == (2.0, 3.0)
    # A run whose pyproj had no geoid grid writes the model's heights, saying so in height_reference: read
    # back (with a geoid separation given, as in that run) they are taken as they are, not as ellipsoidal
    # heights to subtract N from (the priors came out N lower).
    compound = pyproj.CRS("EPSG:25832+7837")
    with_n = PriorFiles(EXIF, compound, geoid_separation_m=39.6).prior(images[0])
    z = float(with_n.pose_world.center[2])
    reference = "orthometric (DHHN2016; geoid NOT applied: not ellipsoidal)"
    flagged = DjiGeotag(g.latitude, g.longitude, z, g.yaw_deg, g.pitch_deg, g.roll_deg, reference)
    (tmp_path / "o.csv").write_text(geotags_csv_text([GeotagRow("a.JPG", flagged)]))
    from_flagged = PriorFiles(tmp_path / "o.csv", compound, geoid_separation_m=39.6).prior(images[0])
    assert from_flagged.pose_world.center[2] == pytest.approx(z, abs=1e-6)
    assert with_n.pose_world.center[2] == pytest.approx(612.5 - 39.6, abs=0.01)  # RTK's ellipsoidal h - N
    from semcityloc.geometry.conventions import colmap_qvec_tvec

    qvec, tvec = colmap_qvec_tvec(prior.pose_world)
    values = " ".join(repr(float(v)) for v in [*qvec, *tvec])
    (tmp_path / "images.txt").write_text(f"1 {values} 1 a.JPG\n\n")
    from_colmap = PriorFiles(tmp_path / "images.txt", None).prior(images[0])
    assert from_colmap.uncertainty is None and center_error_m(from_colmap.pose_world, prior.pose_world) < 1e-6
    # Intrinsics from EXIF: 24 mm equivalent on 80 x 60 px.
    cam = IntrinsicsFiles(EXIF).photo_camera(images[0], 80, 60).camera
    assert cam.fx == pytest.approx(24.0 / np.hypot(36, 24) * 100.0)


def _camera_and_source(lens):
    return lens.camera, lens.source


def test_exif_intrinsics_say_whether_they_are_a_calibration_or_the_35mm_approximation(tmp_path):
    tags = dict(
        CalibratedFocalLength="90.5", CalibratedOpticalCenterX="40.5", CalibratedOpticalCenterY="29.5"
    )
    calibrated = dji_jpeg(tmp_path / "cal.jpg", xmp_packet(**tags), size=(80, 60), focal_35mm=24)
    plain = dji_jpeg(tmp_path / "plain.jpg", xmp_packet(GimbalYawDegree="1"), size=(80, 60), focal_35mm=24)
    cam, source = _camera_and_source(IntrinsicsFiles(EXIF).photo_camera(calibrated, 80, 60))
    assert (cam.fx, cam.cx, cam.cy) == (90.5, 40.5, 29.5) and source == INTRINSICS_DJI_CALIBRATION
    cam, source = _camera_and_source(
        IntrinsicsFiles(EXIF).photo_camera(calibrated, 40, 30)
    )  # the mask's size
    assert (cam.fx, cam.cx) == (45.25, 20.25) and source == INTRINSICS_DJI_CALIBRATION
    cam, source = _camera_and_source(IntrinsicsFiles(EXIF).photo_camera(plain, 80, 60))
    assert cam.fx == pytest.approx(24.0 / np.hypot(36, 24) * 100.0) and source == INTRINSICS_35MM
    (tmp_path / "cam.txt").write_text("100 100 40 30 80 60\n")
    lens = IntrinsicsFiles(tmp_path / "cam.txt").photo_camera(plain, 80, 60)
    assert lens.camera.fx == 100.0 and lens.source == str(tmp_path / "cam.txt") and lens.distortion.is_zero
    dewarp = xmp_packet(DewarpData="2022-06-08;55.5,55.5,0.5,-0.5,-0.2,0.05,0.001,0,0", DewarpFlag="0")
    lens = IntrinsicsFiles(EXIF).photo_camera(
        dji_jpeg(tmp_path / "dw.jpg", dewarp, size=(80, 60), focal_35mm=24), 40, 30
    )
    assert lens.source == INTRINSICS_DJI_DEWARP and lens.distortion == LensDistortion(-0.2, 0.05, 0.001)
    assert (lens.camera.fx, lens.camera.cx, lens.camera.cy) == (27.75, 20.25, 14.75)  # at the mask's size
    broken = dji_jpeg(tmp_path / "broken.jpg", xmp_packet(DewarpData="1;2;3"), size=(80, 60), focal_35mm=24)
    with pytest.raises(PhotoMissing, match="DewarpData"):  # this photo is skipped, not the whole run
        IntrinsicsFiles(EXIF).photo_camera(broken, 80, 60)
    (tmp_path / "cameras.txt").write_text("1 OPENCV 80 60 100 100 40 30 -0.2 0.05 0.001 0\n")
    lens = IntrinsicsFiles(tmp_path / "cameras.txt").photo_camera(plain, 40, 30)
    assert lens.camera.fx == 50.0 and lens.distortion == LensDistortion(-0.2, 0.05, 0.001, 0.0)


def test_a_photo_without_what_it_needs_is_missing_not_a_crash(tmp_path):
    photo = dji_jpeg(tmp_path / "plain.jpg", None, size=(40, 30))
    with pytest.raises(PhotoMissing, match="no latitude"):
        PriorFiles(EXIF, pyproj.CRS("EPSG:25832")).prior(photo)
    with pytest.raises(
        PhotoMissing, match=r"FocalLengthIn35mmFilm.*pass intrinsics=\.\.\. \(a calibration file"
    ):
        IntrinsicsFiles(EXIF).photo_camera(photo, 40, 30)
    (tmp_path / "poses").mkdir()
    with pytest.raises(PhotoMissing, match="no prior pose for plain.jpg"):
        PriorFiles(tmp_path / "poses", None).prior(photo)
    with pytest.raises(CRSError, match="need the city model's CRS.*crs='EPSG:25832'"):
        PriorFiles(EXIF, None)
    with pytest.raises(InputFileError, match="no such pose file"):
        PriorFiles(tmp_path / "absent", None)


def test_a_crs_pose_file_is_no_prior_of_a_model_whose_frame_is_the_crs_minus_an_offset(tmp_path):
    """``run --crs EPSG:32649 --offset X,Y,Z --priors poses/`` took JSON priors labelled EPSG:32649 (true
    UTM coordinates) as coordinates of the model's frame, the CRS minus the offset: each camera 3,208 km
    away (stop 52). Now refused naming both frames: the whole batch for one file, the photo for a
    folder's; the same file without the offset, or with its numbers in the model's frame, is taken."""
    from semcityloc.geometry.io import write_pose_json

    photo = dji_jpeg(tmp_path / "a.jpg", None, size=(40, 30))
    utm, offset = pyproj.CRS("EPSG:32649"), np.array([695672.0, 3131199.0, 0.0])
    model_frame = Pose.from_xyz_rpy([5.0, -4.0, 90.0], 0.5, 20.0, 30.0)
    in_crs = model_frame.shift_world(-offset)  # its centre + offset
    (tmp_path / "poses").mkdir()
    x, y, z, roll, pitch, yaw = in_crs.to_xyz_rpy().tolist()  # as a user writes one, or localize does
    labelled = {"position": [x, y, z], "roll": roll, "pitch": pitch, "yaw": yaw, "crs": "EPSG:32649"}
    (tmp_path / "poses" / "a_pose.txt").write_text(json.dumps(labelled))
    said = "the pose is in EPSG:32649 but the model's frame is EPSG:32649 minus (695672, 3131199, 0)"
    with pytest.raises(PhotoMissing, match=re.escape(said) + ".*subtract the model's offset"):
        PriorFiles(tmp_path / "poses", utm, offset).prior(photo)
    with pytest.raises(CRSError, match=re.escape(said)):
        PriorFiles(tmp_path / "poses" / "a_pose.txt", utm, offset)
    taken = PriorFiles(tmp_path / "poses", utm).prior(photo).pose_world
    np.testing.assert_allclose(taken.center, in_crs.center)
    write_pose_json(
        tmp_path / "poses" / "a_pose.txt", pose_world=model_frame, crs="EPSG:32649", crs_offset=offset
    )
    np.testing.assert_allclose(
        PriorFiles(tmp_path / "poses", utm, offset).prior(photo).pose_world.center, [5, -4, 90]
    )


# ------------------------------------------------------------------------------------------ GeoJSON
def test_nadir_footprint_is_the_ground_rectangle_the_camera_sees():
    camera = Camera(100.0, 100.0, 50.0, 40.0, 100, 80)
    pose = Pose.from_xyz_rpy(np.array([10.0, 20.0, 150.0]), 0.0, 0.0, 0.0)  # nadir, 150 m above z = 0
    xy = footprint_xy(camera, pose, ground_z=0.0)
    # half extents at 150 m: 150 * 50 / 100 = 75 m across, 150 * 40 / 100 = 60 m along.
    np.testing.assert_allclose(xy.min(0), [10 - 75, 20 - 60], atol=1e-9)
    np.testing.assert_allclose(xy.max(0), [10 + 75, 20 + 60], atol=1e-9)
    horizon = Pose.from_xyz_rpy(np.array([0.0, 0.0, 50.0]), 0.0, 90.0, 0.0)  # looking at the horizon
    far = footprint_xy(camera, horizon, ground_z=0.0, max_range_m=500.0)
    assert np.linalg.norm(far, axis=1).max() <= 500.0 * 1.0001


def test_geojson_is_wgs84_when_the_crs_is_known():
    camera = Camera(100.0, 100.0, 50.0, 40.0, 100, 80)
    t = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:25833", always_xy=True)
    x, y = t.transform(13.40, 52.52)
    pose = Pose.from_xyz_rpy(np.array([x, y, 150.0]), 0.0, 0.0, 0.0)
    features = [CameraFeature("a.JPG", camera, pose, {"status": "localized"})]
    doc = json.loads(json.dumps(cameras_geojson(features, pyproj.CRS("EPSG:25833"), 0.0)))
    point, footprint = doc["features"]
    assert point["geometry"]["coordinates"] == pytest.approx([13.40, 52.52], abs=1e-9)
    ring = footprint["geometry"]["coordinates"][0]
    assert ring[0] == ring[-1] and len(ring) == 4 * 8 + 1
    lon, lat = np.array(ring[:-1]).T  # an exterior ring winds counterclockwise (RFC 7946, 3.1.6)
    assert np.dot(lon, np.roll(lat, -1)) - np.dot(np.roll(lon, -1), lat) > 0
    assert footprint["properties"]["image"] == "a.JPG" and "semcityloc_frame" not in doc


def test_geojson_of_a_model_without_a_crs_is_refused_not_written_in_local_metres():
    """GeoJSON coordinates are longitude, latitude (RFC 7946): local metres in them (x -466 m) put a GIS's
    camera at longitude -466; without a CRS there is no GeoJSON (a ``CRSError``), never local metres."""
    camera = Camera(100.0, 100.0, 50.0, 40.0, 100, 80)
    pose = Pose.from_xyz_rpy(np.array([-466.0, 285.0, 150.0]), 0.0, 0.0, 0.0)
    with pytest.raises(CRSError, match="needs the model's CRS"):
        cameras_geojson([CameraFeature("a.JPG", camera, pose)], None, 0.0)


def test_geotag_priors_whose_height_is_not_converted_search_the_geoids_range(tmp_path):
    """Priors from a geotag CSV (ellipsoidal heights) over a model with a vertical datum and no geoid grid
    were marked "geoid NOT applied" but kept the default 10 m height sigma, while the same photo's EXIF
    prior got it widened to 110 m / 3: one photo not localized (p 0.47) that EXIF priors put 0.13 m off
    (user audit, stop 52). One rule now for every source (``dji.height_widened``): the row's accuracy
    columns, or the defaults, with the height sigma widened; an N given converts it, and nothing widens."""
    folder = tmp_path / "photos"
    folder.mkdir()
    image = dji_jpeg(folder / "a.JPG", xmp_packet(**RTK), size=(80, 60))
    compound = pyproj.CRS("EPSG:25832+7837")
    exif = PriorFiles(EXIF, compound).prior(image)
    if exif.details["geoid_applied"]:
        pytest.skip("pyproj has the DHHN2016 geoid grid here: every height is converted")
    g = tag(ypr=(30.0, -60.0, 0.0))
    (tmp_path / "plain.csv").write_text(geotags_csv_text([GeotagRow("a.JPG", g)]))
    (tmp_path / "acc.csv").write_text(geotags_csv_text([GeotagRow("a.JPG", g, 0.05, 0.08)]))
    plain = PriorFiles(tmp_path / "plain.csv", compound).prior(image)
    stated = PriorFiles(tmp_path / "acc.csv", compound).prior(image)
    bound = exif.uncertainty.z_m
    assert bound == pytest.approx(110.0 / 3.0) and "height reference not converted" in exif.uncertainty.source
    assert plain.uncertainty.z_m == bound and plain.uncertainty.xy_m == 5.0  # the defaults, widened
    assert "height reference not converted" in plain.uncertainty.source
    assert (stated.uncertainty.xy_m, stated.uncertainty.z_m) == (0.05, bound)
    converted = PriorFiles(tmp_path / "plain.csv", compound, geoid_separation_m=47.0).prior(image)
    assert converted.uncertainty is None  # the caller's defaults: nothing to widen


def test_geotag_csv_angles_are_the_reference_import_convention(tmp_path):
    """``geotags.csv`` held DJI's gimbal angles, documented for Metashape / Pix4D reference import: those
    tools' pitch is 0 at nadir (DJI's -90), and near nadir DJI's split between yaw and roll is arbitrary (the
    real thermal photo, EXIF -102.3 / -90 / 0, came out yaw -177.9, pitch -89.3, roll 76.4; user audit,
    stop 52). Now the columns are Pix4D's yaw, pitch, roll (``pix4d_*``, what Metashape's reference and
    ODM's geo.txt use, geo.txt's numbers): a camera 0.7 deg off nadir is a heading and two small tilts,
    and it reads back as the same camera. A file of DJI angles (the old columns, exiftool's) reads as DJI's;
    one with both sets is refused."""
    R = odm_world_from_cam(-102.3, 0.5, -0.5)  # image top at -102.3 deg, 0.7 deg off nadir
    camera = Pose.from_rotation_center(R, np.zeros(3))
    dji_angles = dji_gimbal_angles(camera)
    assert abs(dji_angles[2]) > 30.0  # DJI's roll of this camera: the arbitrary split
    text = geotags_csv_text([GeotagRow("a.JPG", tag(ypr=tuple(dji_angles)))])
    header, row = (line.split(",") for line in text.splitlines())
    angles = [float(row[header.index(k)]) for k in ("pix4d_yaw_deg", "pix4d_pitch_deg", "pix4d_roll_deg")]
    np.testing.assert_allclose(angles, [-102.3, 0.5, -0.5], atol=1e-5)
    assert "yaw_deg" not in header and "pitch_deg" not in header
    (tmp_path / "g.csv").write_text(text)
    back = read_geotags_csv(tmp_path / "g.csv")["a.JPG"].geotag
    again = Pose.from_rotation_center(odm_world_from_cam(*angles), np.zeros(3))
    read = Pose.from_rotation_center(
        dji_world_from_cam(back.yaw_deg, back.pitch_deg, back.roll_deg), np.zeros(3)
    )
    assert rotation_error_deg(read, camera) < 1e-4 and rotation_error_deg(again, camera) < 1e-4
    (tmp_path / "dji.csv").write_text("image,lat,lon,alt,yaw,pitch,roll\na.JPG,48.1,11.5,600,-102.3,-90,0\n")
    legacy = read_geotags_csv(tmp_path / "dji.csv")["a.JPG"].geotag
    assert (legacy.yaw_deg, legacy.pitch_deg, legacy.roll_deg) == (-102.3, -90.0, 0.0)
    (tmp_path / "both.csv").write_text(
        "image,lat,lon,alt,yaw,pitch,pix4d_yaw_deg,pix4d_pitch_deg\na.JPG,48.1,11.5,600,0,-90,0,0\n"
    )
    with pytest.raises(InputFileError, match="keep one set"):
        read_geotags_csv(tmp_path / "both.csv")


# ------------------------------------------------------------------------------ stop 52: unusable priors
def test_a_prior_without_a_gnss_fix_or_outside_the_crs_is_that_photos_reason_not_the_runs_end(tmp_path):
    """Stop 52's audit: a DJI photo taken before its GNSS fix (latitude and longitude 0) and a geotag CSV with
    latitude and longitude swapped raised a ``CRSError`` ("outside the area of use ... wrong target CRS?")
    that stopped the whole run, naming neither photo nor row. Now ``PhotoMissing`` (that photo skipped)
    saying what is wrong: no GNSS fix; the CSV's file and line, and whether swapping the two fits."""
    crs = pyproj.CRS("EPSG:25832")
    nofix = dict(RTK, GpsLatitude="+0.0000000", GpsLongitude="+0.0000000")
    photo = dji_jpeg(tmp_path / "NOFIX.JPG", xmp_packet(**nofix), focal_35mm=24, size=(80, 60))
    with pytest.raises(PhotoMissing, match=r"no usable GPS prior: no GNSS fix \(latitude 0, longitude 0"):
        PriorFiles(EXIF, crs).prior(photo)
    rows = [GeotagRow("a.JPG", tag(lat=11.5, lon=48.1)), GeotagRow("b.JPG", tag(lat=-33.9, lon=151.2))]
    (tmp_path / "g.csv").write_text(geotags_csv_text(rows))
    priors = PriorFiles(tmp_path / "g.csv", crs)
    swapped = r"g\.csv line 2\): the position \(lat 11\.5.*latitude and longitude swapped\? \(lat 48\.1"
    with pytest.raises(PhotoMissing, match=swapped):
        priors.prior(tmp_path / "a.JPG")
    with pytest.raises(PhotoMissing, match=r"g\.csv line 3\): .*wrong target CRS\?"):  # Sydney: not swapped
        priors.prior(tmp_path / "b.JPG")


def test_a_runs_pose_records_are_priors_and_truth(tmp_path):
    """Stop 52's audit: a run's own ``poses/`` fed back as ``--priors`` / ``--truth`` (or ``label --poses``)
    was refused ("no prior pose for F001.JPG in run1/poses"). Its ``<stem>.json`` records are read now; a
    photo that run did not localize has none, said so; a folder with nothing for a photo names the files
    it looks for."""
    from semcityloc.datasets.photos import PhotoNotListed
    from semcityloc.geometry.io import write_pose_json

    poses = tmp_path / "poses"
    poses.mkdir()
    pose = Pose.from_xyz_rpy([500100.0, 5400200.0, 300.0], 1.0, 40.0, 120.0)
    write_pose_json(poses / "a.json", pose_world=pose, crs="EPSG:25832", extra={"status": "localized"})
    record = {"status": "not_localized", "reason": "confidence below the acceptance probability"}
    (poses / "b.json").write_text(json.dumps(record))
    priors = PriorFiles(poses, pyproj.CRS("EPSG:25832"))
    assert center_error_m(priors.prior(tmp_path / "a.JPG").pose_world, pose) < 1e-6
    with pytest.raises(
        PhotoNotListed, match=r"b\.JPG has no pose there: that run did not localize it \(conf"
    ):
        priors.prior(tmp_path / "b.JPG")
    with pytest.raises(
        PhotoNotListed, match=r"no prior pose for c\.JPG .*expected c_pose\.txt, c\.txt or c\.json"
    ):
        priors.prior(tmp_path / "c.JPG")


def test_a_folder_with_photos_only_in_subfolders_names_them_as_every_message_does(tmp_path):
    """``list_images`` named the first three photos of the subfolders and then "...", its own copy of
    the list that ``run``'s and ``benchmark``'s messages make with ``shown_names``; it uses that one now:
    the first five, then how many more."""
    sub = tmp_path / "DCIM" / "100MEDIA"
    sub.mkdir(parents=True)
    for k in range(7):
        (sub / f"DJI_{k:04d}.JPG").write_bytes(b"")
    shown = ", ".join(f"DCIM/100MEDIA/DJI_{k:04d}.JPG" for k in range(5))
    with pytest.raises(
        InputFileError, match=re.escape(f"7 in its subfolders ({shown} (+2 more)) are not read")
    ):
        list_images(tmp_path)


def test_photos_in_subfolders_are_listed_with_recursive_and_named_without(tmp_path):
    """Stop 52's audit: photos in subfolders were ignored without a word (a DJI card's
    ``DCIM/100MEDIA/``: "no images"). ``recursive`` reads them (not hidden folders, nor those ``skip_dir``
    names), refusing two of one stem (a photo's outputs are named by it); without it a folder whose
    photos are all in subfolders says how many and what to do."""
    from semcityloc.datasets.photos import subfolder_images

    for name in ("a.JPG", "sub/b.JPG", "sub/deeper/c.jpg", ".thumbs/t.jpg", "masks/a.png"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"")
    masks = lambda folder: folder.name == "masks"  # noqa: E731
    assert [p.name for p in list_images(tmp_path)] == ["a.JPG"]
    listed = list_images(tmp_path, recursive=True, skip_dir=masks)
    assert [str(p.relative_to(tmp_path)) for p in listed] == ["a.JPG", "sub/b.JPG", "sub/deeper/c.jpg"]
    assert [p.name for p in subfolder_images(tmp_path, masks)] == ["b.JPG", "c.jpg"]
    (tmp_path / "sub2").mkdir()
    (tmp_path / "sub2" / "b.JPG").write_bytes(b"")
    with pytest.raises(InputFileError, match=r"sub/b\.JPG and sub2/b\.JPG share the name b.*its own"):
        list_images(tmp_path, recursive=True, skip_dir=masks)
    card = tmp_path / "card"
    (card / "DCIM" / "100MEDIA").mkdir(parents=True)
    (card / "DCIM" / "100MEDIA" / "DJI_0001.JPG").write_bytes(b"")
    with pytest.raises(
        InputFileError, match=r"at its top level; 1 in its subfolders \(DCIM/100MEDIA/DJI_0001"
    ):
        list_images(card)
    assert [p.name for p in list_images(card, recursive=True)] == ["DJI_0001.JPG"]


# ------------------------------------------------------------------------------ stop 54: rows without a yaw
def test_a_geotag_row_without_a_yaw_is_a_prior_that_searches_every_heading(tmp_path):
    """A geotag CSV row with an empty yaw cell, or a file with a pitch and no yaw column, refused the whole
    file ("g.csv: line 2: no yaw_deg", "a geotag CSV needs the columns ... missing yaw_deg"), though a DJI
    photo without ``GimbalYawDegree`` has been localized searching every heading since stop 53. Now such a
    row is read as that photo is: yaw 0 taken, ``heading_known`` False, every heading searched over any
    smaller yaw sigma, said in its notes and its result's warnings (``NO_YAW_NOTE``, the words of
    ``NO_HEADING_NOTE`` after what lacked the heading). A prior without a heading is written back with an
    empty yaw cell. (A row without a pitch: stop 55, below.)"""
    crs = pyproj.CRS("EPSG:25832")
    photo = dji_jpeg(tmp_path / "a.JPG", xmp_packet(**RTK), size=(80, 60))
    header = "image,latitude,longitude,height_m,yaw_deg,pitch_deg,roll_deg\n"
    files = {
        "empty.csv": header + "a.JPG,48.1,11.5,600,,-45,0\n",
        "nocolumn.csv": "Lat;Lon;Alt;Pitch;Label\n",
    }
    files["nocolumn.csv"] += "48.1;11.5;600;-45;a.JPG\n"
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        row = read_geotags_csv(tmp_path / name)["a.JPG"]
        g = row.geotag
        assert not g.heading_known and (g.yaw_deg, g.pitch_deg, g.roll_deg) == (0.0, -45.0, 0.0), name
        prior = PriorFiles(tmp_path / name, crs).prior(photo)
        assert not prior.heading_known and prior.details["heading_known"] is False
        assert prior.warnings() == [NO_YAW_NOTE] and NO_YAW_NOTE in prior.details["notes"]
        assert NO_HEADING_NOTE not in prior.details["notes"]  # no GimbalYawDegree was read from a CSV
        assert prior.searched().yaw_deg == NO_HEADING_YAW_DEG
        assert prior.searched(PriorUncertainty(yaw_deg=3.0)).yaw_deg == NO_HEADING_YAW_DEG
        assert f"its geotag row ({tmp_path / name} line 2) has no yaw" in prior.no_heading_truth
        # Written back (a run's prior of a photo it did not localize): an empty yaw cell, read as none.
        (tmp_path / "back.csv").write_text(geotags_csv_text([GeotagRow("a.JPG", g)]))
        back = read_geotags_csv(tmp_path / "back.csv")["a.JPG"].geotag
        assert not back.heading_known and back.pitch_deg == pytest.approx(-45.0)
    (tmp_path / "yaw.csv").write_text(files["empty.csv"].replace(",,-45", ",30,-45"))
    known = PriorFiles(tmp_path / "yaw.csv", crs).prior(photo)
    assert (
        known.heading_known and known.warnings() == [] and known.details["gimbal_yaw_pitch_roll_deg"][0] == 30
    )


# ------------------------------------------------------------------ stop 55: rows without a pitch, short rows
@pytest.mark.parametrize("cell", ["", "nan", "N/A", " - "])
def test_a_geotag_row_without_a_pitch_skips_its_photo_not_the_whole_file(tmp_path, cell):
    """Stop 55 audit: one geotag row whose pitch cell was empty refused the whole file ("line 3: no
    pitch_deg": every photo of the run), and one holding a missing-value marker too ("pitch_deg is not
    finite"), whereas a DJI photo without ``GimbalPitchDegree`` is only skipped. Now such a row (the same
    ``MISSING_VALUES`` as the yaw's) gives no prior: its photo is skipped (``PhotoMissing``, not
    ``PhotoNotListed``: its row is there) with a reason naming the file, the line and the column, as the
    DJI photo is; the other rows are read. A file without a pitch column is still refused."""
    crs = pyproj.CRS("EPSG:25832")
    photo = dji_jpeg(tmp_path / "a.JPG", xmp_packet(**RTK), size=(80, 60))
    header = "image,latitude,longitude,height_m,yaw_deg,pitch_deg,roll_deg\n"
    (tmp_path / "g.csv").write_text(
        header + "a.JPG,48.1,11.5,600,30,-45,0\n" + f"b.JPG,48.1,11.5,600,30,{cell},0\n"
    )
    rows = read_geotags_csv(tmp_path / "g.csv")
    assert rows["a.JPG"].geotag.pitch_deg == -45.0 and rows["b.JPG"].geotag is None
    priors = PriorFiles(tmp_path / "g.csv", crs)
    assert priors.prior(photo).heading_known
    with pytest.raises(PhotoMissing, match=r"g\.csv line 3\): no pitch_deg: without a pitch") as info:
        priors.prior(tmp_path / "b.JPG")
    assert not isinstance(info.value, PhotoNotListed)
    # Pix4D's angles: the same, named by the file's own column; a file of such rows alone is read too.
    (tmp_path / "p.csv").write_text(
        f"image,lat,lon,alt,pix4d_yaw_deg,pix4d_pitch_deg\na.JPG,48.1,11.5,600,3,{cell}\n"
    )
    with pytest.raises(PhotoMissing, match=r"p\.csv line 2\): no pix4d_pitch_deg"):
        PriorFiles(tmp_path / "p.csv", crs).prior(photo)
    # The DJI path it is consistent with: a photo without GimbalPitchDegree is skipped, not the run.
    no_pitch = dji_jpeg(
        tmp_path / "c.JPG", xmp_packet(**{k: v for k, v in RTK.items() if k != "GimbalPitchDegree"})
    )
    with pytest.raises(PhotoMissing, match="no usable GPS prior"):
        PriorFiles(EXIF, crs).prior(no_pitch)
    (tmp_path / "none.csv").write_text("image,lat,lon,alt,yaw\na.JPG,48.1,11.5,600,30\n")
    with pytest.raises(InputFileError, match="missing pitch_deg in the header"):
        read_geotags_csv(tmp_path / "none.csv")


def test_a_geotag_row_cut_short_is_refused_naming_the_columns_it_lacks(tmp_path):
    """Stop 55 audit: a row with fewer cells than the header (a file cut short, a cell and its delimiter
    lost) read its missing yaw as an empty one: the photo silently searched without a heading. A short row
    is a damaged file: refused naming the file, the line and the columns it lacks. A row whose yaw cell is
    there and empty keeps reading as one without a heading, and a header's trailing delimiter names no
    column a row must have."""
    header = "image,latitude,longitude,height_m,pitch_deg,yaw_deg,roll_deg\n"
    (tmp_path / "g.csv").write_text(header + "a.JPG,48.1,11.5,600,-45,10,0\nb.JPG,48.1,11.5,600,-45\n")
    with pytest.raises(
        InputFileError, match=r"g\.csv: line 3: 5 cells where the header has 7: no yaw_deg, roll_deg"
    ):
        read_geotags_csv(tmp_path / "g.csv")
    (tmp_path / "h.csv").write_text(header + "b.JPG,48.1,11.5,600,-45,,\n")
    assert not read_geotags_csv(tmp_path / "h.csv")["b.JPG"].geotag.heading_known
    (tmp_path / "t.csv").write_text("image,lat,lon,alt,pitch,\nb.JPG,48.1,11.5,600,-45\n")
    assert read_geotags_csv(tmp_path / "t.csv")["b.JPG"].geotag.pitch_deg == -45.0


@pytest.mark.parametrize(("pitch", "roll"), [(0.7, 0.5), (3.0, -2.0), (60.0, 3.0), (30.0, -10.0)])
def test_pix4d_angles_without_a_yaw_keep_the_cameras_tilt(tmp_path, pitch, roll):
    """Pix4D's angles go to DJI's through a rotation: without a yaw it is taken as 0 for it (and the DJI yaw
    that gives dropped for 0: near nadir DJI's yaw / roll split is arbitrary, 35 deg of roll for a camera
    0.9 deg off nadir). The prior's roll and pitch (the camera's tilt) are those of the camera whatever its
    heading, near nadir and oblique; the file's own yaw column may be empty or absent."""
    photo = dji_jpeg(tmp_path / "a.JPG", xmp_packet(**RTK), size=(80, 60))
    for header, cells in (("pix4d_yaw_deg,pix4d_pitch_deg,pix4d_roll_deg", f",{pitch},{roll}"),
                          ("pix4d_pitch_deg,pix4d_roll_deg", f"{pitch},{roll}")):  # fmt: skip
        (tmp_path / "g.csv").write_text(f"image,lat,lon,alt,{header}\na.JPG,48.1,11.5,600,{cells}\n")
        prior = PriorFiles(tmp_path / "g.csv", pyproj.CRS("EPSG:25832")).prior(photo)
        assert not prior.heading_known and prior.details["gimbal_yaw_pitch_roll_deg"][0] == 0.0
        for heading in (0.0, 137.0, -75.0):
            camera = Pose.from_rotation_center(odm_world_from_cam(heading, pitch, roll), np.zeros(3))
            np.testing.assert_allclose(
                prior.pose_world.to_xyz_rpy()[3:5], camera.to_xyz_rpy()[3:5], atol=1e-6
            )


@pytest.mark.parametrize("cell", ["nan", "NaN", "N/A", "-", "null", " none "])
def test_a_yaw_cell_holding_a_missing_value_marker_is_no_heading(tmp_path, cell):
    """Tables write a missing value as 'nan' (numpy's savetxt), 'N/A' or '-': in the yaw column that
    refused the whole run ('line 2: yaw_deg is not finite'); now it reads as an empty cell, a row without a
    heading. A required column holding one is still refused, naming it."""
    header = "image,latitude,longitude,height_m,yaw_deg,pitch_deg,roll_deg\n"
    (tmp_path / "g.csv").write_text(header + f"a.JPG,48.1,11.5,600,{cell},-45,{cell}\n")
    g = read_geotags_csv(tmp_path / "g.csv")["a.JPG"].geotag
    assert not g.heading_known and (g.yaw_deg, g.pitch_deg, g.roll_deg) == (0.0, -45.0, 0.0)
    (tmp_path / "h.csv").write_text(header + f"a.JPG,48.1,11.5,{cell},30,-45,0\n")
    with pytest.raises(InputFileError, match=r"h\.csv: line 2: .*height_m"):
        read_geotags_csv(tmp_path / "h.csv")


def test_a_bad_geotag_value_is_named_by_the_files_own_column(tmp_path):
    """Stop 54 audit: a file whose header says ``yaw`` / ``Alt`` was told about ``yaw_deg`` / ``height_m``
    (the reader's own names), columns the user cannot find in it."""
    (tmp_path / "g.csv").write_text("image,lat,lon,Alt,yaw,pitch\na.JPG,48.1,11.5,600,abc,-45\n")
    with pytest.raises(InputFileError, match=r"g\.csv: line 2: yaw is not a number: 'abc'"):
        read_geotags_csv(tmp_path / "g.csv")
    (tmp_path / "h.csv").write_text("image,lat,lon,Alt,yaw,pitch\na.JPG,48.1,11.5,,30,-45\n")
    with pytest.raises(InputFileError, match=r"h\.csv: line 2: no alt\b"):
        read_geotags_csv(tmp_path / "h.csv")
