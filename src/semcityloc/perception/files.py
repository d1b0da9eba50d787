"""Backends that read precomputed masks / depth maps from a folder, by the photo's file stem.

Why: the foundation models are best run on a GPU machine; their outputs come back as files and the
localizer should not care. ``files`` segmentation reads ``<masks>/<stem>.png`` (palette or grey PNG of
class ids, 255 = ignore) or ``<stem>.npy`` (an (H, W) integer label map or a (NUM_CLASSES, H, W)
probability stack), or ``<stem>.jpg`` / ``.jpeg`` when lossy masks are forced (``find_mask``); ``files``
depth reads ``<depth>/<stem>.npy`` (float depth) or ``<stem>.png`` (16-bit,
``semcityloc.io.images.save_depth`` format). A file named after the photo's whole name
(``<stem>.JPG.png``) is found too, unless a ``<stem>`` one is there as well (``named_file``). ``masks=`` /
``depth=`` may also name one file directly.

The stem comes from ``predict(image, name=...)`` (a file name or path; its stem is used). Without a
name, a folder holding exactly one candidate is used; otherwise a ``ParameterError`` asks for the name.
Outputs are resized to the photo by nearest neighbour (labels, probabilities and depth alike).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semcityloc.classes import IGNORE, NUM_CLASSES
from semcityloc.errors import (
    InputFileError,
    LossyMaskError,
    ParameterError,
    ShapeError,
    parameter,
    true_or_false,
)
from semcityloc.io.images import load_depth, load_npy, mask_labels, read_mask_file, resize_nearest
from semcityloc.perception.base import DepthOutput, SegmentationOutput, check_image

MASK_SUFFIXES = (".png", ".npy")
DEPTH_SUFFIXES = (".npy", ".png")
# Masks in a lossy format, looked for only when forced (``--allow-lossy-mask``, ``find_mask``): their
# compression changes class ids along every edge (``io.images.LOSSY_FORMATS``).
LOSSY_MASK_SUFFIXES = (".jpg", ".jpeg")


def first_file(where: Path, base: str, suffixes: tuple[str, ...]) -> Path | None:
    """The first file ``<base><suffix>`` in ``where``, suffixes in order, each also in upper case (a
    ``stat`` per name tried, nothing read); None when there is none."""
    for suffix in suffixes:
        for candidate in (where / f"{base}{suffix}", where / f"{base}{suffix.upper()}"):
            if candidate.is_file():
                return candidate
    return None


def _bases(name: str) -> tuple[str, ...]:
    """The names a photo's file may be called after: its stem, then its whole file name (``P0.JPG.png``,
    as tools that append a suffix name it)."""
    return tuple(dict.fromkeys((Path(str(name)).stem, Path(str(name)).name)))


def named_file(where: Path, name: str, suffixes: tuple[str, ...], what: str) -> Path | None:
    """The file of image ``name`` in folder ``where``: ``<stem><suffix>`` or ``<name><suffix>`` (``_bases``);
    None when there is none, ``InputFileError`` naming both when there is one of each (which is meant is
    not for us to guess)."""
    hits = [path for path in (first_file(where, base, suffixes) for base in _bases(name)) if path is not None]
    if len(hits) > 1:
        raise InputFileError(
            f"{where}: two {what} files for image {Path(str(name)).name!r}: {hits[0].name} and "
            f"{hits[1].name}; keep one"
        )
    return hits[0] if hits else None


def _looked_for(name: str, suffixes: tuple[str, ...]) -> str:
    """The names ``named_file`` tries, for a message: ``P0.png/.npy or P0.JPG.png/.npy``."""
    return " or ".join(f"{base}{'/'.join(suffixes)}" for base in _bases(name))


def find_file(where: Path, name: str | None, suffixes: tuple[str, ...], what: str) -> Path:
    """The file for image ``name`` in folder ``where`` (``named_file``), or ``where`` itself when it is a
    file; without a name, the folder's only file of those suffixes."""
    if where.is_file():
        return where
    if not where.is_dir():
        raise InputFileError(f"{where}: no such {what} folder or file")
    if name is not None:
        path = named_file(where, name, suffixes, what)
        if path is None:
            stem = Path(str(name)).stem
            raise InputFileError(
                f"{where}: no {what} for image {stem!r} (looked for {_looked_for(name, suffixes)})"
            )
        return path
    found = sorted(p for p in where.iterdir() if p.is_file() and p.suffix.lower() in suffixes)
    if len(found) == 1:
        return found[0]
    raise ParameterError(
        f"{where} holds {len(found)} {what} files: pass the image name to pick one (predict(image, name=...))"
    )


def mask_suffixes(allow_lossy: bool) -> tuple[str, ...]:
    """The suffixes of mask files: the lossy ones too when forced (``LOSSY_MASK_SUFFIXES``)."""
    return MASK_SUFFIXES + LOSSY_MASK_SUFFIXES if allow_lossy else MASK_SUFFIXES


def find_mask(where: Path, name: str | None, allow_lossy: bool, lossy_option: str = "allow_lossy") -> Path:
    """``find_file`` of image ``name``'s mask, a JPEG one too when ``allow_lossy``; without it, a JPEG mask
    that is there is named with the parameter that uses it (``_refuse_lossy_mask``) instead of "no mask":
    ``lossy_option`` (``errors.PARAMETERS``), the caller's own keyword (this backend's ``allow_lossy``, a
    run spec's ``allow_lossy_mask``; stop 55: a spec's caller was told ``allow_lossy=True``)."""
    suffixes = mask_suffixes(allow_lossy)
    if name is not None and not allow_lossy and where.is_dir():
        _refuse_lossy_mask(where, name, suffixes, lossy_option)
    return find_file(where, name, suffixes, "mask")


