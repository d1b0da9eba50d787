"""Outputs that would overwrite an input, two inputs written to one file, writes that fail, ``label``'s resume
and COLMAP's two formats in one folder (stop 55's audit of the commands that write files)."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from semcityloc.benchmark.runfiles import LOCK_FILE, run_lock
from semcityloc.benchmark.warmup import box_city_obj
from semcityloc.cli.main import main
from semcityloc.datasets.colmap import ColmapModel, read_model, write_model
from semcityloc.errors import InputFileError, OutputPathError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import colmap_qvec_tvec
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import load_labels_png, save_labels_png, save_rgb
from semcityloc.perception.autolabel import label_overlay

INTRINSICS = "100,100,64,48,128,96"
POSE = "0,0,150,0,0,0"  # nadir over the box city's centre


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture()
def obj(tmp_path) -> Path:
    path = tmp_path / "u.obj"
    path.write_text(box_city_obj())
    return path


def posed_photos(tmp_path: Path, names: list[str]) -> tuple[Path, Path]:
    """``names`` as 128 x 96 photos in ``tmp_path/photos``, each with a nadir pose in a COLMAP
    ``images.txt`` (its ``cameras.txt`` beside it); returns (photos folder, images.txt)."""
    photos = tmp_path / "photos"
    lines = []
    for i, name in enumerate(names):
        save_rgb(np.full((96, 128, 3), 90 + i, np.uint8), photos / name)
        q, t = colmap_qvec_tvec(Pose.from_xyz_rpy(np.array([10.0 * i, 0.0, 150.0]), 0.0, 0.0, 0.0))
        lines.append(f"{i + 1} {' '.join(f'{v:.12g}' for v in (*q, *t))} 1 {name}\n\n")
    (tmp_path / "images.txt").write_text("# COLMAP\n" + "".join(lines))
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 128 96 100 100 64 48\n")
    return photos, tmp_path / "images.txt"


def label(capsys, obj: Path, photos: Path, poses: Path, out: Path, *extra) -> tuple[int, str, str]:
    return run(capsys, "label", "--city", obj, "--images", photos, "--poses", poses, "--out", out,
               "--no-cache", *extra)  # fmt: skip


# ------------------------------------------------------------------------------ an output that is an input
def test_label_into_its_own_png_photos_is_refused_and_the_photos_stay(obj, tmp_path, capsys):
    photos, poses = posed_photos(tmp_path, ["A.png", "B.png"])
    before = (photos / "A.png").read_bytes()
    code, out, err = label(capsys, obj, photos, poses, photos)
    errors = [line for line in err.splitlines() if line.startswith("semcityloc: error:")]
    assert code == 2 and len(errors) == 1, err
    assert "A.png is an input of this command: writing it would overwrite the input" in err
    assert (photos / "A.png").read_bytes() == before


def test_label_into_the_folder_of_its_jpg_photos_runs_again_over_its_own_label_maps(obj, tmp_path, capsys):
    """``label --images photos --out photos`` of JPG photos, run again (stop 56): the label maps it wrote
    there (``A.png`` beside ``A.JPG``) are its kept maps, not photos that would be overwritten; another
    --out leaves them out of the photos, saying so. A PNG photo beside a JPG of its stem is still refused."""
    photos, poses = posed_photos(tmp_path, ["A.JPG", "B.JPG"])
    code, stdout, err = label(capsys, obj, photos, poses, photos)
    assert code == 0 and "wrote 2 label map(s)" in stdout, err
    made = (photos / "A.png").read_bytes()
    code, stdout, err = label(capsys, obj, photos, poses, photos, "--overlay")
    assert code == 0, err
    assert "2 of 2 already labelled, kept" in stdout and "2 missing overlays drawn" in stdout, stdout
    assert "note" not in err and (photos / "A.png").read_bytes() == made
    code, stdout, err = label(capsys, obj, photos, poses, tmp_path / "labels2")
    assert code == 0 and "wrote 2 label map(s)" in stdout, err
    assert f"A.png, B.png in {photos} are label maps beside photos of their names, not photos: left" in err
    assert sorted(p.name for p in (tmp_path / "labels2").glob("*.png")) == ["A.png", "B.png"]
    save_rgb(np.full((96, 128, 3), 50, np.uint8), photos / "B.png")  # a photo, not a label map
    code, _, err = label(capsys, obj, photos, poses, tmp_path / "labels3")
    assert code == 2 and "B.JPG and B.png would both be written to" in err, err


def test_two_photos_of_one_stem_are_refused_naming_both(obj, tmp_path, capsys):
    photos, poses = posed_photos(tmp_path, ["X.JPG", "X.png"])
    code, out, err = label(capsys, obj, photos, poses, tmp_path / "labels")
    assert code == 2 and "X.JPG and X.png would both be written to" in err, err
    assert not (tmp_path / "labels" / "X.png").exists()


def test_city_convert_onto_its_input_is_refused(obj, tmp_path, capsys):
    before = obj.read_bytes()
    code, _, err = run(capsys, "city", "convert", obj, obj, "--no-cache")
    assert code == 2 and "would overwrite the input" in err, err
    assert obj.read_bytes() == before
    # through another spelling of the same path, and the OBJ's .mtl that another OBJ's export writes
    code, _, err = run(capsys, "city", "convert", obj, tmp_path / "." / "u.obj", "--no-cache")
    assert code == 2 and "would overwrite the input" in err
    mtl = tmp_path / "m.mtl"
    mtl.write_text("newmtl roof\n")
    code, _, err = run(capsys, "city", "convert", mtl, tmp_path / "m.obj", "--no-cache")
    assert code == 2 and "would overwrite the input" in err
    assert mtl.read_text() == "newmtl roof\n"


def test_render_onto_its_photo_is_refused(obj, tmp_path, capsys):
    out = tmp_path / "r"
    save_rgb(np.full((96, 128, 3), 50, np.uint8), out / "labels.png")
    before = (out / "labels.png").read_bytes()
    code, _, err = run(capsys, "render", "--city", obj, "--intrinsics", INTRINSICS, "--pose", POSE,
                       "--image", out / "labels.png", "--out", out, "--no-cache")  # fmt: skip
    assert code == 2 and "would overwrite the input" in err, err
    assert (out / "labels.png").read_bytes() == before


def test_localize_onto_its_prior_and_dji_prior_onto_its_photo_are_refused(obj, tmp_path, capsys):
    out = tmp_path / "r"
    out.mkdir()
    (out / "pose.json").write_text('{"position": [0, 0, 150], "roll": 0, "pitch": 0, "yaw": 0}\n')
    save_labels_png(np.full((96, 128), 2, np.uint8), tmp_path / "mask.png")
    before = (out / "pose.json").read_bytes()
    argv = ["localize", "--city", obj, "--intrinsics", INTRINSICS, "--prior", out / "pose.json"]
    code, _, err = run(capsys, *argv, "--semantic", tmp_path / "mask.png", "--out", out, "--no-cache")
    assert code == 2 and "pose.json is an input of this command" in err, err
    assert (out / "pose.json").read_bytes() == before
    photo = tmp_path / "DJI_0001.JPG"
    photo.write_bytes(b"\xff\xd8 a photo")
    code, _, err = run(capsys, "dataset", "dji-prior", photo, "--crs", "EPSG:25832", "--out", photo)
    assert code == 2 and "DJI_0001.JPG is an input of this command" in err, err
    assert photo.read_bytes() == b"\xff\xd8 a photo"


def test_dataset_overlay_of_two_scenes_with_one_photo_name_is_refused_naming_both(obj, tmp_path, capsys):
    from semcityloc.datasets.lodloc import LodLocQuery, write_lodloc_scene

    cam = Camera(100.0, 100.0, 64.0, 48.0, 128, 96)
    gt = Pose.from_xyz_rpy(np.array([0.0, 0.0, 150.0]), 0.0, 0.0, 0.0)
    prior = Pose.from_xyz_rpy(np.array([5.0, 0.0, 150.0]), 0.0, 0.0, 5.0)
    for scene in ("s1", "s2"):
        write_lodloc_scene(
            tmp_path / "ds" / scene,
            [LodLocQuery("P.JPG", scene, cam, gt_pose_world=gt, prior_pose_world=prior)],
        )
        save_rgb(np.zeros((96, 128, 3), np.uint8), tmp_path / "ds" / scene / "Query_image" / "P.JPG")
    code, _, err = run(capsys, "dataset", "overlay", tmp_path / "ds", "--city", obj, "--out", tmp_path / "o")
    assert code == 2 and "s1/P.JPG and s2/P.JPG would both be written to" in err, err
    assert not (tmp_path / "o" / "P_gt_vs_prior.png").exists()


# ------------------------------------------------------------------------------ writes that fail
def test_a_write_that_fails_is_one_line_and_leaves_no_partial_file(obj, tmp_path, capsys, monkeypatch):
    out = tmp_path / "r"
    (out / "depth.png").mkdir(parents=True)  # a folder where the depth map goes
    code, _, err = run(capsys, "render", "--city", obj, "--intrinsics", INTRINSICS, "--pose", POSE,
                       "--out", out, "--no-cache")  # fmt: skip
    assert code == 2 and "semcityloc: error: cannot write" in err and "depth.png" in err, err
    assert "Traceback" not in err

    photos, poses = posed_photos(tmp_path, ["A.png"])  # before the disk fills up
    import semcityloc.io.files as files

    real_open = open

    def full_disk(path, mode="r", *args, **kwargs):
        fh = real_open(path, mode, *args, **kwargs)
        if "w" in mode and ".tmp" in str(path):
            fh.close()
            with real_open(path, "wb") as part:
                part.write(b"ply\n")  # a few bytes, then the disk is full
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return fh

    monkeypatch.setattr(files, "open", full_disk, raising=False)
    for target in ("m.ply", "m.obj"):
        code, _, err = run(capsys, "city", "convert", obj, tmp_path / "conv" / target, "--no-cache")
        assert code == 2 and "No space left on device; free space" in err, (target, err)
        assert not (tmp_path / "conv" / target).exists()
        assert not [p for p in (tmp_path / "conv").iterdir() if ".tmp" in p.name]
    code, _, err = label(capsys, obj, photos, poses, tmp_path / "labels")
    assert code == 2 and "cannot write" in err and "A.png: No space left on device" in err, err
    assert not (tmp_path / "labels" / "A.png").exists()


# ------------------------------------------------------------------------------ label resumes
def test_label_keeps_finished_and_hand_corrected_labels_unless_overwrite(obj, tmp_path, capsys):
    photos, poses = posed_photos(tmp_path, ["A.png", "B.png", "C.png"])
    out = tmp_path / "labels"
    save_labels_png(np.full((96, 128), 3, np.uint8), out / "B.png")  # corrected by hand
    code, stdout, _ = label(capsys, obj, photos, poses, out)
    assert code == 0 and "1 of 3 already labelled, kept" in stdout and "wrote 2 label map(s)" in stdout
    assert (load_labels_png(out / "B.png") == 3).all()
    code, stdout, _ = label(capsys, obj, photos, poses, out)
    assert code == 0 and "3 of 3 already labelled, kept" in stdout
    code, stdout, _ = label(capsys, obj, photos, poses, out, "--overwrite")
    assert code == 0 and "wrote 3 label map(s)" in stdout and "already labelled" not in stdout
    assert not (load_labels_png(out / "B.png") == 3).all()


def test_an_interrupted_label_run_says_what_it_kept(obj, tmp_path, capsys, monkeypatch):
    """Ctrl-C (a KeyboardInterrupt, what SIGINT raises) right after the second label map is written: the
    run says what it kept and the same command goes on. Interrupted in-process at a fixed photo, so the
    test never races the run (a signal sent from outside may come after a fast run has finished)."""
    import semcityloc.cli.label as cli_label

    photos, poses = posed_photos(tmp_path, [f"P{i:02d}.png" for i in range(5)])
    out = tmp_path / "labels"
    real_save, calls = cli_label.save_labels_png, []

    def save_then_interrupt(labels, path):
        written = real_save(labels, path)
        calls.append(path)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return written

    monkeypatch.setattr(cli_label, "save_labels_png", save_then_interrupt)
    code, _, err = label(capsys, obj, photos, poses, out)
    assert code == 130, err
    assert len(list(out.glob("*.png"))) == 2
    assert f"2/5 done and kept in {out}; the same command again goes on" in err, err
    monkeypatch.setattr(cli_label, "save_labels_png", real_save)
    code, stdout, _ = label(capsys, obj, photos, poses, out)
    assert code == 0 and "2 of 5 already labelled, kept" in stdout and "wrote 3 label map(s)" in stdout


def test_a_resumed_label_run_with_overlay_draws_the_overlays_a_run_without_it_left_out(obj, tmp_path, capsys):
    """Labelled without --overlay, then the same with it (stop 56): each kept photo's missing overlay is
    drawn from its kept label map (a hand correction shows), not left out, and the summary line says so."""
    photos, poses = posed_photos(tmp_path, ["A.png", "B.png", "C.png"])
    out = tmp_path / "labels"
    code, stdout, _ = label(capsys, obj, photos, poses, out)
    assert code == 0 and "wrote 3 label map(s)" in stdout and not (out / "overlays").exists()
    save_labels_png(np.full((96, 128), 3, np.uint8), out / "B.png")  # corrected by hand
    (out / "C.png").unlink()  # labelled again, with its overlay
    code, stdout, err = label(capsys, obj, photos, poses, out, "--overlay")
    assert code == 0 and "2 of 3 already labelled, kept" in stdout, err
    assert "wrote 1 label map(s)" in stdout and "2 missing overlays drawn from the kept label maps" in stdout
    assert sorted(p.name for p in (out / "overlays").iterdir()) == ["A.png", "B.png", "C.png"]
    b = np.asarray(Image.open(out / "overlays" / "B.png"))
    assert (
        b[10, 10].tolist()
        == label_overlay(np.full((96, 128, 3), 91, np.uint8), np.full((96, 128), 3))[10, 10].tolist()
    )  # the corrected map's class, not a fresh render's
    code, stdout, _ = label(capsys, obj, photos, poses, out, "--overlay")
    assert code == 0 and stdout.strip().endswith(f"nothing to label: every photo's label map is in {out}")
    (out / "overlays" / "A.png").unlink()
    save_labels_png(np.full((48, 64), 3, np.uint8), out / "B.png")  # another size: named, not drawn
    (out / "overlays" / "B.png").unlink()
    code, stdout, err = label(capsys, obj, photos, poses, out, "--overlay")
    assert code == 0 and "; 1 missing overlay drawn from the kept label maps" in stdout, err
    assert (
        f"warning: kept, no overlay: the kept label map {out / 'B.png'} is 64x48 pixels, B.png 128x96" in err
    )


def test_a_second_label_run_into_one_folder_is_refused_and_a_stale_lock_taken_over(obj, tmp_path, capsys):
    """Two ``label`` runs into one --out at once (stop 56): the second is refused in one line naming the
    folder and the first's pid, as ``run`` says it; a lock a killed run left is taken over, saying so."""
    photos, poses = posed_photos(tmp_path, ["A.png"])
    out = tmp_path / "labels"
    with run_lock(out):  # another run holds the folder
        code, _, err = label(capsys, obj, photos, poses, out)
        errors = [line for line in err.splitlines() if line.startswith("semcityloc: error:")]
        assert code == 2 and len(errors) == 1, err
        assert f"{out} is in use by another run (pid {os.getpid()}" in err, err
        assert "wait for it to finish or choose another --out" in err, err
        assert not (out / "A.png").exists()
    (out / LOCK_FILE).write_text('{"pid": 999999999, "host": "h", "started": "2026-01-01T00:00:00"}\n')
    code, stdout, err = label(capsys, obj, photos, poses, out)
    assert code == 0 and "wrote 1 label map(s)" in stdout, err
    assert "taking over the stale lock of a run that ended (pid 999999999" in err, err
    assert not (out / LOCK_FILE).exists()


