"""Label masks as palette PNGs, depth as 16-bit millimetre PNGs and .npy, photos as RGB arrays.

Label PNGs are 8-bit palette images whose index is the ``SemanticClass`` id (palette in
``semcityloc.classes.PALETTE``; index 255 = ignore, drawn white). Depth PNGs hold z-depth as uint16 in
millimetres (0 = no surface). Aerial depths often exceed the 65.535 m that millimetres fit in uint16, so
the unit grows to centimetres or decimetres when needed and is written in the PNG's ``depth_unit_m`` text
chunk (``load_depth`` reads it); the exact float32 metres always go to a ``.npy`` beside the PNG.
"""

from __future__ import annotations

import io
import math
import struct
import tokenize
from collections import Counter
from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin

from semcityloc.classes import IGNORE, NUM_CLASSES, PALETTE, invalid_class_ids
from semcityloc.errors import InputFileError, LossyMaskError, ShapeError, parameter
from semcityloc.io.files import write_atomic

# What Pillow raises on a corrupt or hostile image file (a broken chunk is a SyntaxError, a header naming
# billions of pixels a DecompressionBombError): each becomes an ``InputFileError`` naming the file.
IMAGE_DECODE_ERRORS = (OSError, ValueError, SyntaxError, EOFError, struct.error, Image.DecompressionBombError)


def _palette_bytes() -> list[int]:
    pal = np.zeros((256, 3), dtype=np.uint8)
    pal[:NUM_CLASSES] = PALETTE
    pal[IGNORE] = (255, 255, 255)
    return pal.reshape(-1).tolist()


def _save_image(img: Image.Image, path: Path, **options) -> None:
    """``img`` written whole or not at all (``files.write_atomic``): a kill or a Ctrl-C while a label map
    or overlay is written must not leave a truncated PNG under its final name, which a later run would
    read as that photo's mask. The format follows the suffix, as ``Image.save`` chooses it."""
    fmt = Image.registered_extensions().get(path.suffix.lower())
    if fmt is None:  # PIL's own error for a suffix it does not know
        img.save(path, **options)
        return
    buffer = io.BytesIO()
    img.save(buffer, format=fmt, **options)
    write_atomic(path, buffer.getvalue())