def _refuse_lossy_mask(where: Path, name: str, suffixes: tuple[str, ...], lossy_option: str) -> None:
    """``LossyMaskError`` (as for a lossy mask named ``.png``) when folder ``where`` holds no mask of image
    ``name`` with ``suffixes`` but a JPEG one: the user sees why the file they made is not used and how to
    force it, not "no mask"."""
    if named_file(where, name, suffixes, "mask") is not None:
        return
    lossy = named_file(where, name, LOSSY_MASK_SUFFIXES, "mask")
    if lossy is not None:
        raise LossyMaskError(
            f"{where}: no mask for image {Path(str(name)).stem!r} (looked for {_looked_for(name, suffixes)}) "
            f"but {lossy.name}, a lossy format (JPEG) whose compression changes class ids along every edge: "
            f"save masks as PNG, or {parameter(lossy_option)} uses it"
        )


class FilesSegmentation:
    """``files`` segmentation backend (module docstring)."""

    name = "files"
    classes = ("background", "ground", "wall", "roof", "window", "door")

    def __init__(self, masks: str | Path | None = None, allow_lossy: bool | str = False):
        if masks in (None, ""):
            raise ParameterError("the 'files' segmentation backend needs masks=DIR (or masks=FILE)")
        self.where = Path(masks).expanduser()
        self.allow_lossy = _flag(allow_lossy, "allow_lossy")

    def predict(self, image: np.ndarray, *, name: str | None = None) -> SegmentationOutput:
        """The mask file of photo ``name``, resized to the image, as probabilities and labels."""
        img = check_image(image)
        H, W = img.shape[:2]
        path = find_mask(self.where, name, self.allow_lossy)
        if path.suffix.lower() != ".npy":  # a label image: PNG, or JPEG when forced
            return _from_labels(resize_nearest(read_mask_file(path, self.allow_lossy), W, H))
        # A .npy may also be what only this backend reads: a float probability stack.
        arr = load_npy(path, "mask array")
        if arr.ndim == 3 and arr.shape[0] == NUM_CLASSES and np.issubdtype(arr.dtype, np.floating):
            probs = resize_nearest(np.nan_to_num(arr.astype(np.float32)), W, H, channels_first=True)
            return SegmentationOutput(probs, np.argmax(probs, axis=0).astype(np.uint8))
        if arr.ndim == 2 and np.issubdtype(arr.dtype, np.integer):
            return _from_labels(resize_nearest(mask_labels(arr, path), W, H))
        raise ShapeError(
            f"{path}: expected an (H, W) integer label map or a ({NUM_CLASSES}, H, W) float probability "
            "stack, "
            f"got {arr.dtype} {arr.shape}"
        )


def _from_labels(labels: np.ndarray) -> SegmentationOutput:
    """One-hot probabilities of (H, W) uint8 class ids already checked (``io.images.mask_labels``)."""
    probs = np.zeros((NUM_CLASSES,) + labels.shape, dtype=np.float32)
    known = labels != IGNORE
    rows, cols = np.nonzero(known)
    probs[labels[known], rows, cols] = 1.0
    return SegmentationOutput(probs, labels)


class FilesDepth:
    """``files`` depth backend (module docstring)."""

    name = "files"

    def __init__(self, depth: str | Path | None = None):
        if depth in (None, ""):
            raise ParameterError("the 'files' depth backend needs depth=DIR (or depth=FILE)")
        self.where = Path(depth).expanduser()

    def predict(self, image: np.ndarray, *, name: str | None = None) -> DepthOutput:
        """The depth file of photo ``name``, resized to the image; non-finite or <= 0 is invalid."""
        img = check_image(image)
        H, W = img.shape[:2]
        path = find_file(self.where, name, DEPTH_SUFFIXES, "depth")
        d = resize_nearest(load_depth(path), W, H)
        valid = np.isfinite(d) & (d > 0)
        return DepthOutput(np.where(valid, d, np.inf).astype(np.float32), valid, None)


def files_segmentation_backend(masks=None, allow_lossy=False) -> FilesSegmentation:
    """The registry's factory of the ``files`` segmentation backend (options ``masks=DIR`` and
    ``allow_lossy``, as given on the command line).
    """
    return FilesSegmentation(masks, allow_lossy)


def _flag(value: bool | str, name: str) -> bool:
    """A boolean backend option, given as a bool or as the text of ``--backend-option name=VALUE`` (empty:
    false; else ``errors.true_or_false``)."""
    if isinstance(value, str) and not value.strip():
        return False
    return true_or_false(value, f"backend option {name}")


def with_lossy_masks(options: dict, seg_backend: str | None, allow_lossy_mask: bool) -> dict:
    """The backend options, with the ``files`` segmentation backend told to accept lossy masks when the
    command was given ``--allow-lossy-mask`` (an explicit ``allow_lossy`` option wins)."""
    if allow_lossy_mask and seg_backend == "files":
        return {"allow_lossy": True, **options}
    return dict(options)


def files_depth_backend(depth=None) -> FilesDepth:
    """The registry's factory of the ``files`` depth backend (option ``depth=DIR``)."""
    return FilesDepth(depth)
