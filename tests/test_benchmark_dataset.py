"""The benchmark over a LoD-Loc-layout data set: oracle / degraded / precomputed masks, outputs, resume."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from semcityloc.benchmark import dataset_source
from semcityloc.benchmark.dataset_source import (
    ESTIMATES_COLMAP_DIR,
    DatasetSpec,
    oracle_labels,
    working_camera,
)
from semcityloc.benchmark.results import REASON_UNFIT, REASON_UNREADABLE, read_results, write_rows
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.runfiles import ESTIMATES_DIR
from semcityloc.cli.main import main
from semcityloc.datasets.colmap import read_model
from semcityloc.datasets.lodloc import LodLocQuery, read_lodloc, write_lodloc_scene
from semcityloc.errors import (
    BenchmarkError,
    InputFileError,
    ParameterError,
    ResumeMismatchError,
    SemCityLocError,
    ShapeError,
    as_flags,
)
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.errors import center_error_m
from semcityloc.geometry.io import read_pose
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import read_mask_file, save_labels_png
from semcityloc.localization.config import LocalizerConfig

CAM = Camera.from_fov(160, 120, 60.0)
BOX_F = [(1, 4, 3, 2), (5, 6, 7, 8), (1, 2, 6, 5), (2, 3, 7, 6), (3, 4, 8, 7), (4, 1, 5, 8)]


def city_obj(seed: int = 3) -> str:
    rng = np.random.default_rng(seed)
    lines, base = [], 0
    for i in range(5):
        for j in range(5):
            w, d, h = rng.uniform(10, 22), rng.uniform(10, 22), rng.uniform(6, 35)
            x0, y0 = i * 32.0 - 80 + rng.uniform(0, 6), j * 32.0 - 80 + rng.uniform(0, 6)
            v = [(x0, y0, 0), (x0 + w, y0, 0), (x0 + w, y0 + d, 0), (x0, y0 + d, 0)]
            v += [(x0, y0, h), (x0 + w, y0, h), (x0 + w, y0 + d, h), (x0, y0 + d, h)]
            lines += [f"v {x:.3f} {y:.3f} {z:.3f}" for x, y, z in v]
            lines += ["f " + " ".join(str(k + base) for k in f) for f in BOX_F]
            base += 8
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("real") / "scene"
    qs = [
        LodLocQuery(
            "DJI_0001_W.JPG",
            "scene",
            CAM,
            gt_pose_world=Pose.from_xyz_rpy([5.0, -3.0, 90.0], 0.5, 1.0, 20.0),
            prior_pose_world=Pose.from_xyz_rpy([9.0, 1.0, 94.0], 0.0, 0.0, 24.0),
        ),
        LodLocQuery(
            "DJI_0002_W.JPG",
            "scene",
            CAM,
            gt_pose_world=Pose.from_xyz_rpy([-10.0, 8.0, 85.0], -0.5, 0.5, -60.0),
            prior_pose_world=Pose.from_xyz_rpy([-14.0, 5.0, 89.0], 0.0, 0.0, -55.0),
        ),
        LodLocQuery(
            "DJI_0003_W.JPG", "scene", CAM, gt_pose_world=None, prior_pose_world=None
        ),  # no GT: skipped
    ]
    write_lodloc_scene(root, qs)
    (root / "Query_image").mkdir()
    for q in qs:
        Image.new("RGB", (CAM.width, CAM.height)).save(root / "Query_image" / q.name)
    (root / "city.obj").write_text(city_obj())
    return root


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SEMCITYLOC_CACHE", str(tmp_path / "cache"))


def spec(dataset_dir, **kw) -> DatasetSpec:
    return DatasetSpec(dataset=str(dataset_dir), preset="default", **kw)


def test_oracle_run_writes_the_benchmark_files_and_says_oracle(dataset_dir, tmp_path):
    out = run_benchmark(spec(dataset_dir), tmp_path / "run", progress=False)
    assert out.complete and len(out.rows) == 2
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["perception"] == "oracle" and run["mode"] == "dataset"
    assert run["skipped_no_gt_or_prior"] == ["DJI_0003_W.JPG"]
    assert run["labels_source"] == "autolabel"
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["perception"] == "oracle" and "oracle" in summary["perception_label"]
    assert summary["queries"] == 2 and summary["recall_2m2deg"] == 100.0  # oracle masks, small prior errors
    for row in out.rows:
        assert json.loads(row["meta_json"])["perception"] == "oracle"
        assert float(row["prior_err_m"]) > 5.0 and float(row["err_xyz_m"]) < 2.0
    assert (tmp_path / "run" / "details" / "q0000.npz").is_file()
    # Estimates as a COLMAP model in the data set's frame, named by image.
    model = read_model(tmp_path / "run" / ESTIMATES_COLMAP_DIR)
    ds = read_lodloc(dataset_dir)
    for name, (camera, pose) in model.poses().items():
        assert camera == CAM
        assert center_error_m(pose, ds.query(name).gt_pose_world) < 2.0
    # ... written from the full-precision estimates kept per query (world frame), one per localized row.
    localized = [r for r in out.rows if r["status"] == "localized"]
    assert (
        len(model.poses()) == len(localized) == len(list((tmp_path / "run" / ESTIMATES_DIR).glob("*.json")))
    )
    for row in localized:
        path = tmp_path / "run" / ESTIMATES_DIR / f"{row['query_id']}.json"
        est = read_pose(path)
        np.testing.assert_allclose(est.center, [float(row[f"est_world_{k}"]) for k in "xyz"], atol=1e-9)
        sigma = json.loads(path.read_text())["extra"]["covariance"]["sigma"]  # the pose's, beside it
        assert np.hypot(sigma[0], sigma[1]) / np.sqrt(2) == pytest.approx(float(row["sigma_xy_m"]), rel=1e-5)
    stated = np.median([float(r["sigma_xy_m"]) for r in localized])
    assert summary["median_sigma_xy_m"] == pytest.approx(stated) and stated > 0


def test_rerun_resumes_and_other_arguments_are_refused(dataset_dir, tmp_path):
    run_benchmark(spec(dataset_dir), tmp_path / "run", progress=False, limit=1)
    again = run_benchmark(spec(dataset_dir), tmp_path / "run", progress=False)
    assert again.complete and again.new_rows == 1
    with pytest.raises(ResumeMismatchError, match="perception"):
        run_benchmark(spec(dataset_dir, perception="oracle-degraded"), tmp_path / "run", progress=False)


def test_degraded_oracle_reports_its_miou(dataset_dir, tmp_path):
    out = run_benchmark(spec(dataset_dir, perception="oracle-degraded"), tmp_path / "deg", progress=False)
    mious = [float(r["query_miou"]) for r in out.rows]
    assert all(50.0 < m < 100.0 for m in mious)
    assert out.summary["perception"] == "oracle-degraded" and "trained" in out.summary["perception_label"]


def test_precomputed_masks_give_the_oracle_result(dataset_dir, tmp_path):
    ds = read_lodloc(dataset_dir)
    model = ds.load_model()
    masks = tmp_path / "masks"
    for q in ds.queries[:2]:
        labels = oracle_labels(model, q.camera, q.gt_pose_world)
        save_labels_png(labels, masks / f"{q.stem}.png")
    via_masks = run_benchmark(
        spec(dataset_dir, perception="masks", masks=str(masks)), tmp_path / "m", progress=False
    )
    oracle = run_benchmark(spec(dataset_dir), tmp_path / "o", progress=False)
    for a, b in zip(via_masks.rows, oracle.rows, strict=True):
        assert a["err_xyz_m"] == b["err_xyz_m"] and a["status"] == b["status"]
        assert json.loads(a["meta_json"])["labels_source"] == "masks"


def mask_and_depth_files(dataset_dir, folder):
    """``folder``/masks (the oracle labels) and ``folder``/depth (no valid depth) of the data set's two
    evaluable queries."""
    ds = read_lodloc(dataset_dir)
    model = ds.load_model()
    masks, depth = folder / "masks", folder / "depth"
    depth.mkdir()
    for q in ds.queries[:2]:
        save_labels_png(oracle_labels(model, q.camera, q.gt_pose_world), masks / f"{q.stem}.png")
        np.save(depth / f"{q.stem}.npy", np.full((CAM.height, CAM.width), np.nan))
    return masks, depth


def test_missing_mask_files_are_named_when_the_run_starts_and_are_misses(
    dataset_dir, tmp_path, capsys, monkeypatch
):
    """A query whose mask (or depth) file is missing was found only at its turn, where it stopped the run
    (possibly an hour in): the run says at its start, from a ``stat`` of each query's files before any is
    read, how many are missing and which, goes on, and each such query is a miss naming the folder. A
    folder holding no query's file is refused in one line before anything is written."""
    masks, depth = mask_and_depth_files(dataset_dir, tmp_path)
    (masks / "DJI_0002_W.png").unlink()
    opened = []
    read_mask = dataset_source.read_inputs
    monkeypatch.setattr(dataset_source, "read_inputs", lambda *a: opened.append(a[1]) or read_mask(*a))
    out = tmp_path / "run"
    argv = ["benchmark", "--dataset", str(dataset_dir), "--perception", "masks", "--masks", str(masks)]
    argv += ["--depth", str(depth), "--preset", "default", "--out", str(out)]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 0, err
    start = [line for line in err.splitlines() if "no mask or depth file" in line]
    assert len(start) == 1 and start[0].startswith("semcityloc: warning: 1 of the 2 queries to run has no")
    assert "(DJI_0002_W.JPG)" in start[0] and str(masks) in start[0]
    assert err.index(start[0]) < err.index("q0001 (DJI_0002_W.JPG) is a miss")  # said first, then at the end
    assert opened == [masks / "DJI_0001_W.png"]  # the missing file's query read nothing
    rows = {r["query_id"]: r for r in read_results(out / "results.csv")}
    miss = rows["q0001"]
    assert rows["q0000"]["status"] == "localized" and miss["status"] == "not_localized"
    assert miss["reason"].startswith(REASON_UNREADABLE) and "no file for query 'DJI_0002_W'" in miss["reason"]
    assert json.loads((out / "summary.json").read_text())["recall_5m5deg"] == 50.0
    # A resume with nothing left to run says nothing at its start.
    assert main(argv) == 0 and "have no mask or depth file" not in capsys.readouterr().err
    # No query's file in the folder (a wrong --depth): refused in one line, nothing written.
    for name in ("DJI_0001_W.npy", "DJI_0002_W.npy"):
        (depth / name).unlink()
    other = tmp_path / "other"
    assert main([*argv[:-1], str(other)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{depth}: no depth file of any of the 2 queries" in err
    assert not (other / "run.json").exists()


DAMAGES = {  # what makes query q0001's input unusable -> a phrase of the reason
    "truncated": "cannot read label image",
    "not an image": "cannot read label image",
    "invalid class ids": "invalid class ids 9",
    "another aspect": "does not have the photo's aspect",
    "truncated depth": "truncated .npy",
}


@pytest.mark.parametrize("damage", DAMAGES)
def test_an_unreadable_mask_is_that_querys_miss_not_the_runs_end(dataset_dir, tmp_path, capsys, damage):
    """A mask or depth file that cannot be read or used (its body truncated, bytes of no image, ids of no
    class, another aspect) costs its query alone: the run finishes, that query's row is not localized with
    the reason naming the file, a one-line warning says so, and the recall keeps it in its denominator (a
    miss): 1 of 2 queries, not 1 of 1."""
    masks, depth = mask_and_depth_files(dataset_dir, tmp_path)
    bad = depth / "DJI_0002_W.npy" if damage == "truncated depth" else masks / "DJI_0002_W.png"
    data = bad.read_bytes()
    if damage.startswith("truncated"):
        bad.write_bytes(data[: len(data) * 2 // 3])
    elif damage == "not an image":
        bad.write_bytes(b"\x00garbage" * 50)
    elif damage == "invalid class ids":
        Image.fromarray(np.full((CAM.height, CAM.width), 9, np.uint8), mode="L").save(bad)
    else:
        save_labels_png(np.zeros((CAM.height, CAM.height), np.uint8), bad)
    out = tmp_path / "run"
    argv = ["benchmark", "--dataset", str(dataset_dir), "--perception", "masks", "--masks", str(masks)]
    code = main([*argv, "--depth", str(depth), "--preset", "default", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    rows = {r["query_id"]: r for r in read_results(out / "results.csv")}
    assert rows["q0000"]["status"] == "localized"
    miss = rows["q0001"]
    said = REASON_UNFIT if damage == "another aspect" else REASON_UNREADABLE  # it reads, it does not fit
    assert miss["status"] == "not_localized" and miss["reason"].startswith(f"{said}: ")
    assert str(bad) in miss["reason"] and DAMAGES[damage] in miss["reason"]
    assert miss["err_xyz_m"] == "inf" and json.loads(miss["meta_json"])["name"] == "DJI_0002_W.JPG"
    warnings = [line for line in err.splitlines() if line.startswith("semcityloc: warning:")]
    assert len(warnings) == 1 and "q0001" in warnings[0] and str(bad) in warnings[0]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["queries"] == 2 and summary["localized"] == 1 and summary["skipped"] == 0
    assert summary["recall_5m5deg"] == 50.0  # the unreadable query is a miss, not left out
    # Its row has no details file and never will: a resume keeps it (nothing to restore, nothing redone).
    code = main([*argv, "--depth", str(depth), "--preset", "default", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0 and "missing" not in err and "localizing them again" not in err, err


def test_dropped_depth_is_named_in_the_rows(dataset_dir, tmp_path):
    """A depth map of noise is dropped, and the row of its query says so in ``warnings``."""
    ds = read_lodloc(dataset_dir)
    model = ds.load_model()
    masks, depth = tmp_path / "masks", tmp_path / "depth"
    depth.mkdir()
    rng = np.random.default_rng(0)
    for q in ds.queries[:2]:
        save_labels_png(oracle_labels(model, q.camera, q.gt_pose_world), masks / f"{q.stem}.png")
        np.save(depth / f"{q.stem}.npy", rng.uniform(1.0, 100.0, (CAM.height, CAM.width)))
    run = spec(dataset_dir, perception="masks", masks=str(masks), depth=str(depth))
    rows = run_benchmark(run, tmp_path / "run", progress=False).rows
    assert len(rows) == 2
    assert all(r["warnings"].startswith("depth map dropped: it looks like noise") for r in rows)
    assert rows == read_results(tmp_path / "run" / "results.csv")


def jpeg_masks(dataset_dir: Path, masks: Path, suffix: str) -> Path:
    """The oracle masks of the data set's first two queries saved as JPEG under ``<stem><suffix>``."""
    ds = read_lodloc(dataset_dir)
    model = ds.load_model()
    masks.mkdir()
    for q in ds.queries[:2]:
        labels = oracle_labels(model, q.camera, q.gt_pose_world)
        labels[labels == 255] = 0  # no ignore: the compression's ids along the edges stay class ids
        Image.fromarray(labels, mode="L").save(masks / f"{q.stem}{suffix}", format="JPEG", quality=100)
    return masks


@pytest.mark.parametrize("command", [("dataset", "benchmark", "{ds}"), ("benchmark", "--dataset", "{ds}")])
def test_lossy_masks_are_refused_unless_forced(dataset_dir, tmp_path, capsys, command):
    """Masks of JPEG content (the ``.png`` name kept) are refused in one line naming the flag; with
    ``--allow-lossy-mask`` they are read and the run completes, the flag kept in run.json."""
    masks = jpeg_masks(dataset_dir, tmp_path / "masks", ".png")
    argv = [a.format(ds=dataset_dir) for a in command]
    argv += ["--perception", "masks", "--masks", str(masks), "--preset", "fast"]
    code = main([*argv, "--out", str(tmp_path / "refused")])
    err = capsys.readouterr().err.strip().splitlines()[-1]  # after the progress line: the error
    assert code == 2 and err.startswith("semcityloc: error:") and "a lossy format" in err
    assert "--allow-lossy-mask" in err and not (tmp_path / "refused" / "summary.json").exists()
    assert main([*argv, "--out", str(tmp_path / "forced"), "--allow-lossy-mask"]) == 0
    rows = read_results(tmp_path / "forced" / "results.csv")
    assert len(rows) == 2 and all(json.loads(r["meta_json"])["labels_source"] == "masks" for r in rows)
    assert json.loads((tmp_path / "forced" / "run.json").read_text())["allow_lossy_mask"] is True
    # Unset, the flag is not in run.json: runs made before it existed resume.
    assert "allow_lossy_mask" not in spec(dataset_dir, perception="masks", masks=str(masks)).run_config()


def test_jpeg_masks_are_found_when_forced_and_named_when_not(dataset_dir, tmp_path, capsys):
    """Masks saved as ``<stem>.jpg`` were never looked for, even with --allow-lossy-mask ("no mask file of
    any query: is it the data set's mask folder?"). Without the flag the refusal names the JPEG and the
    flag; with it they are read (as ``semcityloc run`` does)."""
    masks = jpeg_masks(dataset_dir, tmp_path / "masks", ".jpg")
    stem = read_lodloc(dataset_dir).queries[0].stem
    argv = ["benchmark", "--dataset", str(dataset_dir), "--perception", "masks", "--masks", str(masks)]
    argv += ["--preset", "fast"]
    assert main([*argv, "--out", str(tmp_path / "refused")]) == 2
    err = capsys.readouterr().err
    assert f"{stem}.jpg is there, a lossy format" in err and "--allow-lossy-mask uses it" in err
    assert main([*argv, "--out", str(tmp_path / "forced"), "--allow-lossy-mask"]) == 0
    rows = read_results(tmp_path / "forced" / "results.csv")
    assert len(rows) == 2 and all(json.loads(r["meta_json"])["labels_source"] == "masks" for r in rows)


def test_options_are_checked_before_anything_runs(dataset_dir, tmp_path):
    with pytest.raises(BenchmarkError, match="unknown perception 'gt'; known: oracle, oracle-degraded"):
        run_benchmark(spec(dataset_dir, perception="gt"), tmp_path / "x", progress=False)
    # Named as a Python caller passes them (the command line prints --perception masks, --masks DIR).
    with pytest.raises(BenchmarkError, match=r"^perception='masks' needs masks='DIR' \(one"):
        run_benchmark(spec(dataset_dir, perception="masks"), tmp_path / "x", progress=False)
    with pytest.raises(BenchmarkError) as info:
        run_benchmark(spec(dataset_dir, masks="m"), tmp_path / "x", progress=False)
    assert str(info.value) == (
        "masks=... / depth=... / allow_lossy_mask=True are only used with perception='masks'"
    )
    flags = "--masks / --depth / --allow-lossy-mask are only used with --perception masks"
    assert as_flags(str(info.value)) == flags
    with pytest.raises(ParameterError, match="unknown localizer preset 'huge'"):
        run_benchmark(DatasetSpec(dataset=str(dataset_dir), preset="huge"), tmp_path / "x")
    with pytest.raises(SemCityLocError, match="unknown segmentation preset 'nope'"):
        run_benchmark(spec(dataset_dir, perception="oracle-degraded", seg_quality="nope"), tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_presets_and_helpers():
    assert DatasetSpec(dataset="x").localizer_config() is LocalizerConfig.preset("default")
    sigma = DatasetSpec(dataset="x", prior_sigma="z=20").localizer_config().prior_uncertainty
    assert (sigma.z_m, sigma.xy_m) == (20.0, LocalizerConfig().prior_uncertainty.xy_m)
    with pytest.raises(ParameterError, match="prior uncertainty"):
        DatasetSpec(dataset="x", prior_sigma="z=much")
    big = Camera(3778.4, 3767.4, 2663.6, 1919.7, 5280, 3956)
    small = working_camera(big)
    assert small.width == 1024 and small.height == 767 and small.hfov_deg == pytest.approx(big.hfov_deg)
    assert working_camera(CAM) is CAM


def test_mask_files_are_validated(tmp_path):
    np.save(tmp_path / "ok.npy", np.array([[0, 3], [255, 2]], dtype=np.uint8))
    assert read_mask_file(tmp_path / "ok.npy").tolist() == [[0, 3], [255, 2]]
    np.save(tmp_path / "bad.npy", np.array([[0, 9]], dtype=np.uint8))
    with pytest.raises(InputFileError, match="class ids must be"):
        read_mask_file(tmp_path / "bad.npy")
    np.save(tmp_path / "float.npy", np.zeros((2, 2)))
    with pytest.raises(ShapeError, match="class ids"):
        read_mask_file(tmp_path / "float.npy")


def test_dataset_cli_actions(dataset_dir, tmp_path, capsys):
    import argparse

    from semcityloc.cli import dataset as cli

    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers(dest="command"))

    def run(*argv):
        args = parser.parse_args([str(a) for a in argv])
        return args.func(args), capsys.readouterr().out

    code, out = run("dataset", "info", dataset_dir, "--json")
    info = json.loads(out)
    assert code == 0 and info["queries"] == 3 and info["frame"] == "z-up"
    assert info["images"][0]["prior_err_m"] > 5.0 and info["images"][2]["gt"] is False
    code, out = run(
        "dataset", "colmap", dataset_dir, "--out", tmp_path / "cm", "--poses", "prior", "--binary"
    )
    assert code == 0 and len(read_model(tmp_path / "cm").images) == 2
    code, out = run("dataset", "overlay", dataset_dir, "--out", tmp_path / "ov", "--name", "DJI_0001_W")
    assert code == 0 and (tmp_path / "ov" / "DJI_0001_W_gt_vs_prior.png").is_file()
    code, out = run("dataset", "benchmark", dataset_dir, "--out", tmp_path / "b", "--preset", "default")
    assert code == 0 and "oracle perception" in out and (tmp_path / "b" / "summary.json").is_file()
    with pytest.raises(InputFileError, match="--ecef-origin needs --frame ecef"):
        run("dataset", "benchmark", dataset_dir, "--out", tmp_path / "c", "--ecef-origin", "1,2,3")


def test_a_pose_far_from_the_model_is_that_querys_miss_in_every_dataset_command(
    dataset_dir, tmp_path, capsys
):
    """One GT pose of a data set in another CRS (5,818 km off) stopped ``dataset benchmark`` and ``dataset
    overlay`` with a library's message naming neither photo nor file, and ``dataset info`` printed its prior
    error of 5.8e6 m without a word (stop 55 audit). Now each command names photo, pose file and distance:
    info warns, overlay skips it, the benchmark counts it as a miss (a skipped query) and runs the others."""
    import shutil

    ds = tmp_path / "scene"
    shutil.copytree(dataset_dir, ds)
    pose_file = ds / "GT_pose" / "DJI_0002_W_pose.txt"
    world_from_cam = np.loadtxt(pose_file)
    world_from_cam[1, 3] += 5_818_000.0
    np.savetxt(pose_file, world_from_cam)
    said = f"DJI_0002_W.JPG: {pose_file}: the camera lies 5,818 km from the model"
    assert main(["dataset", "info", str(ds)]) == 0
    assert said in capsys.readouterr().out
    assert main(["dataset", "overlay", str(ds), "--out", str(tmp_path / "ov")]) == 0
    assert f"warning: skipped {said}" in capsys.readouterr().err
    assert (tmp_path / "ov" / "DJI_0001_W_gt_vs_prior.png").is_file()
    assert not (tmp_path / "ov" / "DJI_0002_W_gt_vs_prior.png").exists()
    out = tmp_path / "run"
    assert main(["dataset", "benchmark", str(ds), "--preset", "default", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"warning: skipped, counted as a miss: {said}" in err and "q0001 (DJI_0002_W.JPG) is a miss" in err
    rows = {r["query_id"]: r for r in read_results(out / "results.csv")}
    assert rows["q0000"]["status"] == "localized" and rows["q0001"]["status"] == "not_localized"
    assert said in rows["q0001"]["reason"]
    assert json.loads((out / "summary.json").read_text())["recall_5m5deg"] == 50.0


def test_dataset_options_fit_the_benchmark_command(dataset_dir, tmp_path, capsys):
    """``semcityloc benchmark`` carries the data-set flags beside its own and runs the real-data benchmark."""
    import argparse

    from semcityloc.cli import benchmark as bench_cli
    from semcityloc.cli import dataset as cli

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command")
    bench_cli.register(sub)
    argv = [
        "benchmark",
        "--dataset",
        str(dataset_dir),
        "--format",
        "lodloc",
        "--city",
        str(dataset_dir / "city.obj"),
    ]
    args = parser.parse_args(
        argv + ["--preset", "default", "--out", str(tmp_path / "b"), "--perception", "oracle"]
    )
    assert cli.run_dataset_benchmark(args) == 0
    assert "oracle perception" in capsys.readouterr().out
    assert json.loads((tmp_path / "b" / "run.json").read_text())["city"] == str(dataset_dir / "city.obj")


@pytest.mark.parametrize(
    "extra, named",
    [
        (["--queries", "50"], "--queries"),
        (["--set", "prior_height_m=10"], "--set"),
        (["--scenario", "clean"], "--scenario"),
        (["--prior-extra", "10-20"], "--prior-extra"),
        (["--seg-quality", "zero-shot"], "--seg-quality (only with --perception oracle-degraded)"),
    ],
)
def test_simulation_options_given_to_a_data_set_run_are_refused(dataset_dir, tmp_path, capsys, extra, named):
    """Each of these gave the identical row before (ignored without a word, stop 50's audit)."""
    argv = ["benchmark", "--dataset", str(dataset_dir), *extra, "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert named in err and "options of a simulated benchmark" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_dataset_colmap_leaves_names_with_spaces_out_of_text_and_says_so(tmp_path, capsys):
    """``dataset colmap`` wrote ``DJI 0001.JPG`` into images.txt, which COLMAP reads back as ``DJI`` (its
    text reader cuts a name at the first space): now left out with one warning; ``--binary`` keeps it."""
    import argparse

    from semcityloc.cli import dataset as cli

    root = tmp_path / "scene"
    pose = Pose.from_xyz_rpy([5.0, -3.0, 90.0], 0.5, 1.0, 20.0)
    qs = [LodLocQuery(name, "scene", CAM, gt_pose_world=pose) for name in ("DJI 0001.JPG", "DJI_0002.JPG")]
    write_lodloc_scene(root, qs)
    (root / "Query_image").mkdir()
    for q in qs:
        Image.new("RGB", (CAM.width, CAM.height)).save(root / "Query_image" / q.name)
    (root / "city.obj").write_text(city_obj())
    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers(dest="command"))
    for form, kept in (("text", {"DJI_0002.JPG"}), ("binary", {"DJI 0001.JPG", "DJI_0002.JPG"})):
        argv = ["dataset", "colmap", str(root), "--out", str(tmp_path / form)]
        args = parser.parse_args(argv + (["--binary"] if form == "binary" else []))
        assert args.func(args) == 0
        err = capsys.readouterr().err
        assert {image.name for image in read_model(tmp_path / form).images.values()} == kept
        assert ("1 image left out of images.txt" in err and "DJI 0001.JPG" in err) == (form == "text")


def test_a_mask_or_depth_changed_after_its_query_finished_is_refused_naming_it(dataset_dir, tmp_path, capsys):
    """Stop 52's note: a data-set benchmark kept no fingerprints of its masks, so a mask fixed (or a missing
    one added) after its query finished left the old row in the recall, exit 0, without a word (a photo run
    refuses it). Each row now keeps the size and SHA-256 of its mask and depth files (``meta_json``
    ``input_fingerprints``); a changed one is refused naming the query and the file, with the one-row
    remedy; rows of an earlier version are kept and said to be unchecked."""
    masks, depth = mask_and_depth_files(dataset_dir, tmp_path)
    (masks / "DJI_0002_W.png").rename(tmp_path / "held_back.png")
    out = tmp_path / "run"
    argv = ["benchmark", "--dataset", str(dataset_dir), "--perception", "masks", "--masks", str(masks)]
    argv += ["--depth", str(depth), "--preset", "fast", "--out", str(out)]
    assert main(argv) == 0, capsys.readouterr().err
    rows = read_results(out / "results.csv")
    kept = json.loads(rows[0]["meta_json"])["input_fingerprints"]
    assert kept["mask"]["file"] == "DJI_0001_W.png" and kept["depth"]["file"] == "DJI_0001_W.npy"
    assert json.loads(rows[1]["meta_json"])["input_fingerprints"]["mask"] is None  # the missing mask
    assert main(argv) == 0, capsys.readouterr().err  # nothing changed: summarised again
    labels = read_mask_file(masks / "DJI_0001_W.png")
    labels[:30, :30] = 255
    save_labels_png(labels, masks / "DJI_0001_W.png")
    (tmp_path / "held_back.png").rename(masks / "DJI_0002_W.png")
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "2 finished queries no longer match their rows" in err, err
    assert "DJI_0001_W.JPG: its mask DJI_0001_W.png changed (" in err
    assert "DJI_0002_W.JPG: its mask DJI_0002_W.png reads now" in err
    assert f"delete their rows from {out / 'results.csv'} and run again" in err and "every query" in err
    for row in rows:  # a run folder of an earlier version: kept, said to be unchecked
        meta = json.loads(row["meta_json"])
        meta.pop("input_fingerprints")
        row["meta_json"] = json.dumps(meta, sort_keys=True)
    write_rows(out / "results.csv", rows)
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "2 finished queries were run by an earlier version that kept no fingerprints" in err, err


def test_an_estimate_re_found_with_a_scaled_focal_length_gets_its_own_colmap_camera(tmp_path):
    """(stop 54) ``estimates_colmap/`` gave every image its query's stated camera: a pose the focal check's
    correction re-found with the focal length times s (``focal_scale`` in its estimate file) now has a
    camera of its own with fx, fy times s; the others keep the stated one."""
    from semcityloc.benchmark.dataset_source import write_estimates_colmap
    from semcityloc.geometry.pose_json import write_pose_json
    from semcityloc.localization.focal_check import with_focal_scale

    cam = Camera.from_fov(160, 120, 60.0)
    pose = Pose.from_xyz_rpy([1.0, 2.0, 80.0], 0.0, 20.0, 30.0)
    queries = [LodLocQuery(f"Q{i}.JPG", "s", cam, gt_pose_world=pose) for i in range(2)]
    (tmp_path / ESTIMATES_DIR).mkdir()
    for i, scale in enumerate((None, 0.976)):
        write_pose_json(tmp_path / ESTIMATES_DIR / f"q{i:04d}.json", pose_world=pose, focal_scale=scale)
    cameras = {
        n: c
        for n, (c, _) in read_model(write_estimates_colmap(queries, tmp_path, tmp_path / "c")).poses().items()
    }
    assert cameras == {"Q0.JPG": cam, "Q1.JPG": with_focal_scale(cam, 0.976)}


def test_a_lost_estimate_file_is_refused_naming_it_not_exported_short(dataset_dir, tmp_path):
    """(stop 55) ``rm estimates/q0001.json`` after a finished run, then the same run again: exit 0, the
    summary counting it localized and ``estimates_colmap/`` one image short, without a word. Refused now
    naming the file and the remedy (delete its row, run again), as a photo run's lost ``poses/`` are."""
    out = tmp_path / "run"
    run_benchmark(spec(dataset_dir), out, progress=False)
    (out / ESTIMATES_DIR / "q0001.json").unlink()
    lost = r"1 localized query has no usable estimate file \(q0001.json of DJI_0002_W.JPG: no estimate file\)"
    with pytest.raises(InputFileError, match=lost):
        run_benchmark(spec(dataset_dir), out, progress=False)
    (out / ESTIMATES_DIR / "q0001.json").write_text((out / ESTIMATES_DIR / "q0000.json").read_text())
    with pytest.raises(InputFileError, match=r"is the estimate of 'DJI_0001_W.JPG'.*delete its row"):
        run_benchmark(spec(dataset_dir), out, progress=False)
    rows = [r for r in read_results(out / "results.csv") if r["query_id"] != "q0001"]
    write_rows(out / "results.csv", rows)
    again = run_benchmark(spec(dataset_dir), out, progress=False)
    assert again.complete and again.new_rows == 1
    assert len(read_model(out / ESTIMATES_COLMAP_DIR).poses()) == 2
