"""``semcityloc run``: a folder of photos + a city model -> poses, COLMAP, geotags, GeoJSON, overlays.

Three cases: a small box city in a local frame (no ../shared needed: skips, resume, one-line errors), a
simulated DJI flight over Berlin LoD2 with DJI-style EXIF written here (the geotags go back through pyproj
to the model's CRS within 1 cm), and the two real UAV images with precomputed degraded masks (every output
file parses; accuracy from the GPS priors with default settings).
"""

from __future__ import annotations

import csv
import json
import math
import os
import pickle
import re
import shutil
from hashlib import sha256
from pathlib import Path

import numpy as np
import pyproj
import pytest
from PIL import Image

from conftest import shared_file
from dji_photo import dji_jpeg, xmp_packet
from semcityloc.benchmark import photo_focal, photo_source
from semcityloc.benchmark.dataset_source import oracle_labels, working_camera
from semcityloc.benchmark.perception_sim import simulate_segmentation
from semcityloc.benchmark.photo_spec import PhotoSpec
from semcityloc.benchmark.queries import STREAM_SEG
from semcityloc.benchmark.report import make_report
from semcityloc.benchmark.results import COLUMNS, REASON_UNREADABLE, read_results, write_rows
from semcityloc.benchmark.warmup import box_city_obj
from semcityloc.citymodel.io import load_city_model
from semcityloc.citymodel.tiles import TileStore, build_store
from semcityloc.classes import IGNORE
from semcityloc.cli.main import main
from semcityloc.datasets import photos
from semcityloc.datasets.colmap import read_model
from semcityloc.datasets.dji_camera import camera_from_exif
from semcityloc.datasets.dji_metadata import read_dji_metadata
from semcityloc.datasets.lodloc import LodLocQuery, read_lodloc, write_lodloc_scene
from semcityloc.datasets.photos import INTRINSICS_35MM
from semcityloc.errors import BenchmarkError, InputFileError, MissingWeightsError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import odm_world_from_cam, pose_from_dji
from semcityloc.geometry.distortion import LensDistortion, distort_image, unseen_by_photo
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.io import read_lens, read_pose
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import load_labels_png, save_labels_png
from semcityloc.localization.focal import estimate_focal_scale
from semcityloc.localization.focal_check import with_focal_scale
from semcityloc.localization.result import REASON_AT_EDGE
from semcityloc.render import Renderer
from test_benchmark_reference import same
from test_tiles import _cityjson_box, split_citygml

BERLIN = "berlin_lod2_citygml2/3910_5817.gml"
REAL = ("real_uav_lodloc", "real_uav_lodloc_oblique")
THERMAL, OBLIQUE = "DJI_20230513163714_0033_T", "DJI_20231018114619_0636_D"


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SEMCITYLOC_CACHE", str(tmp_path / "cache"))


# ------------------------------------------------------------------------------ a box city, local frame
CAM = Camera.from_fov(160, 120, 60.0)


@pytest.fixture
def box_flight(tmp_path) -> dict:
    """Three photos over the box city: a LoD-Loc GPS_pose/ and intrinsic/ beside them, oracle masks; the
    third photo's mask has another aspect (with ``--truth``, a miss of the run)."""
    root = tmp_path / "flight"
    (root / "images").mkdir(parents=True)
    city = root / "city.obj"
    city.write_text(box_city_obj())
    model = load_city_model(city, cache=False)
    truths = [
        Pose.from_xyz_rpy([5.0, -4.0, 90.0], 0.5, 20.0, 30.0),
        Pose.from_xyz_rpy([-10.0, 8.0, 85.0], -0.5, 5.0, -60.0),
        Pose.from_xyz_rpy([0.0, 0.0, 95.0], 0.0, 10.0, 0.0),
    ]
    offsets = [np.array([3.0, 2.0, 2.0]), np.array([-2.5, 3.0, -1.5]), np.array([1.0, 1.0, 1.0])]
    queries = []
    for i, (truth, shift) in enumerate(zip(truths, offsets, strict=True)):
        name = f"P{i}.JPG"
        prior = Pose.from_rotation_center(truth.R_world_from_cam, truth.center + shift)
        queries.append(LodLocQuery(name, "flight", CAM, gt_pose_world=truth, prior_pose_world=prior))
        Image.new("RGB", (CAM.width, CAM.height), (120, 120, 120)).save(root / "images" / name)
        labels = oracle_labels(model, CAM, truth)
        if i == 2:
            labels = labels[:, :100]  # another photo's aspect
        save_labels_png(labels, root / "masks" / f"P{i}.png")
    write_lodloc_scene(root, queries)
    Image.new("RGB", (CAM.width, CAM.height)).save(root / "images" / "P9.JPG")  # no pose, no mask
    argv = ["run", root / "images", "--city", city, "--priors", root / "GPS_pose"]
    argv += ["--intrinsics", root / "intrinsic", "--masks", root / "masks", "--truth", root / "GT_pose"]
    return {"root": root, "argv": argv}


def test_a_crs_the_models_coordinates_cannot_be_in_is_refused_naming_offset(box_flight, tmp_path, capsys):
    """The box city is a local frame (centred near 0, 0): with ``--crs EPSG:32649`` and no ``--offset`` the
    run localized every photo and wrote geotags at the Equator (local metres read as UTM 49N); now one line
    before the run, naming the CRS's area and ``--offset``."""
    out = tmp_path / "out"
    code, stdout, err = run(capsys, *box_flight["argv"], "--crs", "EPSG:32649", "--out", out)
    assert code == 2 and "Traceback" not in err
    assert "are not in WGS 84 / UTM zone 49N" in err and "pass --offset X,Y,Z" in err
    assert not (out / "results.csv").exists()


def test_a_flight_whose_priors_share_a_yaw_offset_is_told(tmp_path, capsys):
    """Six photos whose priors are all turned 7 deg counter-clockwise (a compass bias; within the default
    +-9 deg search): they localize, and the run says the priors share a yaw offset, and which way. A
    seventh photo's prior is 40 m too high for the stated 3 m height sigma: refused at the volume's edge,
    and the run names the --prior-sigma that covers it."""
    root = tmp_path / "flight"
    (root / "images").mkdir(parents=True)
    city = root / "city.obj"
    city.write_text(box_city_obj())
    model = load_city_model(city, cache=False)
    spots = [(5, -4, 90, 20, 30), (-10, 8, 85, 5, -60), (0, 0, 95, 10, 0), (12, 10, 88, 25, 120)]
    spots += [(-6, -12, 92, 15, 200), (8, 6, 86, 30, -150), (3, -8, 90, 20, 60)]
    queries = []
    for i, (x, y, z, pitch, yaw) in enumerate(spots):
        truth = Pose.from_xyz_rpy([float(x), float(y), float(z)], 0.0, float(pitch), float(yaw))
        dz, dyaw = (40.0, 0.0) if i == 6 else (1.0, 7.0)
        prior = Pose.from_xyz_rpy([x + 2.0, y - 1.5, z + dz], 0.0, float(pitch), yaw + dyaw)
        name = f"Y{i}.JPG"
        queries.append(LodLocQuery(name, "flight", CAM, gt_pose_world=truth, prior_pose_world=prior))
        Image.new("RGB", (CAM.width, CAM.height), (120, 120, 120)).save(root / "images" / name)
        save_labels_png(oracle_labels(model, CAM, truth), root / "masks" / f"Y{i}.png")
    write_lodloc_scene(root, queries)
    argv = ["run", root / "images", "--city", city, "--priors", root / "GPS_pose", "--intrinsics"]
    argv += [root / "intrinsic", "--masks", root / "masks", "--truth", root / "GT_pose"]
    code, stdout, err = run(capsys, *argv, "--prior-sigma", "z=3", "--out", tmp_path / "out", "--no-overlays")
    assert code == 0, err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["localized"] == 6 and summary["recall_2m2deg"] == pytest.approx(100 * 6 / 7)
    said = re.search(r"the 6 localized photos are turned a median (\d+\.\d) deg clockwise", stdout + err)
    assert said and 6.0 <= float(said.group(1)) <= 8.0, stdout + err
    assert "share a yaw offset" in stdout + err and "--prior-sigma yaw=" not in stdout + err  # none refused
    record = json.loads((tmp_path / "out" / "poses" / "Y6.json").read_text())
    assert record["reason"] == REASON_AT_EDGE and record["search"]["edge_sigma"] == {"z": 12}
    assert any("--prior-sigma z=12" in w for w in record["warnings"])  # 3 x 12 m = twice the 18 m searched
    assert "1 photo was refused at the search volume's edge (z-: 1)" in err
    assert "run again with --prior-sigma z=12 to cover all of them" in err


def test_box_city_run_skips_what_it_cannot_use_and_resumes(box_flight, tmp_path, capsys):
    out = tmp_path / "out"
    argv = [*box_flight["argv"], "--out", out, "--no-overlays"]
    code, stdout, _ = run(capsys, *argv, "--stop-after", "1")
    assert code == 0 and "1/3 photos done" in stdout and "run again" in stdout
    assert len(list((out / "poses").glob("*.json"))) == 1
    code, stdout, err = run(capsys, *argv)
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["photos"] == 4 and summary["queries"] == 3 and summary["localized"] == 2
    skipped = summary["skipped_photos"]
    assert set(skipped) == {"P9.JPG"} and "intrinsic" in skipped["P9.JPG"]
    # P2's mask is of another aspect: it has a true pose, so it is a miss of the run, not left out of it.
    miss = _rows_by_name(out)["P2.JPG"]
    assert miss["status"] == "not_localized" and miss["reason"].startswith(REASON_UNREADABLE)
    assert "P2.png" in miss["reason"] and "aspect" in miss["reason"] and miss["err_xyz_m"] == "inf"
    assert "4 photos: 2 localized, 1 not localized, 1 skipped" in stdout
    assert f"semcityloc report {out} --out {out / 'report'}" in stdout
    assert summary["with_ground_truth"] == 3 and summary["recall_2m2deg"] == pytest.approx(200 / 3)
    # No CRS: poses and COLMAP in the model's frame, no WGS 84 geotags or GeoJSON, and it says why.
    assert not (out / "geotags.csv").exists() and not (out / "cameras.geojson").exists() and "--crs" in err
    model = read_model(out / "colmap")
    for name, (camera, pose) in model.poses().items():
        truth = read_pose(box_flight["root"] / "GT_pose" / f"{Path(name).stem}_pose.txt")
        assert camera == CAM and center_error_m(pose, truth) < 1.0
        record = json.loads((out / "poses" / f"{Path(name).stem}.json").read_text())
        assert (
            record["extra"]["status"] == "localized" and record["extra"]["prior_uncertainty"]["xy_m"] == 5.0
        )
    # The same folder with other arguments is refused, in one line.
    code, _, err = run(capsys, *argv, "--prior-sigma", "xy=2")
    assert code == 2 and "other benchmark run" in err and err.count("\n") == 1


def _first_localized_re_found(monkeypatch, scale: float) -> None:
    """The run's first localized photo as if the focal check's correction had re-found it with the focal
    lengths times ``scale`` (its ``search`` record; the pose as found)."""
    from semcityloc.localization.localize import Localizer

    real, marked = Localizer.localize, []

    def localize(self, *args, **kwargs):
        result = real(self, *args, **kwargs)
        if result.localized and not marked:
            result.search["focal_check"] = {"scale": 0.988, "correction": {"scale": scale, "taken": True}}
            marked.append(result)
        return result

    monkeypatch.setattr(Localizer, "localize", localize)


def test_a_pose_re_found_with_a_scaled_focal_length_is_exported_with_that_camera(
    box_flight, tmp_path, capsys, monkeypatch
):
    """(stop 54) With --preset focal-correct a pose re-found with the focal length times s kept the stated
    fx in its pose file and COLMAP camera: re-projected with them it was off by the scale. Now its pose
    file has ``focal_scale`` at the top level, the scaled fx, fy in ``extra.intrinsics`` (the stated ones
    in ``extra.intrinsics_stated``) and its own COLMAP camera with them; a pose found with the stated focal
    lengths is written as before."""
    _first_localized_re_found(monkeypatch, 0.976)
    out = tmp_path / "out"
    code, _, err = run(capsys, *box_flight["argv"], "--out", out, "--no-overlays")
    assert code == 0, err
    records = {p.stem: json.loads(p.read_text()) for p in (out / "poses").glob("P[01].json")}
    refound = [stem for stem, record in records.items() if "focal_scale" in record]
    assert len(refound) == 1 and len(records) == 2
    record = records[refound[0]]
    assert record["focal_scale"] == pytest.approx(0.976)
    scaled = with_focal_scale(CAM, 0.976)
    assert record["extra"]["intrinsics"] == scaled.as_dict()
    assert record["extra"]["intrinsics_stated"] == CAM.as_dict()
    (other,) = (record for stem, record in records.items() if stem not in refound)
    assert "intrinsics_stated" not in other["extra"] and other["extra"]["intrinsics"] == CAM.as_dict()
    cameras = {Path(name).stem: camera for name, (camera, _) in read_model(out / "colmap").poses().items()}
    assert cameras[refound[0]] == scaled  # a COLMAP camera of its own
    (stem,) = set(cameras) - set(refound)
    assert cameras[stem] == CAM
    assert _rows_by_name(out)[f"{refound[0]}.JPG"]["focal_scale"] == "0.976"


def test_a_pose_re_found_with_a_scaled_focal_length_is_drawn_in_its_overlay_with_that_camera(
    box_flight, tmp_path, capsys, monkeypatch
):
    """(stop 55) A run's ``overlays/<stem>.png`` drew a pose the focal check's correction re-found with the
    focal length times s with the stated camera: its edges lay off by the scale where the pose file said
    it holds. Now the estimate's panel is drawn with the scaled camera (``focal_check.found_camera``) and
    says so; the prior's with the stated one; a pose found with the stated focal lengths as before."""
    from semcityloc.datasets.overlay import edges_figure

    _first_localized_re_found(monkeypatch, 0.976)
    drawn = []

    def spy(image, model, camera, panels, *args, **kwargs):
        cameras = kwargs.get("cameras") or (args[2] if len(args) > 2 else None) or [None] * len(panels)
        used = [camera if c is None else c for c in cameras]
        drawn.append([(title, c, camera) for (_, _, title), c in zip(panels, used, strict=True)])
        return edges_figure(image, model, camera, panels, *args, **kwargs)

    monkeypatch.setattr(photo_source, "edges_figure", spy)
    out = tmp_path / "out"
    code, _, err = run(capsys, *box_flight["argv"], "--out", out)
    assert code == 0, err
    records = {p.stem: json.loads(p.read_text()) for p in (out / "poses").glob("P[01].json")}
    (refound,) = [stem for stem, record in records.items() if "focal_scale" in record]
    estimates = [panels[0] for panels in drawn if panels[0][0].startswith(photo_source.ESTIMATE_TITLE)]
    assert len(estimates) == 2
    (scaled,) = [e for e in estimates if "focal length x 0.976" in e[0]]
    (plain,) = [e for e in estimates if e is not scaled]
    _, used, stated = scaled
    assert used == with_focal_scale(stated, 0.976) and used.width == stated.width  # the overlay's size
    assert plain[1] == plain[2]  # found with the stated focal lengths: drawn with them
    for panels in drawn:  # the prior: always the stated camera
        (prior,) = [p for p in panels if p[0] == photo_source.PRIOR_TITLE]
        assert prior[1] == prior[2]
    assert (out / "overlays" / f"{refound}.png").is_file()


def test_a_run_says_the_models_warnings_once_on_stderr(box_flight, tmp_path, capsys):
    """The model's load warnings (here: an OBJ line of an unknown keyword) were never shown by ``run``: now
    once, on stderr, also when no photo is localized in this call."""
    city = box_flight["root"] / "city.obj"
    city.write_text("bevel on\n" + city.read_text())
    argv = [*box_flight["argv"], "--out", tmp_path / "out", "--no-overlays", "--no-cache"]
    code, stdout, err = run(capsys, *argv, "--stop-after", "0")
    assert code == 0 and "0/3 photos done" in stdout
    assert err.count("semcityloc: warning:") == 1 and "ignored OBJ keywords: bevel (1 lines)" in err


