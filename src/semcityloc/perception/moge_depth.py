"""MoGe-2 monocular depth (``dlr-moge``: ``moge.model.v2.MoGeModel``) as a ``DepthBackend``.

Loading: a MoGe-2 checkpoint is one ``model.pt`` holding ``{"model_config": {...}, "model": state_dict}``.
``MoGeModel.from_pretrained`` loads it with ``strict=False`` (a truncated or foreign checkpoint would run
with random layers) and falls back to the hub for any path that does not exist; ``load_moge2`` instead
reads the local file itself and compares the key sets and shapes, so a wrong file is an error.

Inference on CPU uses ``use_fp16=False``: MoGe's default fp16 autocast took 146 s instead of 2 s per image
here. The default ``resolution_level`` is 0 (MoGe's 1200 base tokens) instead of MoGe's 9 (3600 tokens):
its decoder runs at 16x the token grid, so cost grows with the tokens; measured on CPU (1 thread) with a
ViT-S model at 512x384, 3600 tokens took about 3.5x as long as 1200 (the localizer compares depth at
about 128x96 anyway). The normal head, if the checkpoint has one, is dropped after the strict load
check (normals are not used and MoGe runs every head present).

Output: ``depth`` is MoGe's metric-scaled z-depth (treated as relative by the localizer, which fits a
scale and shift), ``valid`` its mask (finite, positive), ``K`` its estimated intrinsics converted from
MoGe's normalised form (focal / size, principal point 0.5) to pixels of the photo.

Install: ``pip install --no-deps dlr-moge`` plus ``dlr-utils3d``, ``opencv-python-headless``, ``scipy``,
``huggingface_hub`` (its declared dependencies pull torchvision and gradio, which we do not need).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from semcityloc.errors import MissingWeightsError, ParameterError
from semcityloc.perception.base import (
    DepthOutput,
    check_image,
)
from semcityloc.perception.torch_utils import device_of, image_tensor, parse_threads, require, require_torch
from semcityloc.perception.weight_files import MOGE_DOWNLOAD_HINT, default_moge2_path, moge2_model_file

torch = require_torch("MoGe-2 depth")

# Buffers a checkpoint may omit without harm: fixed ImageNet statistics, rebuilt by the constructor.
OPTIONAL_KEYS = frozenset({"encoder.image_mean", "encoder.image_std"})


def load_moge2(spec: str | Path | None = None, device: str | None = None):
    """``MoGeModel`` from a ``model.pt`` with a strict key/shape check, in eval mode (module docstring)."""
    require("moge.model.v2", "dlr-moge", "MoGe-2 depth")
    require("utils3d", "dlr-utils3d", "MoGe-2 depth")
    from moge.model.v2 import MoGeModel  # optional dependency, loaded only when used

    path = moge2_model_file(spec)  # the file, found (a hub id fetched) before anything heavy loads
    hint = MOGE_DOWNLOAD_HINT.format(default=default_moge2_path())
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle / zip errors of many types
        raise MissingWeightsError(f"{path}: not a readable MoGe-2 checkpoint ({exc}); {hint}") from None
    if not isinstance(checkpoint, dict) or "model_config" not in checkpoint or "model" not in checkpoint:
        raise MissingWeightsError(f"{path}: expected {{'model_config', 'model'}} (a MoGe-2 model.pt); {hint}")
    config = dict(checkpoint["model_config"])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = MoGeModel(**config)
    except Exception as exc:  # an unknown config raises what the constructor raises
        raise MissingWeightsError(
            f"{path}: its model_config is not a MoGe-2 (v2) model ({exc}); {hint}"
        ) from None
    state = checkpoint["model"]
    own = model.state_dict()
    missing = sorted(set(own) - set(state) - OPTIONAL_KEYS)
    unexpected = sorted(set(state) - set(own))
    bad = [k for k in own if k in state and tuple(own[k].shape) != tuple(state[k].shape)]
    if missing or unexpected or bad:
        raise MissingWeightsError(
            f"{path}: weights do not match its model_config (missing {missing[:3]}, unexpected "
            f"{unexpected[:3]}, wrong shape {bad[:3]}); {hint}"
        )
    model.load_state_dict(state, strict=False)
    if hasattr(model, "normal_head"):
        del model.normal_head  # normals are not used; MoGe runs every head present (~1/4 of the decoder)
    model.to(device_of(device))
    model.eval()
    return model


def _number(value, kind, name: str, lo: float, hi: float):
    """An option given as a number or a string (CLI), checked against [lo, hi]; None stays None."""
    if value in (None, ""):
        return None
    try:
        out = kind(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a number, got {value!r}") from None
    if not lo <= out <= hi:
        raise ParameterError(f"{name} must be in [{lo:g}, {hi:g}], got {value!r}")
    return out


class MoGe2Backend:
    """``DepthBackend`` running MoGe-2 (module docstring)."""

    name = "moge2"

    def __init__(
        self,
        model=None,
        device: str | None = None,
        num_tokens: int | str | None = None,
        resolution_level: int | str = 0,
        fov_x: float | str | None = None,
        threads: int | str | None = None,
        module=None,
    ):
        self.threads = parse_threads(threads)
        self.num_tokens = _number(num_tokens, int, "num_tokens", 1, 100_000)
        self.resolution_level = _number(resolution_level, int, "resolution_level", 0, 9) or 0
        self.fov_x = _number(fov_x, float, "fov_x", 1.0, 179.0)
        self.model = module if module is not None else load_moge2(model, device)

    def predict(self, image: np.ndarray, *, name: str | None = None) -> DepthOutput:
        """MoGe-2's depth of ``image`` with the pixels it found valid, and its intrinsics if sane."""
        img = check_image(image)
        H, W = img.shape[:2]
        if self.threads is not None:
            torch.set_num_threads(self.threads)
        x = image_tensor(img, normalize=False)[0].to(self.model.device)
        use_fp16 = self.model.device.type == "cuda"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # MoGe's fp32 autocast warns on CPU
            out = self.model.infer(
                x,
                num_tokens=self.num_tokens,
                resolution_level=self.resolution_level,
                fov_x=self.fov_x,
                apply_mask=False,
                use_fp16=use_fp16,
            )
        depth = out["depth"].float().cpu().numpy()
        valid = np.isfinite(depth) & (depth > 0)
        if "mask" in out:
            valid &= out["mask"].cpu().numpy().astype(bool)
        K = None
        if "intrinsics" in out:
            Kn = out["intrinsics"].double().cpu().numpy()
            if np.all(np.isfinite(Kn)) and Kn[0, 0] > 0 and Kn[1, 1] > 0:  # untrained nets can give nonsense
                K = np.array([[Kn[0, 0] * W, 0, Kn[0, 2] * W], [0, Kn[1, 1] * H, Kn[1, 2] * H], [0, 0, 1]])
        return DepthOutput(np.where(valid, depth, np.inf).astype(np.float32), valid, K)


def moge2_backend(model=None, device=None, num_tokens=None, resolution_level=0, fov_x=None, threads=None):
    """``moge2``: model=PATH to model.pt or its folder (default ``weights_dir()/moge-2-vits-normal``)."""
    return MoGe2Backend(model, device, num_tokens, resolution_level, fov_x, threads)
