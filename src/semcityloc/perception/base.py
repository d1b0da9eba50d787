"""What a perception backend is and what it returns (``perception.registry`` picks one by name).

Why: the localizer needs a semantic mask (and optionally a relative depth map) of the query photo. Where
they come from is the user's choice: a DINOv3 + DPT head, the offline MobileNetV2 head, MoGe-2, or files
computed elsewhere (a GPU box). Every such source is a *backend* with one ``predict(image)`` method, and
``get_segmentation_backend(name, **options)`` / ``get_depth_backend(name, **options)`` build one from a
name and string options (what ``--backend-option key=value`` passes on the command line).

Conventions of every backend:

- input: an (H, W, 3) uint8 RGB photo (an (H, W) grey image is taken as RGB with equal channels);
- ``SegmentationOutput.probs`` is (NUM_CLASSES, H, W) float32 at the photo's size, channel index =
  ``SemanticClass`` id (channels of classes the backend does not predict are 0); ``labels`` is the
  (H, W) uint8 argmax as class ids;
- ``DepthOutput.depth`` is (H, W) float32 relative depth (any positive scale; +inf/NaN allowed only where
  ``valid`` is False), ``K`` the 3x3 pixel intrinsics the model estimated, or None.

Options: each backend declares the option names it accepts. The same option dict may be handed to a
segmentation and a depth backend (the CLI does), so an option that another registered backend knows is
ignored; an option no backend knows is a ``ParameterError`` (a typo). The commands check first that each
option is taken by a selected backend (``registry.check_backend_options``).

Weights are never fetched silently: a missing file raises ``MissingWeightsError`` naming what to download
and where to put it (default folder: ``weights_dir()``). Hugging Face hub ids are looked up only when
``HF_HUB_OFFLINE`` is not set, and hub failures become the same one-line error.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from semcityloc.cache import cache_root
from semcityloc.classes import CLASS_NAMES, NUM_CLASSES
from semcityloc.errors import TRUE_WORDS, ParameterError, ShapeError, unknown_choice

# Photos are shrunk to this width before a backend runs on them (``io.images.load_image(max_width=...)``):
# the localizer compares masks at 64-128 px and resamples any size itself, so a 5280 px photo costs no more
# than a 1024 px one and gives the same masks.
PHOTO_MAX_WIDTH = 1024


# ---------------------------------------------------------------------------------------------- outputs
@dataclass
class SegmentationOutput:
    """Per-pixel class probabilities (NUM_CLASSES, H, W) float32 and labels (H, W) uint8 class ids."""

    probs: np.ndarray
    labels: np.ndarray

    def __post_init__(self) -> None:
        self.probs = np.asarray(self.probs, dtype=np.float32)
        self.labels = np.asarray(self.labels, dtype=np.uint8)
        if self.probs.ndim != 3 or self.probs.shape[0] != NUM_CLASSES:
            raise ShapeError(f"probs must be ({NUM_CLASSES}, H, W), got {self.probs.shape}")
        if self.labels.shape != self.probs.shape[1:]:
            raise ShapeError(f"labels {self.labels.shape} do not match probs {self.probs.shape}")


@dataclass
class DepthOutput:
    """Relative depth (H, W) float32, validity (H, W) bool and the estimated 3x3 intrinsics (or None)."""

    depth: np.ndarray
    valid: np.ndarray
    K: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.depth = np.asarray(self.depth, dtype=np.float32)
        self.valid = np.asarray(self.valid, dtype=bool)
        if self.depth.ndim != 2 or self.valid.shape != self.depth.shape:
            raise ShapeError(
                f"depth and valid must be equal (H, W), got {self.depth.shape}, {self.valid.shape}"
            )
        if self.K is not None:
            self.K = np.asarray(self.K, dtype=np.float64)
            if self.K.shape != (3, 3):
                raise ShapeError(f"K must be 3x3, got {self.K.shape}")

    def masked(self) -> np.ndarray:
        """Depth as float64 with NaN where not valid (what ``Query.from_arrays`` takes)."""
        return np.where(self.valid, self.depth.astype(np.float64), np.nan)


# ---------------------------------------------------------------------------------------------- protocols
@runtime_checkable
class SegmentationBackend(Protocol):
    """What the localizer needs from any segmenter: ``predict(image)`` -> class probabilities and labels.

    A protocol (not a base class) so that a backend from anywhere -- a trained head, a foundation model, masks
    computed on another machine -- plugs in through the registry without importing this package's torch code.
    ``classes`` names the classes it can predict (a subset of ``CLASS_NAMES``), so a caller knows which
    classes the localizer may score.
    """

    name: str
    classes: tuple[str, ...]  # the class names this backend predicts (a subset of CLASS_NAMES)

    def predict(self, image: np.ndarray, *, name: str | None = None) -> SegmentationOutput:
        """Class probabilities and labels of an RGB ``image`` (``name``: the photo's file name)."""


@runtime_checkable
class DepthBackend(Protocol):
    """What the localizer needs from any depth estimator: ``predict(image)`` -> relative depth and validity.

    A protocol for the same reason as ``SegmentationBackend``. The depth may be relative (unknown scale and
    shift): the localizer's depth cost fits both per view.
    """

    name: str

    def predict(self, image: np.ndarray, *, name: str | None = None) -> DepthOutput:
        """Relative depth and its validity for an RGB ``image`` (``name``: the photo's file name)."""


# ---------------------------------------------------------------------------------------------- helpers
def check_image(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB from an RGB / RGBA / grey uint8 array; anything else -> ShapeError."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ShapeError(f"image must be uint8 (0-255), got dtype {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.shape[0] < 1 or img.shape[1] < 1:
        raise ShapeError(f"image must be (H, W, 3) RGB or (H, W) grey, got shape {img.shape}")
    return np.ascontiguousarray(img[..., :3])


def weights_dir() -> Path:
    """Where weights are looked for by default: ``$SEMCITYLOC_WEIGHTS``, else ``weights`` under the one
    cache root (``cache.cache_root()``: ``$SEMCITYLOC_CACHE`` or ``$XDG_CACHE_HOME`` or ``~/.cache``, then
    ``semcityloc``), read at call time."""
    env = os.environ.get("SEMCITYLOC_WEIGHTS")
    return Path(env) if env else cache_root() / "weights"


def hub_offline() -> bool:
    """True when ``HF_HUB_OFFLINE`` is set to a true value (read at call time, not at import)."""
    return os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in TRUE_WORDS


def looks_like_hub_id(spec: str) -> bool:
    """``owner/name`` with no path separators beyond the one slash, not starting like a path, and whose
    ``owner`` is no folder here: ``weights/dinov3-vits16`` beside a ``weights/`` folder is a local path that
    is missing (said at once), not a hub id to try on the network for half a minute."""
    parts = str(spec).split("/")
    if not (len(parts) == 2 and all(parts) and not str(spec).startswith((".", "~")) and "\\" not in spec):
        return False
    return not Path(parts[0]).is_dir()


def class_probs_to_output(probs: np.ndarray, classes: tuple[str, ...]) -> SegmentationOutput:
    """(len(classes), H, W) probabilities of the named classes -> ``SegmentationOutput`` in class-id space."""
    probs = np.asarray(probs, dtype=np.float32)
    full = np.zeros((NUM_CLASSES,) + probs.shape[1:], dtype=np.float32)
    ids = [CLASS_NAMES.index(c) for c in classes]
    full[ids] = probs
    labels = np.asarray(ids, dtype=np.uint8)[np.argmax(probs, axis=0)]
    return SegmentationOutput(full, labels)


def check_classes(classes) -> tuple[str, ...]:
    """Class names as a tuple of known, distinct, lower-case names (ParameterError otherwise)."""
    if isinstance(classes, str):
        classes = [c for c in classes.split(",") if c.strip()]
    out = tuple(str(c).strip().lower() for c in classes)
    unknown = [c for c in out if c not in CLASS_NAMES]
    if unknown:
        raise unknown_choice("class name(s)", unknown, CLASS_NAMES)
    if len(set(out)) != len(out) or len(out) < 2:
        raise ParameterError(f"classes must be at least two distinct names, got {list(out)}")
    return out