def test_a_mask_of_the_photo_turned_for_display_is_refused_saying_so(box_flight, tmp_path, capsys):
    """EXIF orientation 6 (viewers turn the photo by 90 deg) and a mask of the turned photo: that photo is
    skipped with the reason; orientation 3 (180 deg) cannot be told from the mask, so the run says once
    that masks were taken as of the stored pixels."""
    root = box_flight["root"]
    for name, orientation in (("P0", 6), ("P1", 3)):
        exif = Image.Exif()
        exif[274] = orientation
        Image.new("RGB", (CAM.width, CAM.height), (120, 120, 120)).save(
            root / "images" / f"{name}.JPG", exif=exif
        )
    turned = np.rot90(load_labels_png(root / "masks" / "P0.png"))
    save_labels_png(turned, root / "masks" / "P0.png")
    out = tmp_path / "out"
    code, _, err = run(capsys, *box_flight["argv"], "--out", out, "--no-overlays")
    assert code == 0, err
    reason = _rows_by_name(out)["P0.JPG"]["reason"]  # a miss: P0 has a true pose (--truth)
    assert (
        reason.startswith(REASON_UNREADABLE)
        and "turned for display (EXIF orientation 6)" in reason
        and "stored 160x120 pixels" in reason
    )
    assert "1 photo carries an EXIF orientation other than 1" in err
    assert json.loads((out / "poses" / "P1.json").read_text())["extra"]["status"] == "localized"


def _noisy_jpeg(path: Path) -> bytes:
    """A CAM-sized JPEG of noise at ``path`` (its scan data is most of the file); returns its bytes."""
    noise = np.random.default_rng(0).integers(0, 256, (CAM.height, CAM.width, 3), dtype=np.uint8)
    Image.fromarray(noise).save(path, quality=90)
    return path.read_bytes()


def _rows_by_name(out: Path) -> dict[str, dict[str, str]]:
    return {json.loads(r["meta_json"])["name"]: r for r in read_results(out / "results.csv")}