# ------------------------------------------------------------------------------ COLMAP's two formats
def test_colmap_of_one_format_is_not_written_beside_the_other_and_both_are_refused_on_reading(tmp_path):
    model = ColmapModel.from_poses(
        {"a.jpg": (Camera(100.0, 100.0, 64.0, 48.0, 128, 96), Pose.from_xyz_rpy(np.zeros(3), 0, 0, 0))}
    )
    write_model(model, tmp_path / "cg", ".bin")
    with pytest.raises(OutputPathError, match=r"holds a binary COLMAP model already \(cameras.bin"):
        write_model(model, tmp_path / "cg", ".txt")
    assert not (tmp_path / "cg" / "images.txt").exists()
    write_model(model, tmp_path / "cg", ".bin")  # the same format again: replaced
    write_model(model, tmp_path / "both", ".txt")
    for name in ("cameras.bin", "images.bin"):
        (tmp_path / "both" / name).write_bytes((tmp_path / "cg" / name).read_bytes())
    with pytest.raises(InputFileError, match="holds both cameras.bin and cameras.txt"):
        read_model(tmp_path / "both")
    from semcityloc.datasets.photos import PoseFiles

    with pytest.raises(InputFileError, match="holds both images.bin and images.txt"):
        PoseFiles(tmp_path / "both")