def save_labels_png(labels: np.ndarray, path: str | Path) -> Path:
    """Write an (H, W) label mask as an 8-bit palette PNG whose index is the class id (``classes.PALETTE``;
    255 = ignore, white): lossless, viewable in any image viewer, and read back exactly by
    ``load_labels_png``.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ShapeError(f"label mask must be (H, W), got shape {labels.shape}")
    img = Image.fromarray(labels.astype(np.uint8), mode="P")
    img.putpalette(_palette_bytes())
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _save_image(img, path)
    return path


# Image formats whose compression changes pixel values: a label mask saved so has wrong class ids along every
# edge (and a palette image turned RGB), so such masks are refused unless the caller allows them.
LOSSY_FORMATS = ("JPEG", "MPO", "JPEG2000", "WEBP")


def load_labels_png(
    path: str | Path, allow_lossy: bool = False, lossy_option: str = "allow_lossy"
) -> np.ndarray:
    """(H, W) uint8 class ids from a palette PNG (or a grey PNG whose values are class ids); a mask in a
    lossy format (``LOSSY_FORMATS``) is refused unless ``allow_lossy``, the refusal naming ``lossy_option``
    (``errors.PARAMETERS``: the caller's own keyword, a run spec's ``allow_lossy_mask``; stop 55)."""
    try:
        with Image.open(path) as img:
            _check_label_image(img, path, allow_lossy, lossy_option)
            return np.array(img, dtype=np.uint8)
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: cannot read label image ({exc})") from exc


def check_label_header(
    path: str | Path, allow_lossy: bool = False, lossy_option: str = "allow_lossy"
) -> None:
    """What ``load_labels_png`` refuses that a label image's header tells (a lossy format unless
    ``allow_lossy``, a mode other than palette or grey), its pixels not decoded: a photo run checks every
    mask this way before its first photo (``benchmark.photo_inputs``)."""
    try:
        with Image.open(path) as img:
            _check_label_image(img, path, allow_lossy, lossy_option)
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: cannot read label image ({exc})") from exc


def _check_label_image(img: Image.Image, path: str | Path, allow_lossy: bool, lossy_option: str) -> None:
    """``InputFileError`` naming ``path`` when the opened label image ``img`` is in a lossy format (unless
    ``allow_lossy``: a ``LossyMaskError`` naming ``lossy_option``) or not a palette or grey image."""
    if img.format in LOSSY_FORMATS and not allow_lossy:
        raise LossyMaskError(
            f"{path}: label mask saved as {img.format}, a lossy format: its compression changes "
            f"class ids along every edge; save masks as PNG ({parameter(lossy_option)} forces it)"
        )
    if img.mode not in ("P", "L"):
        raise InputFileError(
            f"{path}: label PNG must be a palette or grey image of class ids, got {img.mode}"
        )


def is_label_map(path: str | Path) -> bool:
    """Whether the image file ``path`` is a label map of semcityloc's classes rather than a photo: a palette
    PNG whose palette begins with ``classes.PALETTE`` (what ``save_labels_png`` writes), or a grey PNG whose
    values are all class ids or ``IGNORE``. False for anything else, and for a file that does not read.
    ``semcityloc label`` leaves such a map beside a photo of its stem out of the photos (stop 56)."""
    try:
        with Image.open(path) as img:
            if img.format != "PNG" or img.mode not in ("P", "L"):
                return False
            if img.mode == "P":
                palette = img.getpalette() or []
                return palette[: 3 * NUM_CLASSES] == PALETTE.reshape(-1).tolist()
            return invalid_class_ids(np.array(img)) is None
    except IMAGE_DECODE_ERRORS:
        return False


def label_maps_beside_photos(images: list[Path]) -> set[Path]:
    """The ``images`` that are label maps beside a photo of their stem (``X.png`` beside ``X.JPG``: what
    ``label --out`` into the photos' own folder wrote, ``is_label_map``): no photos to label or train on,
    nor two photos of one stem (stop 56; ``semcityloc label``, ``perception.training.find_pairs``)."""
    stems = Counter(Path(i).stem for i in images)
    maps = {
        i for i in images if stems[Path(i).stem] > 1 and Path(i).suffix.lower() == ".png" and is_label_map(i)
    }
    photos = {Path(i).stem for i in images if i not in maps}
    return {m for m in maps if Path(m).stem in photos}


def save_depth(depth: np.ndarray, path_png: str | Path) -> tuple[Path, Path]:
    """Depth as a 16-bit PNG (unit in its ``depth_unit_m`` chunk, 0 = nothing) + float32 metres in .npy."""
    depth = np.asarray(depth, dtype=np.float32)
    path_png = Path(path_png)
    path_png.parent.mkdir(parents=True, exist_ok=True)
    finite = np.isfinite(depth)
    top = float(depth[finite].max()) if finite.any() else 0.0
    unit = next((u for u in (0.001, 0.01, 0.1, 1.0) if top / u <= 65535), 1.0)
    q = np.where(finite, np.clip(np.round(depth / unit), 0, 65535), 0).astype(np.uint16)
    info = PngImagePlugin.PngInfo()
    info.add_text("depth_unit_m", repr(unit))
    _save_image(Image.fromarray(q), path_png, pnginfo=info)
    npy = path_png.with_suffix(".npy")
    buffer = io.BytesIO()
    np.save(buffer, depth)
    write_atomic(npy, buffer.getvalue())
    return path_png, npy


def load_npy(path: str | Path, what: str) -> np.ndarray:
    """A numeric array from a ``.npy`` file, its header checked first: no pickled objects, and no shape
    larger than the file holds (a forged header would otherwise allocate terabytes)."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            fmt = np.lib.format
            read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
            shape, _, dtype = read_header(fh)
            payload = path.stat().st_size - fh.tell()
        if dtype.hasobject or dtype.kind not in "biuf":
            raise InputFileError(f"{path}: {what} must hold numbers, got dtype {dtype}")
        if math.prod(shape) * dtype.itemsize > payload:
            raise InputFileError(f"{path}: truncated .npy ({what} of shape {shape} needs more bytes)")
        return np.load(path, allow_pickle=False)
    except InputFileError:
        raise
    except (OSError, ValueError, EOFError, SyntaxError, TypeError, tokenize.TokenError) as exc:
        raise InputFileError(f"{path}: not a readable .npy {what} ({type(exc).__name__}: {exc})") from exc


def load_depth(path: str | Path) -> np.ndarray:
    """Depth (H, W) float64 from ``.npy`` (as stored) or a 16-bit PNG in millimetres (0 -> NaN)."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".npy":
            with np.errstate(invalid="ignore"):  # a signalling NaN is an invalid pixel like any NaN
                d = load_npy(path, "depth map").astype(np.float64)
        else:
            with Image.open(path) as img:
                unit = float(img.info.get("depth_unit_m", 0.001))
                d = np.array(img, dtype=np.float64) * unit
            d[d == 0] = np.nan
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: cannot read depth map ({exc})") from exc
    if d.ndim != 2:
        raise ShapeError(f"{path}: depth must be a 2-D array, got shape {d.shape}")
    return d


# Pillow modes of one channel wider than 8 bits (16-bit PNG/TIFF, 32-bit integer, float): a radiometric
# thermal or multispectral frame. Pillow's own convert("RGB") clips them to 0 or 255.
WIDE_GREY_MODES = frozenset({"I;16", "I;16L", "I;16B", "I;16N", "I", "F"})
# The share of the darkest and brightest pixels a wide grey frame's stretch to 8 bits lets saturate.
STRETCH_PERCENTILES = (0.5, 99.5)


def _stretched_rgb(img: Image.Image) -> Image.Image:
    """An 8-bit RGB image of a one-channel frame wider than 8 bits, stretched between its 0.5th and 99.5th
    percentiles: a thermal frame's values span a few hundred of 65,536 levels, which a fixed /257 turns
    into one flat grey; a NaN or infinite pixel becomes black."""
    values = np.asarray(img, dtype=np.float64)
    finite = np.isfinite(values)
    if not finite.any():
        return Image.new("RGB", img.size)
    lo, hi = np.percentile(values[finite], STRETCH_PERCENTILES)
    scaled = (np.where(finite, values, lo) - lo) / max(hi - lo, 1e-12)
    grey = np.round(np.clip(scaled, 0.0, 1.0) * 255.0).astype(np.uint8)
    return Image.fromarray(grey, mode="L").convert("RGB")


def load_image(path: str | Path, max_width: int | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB; with ``max_width``, a wider photo is shrunk (area filter) to that width, its
    height in proportion (``scaled_size``). A one-channel frame of more than 8 bits (16-bit PNG or TIFF,
    float TIFF) is stretched to 8 bits between its 0.5th and 99.5th percentiles (``_stretched_rgb``)."""
    try:
        with Image.open(path) as img:
            rgb = _stretched_rgb(img) if img.mode in WIDE_GREY_MODES else img.convert("RGB")
            if max_width is not None and rgb.width > max_width:
                rgb = rgb.resize(scaled_size(rgb.width, rgb.height, max_width), Image.Resampling.BOX)
            return np.array(rgb)
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: cannot read image ({exc})") from exc


def scaled_size(width: int, height: int, max_width: int) -> tuple[int, int]:
    """(w, h) of a ``width`` x ``height`` image shrunk to at most ``max_width`` wide, same aspect."""
    if width <= max_width:
        return int(width), int(height)
    return int(max_width), max(1, round(height * max_width / width))


# Masks and depth may come at any resolution, but must show the photo's field of view: their aspect may
# differ from the camera's by this much (rounding of a downscaled size), as the localizer checks masks.
ASPECT_TOLERANCE = 0.02


def _has_aspect(shape: tuple[int, ...], width: int, height: int) -> bool:
    """Whether an (H, W) shape has the aspect of a ``width`` x ``height`` image (``ASPECT_TOLERANCE``)."""
    return abs((shape[1] / shape[0]) / (width / height) - 1.0) <= ASPECT_TOLERANCE


def check_aspect(shape: tuple[int, ...], width: int, height: int, what: str, source: object = None) -> None:
    """``ShapeError`` when an (H, W) array does not have the aspect of a ``width`` x ``height`` image
    (``ASPECT_TOLERANCE``): a mask or depth map of another photo, or cropped."""
    if len(shape) != 2 or min(shape) < 1:
        raise ShapeError(f"{source or what}: {what} must be an (H, W) array, got shape {tuple(shape)}")
    if not _has_aspect(shape, width, height):
        raise ShapeError(
            f"{source or what}: {what} {shape[1]}x{shape[0]} does not have the photo's aspect "
            f"({width}x{height})"
        )


# EXIF orientations (tag 274) that turn the stored pixels by 90 degrees for display (5-8; 2-4 flip or
# turn by 180 degrees, 1 is as stored).
TURNED_ORIENTATIONS = (5, 6, 7, 8)


def exif_orientation(path: str | Path) -> int:
    """The EXIF orientation (tag 274, 1-8) of an image file; 1 (as stored) when it has none or it is not
    one of 1-8. semcityloc works on the STORED pixels, which a camera's calibration and a gimbal's angles
    describe; viewers and many tools (OpenCV's imread, PIL's ``exif_transpose``) show them turned."""
    try:
        with Image.open(path) as img:
            return _orientation_of(img)
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: cannot read image ({exc})") from exc


def _orientation_of(img: Image.Image) -> int:
    """``exif_orientation`` of an opened image (Pillow's errors raised as they come)."""
    value = img.getexif().get(274, 1)
    return value if isinstance(value, int) and 1 <= value <= 8 else 1


def check_aspect_of_photo(
    shape: tuple[int, ...], width: int, height: int, what: str, source: object, orientation: int
) -> None:
    """``check_aspect``, and when the array has the aspect of the photo turned for display by its EXIF
    ``orientation`` (5-8; ``exif_orientation``), a ``ShapeError`` that says so: a mask made from the
    turned photo."""
    try:
        check_aspect(shape, width, height, what, source)
        return
    except ShapeError as exc:
        error = exc
    if orientation in TURNED_ORIENTATIONS and len(shape) == 2 and _has_aspect(shape[::-1], width, height):
        raise ShapeError(
            f"{source or what}: {what} {shape[1]}x{shape[0]} is the photo turned for display (EXIF "
            f"orientation {orientation}); make it of the photo's stored {width}x{height} pixels, which "
            "its calibration and gimbal angles describe (PIL without exif_transpose, OpenCV with "
            "IMREAD_IGNORE_ORIENTATION), or turn it back"
        )
    raise error


def image_size(path: str | Path, what: str = "image") -> tuple[int, int]:
    """``(width, height)`` of an image file, from its header (the pixels are not decoded)."""
    try:
        with Image.open(path) as img:
            return img.size
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: cannot read {what} ({exc})") from exc


def check_decodes(path: str | Path, what: str = "image") -> None:
    """Decode an image file's pixels, so that a truncated or corrupt one fails here (an ``InputFileError``
    naming it) rather than where its pixels are first needed. A JPEG is decoded at an eighth of its size
    (Pillow's draft mode: every byte of its data is still read, in a tenth of the time)."""
    try:
        with Image.open(path) as img:
            _decode_small(img)
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: cannot read {what} ({exc})") from exc


def _decode_small(img: Image.Image) -> None:
    """Decode an opened image's pixels, a JPEG at an eighth of its size (``check_decodes``); the image's
    ``size`` is the reduced one afterwards."""
    img.draft("RGB", (max(1, img.width // 8), max(1, img.height // 8)))  # a no-op but for JPEG
    img.load()


def decoded_size_and_orientation(path: str | Path, what: str = "image") -> tuple[int, int, int]:
    """(width, height, EXIF orientation) of an image file whose pixels decode: ``image_size``,
    ``exif_orientation`` and ``check_decodes`` with their errors, from one opening of the file instead of
    three (a photo run asks this of every photo before its first, ``benchmark.photo_inputs``)."""
    try:
        img = Image.open(path)
    except IMAGE_DECODE_ERRORS as exc:
        raise InputFileError(f"{path}: cannot read {what} ({exc})") from exc
    with img:
        width, height = img.size  # before the draft, which shrinks it
        try:
            orientation = _orientation_of(img)
        except IMAGE_DECODE_ERRORS as exc:
            raise InputFileError(f"{path}: cannot read image ({exc})") from exc
        try:
            _decode_small(img)
        except IMAGE_DECODE_ERRORS as exc:
            raise InputFileError(f"{path}: cannot read {what} ({exc})") from exc
    return width, height, orientation


def save_rgb(image: np.ndarray, path: str | Path, optimize: bool = False) -> Path:
    """An RGB (or grey) uint8 image as a file (format from the suffix); ``optimize``: smallest PNG."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _save_image(Image.fromarray(np.asarray(image, dtype=np.uint8)), path, optimize=optimize)
    return path


def read_mask_file(
    path: str | Path, allow_lossy: bool = False, lossy_option: str = "allow_lossy"
) -> np.ndarray:
    """(H, W) uint8 class ids (0..5, 255 = ignore) from a ``.npy`` or a label PNG (palette or grey image
    whose values are class ids, ``load_labels_png``; lossy formats only with ``allow_lossy``, else refused
    naming ``lossy_option``); ids outside the classes are refused, naming them (``mask_labels``)."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        labels = load_npy(path, "mask")
    else:
        labels = load_labels_png(path, allow_lossy, lossy_option)
    return mask_labels(labels, path)


def mask_labels(labels: np.ndarray, path: str | Path) -> np.ndarray:
    """(H, W) uint8 class ids of a label map read from file ``path``: an (H, W) integer array whose ids are
    classes or ``IGNORE`` (``classes.invalid_class_ids``), else a ``ShapeError`` / an ``InputFileError``
    naming the file and the bad ids."""
    labels = np.asarray(labels)
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer):
        raise ShapeError(
            f"{path}: a mask must be an (H, W) array of class ids, got {labels.shape} {labels.dtype}"
        )
    problem = invalid_class_ids(labels)
    if problem is not None:
        raise InputFileError(f"{path}: {problem}")
    return labels.astype(np.uint8)


def resize_nearest(a: np.ndarray, width: int, height: int, channels_first: bool = False) -> np.ndarray:
    """``a`` resized to ``height`` x ``width`` by nearest neighbour at pixel centres: target row ``i`` takes
    source row ``floor((i + 0.5) * h / height)`` (clipped to ``h - 1``), columns alike; the one rule for
    labels, probabilities, depth and overlays, whatever the ratio. Axes 0 and 1 are resized ((H, W) or
    (H, W, C)), the last two with ``channels_first`` ((C, H, W)). ``a`` itself when it has that size."""
    a = np.asarray(a)
    h, w = a.shape[-2:] if channels_first else a.shape[:2]
    if (h, w) == (height, width):
        return a
    rows = np.minimum(((np.arange(height) + 0.5) * h / height).astype(int), h - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w / width).astype(int), w - 1)
    if channels_first:
        return a[..., rows[:, None], cols[None, :]]
    return a[rows[:, None], cols[None, :]]


def read_depth_file(path: str | Path) -> np.ndarray:
    """(H, W) float64 relative depth from a ``.npy`` or a 16-bit depth PNG (``load_depth``);
    NaN / <= 0 = invalid."""
    if not Path(path).is_file():
        raise InputFileError(f"{path}: no such depth file")
    depth = load_depth(path)
    if not np.issubdtype(depth.dtype, np.number):
        raise ShapeError(f"{path}: depth must be numeric, got {depth.dtype}")
    return depth.astype(np.float64)