def test_an_unreadable_photo_is_a_miss_with_a_true_pose_else_skipped(box_flight, tmp_path, capsys):
    """A truncated JPEG (its header reads, its pixels do not), random bytes, an empty file and a folder
    named like a photo: each is found before anything runs, with a reason naming it; the readable photo
    is localized and written (pose, overlay, exports) instead of the run stopping at the first bad one.
    The two with a true pose (``--truth``) are misses of the run, in the recall's denominator (they were
    skipped, so that a flight lost no recall by its unreadable photos); the two without one are skipped."""
    images = box_flight["root"] / "images"
    data = _noisy_jpeg(images / "P0.JPG")
    (images / "P0.JPG").write_bytes(data[: len(data) * 2 // 3])
    (images / "P2.JPG").write_bytes(np.random.default_rng(1).bytes(3000))
    (images / "P3.JPG").write_bytes(b"")
    (images / "P4.JPG").mkdir()
    out = tmp_path / "out"
    code, stdout, err = run(capsys, *box_flight["argv"], "--out", out)
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["photos"] == 6 and summary["queries"] == 3 and summary["localized"] == 1
    assert summary["with_ground_truth"] == 3 and summary["recall_5m5deg"] == pytest.approx(100 / 3)
    skipped = summary["skipped_photos"]
    assert set(skipped) == {"P3.JPG", "P4.JPG", "P9.JPG"}
    assert "P3.JPG" in skipped["P3.JPG"] and "empty" in skipped["P3.JPG"]
    assert "P4.JPG" in skipped["P4.JPG"] and "not a file" in skipped["P4.JPG"]
    assert json.loads((out / "run.json").read_text())["skipped_photos"] == skipped
    rows = _rows_by_name(out)
    for name, why in (("P0.JPG", "truncated"), ("P2.JPG", "cannot read photo")):
        miss = rows[name]
        assert miss["status"] == "not_localized" and miss["reason"].startswith(REASON_UNREADABLE)
        assert str(box_flight["root"] / "images" / name) in miss["reason"] and why in miss["reason"]
        assert miss["err_xyz_m"] == "inf" and miss["true_x"] != ""
        record = json.loads((out / "poses" / f"{Path(name).stem}.json").read_text())
        assert record["status"] == "not_localized" and record["reason"] == miss["reason"]
    assert rows["P2.JPG"]["prior_x"] != "" and rows["P0.JPG"]["prior_err_m"] != ""  # priors from GPS_pose
    assert "6 photos: 1 localized, 2 not localized, 3 skipped" in stdout
    assert "truncated" in stdout and "Traceback" not in err
    assert json.loads((out / "poses" / "P1.json").read_text())["extra"]["status"] == "localized"
    assert (out / "overlays" / "P1.png").is_file() and not (out / "overlays" / "P0.png").exists()
    # Run again: the finished run is summarised, the same photos missed and skipped, nothing refused.
    code, stdout, _ = run(capsys, *box_flight["argv"], "--out", out)
    assert code == 0 and "6 photos: 1 localized, 2 not localized, 3 skipped" in stdout


def test_a_true_pose_file_that_cannot_be_read_skips_its_photo_saying_so(box_flight):
    """Audit s51, finding 11: a ``--truth`` entry that is there but cannot be read (here bytes that are no
    UTF-8 text) was taken as "no ground truth": the photo ran, left out of the recall without a word. Now
    it is skipped with the reason naming the file and what to do; a photo the truth does not list still
    runs without ground truth, and an unreadable photo's reason keeps its own file's too."""
    root = box_flight["root"]
    truth = sorted((root / "GT_pose").glob("P1*.txt"))[0]
    truth.write_bytes(b"\xff\xfe\x00 not a pose")
    data = _noisy_jpeg(root / "images" / "P0.JPG")  # P0: its photo truncated, its truth broken too
    (root / "images" / "P0.JPG").write_bytes(data[: len(data) * 2 // 3])
    (sorted((root / "GT_pose").glob("P0*.txt"))[0]).write_bytes(b"\xff\xfe")
    (sorted((root / "GT_pose").glob("P2*.txt"))[0]).unlink()  # P2: not in the truth at all
    (root / "masks" / "P2.png").unlink()
    save_labels_png(np.zeros((CAM.height, CAM.width), np.uint8), root / "masks" / "P2.png")
    _, inputs, skipped, _ = _box_spec(root, truth=str(root / "GT_pose")).resolved()
    assert [(i.name, i.truth_world) for i in inputs] == [("P2.JPG", None)]
    assert set(skipped) == {"P0.JPG", "P1.JPG", "P9.JPG"}
    why = skipped["P1.JPG"]
    assert why.startswith("its true pose cannot be used (") and str(truth) in why and "UTF-8" in why
    assert why.endswith(
        "fix its entry in the ground truth (truth=...), or remove it to run the photo without ground truth"
    )
    assert "truncated" in skipped["P0.JPG"] and "its true pose cannot be used" in skipped["P0.JPG"]


def test_a_mask_unreadable_only_when_read_in_full_is_that_photos_result_not_the_runs_end(
    box_flight, tmp_path, capsys
):
    """A mask PNG whose header reads (so the checks before the run pass) but whose body is truncated: that
    photo gets its own row and pose record naming the mask and why; the two good photos are localized and
    written, and the run exits 0 instead of stopping at the bad one. With a true pose (``--truth``) that
    photo is a miss of the run (it was skipped, out of the recall); without one it is skipped."""
    masks = box_flight["root"] / "masks"
    data = (masks / "P0.png").read_bytes()  # the photos' aspect: P2's own mask has another
    (masks / "P2.png").write_bytes(data[: len(data) * 2 // 3])
    out = tmp_path / "out"
    code, stdout, err = run(capsys, *box_flight["argv"], "--out", out)
    assert code == 0, err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["photos"] == 4 and summary["localized"] == 2 and summary["not_localized"] == 1
    assert summary["with_ground_truth"] == 3 and summary["recall_5m5deg"] == pytest.approx(200 / 3)
    assert set(summary["skipped_photos"]) == {"P9.JPG"}
    rows = _rows_by_name(out)
    assert set(rows) == {"P0.JPG", "P1.JPG", "P2.JPG"}
    reason = rows["P2.JPG"]["reason"]
    assert rows["P2.JPG"]["status"] == "not_localized" and reason.startswith(REASON_UNREADABLE)
    assert str(masks / "P2.png") in reason and "cannot read label image" in reason
    record = json.loads((out / "poses" / "P2.json").read_text())
    assert record["status"] == "not_localized" and record["reason"] == reason
    for stem in ("P0", "P1"):
        assert json.loads((out / "poses" / f"{stem}.json").read_text())["extra"]["status"] == "localized"
        assert (out / "overlays" / f"{stem}.png").is_file()
    assert "4 photos: 2 localized, 1 not localized, 1 skipped" in stdout
    assert "not localized (input file cannot be read: " in stdout and "P2.png" in stdout
    # Run again: the finished run is summarised the same, nothing redone.
    code, again, _ = run(capsys, *box_flight["argv"], "--out", out)
    assert code == 0 and "4 photos: 2 localized, 1 not localized, 1 skipped" in again
    # Without --truth the photo has no true pose: skipped, out of the metrics, as before.
    no_truth = box_flight["argv"][: box_flight["argv"].index("--truth")]
    code, plain_run, err = run(capsys, *no_truth, "--out", tmp_path / "no_truth", "--no-overlays")
    assert code == 0, err
    skipped = json.loads((tmp_path / "no_truth" / "summary.json").read_text())["skipped_photos"]
    assert "cannot read label image" in skipped["P2.JPG"]
    assert _rows_by_name(tmp_path / "no_truth")["P2.JPG"]["status"] == "skipped"
    assert "4 photos: 2 localized, 0 not localized, 2 skipped" in plain_run
    # The mask fixed and its row deleted, a run again redoes that photo alone.
    (masks / "P2.png").write_bytes(data)
    lines = (out / "results.csv").read_text().splitlines(keepends=True)
    (out / "results.csv").write_text("".join(x for x in lines if '"name"": ""P2.JPG""' not in x))
    code, _, err = run(capsys, *box_flight["argv"], "--out", out)
    assert code == 0, err
    assert json.loads((out / "summary.json").read_text())["skipped_photos"].keys() == {"P9.JPG"}
    redone = json.loads((out / "poses" / "P2.json").read_text())
    assert redone.get("extra", redone)["status"] != "skipped"  # localized or not, on the fixed mask


def test_a_run_whose_every_photo_is_unreadable_stops_in_one_line(box_flight, tmp_path, capsys):
    for photo in (box_flight["root"] / "images").iterdir():
        photo.write_bytes(b"\xff\xd8\xff")  # a JPEG's first bytes, nothing after
    out = tmp_path / "out"
    code, _, err = run(capsys, *box_flight["argv"], "--out", out)
    last = err.strip().splitlines()[-1]
    assert code == 2 and last.startswith("semcityloc: error:") and "Traceback" not in err
    assert "no photo can be localized" in last and "P0.JPG: cannot read photo" in last


def test_a_run_undistorts_the_masks_of_a_distorting_lens(box_flight, tmp_path, capsys):
    """Masks in a wide lens's distorted pixels: right with the lens in the intrinsics, off without."""
    root = box_flight["root"]
    lens = LensDistortion(k1=-0.27, k2=0.11, p1=0.0008, p2=-0.0003)
    for stem in ("P0", "P1"):
        mask = root / "masks" / f"{stem}.png"
        save_labels_png(distort_image(load_labels_png(mask), CAM, lens, fill=IGNORE, nearest=True), mask)
    (tmp_path / "lens.json").write_text(json.dumps({**CAM.as_dict(), **lens.as_dict()}))
    argv = [str(a) for a in box_flight["argv"]]
    at = argv.index("--intrinsics") + 1

    def errors(intrinsics, out) -> list[float]:
        argv[at] = str(intrinsics)
        assert run(capsys, *argv, "--out", tmp_path / out, "--no-overlays")[0] == 0
        rows = read_results(tmp_path / out / "results.csv")
        return [float(r["err_xyz_m"]) for r in rows if json.loads(r["meta_json"])["name"] != "P2.JPG"]

    with_lens = errors(tmp_path / "lens.json", "with_lens")
    record = json.loads((tmp_path / "with_lens" / "poses" / "P0.json").read_text())["extra"]
    assert record["lens_distortion"] == lens.as_dict()
    # The COLMAP export describes the photos as they are: their camera with its lens (OPENCV).
    (line,) = [
        r
        for r in (tmp_path / "with_lens" / "colmap" / "cameras.txt").read_text().splitlines()
        if r[:1] != "#"
    ]
    assert line.split()[1] == "OPENCV" and read_lens(line) == (CAM, lens)
    as_pinhole = errors(root / "intrinsic", "as_pinhole")
    assert max(with_lens) < 0.5 and np.mean(as_pinhole) > 2 * np.mean(with_lens), (with_lens, as_pinhole)


def test_the_focal_length_is_estimated_only_when_asked_or_approximate(box_flight, tmp_path, capsys):
    """--calibrate-focal on: too few oblique photos here, so no estimate, and the run says why (in the
    notes and in each pose file); auto (the default) leaves a calibration file's camera alone."""
    argv = [*box_flight["argv"], "--no-overlays"]
    code, _, err = run(capsys, *argv, "--out", tmp_path / "on", "--calibrate-focal", "on")
    assert code == 0
    record = json.loads((tmp_path / "on" / "poses" / "P0.json").read_text())["extra"]
    assert record["focal_estimate"]["scale"] is None and "need 5" in record["focal_estimate"]["reason"]
    assert "the focal length of 2 photos could not be estimated: 1 oblique images" in err
    assert json.loads((tmp_path / "on" / "run.json").read_text())["calibrate_focal"] == "on"
    code, _, err = run(capsys, *argv, "--out", tmp_path / "auto")
    record = json.loads((tmp_path / "auto" / "poses" / "P0.json").read_text())["extra"]
    assert code == 0 and record["focal_estimate"] is None and "focal length of" not in err


def test_lossy_masks_are_refused_unless_forced(box_flight, tmp_path, capsys):
    """A lossy mask's format is in its header: refused before the run, so a flight of JPEG masks (nothing
    else left) stops in one line naming the flag. Forced, the masks are read in full when their photos'
    turn comes; the ids the compression made along the edges are then named, photo by photo, and the run
    completes with each photo a miss for that reason (they have true poses: ``--truth``)."""
    for mask in (box_flight["root"] / "masks").glob("P[01].png"):  # JPEG content, the .png name kept
        ids = np.array(Image.open(mask))  # the palette PNG's class ids
        Image.fromarray(ids, mode="L").save(mask, format="JPEG", quality=95)
    argv = [*box_flight["argv"], "--no-overlays"]
    code, _, err = run(capsys, *argv, "--out", tmp_path / "refused")
    last = err.strip().splitlines()[-1]  # the error, one line
    assert (
        code == 2
        and last.startswith("semcityloc: error:")
        and "no photo can be localized" in last
        and "a lossy format" in last
        and "--allow-lossy-mask" in last
    )
    # Forced, the masks are read; the ids the compression made along the edges are then named per photo.
    code, stdout, err = run(capsys, *argv, "--out", tmp_path / "forced", "--allow-lossy-mask")
    assert code == 1 and "a lossy format" not in err and "Traceback" not in err  # none localized
    rows = _rows_by_name(tmp_path / "forced")
    for name in ("P0", "P1"):
        reason = rows[f"{name}.JPG"]["reason"]
        assert reason.startswith(REASON_UNREADABLE) and f"{name}.png" in reason
        assert "invalid class ids" in reason
    assert "4 photos: 0 localized, 3 not localized, 1 skipped" in stdout  # P2: its mask's aspect
    assert json.loads((tmp_path / "forced" / "run.json").read_text())["allow_lossy_mask"] is True


def test_a_jpeg_mask_is_found_when_forced_and_named_when_not(box_flight, tmp_path, capsys):
    """Stop 50's audit: ``<stem>.jpg`` masks were never found by ``run``, even with --allow-lossy-mask
    (``no mask ... (looked for <stem>.png/.npy)``, the JPEG there unmentioned). Now forced, the JPEG is the
    photo's mask; not forced, the photo is skipped naming the JPEG and the flag. A mask named after the
    photo's whole file name (``P1.JPG.png``) is found either way."""
    masks = box_flight["root"] / "masks"
    ids = np.array(Image.open(masks / "P0.png"))
    Image.fromarray(ids, mode="L").save(masks / "P0.jpg", quality=95)
    (masks / "P0.png").unlink()
    (masks / "P1.png").rename(masks / "P1.JPG.png")
    no_truth = box_flight["argv"][: box_flight["argv"].index("--truth")]
    code, _, err = run(capsys, *no_truth, "--out", tmp_path / "plain", "--stop-after", "0")
    assert code == 0, err
    config = json.loads((tmp_path / "plain" / "run.json").read_text())
    assert config["query_names"] == ["P1.JPG"]
    said = config["skipped_photos"]["P0.JPG"]
    assert said.startswith(f"{masks}: no mask for image 'P0' (looked for P0.png/.npy or P0.JPG.png/.npy)")
    assert "but P0.jpg, a lossy format" in said and "--allow-lossy-mask" in said
    code, _, err = run(
        capsys, *no_truth, "--out", tmp_path / "forced", "--stop-after", "0", "--allow-lossy-mask"
    )
    assert code == 0, err
    assert json.loads((tmp_path / "forced" / "run.json").read_text())["query_names"] == ["P0.JPG", "P1.JPG"]


def test_a_lossy_mask_refusal_names_the_specs_own_keyword(box_flight, tmp_path):
    """Stop 55 audit: a ``PhotoSpec`` (or ``DatasetSpec``) whose mask was a JPEG was told to pass
    ``allow_lossy=True``, the keyword of the functions below it, which a spec does not take: it has
    ``allow_lossy_mask``. Each refusal a spec's caller meets (a ``<stem>.jpg`` beside no other mask, a
    ``.png`` of JPEG content, read before the run or when its photo's turn comes) names that keyword; the
    command line still prints ``--allow-lossy-mask``, and the functions themselves still name theirs."""
    from semcityloc.benchmark.dataset_source import read_inputs
    from semcityloc.errors import LossyMaskError, as_flags
    from semcityloc.io.images import read_mask_file
    from semcityloc.perception.files import find_mask

    masks = box_flight["root"] / "masks"
    ids = np.array(Image.open(masks / "P0.png"))
    Image.fromarray(ids, mode="L").save(masks / "P0.jpg", quality=95)
    (masks / "P0.png").unlink()
    Image.fromarray(np.array(Image.open(masks / "P1.png")), mode="L").save(masks / "P1.png", format="JPEG")
    _, _, skipped, _ = _box_spec(box_flight["root"]).resolved()
    for name in ("P0.JPG", "P1.JPG"):
        assert "allow_lossy_mask=True" in skipped[name] and "allow_lossy=True" not in skipped[name], skipped
        assert "--allow-lossy-mask" in as_flags(skipped[name])
    with pytest.raises(LossyMaskError, match=r"allow_lossy_mask=True forces it"):  # a DatasetSpec's query
        read_inputs(CAM, masks / "P1.png", None, False)
    with pytest.raises(LossyMaskError, match=r"\(allow_lossy=True forces it"):
        read_mask_file(masks / "P1.png")
    with pytest.raises(LossyMaskError, match="or allow_lossy=True uses it"):
        find_mask(masks, "P0.JPG", False)


def _drop_column(path: Path, column: str) -> None:
    """Rewrite a results.csv without ``column``: the layout of a version before it was added."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
        header = [c for c in rows[0] if c != column]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, header, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def test_dropped_depth_is_in_the_rows_and_an_old_results_file_resumes(box_flight, tmp_path, capsys):
    """A photo's depth dropped as noise is named in its row's ``warnings`` (empty for the photo whose
    depth was used); a results.csv of the version before that column resumes and is reported on."""
    root = box_flight["root"]
    model = load_city_model(root / "city.obj", cache=False)
    truth = read_pose(root / "GT_pose" / "P0_pose.txt")
    clean = Renderer(model, engine="numba").render(CAM, model.pose_to_local(truth), depth=True).depth[0]
    (root / "depth").mkdir()
    np.save(root / "depth" / "P0.npy", clean.astype(np.float32))
    noise = np.random.default_rng(0).uniform(1.0, 100.0, (CAM.height, CAM.width)).astype(np.float32)
    np.save(root / "depth" / "P1.npy", noise)
    out = tmp_path / "out"
    argv = [*box_flight["argv"], "--depth", root / "depth", "--out", out, "--no-overlays"]
    assert run(capsys, *argv, "--stop-after", "1")[0] == 0
    _drop_column(out / "results.csv", "warnings")  # the first photo's row, as an earlier version wrote it
    assert "warnings" not in (out / "results.csv").read_text().split("\n", 1)[0]
    assert make_report([out], tmp_path / "report_old").markdown.is_file()  # reported on as it is
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    text = (out / "results.csv").read_text()
    assert text.split("\n", 1)[0] == ",".join(COLUMNS)  # brought up to this version's columns
    rows = {r["query_id"]: r for r in read_results(out / "results.csv")}
    assert len(rows) == 3 and rows["q0000"]["warnings"] == "" and rows["q0000"]["status"] == "localized"
    assert rows["q0001"]["warnings"].startswith("depth map dropped: it looks like noise")
    assert json.loads((out / "poses" / "P1.json").read_text())["extra"]["warnings"] == [
        rows["q0001"]["warnings"]
    ]
    assert main(["report", str(out), "--out", str(tmp_path / "report"), "--no-html"]) == 0


def test_run_without_perception_or_with_bad_options_is_one_line(box_flight, tmp_path, capsys):
    base = [a for a in box_flight["argv"] if a not in ("--masks", box_flight["root"] / "masks")]
    code, _, err = run(capsys, *base, "--out", tmp_path / "o")
    assert code == 2 and err.count("\n") == 1
    assert "no perception source" in err and "dinov3-dpt" in err and "train-segmenter" in err
    code, _, err = run(capsys, *box_flight["argv"], "--prior-sigma", "xy=five", "--out", tmp_path / "o")
    assert code == 2 and "not a number" in err and err.count("\n") == 1
    code, _, err = run(capsys, "run", tmp_path / "absent", "--city", "generated", "--masks", tmp_path)
    assert code == 2 and "no such images folder" in err
    code, _, err = run(capsys, *box_flight["argv"], "--map-eaves", "-1", "--out", tmp_path / "o")
    assert code == 2 and "map_eaves_m must be a number of metres in [0, 3]" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_a_run_whose_backend_fails_to_load_does_not_block_the_corrected_command(
    box_flight, tmp_path, capsys, monkeypatch
):
    """A segmentation backend without its weights fails before the first photo: the folder keeps nothing of
    that run, so the same command with --masks instead is not refused as "another benchmark run" (stop
    50)."""

    def no_weights(name, **options):
        raise MissingWeightsError(f"no trained segmentation head for {name}; give --backend-option head=DIR")

    monkeypatch.setattr(photo_source, "get_segmentation_backend", no_weights)
    out = tmp_path / "out"
    base = [a for a in box_flight["argv"] if a not in ("--masks", box_flight["root"] / "masks")]
    code, _, err = run(capsys, *base, "--seg-backend", "files", "--no-overlays", "--out", out)
    assert code == 2 and "no trained segmentation head" in err and err.count("\n") == 1
    assert not out.exists()
    code, stdout, err = run(capsys, *box_flight["argv"], "--no-overlays", "--out", out)
    assert code == 0 and "another benchmark run" not in err, err
    assert "4 photos: 2 localized, 1 not localized, 1 skipped" in stdout


def _fake_head(folder: Path, weights: bytes, classes=("ground", "wall", "roof")) -> Path:
    """A head folder whose head.json reads (``weight_files.read_head_spec``), of ``classes``, and whose
    head.safetensors holds ``weights`` (the backend itself is replaced in the tests using it)."""
    folder.mkdir(parents=True, exist_ok=True)
    spec = {"format": "semcityloc-segmentation-head", "version": 1, "backbone": {"kind": "mobilenetv2"}}
    spec.update(head={"type": "fpn", "params": {}}, classes=list(classes), input_size=[64, 64], stride=32)
    (folder / "head.json").write_text(json.dumps(spec))
    (folder / "head.safetensors").write_bytes(weights)
    return folder


def test_a_head_retrained_at_the_same_path_is_another_run_and_a_missing_one_is_said_first(
    box_flight, tmp_path, capsys, monkeypatch
):
    """Stop 56 (audit B 7): run.json kept the head's path only, so a head retrained in place left the old
    poses reported as this head's; its files' fingerprints are now part of the run. A missing head is said
    before the city model loads (it was said after)."""
    from semcityloc.perception.files import FilesSegmentation

    masks = box_flight["root"] / "masks"
    monkeypatch.setattr(photo_source, "get_segmentation_backend", lambda name, **o: FilesSegmentation(masks))
    head = _fake_head(tmp_path / "head", b"first head")
    out = tmp_path / "out"
    base = [a for a in box_flight["argv"] if a not in ("--masks", masks)]
    argv = [*base, "--seg-backend", "mobilenetv2", "--backend-option", f"head={head}", "--no-overlays"]
    code, stdout, err = run(capsys, *argv, "--out", out)
    assert code == 0 and "3 localized" in stdout, err
    weights = json.loads((out / "run.json").read_text())["perception_weights"]
    assert weights["head"]["sha256"] == sha256(b"first head").hexdigest() and "head_spec" in weights
    code, _, err = run(capsys, *argv, "--out", out)  # the same head: the finished run, not refused
    assert code == 0, err
    _fake_head(head, b"the head trained again")
    code, _, err = run(capsys, *argv, "--out", out)
    assert code == 2 and "arguments differ: perception_weights.head.bytes" in err and err.count("\n") == 1
    assert "perception_weights.head.sha256" in err and "--overwrite" in err

    def no_model(*args, **kwargs):
        raise AssertionError("the city model was loaded")

    monkeypatch.setattr(PhotoSpec, "load_model", no_model)
    argv[argv.index(f"head={head}")] = f"head={tmp_path / 'absent'}"
    code, _, err = run(capsys, *argv, "--out", tmp_path / "out2")
    assert code == 2 and "absent: no trained segmentation head" in err and err.count("\n") == 1, err


HEAD_WITHOUT_ROOF = (
    "semcityloc: warning: the head in {} predicts no roof (its head.json classes: ground, wall): the "
    "localizer's score needs roof and wall, which a head trained with --classes that left them out cannot "
    "give; its poses will be poor or missing: train a head with them\n"
)


def test_a_head_without_roof_or_wall_is_said_once(box_flight, tmp_path, capsys, monkeypatch):
    """Stop 56: a head trained with ``--classes ground,wall`` localized without a word that the
    localizer's score needs roof and wall (``localize`` says it too: ``test_cli.py``)."""
    from semcityloc.perception.files import FilesSegmentation

    masks = box_flight["root"] / "masks"
    monkeypatch.setattr(photo_source, "get_segmentation_backend", lambda name, **o: FilesSegmentation(masks))
    head = _fake_head(tmp_path / "head", b"a head", classes=("ground", "wall"))
    base = [a for a in box_flight["argv"] if a not in ("--masks", masks)]
    argv = [*base, "--seg-backend", "mobilenetv2", "--backend-option", f"head={head}", "--no-overlays"]
    code, _, err = run(capsys, *argv, "--out", tmp_path / "out")
    assert code == 0 and err.count(HEAD_WITHOUT_ROOF.format(head)) == 1 and err.count("head.json") == 1, err


def test_run_given_a_photo_instead_of_its_folder_says_it_is_a_file(tmp_path, capsys):
    """Stop 50's audit: ``semcityloc run PHOTO.JPG`` said "no such images folder" of a file that is there."""
    photo = tmp_path / "P0.JPG"
    Image.new("RGB", (16, 12)).save(photo)
    code, _, err = run(
        capsys, "run", photo, "--city", "generated", "--masks", tmp_path, "--out", tmp_path / "o"
    )
    assert code == 2 and err.count("\n") == 1 and "no such" not in err
    assert (
        f"{photo}: is a file, not a folder of photos" in err
        and "('semcityloc localize --image' takes one image)" in err
    )
    assert not (tmp_path / "o").exists()
    with pytest.raises(InputFileError, match="is a file, not a folder of photos"):
        photos.list_images(photo)


def test_a_run_searches_the_map_with_the_eaves_it_is_given(box_flight, tmp_path, capsys):
    out = tmp_path / "out"
    argv = [*box_flight["argv"], "--out", out, "--no-overlays", "--map-eaves", "0.3", "--map-eaves-flat"]
    code, _, _ = run(capsys, *argv)
    localizer = json.loads((out / "run.json").read_text())["localizer"]
    assert code == 0 and localizer["map_eaves_m"] == 0.3 and localizer["map_eaves_flat_roofs"] == "on"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["localized"] == 2  # the box city's flat roofs, 0.3 m wider, still hold both photos
    # The eaves are part of what the run is: the same folder with the default map is refused.
    code, _, err = run(capsys, *box_flight["argv"], "--out", out, "--no-overlays")
    assert code == 2 and "other benchmark run" in err


# ------------------------------------------------------------------------------ a tile store of one box
@pytest.fixture
def store_flight(tmp_path) -> dict:
    """Two nadir photos over a store of one CityJSON box (EPSG:25832, built without --lod / --crs):
    LoD-Loc priors and intrinsics in the store's CRS, empty masks (the runs here localize nothing)."""
    (tmp_path / "tiles").mkdir()
    _cityjson_box(tmp_path / "tiles" / "a.json", 25832, 390000.0, 5810000.0)
    build_store(tmp_path / "tiles", tmp_path / "store")
    root = tmp_path / "flight"
    (root / "images").mkdir(parents=True)
    queries = []
    for i in range(2):
        name = f"P{i}.JPG"
        prior = Pose.from_xyz_rpy([390005.0 + i, 5810004.0, 120.0], 0.0, 0.0, 0.0)
        queries.append(LodLocQuery(name, "flight", CAM, prior_pose_world=prior))
        Image.new("RGB", (CAM.width, CAM.height)).save(root / "images" / name)
        save_labels_png(np.zeros((CAM.height, CAM.width), np.uint8), root / "masks" / f"P{i}.png")
    write_lodloc_scene(root, queries)
    argv = ["run", root / "images", "--city", tmp_path / "store", "--priors", root / "GPS_pose"]
    argv += ["--intrinsics", root / "intrinsic", "--masks", root / "masks"]
    return {"root": root, "store": tmp_path / "store", "argv": argv}


def test_a_photo_run_opens_its_store_once(store_flight, monkeypatch):
    """The store is opened once per run: its frame, the flight's tiles, its identity in run.json and the
    localizer's parts per photo all come from the same opened store."""
    opened = []
    real_open = TileStore.open.__func__

    def counting_open(cls, path, budget_mb=None):
        opened.append(path)
        return real_open(cls, path, budget_mb)

    monkeypatch.setattr(TileStore, "open", classmethod(counting_open))
    root = store_flight["root"]
    spec = PhotoSpec(
        images=str(root / "images"),
        city=str(store_flight["store"]),
        priors=str(root / "GPS_pose"),
        intrinsics=str(root / "intrinsic"),
        masks=str(root / "masks"),
    )
    config = spec.run_config()
    source = spec.open_source(config)
    assert len(opened) == 1
    assert source.tile_store is spec.resolved().store and source.map_model.num_triangles == 12
    assert config["city_sha256"] == source.tile_store.sha256 and len(source) == 2


@pytest.mark.parametrize(
    ("option", "said"),
    [
        # a LoD no tile holds: as a single file without it (stop 56; was "built with lod=None")
        (
            ("--lod", "1"),
            "no LoD 1 building geometry; LoDs present: 2 (the store was built with each building's",
        ),
        (("--crs", "EPSG:25833"), "the store was built with crs=ETRS89 / UTM zone 32N; build it again with "),
    ],
)
def test_a_photo_run_refuses_a_store_built_with_another_lod_or_crs(
    store_flight, tmp_path, capsys, option, said
):
    code, _, err = run(capsys, *store_flight["argv"], *option, "--out", tmp_path / "o", "--no-overlays")
    assert code == 2 and err.count("\n") == 1 and err.startswith("semcityloc: error:")
    assert said in err and "None" not in err
    assert not (tmp_path / "o" / "results.csv").exists()


@pytest.mark.parametrize("crs", ["EPSG:25832", "urn:ogc:def:crs:EPSG::25832"])
def test_a_photo_run_takes_a_crs_that_names_the_stores_own(store_flight, tmp_path, capsys, crs):
    """--crs naming the CRS the store's tiles are in changes nothing: it is not refused."""
    code, _, err = run(capsys, *store_flight["argv"], "--crs", crs, "--out", tmp_path / "o", "--no-overlays")
    assert code == 1, err  # it ran: its empty masks localize nothing (exit 1 since stop 52)
    assert (tmp_path / "o" / "results.csv").exists()


# ------------------------------------------------------------------------------ Berlin, DJI EXIF priors
def _dji_angles_true_north(crs, lon, lat, pose) -> tuple[float, float, float]:
    """DJI gimbal (yaw from TRUE north, pitch, roll) of a pose in a projected CRS, with pyproj's meridian
    convergence (independent of the library's own geodesy)."""
    from semcityloc.geometry.conventions import dji_gimbal_angles

    convergence = pyproj.Proj(crs).get_factors(lon, lat).meridian_convergence  # grid north from true north
    yaw, pitch, roll = dji_gimbal_angles(pose).tolist()
    return yaw + convergence, pitch, roll


@pytest.fixture(scope="module")
def berlin_run(tmp_path_factory):
    """A simulated DJI flight over Berlin LoD2 (EPSG:25833): photos with DJI XMP / EXIF (single-point GNSS,
    priors metres off), oracle masks; one photo sees no building, one has no GPS. Run once, then checked."""
    gml = shared_file(BERLIN)
    root = tmp_path_factory.mktemp("berlin")
    (root / "photos").mkdir()
    model = load_city_model(gml)
    crs = pyproj.CRS("EPSG:25833")
    to_wgs = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    centre = model.origin + [0.0, 0.0, 0.0]
    views = {  # name: (position in the CRS, grid yaw, DJI pitch); the last looks at the sky
        "DJI_0001.JPG": (centre + [-60.0, -40.0, 150.0], 60.0, -45.0),
        "DJI_0002.JPG": (centre + [100.0, 20.0, 170.0], -20.0, -88.0),
        "DJI_0003.JPG": (centre + [0.0, 0.0, 150.0], 10.0, 30.0),
    }
    size, focal_35mm = (640, 480), 24
    truths = {}
    for i, (name, (position, grid_yaw, pitch)) in enumerate(views.items()):
        truth = pose_from_dji(position, grid_yaw, pitch, 0.0)
        truths[name] = truth
        prior_position = position + [4.0, -3.0, 3.0]
        lon, lat = to_wgs.transform(prior_position[0], prior_position[1])
        yaw, pitch_, roll = _dji_angles_true_north(crs, lon, lat, truth)
        fields = dict(
            GpsLatitude=f"{lat:+.10f}",
            GpsLongitude=f"{lon:+.10f}",
            AbsoluteAltitude=f"{prior_position[2]:+.3f}",
            GimbalYawDegree=f"{yaw + 2.0:+.6f}",
            GimbalPitchDegree=f"{pitch_:+.6f}",
            GimbalRollDegree=f"{roll:+.6f}",
            AltitudeType="GpsFusionAlt",
            RtkFlag="16",
        )
        photo = dji_jpeg(root / "photos" / name, xmp_packet(**fields), size=size, focal_35mm=focal_35mm)
        camera = camera_from_exif(read_dji_metadata(photo))
        labels = oracle_labels(model, camera, truth)
        if i == 0:  # masks at any size with the photo's aspect
            labels = labels[::2, ::2]
        save_labels_png(labels, root / "masks" / f"{Path(name).stem}.png")
    dji_jpeg(root / "photos" / "NOGPS.JPG", None, size=size, focal_35mm=focal_35mm)
    save_labels_png(np.zeros((480, 640), np.uint8), root / "masks" / "NOGPS.png")
    out = root / "out"
    code = main(
        ["run", str(root / "photos"), "--city", str(gml), "--masks", str(root / "masks"), "--out", str(out)]
    )
    assert code == 0
    return {"out": out, "truths": truths, "crs": crs, "model": model}


def test_berlin_run_localizes_from_exif_priors_and_counts_what_it_did(berlin_run):
    out = berlin_run["out"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["photos"] == 4 and summary["localized"] == 2 and summary["not_localized"] == 1
    assert (
        list(summary["skipped_photos"]) == ["NOGPS.JPG"]
        and "latitude" in summary["skipped_photos"]["NOGPS.JPG"]
    )
    assert summary["not_localized_reasons"] == {"query mask has no building pixels": 1}
    # Single-point GNSS photos: how their heights were taken is said once for the run.
    assert [n for n in summary["outputs"]["notes"] if "barometric" in n] != []
    # ... and that their cameras are the EXIF's approximate 35 mm focal length.
    assert [n for n in summary["outputs"]["notes"] if n.startswith("3 of 3 photos have no calibrated")] != []
    for name in ("DJI_0001", "DJI_0002"):
        pose = read_pose(out / "poses" / f"{name}.json")
        truth = berlin_run["truths"][f"{name}.JPG"]
        assert center_error_m(pose, truth) < 1.5 and rotation_error_deg(pose, truth) < 1.5
        record = json.loads((out / "poses" / f"{name}.json").read_text())
        assert record["frame"] == "crs" and record["extra"]["crs"] == "EPSG:25833"
        assert (
            record["extra"]["prior_source"] == "exif"
            and "no RTK" in record["extra"]["prior_uncertainty"]["source"]
        )
        assert record["extra"]["intrinsics_source"] == INTRINSICS_35MM
        assert (out / "overlays" / f"{name}.png").is_file()
    refused = json.loads((out / "poses" / "DJI_0003.json").read_text())
    assert refused["status"] == "not_localized" and "position" not in refused
    assert refused["prior"]["crs"] == "EPSG:25833"


def test_berlin_geotags_go_back_to_the_model_crs_within_a_centimetre(berlin_run):
    out, crs = berlin_run["out"], berlin_run["crs"]
    with open(out / "geotags.csv", newline="") as fh:
        rows = {r["image"]: r for r in csv.DictReader(fh)}
    assert set(rows) == {"DJI_0001.JPG", "DJI_0002.JPG", "DJI_0003.JPG"}
    to_crs = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    angles = {}
    for name, r in rows.items():
        record = json.loads((out / "poses" / f"{Path(name).stem}.json").read_text())
        lon, lat, h = float(r["longitude"]), float(r["latitude"]), float(r["height_m"])
        x, y = to_crs.transform(lon, lat)
        if r["source"] == "semcityloc":
            expected, pose = (
                np.array(record["position"]),
                read_pose(out / "poses" / f"{Path(name).stem}.json"),
            )
            # The accuracy is the pose's own: its covariance's per-axis horizontal and vertical sigma.
            sx, sy, sz = record["extra"]["covariance"]["sigma"][:3]
            assert float(r["accuracy_xy_m"]) == pytest.approx(np.hypot(sx, sy) / np.sqrt(2), abs=1e-3)
            assert float(r["accuracy_z_m"]) == pytest.approx(sz, abs=1e-3)
        else:  # not localized: the photo keeps its prior, with its uncertainty as accuracy
            assert r["source"].startswith("prior (not localized") and float(r["accuracy_xy_m"]) == 5.0
            expected, pose = np.array(record["prior"]["position"]), read_pose(json.dumps(record["prior"]))
        assert np.abs(np.array([x, y, h]) - expected).max() < 0.01, name
        # The angles, Pix4D's / Metashape's / ODM's yaw, pitch, roll (yaw from true north, pitch 0 = nadir;
        # DJI's before stop 52): the same rotation back, and geo.txt's numbers.
        convergence = pyproj.Proj(crs).get_factors(lon, lat).meridian_convergence
        yaw, pitch, roll = (float(r[k]) for k in ("pix4d_yaw_deg", "pix4d_pitch_deg", "pix4d_roll_deg"))
        R = odm_world_from_cam(yaw - convergence, pitch, roll)
        back = Pose.from_rotation_center(R, np.array([x, y, h]))
        assert float(rotation_error_deg(back, pose)) < 1e-4, name
        angles[name] = (yaw, pitch, roll)
    lines = (out / "geo.txt").read_text().splitlines()
    assert lines[0] == "EPSG:25833" and len(lines) == 3
    for line in lines[1:]:
        name, x, y, z = line.split()[:4]
        position = read_pose(out / "poses" / f"{Path(name).stem}.json").center
        np.testing.assert_allclose([float(x), float(y), float(z)], position, atol=1e-3)
        np.testing.assert_allclose([float(v) for v in line.split()[4:7]], angles[name], atol=1e-5)
        horizontal, vertical = (float(v) for v in line.split()[7:9])  # ODM's accuracy columns
        assert horizontal == pytest.approx(float(rows[name]["accuracy_xy_m"]), abs=1e-3)
        assert vertical == pytest.approx(float(rows[name]["accuracy_z_m"]), abs=1e-3)


def test_berlin_geojson_and_colmap_parse_and_agree(berlin_run):
    out = berlin_run["out"]
    doc = json.loads((out / "cameras.geojson").read_text())
    assert doc["type"] == "FeatureCollection" and len(doc["features"]) == 6
    points = [f for f in doc["features"] if f["geometry"]["type"] == "Point"]
    for f in points:
        lon, lat = f["geometry"]["coordinates"]
        assert 13.3 < lon < 13.5 and 52.4 < lat < 52.6
    assert {f["properties"]["pose"] for f in points} == {"semcityloc estimate", "prior"}
    model = read_model(out / "colmap")
    poses = model.poses()
    assert set(poses) == {"DJI_0001.JPG", "DJI_0002.JPG"}
    for name, (camera, pose) in poses.items():
        assert (camera.width, camera.height) == (640, 480)
        assert center_error_m(pose, read_pose(out / "poses" / f"{Path(name).stem}.json")) < 1e-6


# ------------------------------------------------------------------------------ the two real images
@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    """Both real images in one folder (each beside its own GPS prior, intrinsics and GT), masks: the oracle
    labels at GT degraded by the 'trained' segmentation preset, the oblique one at 1024 px wide."""
    roots = [shared_file(name) for name in REAL]
    root = tmp_path_factory.mktemp("real")
    for sub in ("photos", "GPS_pose", "GT_pose", "intrinsic", "masks"):
        (root / sub).mkdir()
    ds = read_lodloc(roots[0].parent)  # a folder of scenes: both images, the one LoD1 model
    model = ds.load_model()
    for i, q in enumerate(sorted(ds.queries, key=lambda q: q.name)):
        scene = q.image_path.parent.parent
        shutil.copy(q.image_path, root / "photos" / q.name)
        for sub, suffix in (("GPS_pose", "pose"), ("GT_pose", "pose"), ("intrinsic", "intrinsic")):
            shutil.copy(scene / sub / f"{q.stem}_{suffix}.txt", root / sub)
        camera = working_camera(q.camera)
        clean = oracle_labels(model, camera, q.gt_pose_world)
        noisy = simulate_segmentation(
            np.where(clean == IGNORE, 0, clean).astype(np.uint8),
            "trained",
            np.random.default_rng([0, i, STREAM_SEG]),
        )
        noisy[clean == IGNORE] = IGNORE
        save_labels_png(noisy, root / "masks" / f"{q.stem}.png")
    out = root / "out"
    argv = ["run", root / "photos", "--city", ds.model_path, "--priors", root / "GPS_pose"]
    argv += ["--intrinsics", root / "intrinsic", "--truth", root / "GT_pose", "--masks", root / "masks"]
    assert main([str(a) for a in [*argv, "--out", out]]) == 0
    return {"out": out, "root": root}


def test_run_over_both_real_images_writes_files_that_parse(real_run):
    out = real_run["out"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["photos"] == 2 and summary["queries"] == 2 and summary["with_ground_truth"] == 2
    assert summary["localized"] == 2 and summary["skipped_photos"] == {}
    model = read_model(out / "colmap")
    assert set(model.poses()) == {f"{THERMAL}.JPG", f"{OBLIQUE}.JPG"}
    assert {c.width for c, _ in model.poses().values()} == {640, 2325}
    assert not (out / "cameras.geojson").exists()  # no CRS: no GeoJSON (its coordinates are WGS 84)
    for stem in (THERMAL, OBLIQUE):
        record = json.loads((out / "poses" / f"{stem}.json").read_text())
        assert (
            record["extra"]["perception"] == "masks"
            and record["extra"]["prior_source"] == "pose file GPS_pose"
        )
        with Image.open(out / "overlays" / f"{stem}.png") as im:
            assert im.size[0] > 1000  # two panels: estimate and prior
    assert not (out / "geotags.csv").exists()  # UAVD4L-LoD's frame has no published CRS


def _errors(real_run, stem):
    pose = read_pose(real_run["out"] / "poses" / f"{stem}.json")
    truth = read_pose(real_run["root"] / "GT_pose" / f"{stem}_pose.txt")
    return float(center_error_m(pose, truth)), float(rotation_error_deg(pose, truth))


def test_oblique_real_image_within_1m_1deg_from_its_gps_prior(real_run):
    err_m, err_deg = _errors(real_run, OBLIQUE)
    print(f"oblique, degraded masks, default settings: {err_m:.2f} m, {err_deg:.2f} deg")
    assert err_m < 1.0 and err_deg < 1.0


def test_thermal_real_image_within_2_5m_1deg_from_its_gps_prior(real_run):
    """2.5 m: the thermal image's tilt-shift ridge (tests/test_real_uav_both.py says why and what was
    measured); the prior is 20.7 m off."""
    err_m, err_deg = _errors(real_run, THERMAL)
    print(f"thermal, degraded masks, default settings: {err_m:.2f} m, {err_deg:.2f} deg")
    assert err_m < 2.5 and err_deg < 1.0


def _box_spec(root: Path, **options) -> PhotoSpec:
    """The ``PhotoSpec`` of ``box_flight``'s photos, their masks and priors (``options``: the others, e.g.
    ``truth``)."""
    return PhotoSpec(
        images=str(root / "images"),
        city=str(root / "city.obj"),
        priors=str(root / "GPS_pose"),
        intrinsics=str(root / "intrinsic"),
        masks=str(root / "masks"),
        **options,
    )


def _box_source(root: Path):
    """The ``PhotoSource`` of ``box_flight``'s photos, their masks and priors (no truth given)."""
    spec = _box_spec(root)
    return spec.open_source(spec.run_config())


def test_a_photo_source_goes_to_worker_processes_without_its_renderer(box_flight):
    """Workers get the source pickled once: models and inputs travel, the renderer and backends are
    rebuilt in each process; a query made there is the same."""
    import pickle

    source = _box_source(box_flight["root"])
    assert source.renderer is not None and len(source) == 2
    copy = pickle.loads(pickle.dumps(source))
    assert copy._renderer is None and copy._backends is None and copy._maps is None
    a, b = source.query(1), copy.query(1)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert a.prior_pose_local.cam_from_world.tolist() == b.prior_pose_local.cam_from_world.tolist()
    assert b.prior_uncertainty == a.prior_uncertainty and b.meta["image"].endswith("P1.JPG")


def test_a_photos_overlay_draws_the_estimate_on_the_map_it_was_found_on(box_flight, tmp_path):
    """``overlays/<stem>.png``: an estimate ``map_eaves_flat_roofs="auto"`` took from the map with eaves on
    its flat roofs (the box city's roofs are all flat) is drawn on that map; the prior's panel stays on the
    map as it is."""
    from semcityloc.datasets.overlay import HEADER_PX
    from semcityloc.localization.result import LOCALIZED, LocalizationResult

    source = _box_source(box_flight["root"])
    q = source.query(0)
    figures = {}
    for used in (False, True):
        look = {"gain_at_found": 0.01, "used": used}
        pose = q.prior_pose_local  # a pose the photo sees the boxes from
        result = LocalizationResult(status=LOCALIZED, pose_local=pose, search={"flat_roof_eaves": look})
        out = tmp_path / str(used)
        out.mkdir()
        source.save_estimate(out, q, result)
        with Image.open(out / "overlays" / "P0.png") as im:
            figures[used] = np.asarray(im.convert("RGB"))
    plain, flat = figures[False], figures[True]
    width = (plain.shape[1] - 6) // 2  # two panels and a 6-pixel gap: the estimate, then the prior
    assert plain.shape == flat.shape
    drawing = slice(HEADER_PX, None)  # below the title (cut at this photo's 160 pixels)
    assert not np.array_equal(plain[drawing, :width], flat[drawing, :width])  # the estimate's map's edges
    np.testing.assert_array_equal(plain[:, width:], flat[:, width:])  # the prior's


def test_berlin_run_on_a_tile_store_gives_the_same_poses(berlin_run, tmp_path):
    """``--city STORE`` (Berlin in four tiles): the same statuses and poses as the single file (to 1e-9
    relative, as the reference rows: docs/scale.md), the overlays drawn from the flight's tiles."""
    split_citygml(shared_file(BERLIN), tmp_path / "tiles", nx=4, ny=1)
    assert main(["tiles", "build", str(tmp_path / "tiles"), "--out", str(tmp_path / "store")]) == 0
    root, out = berlin_run["out"].parent, tmp_path / "out"
    argv = ["run", root / "photos", "--city", tmp_path / "store", "--masks", root / "masks", "--out", out]
    assert main([str(a) for a in argv]) == 0
    with open(berlin_run["out"] / "results.csv", newline="", encoding="utf-8") as fh:
        expected = {r["query_id"]: r for r in csv.DictReader(fh)}
    with open(out / "results.csv", newline="", encoding="utf-8") as fh:
        got = {r["query_id"]: r for r in csv.DictReader(fh)}
    assert got.keys() == expected.keys() and any(r["status"] == "localized" for r in got.values())
    columns = ("status", "reason", "est_world_x", "est_world_y", "est_world_z", "est_yaw", "err_xyz_m")
    assert [(q, c) for q in got for c in columns if not same(expected[q][c], got[q][c])] == []
    assert sorted(p.name for p in (out / "overlays").glob("*.png")) == sorted(
        p.name for p in (berlin_run["out"] / "overlays").glob("*.png")
    )
    # The report of a store's run reads the store (the query figures draw its map).
    assert main(["report", str(out), "--out", str(tmp_path / "report"), "--no-html"]) == 0
    assert (tmp_path / "report" / "report.md").is_file()


def test_a_network_on_an_undistorted_photo_says_nothing_where_the_photo_shows_nothing(box_flight, tmp_path):
    """Pincushion: the pinhole view's border lies outside the photo, the undistorted photo is black there;
    what a backend predicts there is IGNORE (labels) and NaN (depth), not a guess about black pixels."""
    root = box_flight["root"]
    lens = LensDistortion(k1=0.08)
    (tmp_path / "lens.json").write_text(json.dumps({**CAM.as_dict(), **lens.as_dict()}))
    spec = PhotoSpec(
        images=str(root / "images"),
        city=str(root / "city.obj"),
        priors=str(root / "GPS_pose"),
        intrinsics=str(tmp_path / "lens.json"),
        seg_backend="files",
        backend_options=(("masks", str(root / "masks")),),
    )
    source = spec.open_source(spec.run_config())
    labels = source.query(0).labels
    predicted = load_labels_png(root / "masks" / "P0.png")  # what the files backend returns for P0
    unseen = unseen_by_photo(labels.shape, CAM, lens)
    assert unseen[0, 0] and not unseen[60, 80] and 0.005 < unseen.mean() < 0.2
    assert (predicted[unseen] != IGNORE).any()  # the backend did say something there
    np.testing.assert_array_equal(labels, np.where(unseen, IGNORE, predicted))


@pytest.mark.slow
def test_a_flight_of_uncalibrated_photos_gets_its_focal_length(tmp_path, capsys, monkeypatch):
    """Eight oblique DJI photos whose only intrinsics are an EXIF 35 mm focal length 2.5 % short: the run
    estimates the flight's scale (``--calibrate-focal auto``), applies it, and the poses come out right."""
    from helpers import perturbed, view
    from semcityloc.citymodel.generator import generate_city

    root = tmp_path / "flight"
    (root / "images").mkdir(parents=True)
    gml = generate_city(tmp_path / "city", seed=0)[2]
    model = load_city_model(gml, cache=False)
    exif_f = 24.0 / math.hypot(36.0, 24.0) * math.hypot(256, 192)  # what FocalLengthIn35mmFilm=24 says
    true_cam = Camera(exif_f / 0.975, exif_f / 0.975, 128.0, 96.0, 256, 192)
    # (dx, dy, height, pitch from nadir, yaw) of each photo over the city
    views = [
        (-30, 15, 90, 40, 200),
        (20, -25, 80, 45, 30),
        (-10, -30, 85, 35, 120),
        (25, 20, 95, 50, 300),
        (0, 0, 75, 40, 80),
        (-25, -10, 90, 45, 250),
        (15, 30, 85, 38, 160),
        (-20, 25, 80, 42, 10),
    ]
    queries = []
    for k, (dx, dy, height, pitch, yaw) in enumerate(views):
        truth = view(model, dx, dy, height, 0.0, pitch, yaw)
        prior = perturbed(truth, [3.0, -2.0, 12.0], dyaw=2.0)  # the flight's heights all 12 m high
        name = f"F{k}.JPG"
        dji_jpeg(root / "images" / name, xmp_packet(GimbalYawDegree="0"), size=(256, 192), focal_35mm=24)
        truth_w, prior_w = model.pose_to_world(truth), model.pose_to_world(prior)
        save_labels_png(oracle_labels(model, true_cam, truth_w), root / "masks" / f"F{k}.png")
        queries.append(LodLocQuery(name, "flight", true_cam, gt_pose_world=truth_w, prior_pose_world=prior_w))
    write_lodloc_scene(root, queries)
    out = tmp_path / "out"
    argv = ["run", root / "images", "--city", gml, "--priors", root / "GPS_pose", "--truth", root / "GT_pose"]
    code, _, err = run(capsys, *argv, "--masks", root / "masks", "--no-overlays", "--out", out)
    assert code == 0, err
    estimate = json.loads((out / "poses" / "F0.json").read_text())["extra"]["focal_estimate"]
    assert estimate["images"] == len(views) and estimate["scale"] == pytest.approx(1 / 0.975, abs=0.01)
    assert f"was estimated from {len(views)} oblique ones" in err
    assert f"focal estimate: {len(views)}/{len(views)} queries done" in err  # its progress
    assert "have no calibrated intrinsics" not in err  # the approximate focal length was replaced
    assert json.loads((out / "summary.json").read_text())["recall_2m2deg"] == 100.0
    assert re.search(r"the 8 localized photos sit a median 1[12]\.\d m below their priors", err)  # shared

    # Run again: the estimate is read back (localizing nothing for it), the poses are the same.
    def no_estimate(*args, **kwargs):
        raise AssertionError("the focal length was estimated again")

    monkeypatch.setattr(photo_focal, "estimate_focal_scale", no_estimate)
    photo_focal._calibrated.cache_clear()  # as a new process would: only the disk cache is left
    again = tmp_path / "again"
    code, _, err = run(capsys, *argv, "--masks", root / "masks", "--no-overlays", "--out", again)
    assert code == 0, err
    assert "from an earlier run's estimate" in err
    for k in range(len(views)):
        first, second = (json.loads((o / "poses" / f"F{k}.json").read_text()) for o in (out, again))
        assert second["extra"]["focal_estimate"]["scale"] == estimate["scale"]
        assert second["cam_from_world"] == first["cam_from_world"]

    # A segmentation backend (here the one that reads files) is loaded once for the estimate and the run.
    built = []

    def counted(name, **options):
        built.append(name)
        return original_backend(name, **options)

    original_backend = photo_source.get_segmentation_backend
    monkeypatch.setattr(photo_source, "get_segmentation_backend", counted)
    monkeypatch.setattr(photo_focal, "estimate_focal_scale", estimate_focal_scale)
    photo_focal._calibrated.cache_clear()
    backend = ["--seg-backend", "files", "--backend-option", f"masks={root / 'masks'}"]
    code, _, err = run(capsys, *argv, *backend, "--no-cache", "--no-overlays", "--out", tmp_path / "backend")
    assert code == 0, err
    assert f"was estimated from {len(views)} oblique ones" in err and built == ["files"]


def test_the_checks_before_a_run_open_each_photo_once_and_read_its_metadata_once(tmp_path, monkeypatch):
    """Before the first photo, each photo of a DJI flight (EXIF intrinsics and priors) is opened by Pillow
    twice, not five times: once for its size, orientation and the decode check together, once by the
    metadata reader, whose result serves both camera and prior; a truncated photo is still skipped with the
    reason it always had."""
    root = tmp_path / "flight"
    (root / "images").mkdir(parents=True)
    fields = dict(GpsLatitude="+48.1", GpsLongitude="+11.5", AbsoluteAltitude="+600", GimbalYawDegree="0")
    fields["GimbalPitchDegree"] = "-45"
    for k in range(3):
        dji_jpeg(root / "images" / f"D{k}.JPG", xmp_packet(**fields), size=(64, 48), focal_35mm=24)
        save_labels_png(np.zeros((48, 64), np.uint8), root / "masks" / f"D{k}.png")
    (root / "city.obj").write_text(box_city_obj())
    data = _noisy_jpeg(root / "images" / "D2.JPG")
    (root / "images" / "D2.JPG").write_bytes(data[: len(data) * 2 // 3])
    images, masks = str(root / "images"), str(root / "masks")
    offset = (686_100.0, 5_330_400.0, 0.0)  # the box (a local frame) placed under the photos (48.1 N, 11.5 E)
    spec = PhotoSpec(images, str(root / "city.obj"), crs="EPSG:25832", masks=masks, offset=offset)
    opened, read = [], []
    pillow_open, read_metadata = Image.open, photos.read_dji_metadata

    def counted_open(path, *args, **kwargs):
        opened.append(Path(path).name)
        return pillow_open(path, *args, **kwargs)

    def counted_read(path):
        read.append(Path(path).name)
        return read_metadata(path)

    monkeypatch.setattr(Image, "open", counted_open)
    monkeypatch.setattr(photos, "read_dji_metadata", counted_read)
    _, inputs, skipped, _ = spec.resolved()
    assert [i.name for i in inputs] == ["D0.JPG", "D1.JPG"] and list(skipped) == ["D2.JPG"]
    assert "truncated" in skipped["D2.JPG"] and str(root / "images" / "D2.JPG") in skipped["D2.JPG"]
    photos_opened = sorted(n for n in opened if n.endswith(".JPG"))
    assert photos_opened == ["D0.JPG", "D0.JPG", "D1.JPG", "D1.JPG", "D2.JPG"]
    assert sorted(read) == ["D0.JPG", "D1.JPG"]
    assert inputs[0].intrinsics_source == INTRINSICS_35MM and inputs[0].prior.source == "exif"


def test_a_finished_run_whose_pose_files_were_deleted_refuses_to_export_naming_them(
    box_flight, tmp_path, capsys
):
    """Pose files deleted after a run used to give exports without those photos (COLMAP lacking them,
    the GeoJSON marking them "no result" at their prior) while the summary counted them localized, exit 0:
    now a run again refuses in one line naming the files and the remedy; deleting those rows redoes them."""
    out = tmp_path / "out"
    argv = [*box_flight["argv"], "--out", out, "--no-overlays"]
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    p0 = (out / "poses" / "P0.json").read_text()
    (out / "poses" / "P0.json").unlink()
    code, _, err = run(capsys, *argv)
    assert code == 2 and "P0.json: no pose file" in err and "delete its row from" in err, err
    assert "results.csv" in err and err.count("\n") == 1, err
    # A record that is JSON but no result, another photo's record copied over it, one cut short (batch
    # audit, stop 51): the first two passed (COLMAP lacked the photo or held one pose twice, exit 0), the
    # third was told to run everything again with --overwrite.
    for damaged, why in (
        ("{}", "P0.json: holds no result record"),
        ((out / "poses" / "P1.json").read_text(), "P0.json: is the record of 'P1.JPG'"),
        (p0[: len(p0) // 2], "P0.json: unreadable"),
    ):
        (out / "poses" / "P0.json").write_text(damaged)
        code, _, err = run(capsys, *argv)
        assert code == 2 and why in err and "delete its row from" in err and "redoes every photo" in err, err
    shutil.rmtree(out / "poses")
    code, _, err = run(capsys, *argv)
    assert code == 2 and "3 finished photos have no usable pose file" in err, err
    assert "P0.json: no pose file, P1.json: no pose file" in err and "delete their rows" in err, err
    lines = (out / "results.csv").read_text().splitlines(keepends=True)
    (out / "results.csv").write_text("".join(lines[:1]))  # the remedy: their rows deleted, they run again
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    assert len(read_model(out / "colmap").poses()) == 2


def test_a_photo_run_gives_the_same_poses_with_one_worker_and_with_two(box_flight, tmp_path, capsys):
    """The photos' priors used to hold transposed views (``Pose``'s rotation); pickled to a worker process
    they arrived C-contiguous, and numpy's matrix products round by memory layout: the local-frame priors
    differed in the last bits and 5 of 60 poses of a flight by 0.1 m between ``--workers 1`` and 2. The
    records, but for their timings, are now the same."""
    outs = [tmp_path / "w1", tmp_path / "w2"]
    for out, workers in zip(outs, ("1", "2"), strict=True):
        code, _, err = run(capsys, *box_flight["argv"], "--out", out, "--no-overlays", "--workers", workers)
        assert code == 0, err
    records = []
    for out in outs:
        poses = {p.name: json.loads(p.read_text()) for p in sorted((out / "poses").glob("*.json"))}
        for record in poses.values():
            record.get("extra", record).pop("timings_s")
        records.append(poses)
    assert len(records[0]) == 3 and records[0] == records[1]
    assert [n for n, r in records[0].items() if r.get("extra", r)["status"] == "localized"] == [
        "P0.json",
        "P1.json",
    ]


def test_a_pose_holds_c_contiguous_arrays_so_a_pickled_one_computes_the_same():
    """The cause of the test above, on one pose: its arrays are C-contiguous however it was made, so a copy
    pickled to a worker process moves to a local frame bit for bit as the original does."""
    truth = Pose.from_xyz_rpy([5.0, -4.0, 90.0], 0.5, 20.0, 30.0)
    made = [
        Pose.from_world_from_cam(truth.world_from_cam),
        Pose.from_cam_from_world(truth.cam_from_world.T.T),
    ]
    made.append(Pose(np.asfortranarray(truth.R), truth.t))
    for pose in made:
        assert pose.R.flags.c_contiguous and pose.t.flags.c_contiguous
    origin = np.array([654321.4567, 5812345.0123, 34.5678])
    for pose in made:
        local, copied = (p.shift_world(origin) for p in (pose, pickle.loads(pickle.dumps(pose))))
        assert np.array_equal(local.t, copied.t) and np.array_equal(local.R, copied.R)


def test_a_photo_of_the_truth_without_its_mask_is_a_miss_else_skipped(box_flight, tmp_path, capsys):
    """A photo with a true pose whose mask file is missing is in the recall's denominator as a miss naming
    the masks folder (as in a data-set benchmark); without ``--truth`` it is skipped, as before."""
    (box_flight["root"] / "masks" / "P1.png").unlink()
    out = tmp_path / "out"
    code, _, err = run(capsys, *box_flight["argv"], "--out", out, "--no-overlays")
    assert code == 0, err
    miss = _rows_by_name(out)["P1.JPG"]
    assert miss["status"] == "not_localized" and miss["reason"].startswith(REASON_UNREADABLE)
    assert "P1" in miss["reason"] and str(box_flight["root"] / "masks") in miss["reason"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["with_ground_truth"] == 3 and set(summary["skipped_photos"]) == {"P9.JPG"}
    no_truth = box_flight["argv"][: box_flight["argv"].index("--truth")]
    code, _, err = run(capsys, *no_truth, "--out", tmp_path / "no_truth", "--no-overlays")
    assert code == 0, err
    skipped = json.loads((tmp_path / "no_truth" / "summary.json").read_text())["skipped_photos"]
    assert set(skipped) == {"P1.JPG", "P2.JPG", "P9.JPG"}


def test_intrinsics_of_another_image_are_that_photos_miss_or_skip_naming_file_and_sizes(
    box_flight, tmp_path, capsys
):
    """Stop 50's audit: a calibration of another image (the thermal camera's K on the wide photo) was
    applied unchecked, and the photo ended "confidence below the acceptance probability". Now, as for a
    mask of another aspect: with a true pose a miss, else skipped, the reason naming the file, the photo
    and both sizes. P0: a K of another image (principal point 25 % off the photo's centre, the centre of an
    80x80 image: since stop 55 a K of the photo at half its size, 80x60, is rescaled as a stated size is);
    P2: intrinsics stating a 160x160 image (no resize of the 160x120 photo). P1 runs."""
    root = box_flight["root"]
    other = Camera(CAM.fx / 2, CAM.fy / 2, 40.0, 40.0, 80, 80)
    np.savetxt(root / "intrinsic" / "P0_intrinsic.txt", np.hstack([other.K, np.zeros((3, 1))]))
    square = {"fx": CAM.fx, "fy": CAM.fy, "cx": 80, "cy": 80, "width": 160, "height": 160}
    (root / "intrinsic" / "P2_intrinsic.txt").write_text(json.dumps(square))
    out = tmp_path / "out"
    code, _, err = run(capsys, *box_flight["argv"], "--out", out, "--no-overlays", "--stop-after", "1")
    assert code == 0, err
    miss = _rows_by_name(out)["P0.JPG"]
    assert miss["status"] == "not_localized" and miss["err_xyz_m"] == "inf"
    said = f"{root / 'intrinsic' / 'P0_intrinsic.txt'}: principal point (40, 40) lies 25 % of the image size "
    assert said + "off the centre of photo P0.JPG (160x120" in miss["reason"]
    assert "centre of a 80x80 image" in miss["reason"]
    no_truth = box_flight["argv"][: box_flight["argv"].index("--truth")]
    code, _, err = run(capsys, *no_truth, "--out", tmp_path / "no_truth", "--stop-after", "0")
    assert code == 0, err
    skipped = json.loads((tmp_path / "no_truth" / "run.json").read_text())["skipped_photos"]
    assert skipped["P0.JPG"].startswith(said)
    assert skipped["P2.JPG"] == (
        f"{root / 'intrinsic' / 'P2_intrinsic.txt'}: intrinsics of a 160x160 image do not fit photo P2.JPG "
        "(160x120), which is no resized copy of it: the calibration of another camera or image size"
    )


def test_a_geoid_separation_that_is_no_number_of_metres_is_refused_when_the_run_is_made(tmp_path):
    """``--geoid-separation nan`` was accepted (and written to run.json) whenever the priors came from
    files, since only a photo's EXIF prior checked it: now the run is refused before anything is read."""
    from semcityloc.errors import ParameterError

    for bad in (float("nan"), 500.0):
        with pytest.raises(ParameterError, match="geoid separation N must be"):
            PhotoSpec(str(tmp_path), "city.obj", masks=str(tmp_path), geoid_separation_m=bad)
    assert PhotoSpec(str(tmp_path), "city.obj", masks=str(tmp_path), geoid_separation_m=47.2)


def test_a_backend_option_no_selected_backend_takes_is_refused_when_the_run_is_made(tmp_path, capsys):
    """Stop 56: ``--backend-option model=...`` without ``--depth-backend moge2`` was ignored without a word;
    refused before anything is read, in Python as ``PhotoSpec`` takes it, on the command line as flags."""
    from semcityloc.errors import ParameterError

    masks = ("masks", str(tmp_path))
    with pytest.raises(ParameterError, match="model=m.pt is not used.*depth_backend='moge2'"):
        PhotoSpec(str(tmp_path), "city.obj", seg_backend="files", backend_options=(masks, ("model", "m.pt")))
    argv = ["run", tmp_path, "--city", "city.obj", "--seg-backend", "files", "--out", tmp_path / "out"]
    code, _, err = run(
        capsys, *argv, "--backend-option", f"masks={tmp_path}", "--backend-option", "model=m.pt"
    )
    assert code == 2 and err.count("\n") == 1 and "model=m.pt is not used" in err, err
    assert "--depth-backend moge2" in err and not (tmp_path / "out").exists()


def test_a_geoid_separation_with_ellipsoidal_model_heights_is_refused(tmp_path, capsys):
    """``--geoid-separation`` was used only with ``--target-height orthometric`` (or a compound CRS) and said
    unused otherwise (user audit, stop 52): with ``auto`` it now applies (``dji.model_heights_orthometric``);
    with ``ellipsoidal``, which says the model's heights need no N, the run is refused naming both: in
    Python as ``PhotoSpec`` takes them (it named the flags until stop 54), on the command line as flags."""
    said = "geoid_separation_m=36.7 converts .* but target_height='ellipsoidal' says .* give one or the other"
    with pytest.raises(BenchmarkError, match=said):
        PhotoSpec(
            str(tmp_path),
            "city.obj",
            masks=str(tmp_path),
            target_height="ellipsoidal",
            geoid_separation_m=36.7,
        )
    argv = ["run", tmp_path, "--city", "city.obj", "--masks", tmp_path, "--out", tmp_path / "out"]
    code, _, err = run(capsys, *argv, "--target-height", "ellipsoidal", "--geoid-separation", "36.7")
    assert (
        code == 2 and "--geoid-separation 36.7 converts" in err and "but --target-height ellipsoidal" in err
    )


def _rename_photo(root: Path, stem: str, new_stem: str) -> None:
    """Rename a box-flight photo and its mask, prior, truth and intrinsics files (named by its stem)."""
    for sub, suffix in (
        ("images", ".JPG"),
        ("masks", ".png"),
        ("GPS_pose", "_pose.txt"),
        ("GT_pose", "_pose.txt"),
        ("intrinsic", "_intrinsic.txt"),
    ):
        (root / sub / f"{stem}{suffix}").rename(root / sub / f"{new_stem}{suffix}")


UTM_49N = ["--crs", "EPSG:32649", "--offset", "695672,3131199,0"]  # the user's flight, south China


def test_a_photo_named_with_spaces_is_left_out_of_colmap_and_geo_txt_and_the_rest_is_exported(
    box_flight, tmp_path, capsys
):
    """One photo named ``my photo ü.JPG`` cost the whole flight's exports: every photo localized, then
    ``geo.txt cannot hold image names with spaces``, exit 2, no geo.txt or summary.json, and the same on
    every run again. COLMAP's images.txt and ODM's geo.txt split a line on spaces (COLMAP reads the name as
    ``my``), so the photo is left out of those two with one warning naming it; everything else is written."""
    root = box_flight["root"]
    _rename_photo(root, "P0", "my photo ü")
    out = tmp_path / "out"
    argv = [*box_flight["argv"], *UTM_49N, "--out", out, "--no-overlays"]
    for _ in range(2):  # and the same run again: the exports written anew
        code, _, err = run(capsys, *argv)
        assert code == 0, err
        assert err.count("semcityloc: warning:") == 1, err
        assert (
            "semcityloc: warning: 1 localized photo left out of colmap/images.txt and geo.txt "
            "(their readers split a line on spaces"
            in err
            and "read back cut short): my photo ü.JPG; the poses are in poses/" in err
        )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["localized"] == 2 and summary["outputs"]["geo_txt"] == str(out / "geo.txt")
    assert set(read_model(out / "colmap").poses()) == {"P1.JPG"}
    geo = (out / "geo.txt").read_text().splitlines()
    assert geo[0] == "EPSG:32649" and [line.split()[0] for line in geo[1:]] == ["P1.JPG"]
    with open(out / "geotags.csv", newline="", encoding="utf-8") as fh:
        tagged = {row["image"]: row["source"] for row in csv.DictReader(fh)}
    assert tagged["my photo ü.JPG"] == "semcityloc" and tagged["P1.JPG"] == "semcityloc"
    features = json.loads((out / "cameras.geojson").read_text(encoding="utf-8"))["features"]
    assert {f["properties"]["image"] for f in features} >= {"my photo ü.JPG", "P1.JPG"}
    assert read_pose(out / "poses" / "my photo ü.json") is not None
    # With --offset the pose files hold the CRS minus the offset: labelled EPSG:32649 they put the camera
    # 3,153 km from its geo.txt line (frames audit, stop 51). Now no label; the offset and its CRS said.
    pose_file = json.loads((out / "poses" / "P1.json").read_text())
    assert "crs" not in pose_file and pose_file["extra"]["crs"] is None
    assert pose_file["extra"]["crs_offset"] == [695672.0, 3131199.0, 0.0]
    assert pose_file["extra"]["offset_crs"] == "EPSG:32649"
    in_crs = np.add(pose_file["position"], pose_file["extra"]["crs_offset"])
    np.testing.assert_allclose(in_crs, [float(v) for v in geo[1].split()[1:4]], atol=1e-3)


def test_run_offset_pose_files_say_their_frame_and_a_model_of_another_offset_refuses_them(
    box_flight, tmp_path, capsys
):
    """``run --offset`` wrote its pose files with ``"frame": "crs"`` over the CRS minus the offset (only
    ``extra`` said so): read with a model in that CRS they were taken as its coordinates, the camera 3,208 km
    away, and a run with another offset took them as its own frame (stop 52). Now ``"frame": "crs_offset"``
    with ``offset_crs`` / ``crs_offset``; read with the frame they were written in they pass, with another
    (the CRS itself, another offset) they are refused naming both, the old layout as well."""
    from semcityloc.citymodel import read_pose_world
    from semcityloc.errors import CRSError

    out = tmp_path / "out"
    code, _, err = run(capsys, *box_flight["argv"], *UTM_49N, "--out", out, "--no-overlays")
    assert code == 0, err
    pose_file = out / "poses" / "P1.json"
    data = json.loads(pose_file.read_text())
    offset = [695672.0, 3131199.0, 0.0]
    assert data["frame"] == "crs_offset" and "crs" not in data
    assert data["offset_crs"] == "EPSG:32649" and data["crs_offset"] == offset
    assert data["extra"]["prior"]["frame"] == "crs_offset" and data["extra"]["prior"]["crs_offset"] == offset
    utm = pyproj.CRS("EPSG:32649")
    refused = r"the prior is in EPSG:32649 minus \(695672, 3131199, 0\) but the model's frame is EPSG:32649: "
    with pytest.raises(CRSError, match=refused + r"taken as the model's, its numbers would be 3,208 km off"):
        read_pose_world(pose_file, utm, "prior")
    same_frame = read_pose_world(pose_file, utm, crs_offset=offset)
    np.testing.assert_allclose(same_frame.center, data["position"], rtol=0, atol=1e-9)
    assert read_pose_world(pose_file, None).center.shape == (3,)  # a model without a CRS: nothing to check
    # The same file in the layout written before stop 52: read as what it was.
    old = {k: v for k, v in data.items() if k not in ("offset_crs", "crs_offset")}
    (tmp_path / "old.json").write_text(json.dumps({**old, "frame": "crs"}))
    with pytest.raises(CRSError, match=refused):
        read_pose_world(tmp_path / "old.json", utm, "prior")
    np.testing.assert_allclose(
        read_pose_world(tmp_path / "old.json", utm, crs_offset=offset).center, data["position"]
    )
    # The run's estimates as the priors of another run: its own offset takes them, another is refused.
    priors = tmp_path / "priors"
    priors.mkdir()
    for stem in ("P0", "P1"):
        shutil.copy(out / "poses" / f"{stem}.json", priors / f"{stem}_pose.txt")
    argv = [str(a) for a in box_flight["argv"]]
    argv[argv.index("--priors") + 1] = str(priors)
    code, _, err = run(capsys, *argv, *UTM_49N, "--out", tmp_path / "again", "--no-overlays")
    summary = json.loads((tmp_path / "again" / "summary.json").read_text())
    assert code == 0 and summary["localized"] == 2, err
    moved = ["--crs", "EPSG:32649", "--offset", "695670,3131199,0"]
    code, _, err = run(capsys, *argv, *moved, "--out", tmp_path / "moved", "--no-overlays")
    assert code == 2 and "no photo can be localized" in err and "P2.JPG: no prior pose" in err
    assert (
        "priors/P1_pose.txt: the pose is in EPSG:32649 minus (695672, 3131199, 0) but the model's frame is "
        "EPSG:32649 minus (695670, 3131199, 0): taken as the model's, its numbers would be 2.0 m off; give "
        "the model the offset its numbers are by (--offset 695672,3131199,0); P2.JPG" in err
    )


def test_a_run_without_a_crs_writes_no_geojson_and_says_so(box_flight, tmp_path, capsys):
    """A model in a local frame gave a cameras.geojson of local metres (only a non-standard
    ``semcityloc_frame`` member said so), which QGIS placed at longitude -466: GeoJSON coordinates are WGS 84
    (RFC 7946). Now no GeoJSON, one note naming --crs, and one an older version left is removed."""
    out = tmp_path / "out"
    argv = [*box_flight["argv"], "--out", out, "--no-overlays"]
    code, stdout, err = run(capsys, *argv)
    assert code == 0, err
    assert not (out / "cameras.geojson").exists() and "cameras.geojson" not in stdout
    note = "semcityloc: note: the city model names no CRS, so no geotags.csv / geo.txt / cameras.geojson"
    assert err.count(note) == 1 and "pass --crs" in err
    assert json.loads((out / "summary.json").read_text())["outputs"]["geojson"] is None
    (out / "cameras.geojson").write_text('{"type": "FeatureCollection", "features": []}')  # an older one
    code, _, err = run(capsys, *argv)
    assert code == 0 and not (out / "cameras.geojson").exists(), err
    code, _, err = run(capsys, *argv, *UTM_49N, "--overwrite")  # with a CRS: on the map
    (point, *_) = json.loads((out / "cameras.geojson").read_text())["features"]
    lon, lat = point["geometry"]["coordinates"]
    assert code == 0 and 112.9 < lon < 113.1 and 28.2 < lat < 28.4, err


def test_a_one_photo_run_counts_one_photo(box_flight, tmp_path, capsys):
    """A run of one photo said "1 photos: 1 localized ..." (and "1/1 photos done" when stopped)."""
    for name in ("P1.JPG", "P2.JPG", "P9.JPG"):
        (box_flight["root"] / "images" / name).unlink()
    argv = [*box_flight["argv"], "--out", tmp_path / "out", "--no-overlays"]
    code, stdout, err = run(capsys, *argv, "--stop-after", "0")
    assert code == 0 and "0/1 photo done" in stdout, stdout + err
    code, stdout, err = run(capsys, *argv)
    assert code == 0 and "1 photo: 1 localized, 0 not localized, 0 skipped" in stdout, stdout + err
    assert "1 photos" not in stdout + err and "1/1 query done" in err


def test_a_truth_or_prior_changed_after_a_photo_finished_is_told_not_kept(box_flight, tmp_path, capsys):
    """A corrected ``--truth`` file (or a replaced prior) for a finished photo: the run again kept the
    old row, its error 14.6 m and the summary's recall from the wrong truth, exit 0 (batch audit, stop 51).
    Rows carry the prior and truth they were made from: a changed one is refused naming the photo and the
    remedy; deleting that row redoes the photo with the new truth."""
    out = tmp_path / "out"
    argv = [*box_flight["argv"], "--out", out, "--no-overlays"]
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    truth_file = box_flight["root"] / "GT_pose" / "P1_pose.txt"
    original = truth_file.read_text()
    c2w = np.loadtxt(truth_file)
    c2w[0, 3] += 3.0  # the truth moved 3 m east
    np.savetxt(truth_file, c2w)  # read again in this process too (stop 52: no cache to clear first)
    try:
        code, _, err = run(capsys, *argv)
        assert code == 2 and "1 finished photo no longer matches its row" in err, err
        assert "P1.JPG: its truth moved 3 m" in err and "delete its row" in err, err
        rows = (out / "results.csv").read_text().splitlines(keepends=True)
        (out / "results.csv").write_text("".join(r for r in rows if not r.startswith("q0001,")))
        code, _, err = run(capsys, *argv)
        assert code == 0, err
        with open(out / "results.csv", encoding="utf-8", newline="") as fh:
            row = next(r for r in csv.DictReader(fh) if r["index"] == "1")
        assert float(row["true_world_x"]) == pytest.approx(c2w[0, 3])
    finally:
        truth_file.write_text(original)


def _drop_rows(out: Path, *names: str) -> None:
    """``results.csv`` without the rows of photos ``names``: what the remedy of a changed input asks."""
    write_rows(out / "results.csv", [r for n, r in _rows_by_name(out).items() if n not in names])


def _edit_keeping_times(path: Path, edit) -> None:
    """``edit(path)``, then the file's modification time put back, as ``cp -p`` or an archive restore leave
    it: a check by modification time alone would take the new file for the old."""
    before = path.stat()
    edit(path)
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))


def test_a_photo_or_mask_changed_after_it_finished_is_told_not_kept(box_flight, tmp_path, capsys):
    """A mask fixed (or a photo replaced) after its photo finished: the run again kept the old row and pose
    and exited 0, the fixed file never read (only the prior and truth were compared; fixer, stop 52).
    Each row keeps the size and SHA-256 of the photo, mask and depth it was made from (``meta_json``, and
    the pose record): a changed one is refused naming the photo and the file, with the one-row remedy, also
    when the new file keeps the old one's modification time; deleting those rows redoes them."""
    root, out = box_flight["root"], tmp_path / "out"
    argv = [*box_flight["argv"], "--out", out, "--no-overlays"]
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    kept = json.loads(_rows_by_name(out)["P1.JPG"]["meta_json"])["input_fingerprints"]
    mask_bytes = (root / "masks" / "P1.png").read_bytes()
    assert kept["mask"] == {
        "file": "P1.png",
        "bytes": len(mask_bytes),
        "sha256": sha256(mask_bytes).hexdigest(),
    }
    assert kept["photo"]["file"] == "P1.JPG" and "depth" not in kept
    record = json.loads((out / "poses" / "P1.json").read_text())["extra"]
    assert record["input_fingerprints"] == kept
    # Nothing changed: the finished run is summarised again, nothing refused.
    code, _, err = run(capsys, *argv)
    assert code == 0, err

    def fix_mask(path: Path) -> None:
        labels = load_labels_png(path)
        labels[:40, :40] = IGNORE
        save_labels_png(labels, path)

    _edit_keeping_times(root / "masks" / "P1.png", fix_mask)
    _edit_keeping_times(
        root / "images" / "P0.JPG",
        lambda p: Image.new("RGB", (CAM.width, CAM.height), (90, 90, 90)).save(p),
    )
    code, _, err = run(capsys, *argv)
    assert code == 2 and "2 finished photos no longer match their rows" in err, err
    assert "P0.JPG: its photo P0.JPG changed (" in err and "P1.JPG: its mask P1.png changed (" in err
    assert f"delete their rows from {out / 'results.csv'} and run again" in err and err.count("\n") == 1
    _drop_rows(out, "P0.JPG", "P1.JPG")
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    now = json.loads(_rows_by_name(out)["P1.JPG"]["meta_json"])["input_fingerprints"]["mask"]
    assert (
        now["sha256"]
        == sha256((root / "masks" / "P1.png").read_bytes()).hexdigest()
        != kept["mask"]["sha256"]
    )


def test_a_skipped_photo_whose_mask_was_fixed_is_told_not_kept(box_flight, tmp_path, capsys):
    """A photo skipped because its mask did not read in full, the mask then fixed: the run again kept the
    ``skipped`` row (the fixed mask never ran) and exited 0. Now refused naming the mask."""
    masks, out = box_flight["root"] / "masks", tmp_path / "out"
    data = (masks / "P0.png").read_bytes()  # the photos' aspect: P2's own mask has another
    (masks / "P2.png").write_bytes(data[: len(data) * 2 // 3])
    argv = [*box_flight["argv"][: box_flight["argv"].index("--truth")], "--out", out, "--no-overlays"]
    code, _, err = run(capsys, *argv)
    assert code == 0 and _rows_by_name(out)["P2.JPG"]["status"] == "skipped", err
    (masks / "P2.png").write_bytes(data)
    code, _, err = run(capsys, *argv)
    assert code == 2 and "1 finished photo no longer matches its row" in err, err
    assert f"P2.JPG: its mask P2.png changed ({len(data) * 2 // 3} -> {len(data)} bytes)" in err
    _drop_rows(out, "P2.JPG")
    code, _, err = run(capsys, *argv)
    assert code == 0 and _rows_by_name(out)["P2.JPG"]["status"] != "skipped", err


def test_rows_of_an_earlier_version_without_fingerprints_resume_and_say_so(box_flight, tmp_path, capsys):
    """A run folder of a version before stop 52 (no fingerprints in its rows) is not refused for them: its
    rows are kept, a changed file cannot be noticed for them, and the run says so with the remedy."""
    out = tmp_path / "out"
    argv = [*box_flight["argv"], "--out", out, "--no-overlays"]
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    rows = read_results(out / "results.csv")
    for row in rows:
        meta = json.loads(row["meta_json"])
        meta.pop("input_fingerprints", None)
        row["meta_json"] = json.dumps(meta, sort_keys=True)
    write_rows(out / "results.csv", rows)
    (box_flight["root"] / "masks" / "P1.png").unlink()
    save_labels_png(np.zeros((CAM.height, CAM.width), np.uint8), box_flight["root"] / "masks" / "P1.png")
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    assert "3 finished photos were run by an earlier version that kept no fingerprints" in err
    assert f"delete their rows from {out / 'results.csv'} and run again to redo them" in err


def test_a_spec_reads_its_files_again_when_they_change_in_one_process(box_flight):
    """``PhotoSpec.resolved`` was cached per process by the spec alone: a caller that corrected a truth or
    prior file between two runs in one process got the old one (fixer, stop 52). Now cached while the
    files it names have the same stamp (``io.stamps``): an edit of the same size, at once, is read."""
    root = box_flight["root"]
    spec = _box_spec(root, truth=str(root / "GT_pose"))
    first = spec.resolved()
    assert spec.resolved() is first  # unchanged: not read again
    truth_file = root / "GT_pose" / "P1_pose.txt"
    c2w = np.loadtxt(truth_file)
    size = truth_file.stat().st_size
    c2w[0, 3] += 3.0
    np.savetxt(truth_file, c2w)
    assert truth_file.stat().st_size == size
    again = spec.resolved()
    moved = center_error_m(again.inputs[1].truth_world, first.inputs[1].truth_world)
    assert moved == pytest.approx(3.0)
    (root / "images" / "P1.JPG").unlink()  # a photo gone: the list of photos read again too
    assert [i.name for i in spec.resolved().inputs] == ["P0.JPG", "P2.JPG"]


def test_photos_that_change_while_a_run_starts_are_refused_not_given_other_rows(box_flight):
    """The inputs are read again when their files change: a photo removed between ``run.json`` and the
    source's opening would shift every later photo onto another's row; refused in one line instead."""
    root = box_flight["root"]
    spec = _box_spec(root, truth=str(root / "GT_pose"))
    config = spec.run_config()
    (root / "images" / "P0.JPG").unlink()
    with pytest.raises(InputFileError, match="changed while this run was starting or running"):
        spec.open_source(config)


def test_a_photo_named_with_a_leading_hash_is_left_out_of_geo_txt_only(box_flight, tmp_path, capsys):
    """``#one.JPG`` went into geo.txt as a line OpenDroneMap reads as a comment: that photo's position
    silently dropped (adversarial test, stop 51). Now left out of geo.txt with a warning; COLMAP's
    images.txt (whose lines start with the image id) holds it."""
    root = box_flight["root"]
    _rename_photo(root, "P1", "#one")
    out = tmp_path / "out"
    code, _, err = run(capsys, *box_flight["argv"], *UTM_49N, "--out", out, "--no-overlays")
    assert code == 0, err
    assert "1 localized photo left out of geo.txt (OpenDroneMap reads a line starting with '#'" in err
    geo = (out / "geo.txt").read_text().splitlines()
    assert [line.split()[0] for line in geo[1:]] == ["P0.JPG"]
    assert "#one.JPG" in read_model(out / "colmap").poses()


# ------------------------------------------------------------------------------ stop 52: priors, folders
def test_a_photo_whose_prior_lies_hundreds_of_km_away_is_skipped_not_the_runs_end(
    box_flight, tmp_path, capsys
):
    """Stop 52's audit: a photo whose prior lies more than 100 km from the model (a photo of another place,
    a COLMAP quaternion in another order) stopped the whole run with the renderer's "Renderer.render takes
    poses in the model's local frame ..." when its overlay was drawn, and again on every resume: the flight
    could never finish. Now it is skipped before anything is searched or drawn, with the distance and where
    the prior came from (``MapLayout.off_map``, the localizer's own bound); the others run. With a true pose
    (stop 53) it is a miss keeping that reason, not left out of the recall."""
    root = box_flight["root"]
    prior = read_pose(root / "GPS_pose" / "P0_pose.txt")
    far = Pose.from_rotation_center(prior.R_world_from_cam, prior.center + [300_000.0, 0.0, 0.0])
    np.savetxt(root / "GPS_pose" / "P0_pose.txt", far.world_from_cam)
    no_truth = box_flight["argv"][: box_flight["argv"].index("--truth")]
    out = tmp_path / "out"
    code, stdout, err = run(capsys, *no_truth, "--out", out)
    assert code == 0 and "Traceback" not in err, err
    summary = json.loads((out / "summary.json").read_text())
    why = summary["skipped_photos"]["P0.JPG"]
    assert why.startswith("the prior lies 300 km from the model's nearest building") and "GPS_pose" in why
    assert summary["localized"] == 1 and "4 photos: 1 localized, 0 not localized, 3 skipped" in stdout
    assert not (out / "overlays" / "P0.png").exists() and (out / "overlays" / "P1.png").is_file()
    code, stdout, _ = run(capsys, *no_truth, "--out", out)  # and the finished run resumes
    assert code == 0 and "4 photos: 1 localized" in stdout
    code, stdout, err = run(capsys, *box_flight["argv"], "--out", tmp_path / "truth")
    assert code == 0 and "Traceback" not in err, err
    miss = _rows_by_name(tmp_path / "truth")["P0.JPG"]
    assert miss["status"] == "not_localized" and miss["reason"] == f"skipped, counted as a miss: {why}"
    said = "4 photos: 1 localized, 2 not localized (1 of them skipped, counted as a miss), 1 skipped"
    assert said in stdout
    assert not (tmp_path / "truth" / "overlays" / "P0.png").exists()


def test_a_runs_poses_folder_is_the_priors_and_truth_of_the_next_run(box_flight, tmp_path, capsys):
    """Stop 52's audit: a run's own ``poses/`` given back as ``--priors`` / ``--truth`` was refused ("no
    prior pose for P0.JPG in .../poses"): the tool's own output format. Now read; a photo that run did not
    localize has no pose there and is skipped saying so."""
    first = tmp_path / "first"
    code, _, err = run(capsys, *box_flight["argv"], "--out", first, "--no-overlays")
    assert code == 0, err
    given = (box_flight["root"] / "GPS_pose", box_flight["root"] / "GT_pose")
    argv = [first / "poses" if a in given else a for a in box_flight["argv"]]
    code, stdout, err = run(capsys, *argv, "--out", tmp_path / "second", "--no-overlays")
    assert code == 0, err
    summary = json.loads((tmp_path / "second" / "summary.json").read_text())
    assert summary["localized"] == 2 and summary["with_ground_truth"] == 2
    assert "P2.JPG has no pose there: that run did not localize it" in summary["skipped_photos"]["P2.JPG"]


def test_photos_in_subfolders_are_said_and_read_with_recursive(box_flight, tmp_path, capsys):
    """Stop 52's audit: photos in subfolders were ignored without a word ("6 photos" with one of the truth in
    ``sub/``; a DJI card's ``DCIM/100MEDIA/``: "no images"). The run says how many it did not read and
    ``--recursive`` reads them; two photos of one name in two subfolders are refused (their outputs would
    overwrite each other's); the run's own folder placed inside is not read as photos on resume."""
    images = box_flight["root"] / "images"
    (images / "sub").mkdir()
    (images / "P1.JPG").rename(images / "sub" / "P1.JPG")
    code, stdout, err = run(capsys, *box_flight["argv"], "--out", tmp_path / "top", "--no-overlays")
    assert code == 0, err
    assert f"note: 1 photo in subfolders of {images} is not read (sub/P1.JPG)" in err and "--recursive" in err
    assert "3 photos: 1 localized" in stdout
    out = images / "run"  # inside the photos' folder: not read as photos when the run is resumed
    for _ in range(2):
        code, stdout, err = run(capsys, *box_flight["argv"], "--recursive", "--out", out)
        assert code == 0, err
        assert "4 photos: 2 localized" in stdout and "not read" not in err
    (images / "sub2").mkdir()
    shutil.copy(images / "sub" / "P1.JPG", images / "sub2" / "P1.JPG")
    code, _, err = run(capsys, *box_flight["argv"], "--recursive", "--out", tmp_path / "dup")
    assert code == 2 and "sub/P1.JPG and sub2/P1.JPG share the name P1" in err


def test_a_run_that_localizes_none_of_its_photos_exits_1_saying_so(box_flight, tmp_path, capsys):
    """Stop 52's audit: ``run`` exited 0 when 0 of N photos were localized; a script went on as if it had
    worked. Its files are written as before, and it exits 1 (as ``localize`` does for its photo) with a
    line saying so."""
    for name in ("P0", "P1"):  # masks that see no building
        save_labels_png(
            np.zeros((CAM.height, CAM.width), np.uint8), box_flight["root"] / "masks" / f"{name}.png"
        )
    out = tmp_path / "out"
    code, stdout, err = run(capsys, *box_flight["argv"], "--out", out, "--no-overlays")
    assert code == 1 and "4 photos: 0 localized" in stdout
    assert "warning: 0 of 4 photos localized (the reasons above): exit status 1" in err
    assert (out / "summary.json").is_file() and (out / "poses" / "P0.json").is_file()


def test_a_run_skips_a_photo_without_a_gnss_fix_and_names_swapped_coordinates(tmp_path, capsys):
    """Stop 52's audit: a DJI photo taken before its GNSS fix (GPS 0, 0) stopped the whole run with "the
    image (lat 0, lon 0) is outside the area of use of ...: wrong target CRS?", exit 2, nothing localized.
    Now that photo is skipped with "no GNSS fix" and the others run; a geotag CSV with latitude and
    longitude swapped names its file, line and the swap."""
    root = tmp_path / "flight"
    (root / "photos").mkdir(parents=True)
    city = root / "city.obj"
    city.write_text(box_city_obj())
    model = load_city_model(city, cache=False)
    crs, offset = pyproj.CRS("EPSG:25832"), np.array([500_000.0, 5_400_000.0, 0.0])
    to_wgs = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    truth = Pose.from_xyz_rpy([5.0, -4.0, 90.0], 0.5, 20.0, 30.0)
    world = Pose.from_rotation_center(truth.R_world_from_cam, truth.center + offset)
    prior = world.center + [3.0, 2.0, 2.0]
    lon, lat = to_wgs.transform(prior[0], prior[1])
    yaw, pitch, roll = _dji_angles_true_north(crs, lon, lat, world)
    fields = dict(AbsoluteAltitude=f"{prior[2]:+.3f}", GimbalYawDegree=f"{yaw:+.6f}", RtkFlag="16")
    fields.update(
        GimbalPitchDegree=f"{pitch:+.6f}", GimbalRollDegree=f"{roll:+.6f}", AltitudeType="GpsFusionAlt"
    )
    for name, (la, lo) in {"F001.JPG": (lat, lon), "NOFIX.JPG": (0.0, 0.0)}.items():
        xmp = xmp_packet(GpsLatitude=f"{la:+.10f}", GpsLongitude=f"{lo:+.10f}", **fields)
        dji_jpeg(root / "photos" / name, xmp, size=(CAM.width, CAM.height))
        save_labels_png(oracle_labels(model, CAM, truth), root / "masks" / f"{Path(name).stem}.png")
    cam = root / "K.txt"
    cam.write_text(f"{CAM.fx},{CAM.fy},{CAM.cx},{CAM.cy},{CAM.width},{CAM.height}\n")
    argv = ["run", root / "photos", "--city", city, "--crs", "EPSG:25832", "--offset", "500000,5400000,0"]
    argv += ["--intrinsics", cam, "--masks", root / "masks", "--no-overlays"]
    code, stdout, err = run(capsys, *argv, "--out", tmp_path / "exif")
    assert code == 0, err
    assert "2 photos: 1 localized, 0 not localized, 1 skipped" in stdout
    assert "skipped (1): no usable GPS prior: no GNSS fix (latitude 0, longitude 0" in stdout
    rows = "image,latitude,longitude,height_m,yaw_deg,pitch_deg,roll_deg\n"
    rows += f"F001.JPG,{lon},{lat},{prior[2]},0,-45,0\n"  # longitude in the latitude column
    (root / "swapped.csv").write_text(rows)
    code, _, err = run(capsys, *argv, "--priors", root / "swapped.csv", "--out", tmp_path / "csv")
    assert code == 2 and "no photo can be localized (F001.JPG: no usable GPS prior" in err
    assert "swapped.csv line 2): the position" in err and "latitude and longitude swapped?" in err


def test_a_photo_of_the_truth_skipped_for_its_prior_is_a_miss_in_the_recall(box_flight, tmp_path, capsys):
    """Stop 52's note: a photo skipped for an unusable prior (none in the file, no GNSS fix, outside the
    CRS, 3-100 km off) left the recall's denominator, so a flight scored better by losing the photos it
    could not place. With ``--truth`` such a photo is now a miss: a ``not_localized`` row keeping the skip's
    reason, counted in the summary (``skipped_counted_as_misses``), the closing line, the report's note and
    its misses table; without a true pose it is skipped as before."""
    (box_flight["root"] / "GPS_pose" / "P1_pose.txt").unlink()
    out = tmp_path / "out"
    code, stdout, err = run(capsys, *box_flight["argv"], "--out", out, "--no-overlays")
    assert code == 0, err
    miss = _rows_by_name(out)["P1.JPG"]
    assert miss["status"] == "not_localized" and miss["err_xyz_m"] == "inf"
    assert miss["reason"].startswith("skipped, counted as a miss: no prior pose for P1.JPG in ")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["with_ground_truth"] == 3 and summary["recall_2m2deg"] == pytest.approx(100 / 3)
    assert summary["skipped_counted_as_misses"] == 1 and set(summary["skipped_photos"]) == {"P9.JPG"}
    said = "4 photos: 1 localized, 2 not localized (1 of them skipped, counted as a miss), 1 skipped"
    assert said in stdout
    assert json.loads((out / "poses" / "P1.json").read_text())["reason"] == miss["reason"]
    report = make_report([out], tmp_path / "report", overlays=0)
    assert any("1 skipped, counted as a miss" in n and "P1.JPG (no prior pose" in n for n in report.notes)
    (misses,) = list(csv.DictReader(report.tables["misses"][1].open(encoding="utf-8")))
    assert (misses["hit"], misses["skipped"], misses["unreadable-input"]) == ("1", "1", "1")
    no_truth = box_flight["argv"][: box_flight["argv"].index("--truth")]
    code, _, err = run(capsys, *no_truth, "--out", tmp_path / "no_truth", "--no-overlays")
    assert code == 0, err
    skipped = json.loads((tmp_path / "no_truth" / "summary.json").read_text())["skipped_photos"]
    assert skipped["P1.JPG"].startswith("no prior pose for P1.JPG in ")


def test_an_intrinsics_file_or_a_backends_mask_changed_after_it_finished_is_told_not_kept(
    box_flight, tmp_path, capsys
):
    """Stop 52's note: a photo run fingerprinted the photo, mask and depth files, but not the intrinsics file
    (``--intrinsics``) nor the masks a ``files`` backend reads (``--seg-backend files``): either corrected
    after its photo finished left the old row and pose, exit 0, without a word. Both are now in each row's
    fingerprints and a changed one is refused naming the photo and the file; rows of an earlier version
    without them are kept and said to be unchecked for them."""
    root, out = box_flight["root"], tmp_path / "out"
    argv = [str(a) for a in box_flight["argv"]]
    at = argv.index("--masks")
    argv[at : at + 2] = ["--seg-backend", "files", "--backend-option", f"masks={root / 'masks'}"]
    argv += ["--out", str(out), "--no-overlays"]
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    kept = json.loads(_rows_by_name(out)["P1.JPG"]["meta_json"])["input_fingerprints"]
    assert kept["intrinsics"]["file"] == "P1_intrinsic.txt" and kept["mask"]["file"] == "P1.png"
    code, _, err = run(capsys, *argv)  # nothing changed
    assert code == 0, err
    calibration = root / "intrinsic" / "P0_intrinsic.txt"
    _edit_keeping_times(calibration, lambda p: p.write_text(p.read_text() + "\n"))

    def fix_mask(path: Path) -> None:
        labels = load_labels_png(path)
        labels[:40, :40] = IGNORE
        save_labels_png(labels, path)

    _edit_keeping_times(root / "masks" / "P1.png", fix_mask)
    code, _, err = run(capsys, *argv)
    assert code == 2 and "2 finished photos no longer match their rows" in err, err
    assert "P0.JPG: its intrinsics P0_intrinsic.txt changed (" in err
    assert "P1.JPG: its mask P1.png changed (" in err
    rows = read_results(out / "results.csv")  # as an earlier version wrote them: no such fingerprints
    for row in rows:
        meta = json.loads(row["meta_json"])
        for kind in ("intrinsics", "mask"):
            meta["input_fingerprints"].pop(kind, None)
        row["meta_json"] = json.dumps(meta, sort_keys=True)
    write_rows(out / "results.csv", rows)
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    assert "3 finished photos were run by an earlier version that kept no fingerprints" in err
    assert "intrinsics file and a files backend's mask and depth (before stop 53)" in err


def _headingless_flight(tmp_path) -> tuple[Path, Pose, np.ndarray, list]:
    """One DJI photo over the box city placed at 48.1 N, 11.5 E (EPSG:25832), its XMP without
    GimbalYawDegree (position and pitch known), its oracle mask; (folder, true pose, offset, the run's
    argv without ``--out``: a flight yaw sigma of 3 deg stated). Its prior is 2-3 m off and 120 deg off
    the yaw 0 taken."""
    root = tmp_path / "flight"
    (root / "images").mkdir(parents=True)
    city = root / "city.obj"
    city.write_text(box_city_obj())
    model = load_city_model(city, cache=False)
    offset = np.array([686_100.0, 5_330_400.0, 0.0])  # the box placed at 48.1 N, 11.5 E (EPSG:25832)
    to_wgs = pyproj.Transformer.from_crs("EPSG:25832", "EPSG:4326", always_xy=True)
    truth = pose_from_dji(np.array([120.0, 60.0, 70.0]), -120.0, -30.0, 0.0)  # 120 deg from yaw 0 (grid)
    prior_centre = truth.center + offset + [2.0, -1.5, 2.0]
    lon, lat = to_wgs.transform(prior_centre[0], prior_centre[1])
    fields = dict(GpsLatitude=f"{lat:+.10f}", GpsLongitude=f"{lon:+.10f}")
    fields.update(AbsoluteAltitude=f"{prior_centre[2]:+.3f}", GimbalPitchDegree="-30.0", GimbalRollDegree="0")
    photo = dji_jpeg(root / "images" / "H0.JPG", xmp_packet(**fields), size=(160, 120), focal_35mm=24)
    camera = camera_from_exif(read_dji_metadata(photo))
    save_labels_png(oracle_labels(model, camera, truth), root / "masks" / "H0.png")
    argv = ["run", root / "images", "--city", city, "--masks", root / "masks", "--crs", "EPSG:25832"]
    argv += ["--offset", ",".join(f"{v:g}" for v in offset), "--prior-sigma", "yaw=3", "--no-overlays"]
    return root, truth, offset, argv


def _localized_searching_every_heading(out: Path, truth: Pose, offset: np.ndarray, note: str) -> None:
    """The one photo of ``_headingless_flight`` localized from a prior without a heading: its yaw sigma every
    heading's over the 3 deg stated, its record and row saying ``note``, within 1 m / 1 deg."""
    from semcityloc.citymodel import read_pose_world
    from semcityloc.geometry.uncertainty import NO_HEADING_YAW_DEG

    summary = json.loads((out / "summary.json").read_text())
    assert summary["skipped_photos"] == {} and summary["localized"] == 1, summary
    record = json.loads((out / "poses" / "H0.json").read_text())
    assert record["extra"]["prior_uncertainty"]["yaw_deg"] == NO_HEADING_YAW_DEG
    assert record["extra"]["prior"]["extra"]["heading_known"] is False
    assert note in record["extra"]["warnings"] and note in record["extra"]["prior"]["extra"]["notes"]
    assert note in _rows_by_name(out)["H0.JPG"]["warnings"]
    found = read_pose_world(out / "poses" / "H0.json", pyproj.CRS("EPSG:25832"), crs_offset=list(offset))
    assert center_error_m(found, truth) < 1.0 and rotation_error_deg(found, truth) < 1.0


def test_a_dji_photo_without_a_heading_is_localized_searching_every_heading(tmp_path, capsys):
    """A DJI photo whose XMP has no GimbalYawDegree (position and pitch known) was skipped ("no usable GPS
    prior: the image metadata has no gimbal_yaw_deg"), though a prior without a heading can be searched
    (stop 53). Now its prior has yaw 0 and a yaw sigma that searches every heading, over a smaller yaw
    sigma the user stated for the flight; its record and row say that its tags had no heading. As ground
    truth such tags are refused."""
    from semcityloc.datasets.dji import NO_HEADING_NOTE

    _, truth, offset, argv = _headingless_flight(tmp_path)
    code, _, err = run(capsys, *argv, "--out", tmp_path / "out")
    assert code == 0, err
    _localized_searching_every_heading(tmp_path / "out", truth, offset, NO_HEADING_NOTE)
    # Such tags as ground truth are none: a yaw of 0 taken for the missing one is no true pose.
    code, _, err = run(capsys, *argv, "--truth", "exif", "--out", tmp_path / "truth")
    assert code == 2 and "its tags have no heading (GimbalYawDegree)" in err, err


def test_a_geotag_row_without_a_yaw_is_localized_searching_every_heading(tmp_path, capsys):
    """Stop 54: a geotag CSV (``--priors``) whose row has an empty yaw cell (here Pix4D's angles, pitch 60 =
    DJI's -30) refused the whole run ("line 2: no pix4d_yaw_deg"). Now its photo is localized as a DJI
    photo without GimbalYawDegree is: yaw 0, every heading searched, its record and row saying that its
    geotag row had no yaw; as ``--truth`` the row is refused for that photo, naming file and line. A photo
    of such a row that is not localized (a mask without buildings) keeps its prior in the run's
    ``geotags.csv`` with an empty yaw cell, not the yaw 0 taken for it."""
    from semcityloc.datasets.geotags import NO_YAW_NOTE, read_geotags_csv

    root, truth, offset, argv = _headingless_flight(tmp_path)
    shutil.copy(root / "images" / "H0.JPG", root / "images" / "H1.JPG")
    save_labels_png(np.full((120, 160), IGNORE, np.uint8), root / "masks" / "H1.png")
    metadata = read_dji_metadata(root / "images" / "H0.JPG")
    csv_file = root / "geotags.csv"
    where = f"{metadata.latitude!r},{metadata.longitude!r},{metadata.absolute_altitude_m!r}"
    csv_file.write_text(
        "image,latitude,longitude,height_m,pix4d_yaw_deg,pix4d_pitch_deg,pix4d_roll_deg\n"
        f"H0.JPG,{where},,60,0\nH1.JPG,{where},,60,0\n"
    )
    out = tmp_path / "out"
    code, _, err = run(capsys, *argv, "--priors", csv_file, "--out", out)
    assert code == 0, err
    _localized_searching_every_heading(out, truth, offset, NO_YAW_NOTE)
    assert NO_YAW_NOTE in _rows_by_name(out)["H1.JPG"]["warnings"]
    kept = read_geotags_csv(out / "geotags.csv")["H1.JPG"]
    assert kept.source.startswith("prior (not localized") and not kept.geotag.heading_known
    assert ",,60.000000," in (out / "geotags.csv").read_text().splitlines()[2]
    code, _, err = run(capsys, *argv, "--truth", csv_file, "--out", tmp_path / "truth")
    assert code == 2 and f"its geotag row ({csv_file} line 2) has no yaw" in err, err


def test_a_geotag_row_without_a_pitch_skips_its_photo_and_the_run_goes_on(tmp_path):
    """Stop 55 audit: one row of a ``--priors`` geotag CSV with an empty pitch cell refused the whole run
    ("line 3: no pitch"); now its photo is skipped, as a DJI photo without GimbalPitchDegree is, the reason
    naming the file, the line and the column; the other photos run."""
    root, _, offset, _ = _headingless_flight(tmp_path)
    shutil.copy(root / "images" / "H0.JPG", root / "images" / "H1.JPG")
    shutil.copy(root / "masks" / "H0.png", root / "masks" / "H1.png")
    metadata = read_dji_metadata(root / "images" / "H0.JPG")
    where = f"{metadata.latitude!r},{metadata.longitude!r},{metadata.absolute_altitude_m!r}"
    csv_file = root / "priors.csv"
    csv_file.write_text(
        f"image,latitude,longitude,height_m,yaw,pitch,roll\nH0.JPG,{where},30,-30,0\nH1.JPG,{where},30,,0\n"
    )
    spec = PhotoSpec(
        images=str(root / "images"),
        city=str(root / "city.obj"),
        priors=str(csv_file),
        masks=str(root / "masks"),
        crs="EPSG:25832",
        offset=tuple(offset),
    )
    _, inputs, skipped, _ = spec.resolved()
    assert [i.name for i in inputs] == ["H0.JPG"] and list(skipped) == ["H1.JPG"]
    assert f"no usable GPS prior ({csv_file} line 3): no pitch: without a pitch" in skipped["H1.JPG"]


def test_a_run_of_photos_without_a_heading_says_so_once_and_gives_no_yaw_error_of_a_yaw_taken(
    tmp_path, capsys
):
    """Stop 54 audit: photos whose prior had no heading were fed to the compass notes (their yaw 0 taken
    read as a shared yaw offset: "turned a median 117.8 deg ... a compass bias"), the run never said that
    some photos had no heading, and with ``--truth`` their row gave a prior yaw error and rotation error of
    the yaw taken. Now the run's notes name them once, their yaw is left out of the compass notes, and
    their rows leave the prior's rotation and yaw errors empty (its position error stays)."""
    from semcityloc.benchmark.photo_exports import no_heading_notes

    root, truth, offset, argv = _headingless_flight(tmp_path)
    metadata = read_dji_metadata(root / "images" / "H0.JPG")
    where = f"{metadata.latitude!r},{metadata.longitude!r},{metadata.absolute_altitude_m!r}"
    (root / "priors.csv").write_text(
        f"image,latitude,longitude,height_m,yaw,pitch,roll\nH0.JPG,{where},nan,-30,0\n"
    )
    to_wgs = pyproj.Transformer.from_crs("EPSG:25832", "EPSG:4326", always_xy=True)
    centre = truth.center + offset
    lon, lat = to_wgs.transform(centre[0], centre[1])
    (root / "truth.csv").write_text(
        f"image,latitude,longitude,height_m,yaw,pitch,roll\nH0.JPG,{lat:.10f},{lon:.10f},{centre[2]:.3f},-120,-30,0\n"
    )
    out = tmp_path / "out"
    code, printed, err = run(
        capsys, *argv, "--priors", root / "priors.csv", "--truth", root / "truth.csv", "--out", out
    )
    assert code == 0, err
    row = _rows_by_name(out)["H0.JPG"]
    assert row["status"] == "localized" and float(row["err_xyz_m"]) < 1.0
    assert row["prior_yaw_err_deg"] == "" and row["prior_rot_deg"] == "" and float(row["prior_err_m"]) > 1.0
    (said,) = no_heading_notes(["H0.JPG"])
    assert said in printed + err or said in json.dumps(json.loads((out / "summary.json").read_text()))
    assert "compass bias" not in printed + err


def test_two_photos_of_one_stem_are_refused_and_label_maps_beside_photos_left_out(
    box_flight, tmp_path, capsys
):
    """``X.JPG`` and ``X.png`` photos wrote one ``poses/X.json`` (the second's) and then refused the exports
    with advice that could never help; a label map ``semcityloc label`` wrote beside its photo was
    localized as a photo (stop 56)."""
    images = box_flight["root"] / "images"
    shutil.copy(images / "P0.JPG", images / "P0.png")  # a second photo of the stem P0
    code, _, err = run(capsys, *box_flight["argv"], "--out", tmp_path / "a", "--no-overlays")
    assert code == 2 and err.count("\n") == 1
    assert "P0.JPG and P0.png share the name P0" in err and "rename one" in err
    assert not (tmp_path / "a" / "poses").exists()
    # A label map beside its photo (what ``label --out images`` writes) is no photo: left out, said once.
    shutil.copy(box_flight["root"] / "masks" / "P0.png", images / "P0.png")
    code, stdout, err = run(capsys, *box_flight["argv"], "--out", tmp_path / "b", "--no-overlays")
    assert code == 0 and "1 label map beside the photo of its name (P0.png; semcityloc label's)" in err
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["photos"] == 4 and "P0.png" not in _rows_by_name(tmp_path / "b")
    assert json.loads((tmp_path / "b" / "poses" / "P0.json").read_text())["extra"]["status"] == "localized"
