"""Intrinsics and lens distortion read from a file or inline text in any of the forms the CLI accepts
(``read_lens``, ``read_intrinsics``: LoD-Loc K matrices, COLMAP ``cameras.txt`` lines, JSON,
``fx,fy,cx,cy,w,h``), and whether they fit the photo they are used with (``check_fits_photo``).
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from semcityloc.errors import CameraError, IntrinsicsMismatchError, UnknownImageSizeError, parameter
from semcityloc.geometry.camera import PRINCIPAL_POINT_TOLERANCE, Camera
from semcityloc.geometry.colmap_text import CAMERA_MODELS, camera_values, is_number, numbers
from semcityloc.geometry.distortion import COEFFICIENTS, LensDistortion
from semcityloc.geometry.spec_text import (
    json_matrix,
    json_number,
    labelled,
    load_spec,
    parse_json,
    pick_entry,
    spec_lines,
)

# COLMAP camera models we read: name -> parameter names. Their distortion is ``LensDistortion``'s model
# (``read_lens``); FULL_OPENCV only without its rational terms k4..k6.
COLMAP_MODELS: dict[str, tuple[str, ...]] = {
    name: CAMERA_MODELS[name][1]
    for name in ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")
}
_RATIONAL_TERMS = ("k4", "k5", "k6")


INTRINSICS_FORMS = (
    "a 3x4 [K|0] or 3x3 K matrix (LoD-Loc *_intrinsic.txt), 'name PINHOLE w h fx fy cx cy' "
    "(COLMAP; also SIMPLE_PINHOLE w h f cx cy), JSON, or 'fx,fy,cx,cy,w,h'"
)


def _size_from_principal_point(c: float, axis: str) -> int:
    """Image size 2c for a principal point c at the image centre (LoD-Loc files do not store the size)."""
    size = 2.0 * c
    if not math.isfinite(size) or size < 1 or abs(size - round(size)) > 1e-6:
        raise UnknownImageSizeError(
            f"cannot infer the image {axis} from c{'x' if axis == 'width' else 'y'}={c:g} "
            f"(not at the centre of a whole-pixel image): pass the image {axis}"
        )
    return int(round(size))


def implied_size(cx: float, cy: float, width: int, height: int) -> tuple[int, int] | None:
    """The size ``2 cx`` x ``2 cy`` a sizeless K (LoD-Loc's ``[K|0]``) was made for when an image of
    ``width`` x ``height`` is that size resized by one exact factor (a downscaled copy: 320x256 of a
    640x512 K), else None (the same size, another aspect, or a principal point off any whole-pixel
    centre: the K is taken at the given size, as it is). Such a K is then read as one that states its size
    and resampled the same way (``read_lens``: ``check_fits_photo``, then ``Camera.scaled``)."""
    w2, h2 = 2.0 * cx, 2.0 * cy
    if not (math.isfinite(w2) and math.isfinite(h2)) or w2 < 1 or h2 < 1:
        return None
    if abs(w2 - round(w2)) > 1e-6 or abs(h2 - round(h2)) > 1e-6:
        return None
    implied = (int(round(w2)), int(round(h2)))
    if implied == (width, height) or width * implied[1] != height * implied[0]:
        return None
    return implied


def _camera(
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    own_w: int | None,
    own_h: int | None,
    width: int | None,
    height: int | None,
) -> Camera:
    """The camera at its own size if it has one (``read_lens`` resamples it to the requested size, after
    checking it against the photo it is for; a sizeless K of which the given size is an exact-factor resize
    has ``implied_size``), else at the given size, else ``2 cx`` x ``2 cy``."""
    if own_w is None and own_h is None and width is not None and height is not None:
        own_w, own_h = implied_size(cx, cy, width, height) or (None, None)
    if own_w is not None and own_h is not None:
        if (width is None) != (height is None):
            raise CameraError(
                f"intrinsics are for {own_w}x{own_h}; give both width and height to resample them, or neither"
            )
        return Camera(fx, fy, cx, cy, own_w, own_h)
    w = width if width is not None else _size_from_principal_point(cx, "width")
    h = height if height is not None else _size_from_principal_point(cy, "height")
    return Camera(fx, fy, cx, cy, w, h)


def _resampled(camera: Camera, width: int | None, height: int | None) -> Camera:
    """``camera`` at ``width`` x ``height`` when both are given and differ from its size (``Camera.scaled``:
    the same field of view, e.g. a downscaled image)."""
    if width is None or height is None or (width, height) == camera.size:
        return camera
    return camera.scaled(width, height)


def _is_resized(size: tuple[int, int], other: tuple[int, int]) -> bool:
    """Whether an image of size ``other`` is one of ``size`` resized by one factor, each side rounded to
    whole pixels: what ``Camera.scaled`` resamples intrinsics for. Another aspect is another image."""
    (w, h), (w2, h2) = size, other
    return abs(h * w2 / w - h2) <= 1.0 or abs(w * h2 / h - w2) <= 1.0


def check_fits_photo(camera: Camera, source: str, photo: tuple[str, int, int]) -> None:
    """``IntrinsicsMismatchError`` naming ``source`` (the intrinsics' file), the photo and both sizes unless
    ``camera`` (at the size the file states, or was placed at) can describe ``photo`` (name, width, height):
    its size is the photo's or the photo is it resized (``_is_resized``), and its principal point is
    within ``PRINCIPAL_POINT_TOLERANCE`` of the image centre (the bound DJI's calibration tags are held to).
    Why: the intrinsics of another image (a thermal camera's 640x512 on a 2325x1742 photo) localize
    nothing, and the run then blames the map and the prior."""
    name, width, height = photo
    if camera.size != (width, height) and not _is_resized(camera.size, (width, height)):
        raise IntrinsicsMismatchError(
            f"{source}: intrinsics of a {camera.width}x{camera.height} image do not fit photo {name} "
            f"({width}x{height}), which is no resized copy of it: the calibration of another camera or "
            "image size"
        )
    offset = camera.principal_point_offset()
    if offset > PRINCIPAL_POINT_TOLERANCE:
        raise IntrinsicsMismatchError(
            f"{source}: principal point ({camera.cx:g}, {camera.cy:g}) lies {100 * offset:.0f} % of the "
            f"image size off the centre of photo {name} ({width}x{height}; at most "
            f"{100 * PRINCIPAL_POINT_TOLERANCE:.0f} %): it is the centre of a {2 * camera.cx:.0f}x"
            f"{2 * camera.cy:.0f} image, the calibration of another camera or image size"
        )


def _check_K(K: np.ndarray) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of a 3x3 K or 3x4 [K|0]; anything else that is not a pinhole K -> CameraError."""
    if K.shape[1] == 4 and np.abs(K[:, 3]).max() > 0:
        raise CameraError("a 3x4 intrinsic matrix must be [K|0] (its last column is not zero)")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise CameraError("not an intrinsic matrix: expected [[fx 0 cx] [0 fy cy] [0 0 1]]")
    if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0):
        raise CameraError("skewed intrinsics (K[0][1] != 0) are not supported")
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])


def _lens_from_json(obj: Any, width: int | None, height: int | None) -> tuple[Camera, LensDistortion]:
    camera = _camera_from_json(obj, width, height)
    terms = {k: json_number(obj, k, CameraError) for k in COEFFICIENTS if k in obj}
    return camera, LensDistortion(**terms)


def _camera_from_json(obj: Any, width: int | None, height: int | None) -> Camera:
    if not isinstance(obj, dict):
        raise CameraError(f"intrinsics JSON must be an object, got {type(obj).__name__}")
    size = [None, None]
    for i, key in enumerate(("width", "height")):
        if key in obj:
            v = json_number(obj, key, CameraError)
            if not v.is_integer():
                raise CameraError(f"{key!r} must be a whole number of pixels, got {v:g}")
            size[i] = int(v)
    if (size[0] is None) != (size[1] is None):
        raise CameraError("intrinsics JSON has only one of 'width' and 'height'")
    if "K" in obj:
        fx, fy, cx, cy = _check_K(json_matrix(obj["K"], ((3, 3), (3, 4)), "K"))
    else:
        missing = [k for k in ("fx", "fy", "cx", "cy") if k not in obj]
        if missing:
            raise CameraError(
                f"intrinsics JSON needs 'fx', 'fy', 'cx', 'cy' (or 'K'); missing {', '.join(missing)}"
            )
        fx, fy, cx, cy = (json_number(obj, k, CameraError) for k in ("fx", "fy", "cx", "cy"))
    return _camera(fx, fy, cx, cy, size[0], size[1], width, height)


def _colmap_lens(
    tokens: list[str], at: int, width: int | None, height: int | None
) -> tuple[Camera, LensDistortion]:
    model, w, h, params = camera_values(tokens, at, COLMAP_MODELS)
    rational = {k: params[k] for k in _RATIONAL_TERMS if params.get(k, 0.0) != 0}
    if rational:
        terms = ", ".join(f"{k}={v:g}" for k, v in rational.items())
        raise CameraError(
            f"{model} has rational distortion terms ({terms}), which are not supported: calibrate with "
            "OPENCV (k1 k2 p1 p2) or undistort the images first"
        )
    fx = params.get("fx", params.get("f"))
    fy = params.get("fy", params.get("f"))
    camera = _camera(fx, fy, params["cx"], params["cy"], w, h, width, height)
    return camera, LensDistortion.from_params(params)


def _camera_entries(
    text: str, width: int | None, height: int | None
) -> dict[str, tuple[Camera, LensDistortion]]:
    rows = spec_lines(text)
    if not rows:
        raise CameraError(f"no intrinsic values; expected {INTRINSICS_FORMS}")
    model_at = [next((i for i in (0, 1) if i < len(r) and r[i].upper() in COLMAP_MODELS), None) for r in rows]
    if any(m is not None for m in model_at):
        out = {}
        for r, at in zip(rows, model_at, strict=True):
            if at is None:
                raise CameraError(
                    f"line {' '.join(r)[:60]!r} names no camera model; expected {INTRINSICS_FORMS}"
                )
            out[r[0] if at == 1 else ""] = _colmap_lens(r, at, width, height)
        return out
    for r in rows:
        if len(r) > 2 and not is_number(r[1]) and is_number(r[2]):
            raise CameraError(f"unsupported camera model {r[1]!r} (supported: {', '.join(COLMAP_MODELS)})")
    values = [numbers(r, CameraError) for r in rows]
    counts = [len(v) for v in values]
    if len(rows) == 3 and (all(c == 4 for c in counts) or all(c == 3 for c in counts)):
        return {"": (_camera(*_check_K(np.array(values)), None, None, width, height), LensDistortion())}
    if len(rows) == 1 and counts[0] in (4, 6):
        v = values[0]
        own = (None, None)
        if counts[0] == 6:
            if not (v[4].is_integer() and v[5].is_integer()):
                raise CameraError(f"image size must be whole pixels, got {v[4]:g} x {v[5]:g}")
            own = (int(v[4]), int(v[5]))
        return {"": (_camera(v[0], v[1], v[2], v[3], *own, width, height), LensDistortion())}
    shape = " / ".join(str(c) for c in counts[:5]) + (" / ..." if len(counts) > 5 else "")
    raise CameraError(
        f"{len(rows)} line(s) with {shape} numbers are not intrinsics; expected {INTRINSICS_FORMS}"
    )


def read_intrinsics(
    spec: str | os.PathLike,
    width: int | None = None,
    height: int | None = None,
    name: str | None = None,
    photo: tuple[str, int, int] | None = None,
) -> Camera:
    """Pinhole intrinsics from a file or inline text (``read_lens``'s forms and ``photo`` check);
    ``CameraError`` when they carry a non-zero lens distortion, since a caller of this function uses the
    image as it is."""
    camera, distortion = read_lens(spec, width, height, name, photo)
    if not distortion.is_zero:
        terms = ", ".join(f"{k}={v:g}" for k, v in distortion.as_dict().items() if k != "model" and v)
        raise CameraError(
            f"{load_spec(spec, CameraError, 'intrinsics')[1]}: non-zero lens distortion "
            f"({terms}); these images are taken as pinhole ones: undistort them first (colmap "
            f"image_undistorter), or give them to {parameter('undistorting')}, which undistorts photo, mask "
            "and depth"
        )
    return camera


def read_lens(
    spec: str | os.PathLike,
    width: int | None = None,
    height: int | None = None,
    name: str | None = None,
    photo: tuple[str, int, int] | None = None,
) -> tuple[Camera, LensDistortion]:
    """Intrinsics and lens distortion (``geometry.distortion``; zero for the pinhole forms) from a file or
    inline text. Accepted forms:

    - LoD-Loc ``*_intrinsic.txt``: a 3x4 ``[K|0]`` (or 3x3 ``K``) matrix. It stores no image size: unless
      ``width`` / ``height`` are given they are taken as ``2 cx`` / ``2 cy`` (principal point at the image
      centre; the real file has cx = 320, cy = 256 for a 640x512 image). A principal point that is not at
      the centre of a whole-pixel image raises ``CameraError`` asking for the size. A ``width`` x
      ``height`` that is ``2 cx`` x ``2 cy`` resized by one exact factor (a downscaled photo) resamples the
      K as a stated size is (``implied_size``);
    - a COLMAP ``cameras.txt`` / LoD-Loc ``intrinsic.txt`` line ``name MODEL w h params`` (or without the
      name/id), MODEL one of PINHOLE ``fx fy cx cy``, SIMPLE_PINHOLE ``f cx cy``, SIMPLE_RADIAL ``f cx cy
      k``, RADIAL ``f cx cy k1 k2``, OPENCV ``fx fy cx cy k1 k2 p1 p2`` and FULL_OPENCV with its rational
      terms k4..k6 zero; several lines need ``name``;
    - JSON ``{"fx", "fy", "cx", "cy", "width", "height"}`` or ``{"K": 3x3, "width", "height"}``
      (``Camera.as_dict`` output reads back), optionally with ``"k1", "k2", "p1", "p2", "k3"``;
    - inline ``fx,fy,cx,cy,w,h`` (or ``fx,fy,cx,cy`` with the size rule above).

    When the intrinsics carry their own size and both ``width`` and ``height`` are given and differ, the
    camera is resampled to that size (``Camera.scaled``: same field of view, e.g. a downscaled image; the
    distortion, in normalised coordinates, is the same at any size).

    ``photo``: (name, width, height) of the photo the intrinsics are used with; before any resampling they
    must fit it (``check_fits_photo``: the same size or the photo resized, a principal point near the
    centre), else ``IntrinsicsMismatchError`` naming the file, the photo and both sizes.
    """
    for key, value in (("width", width), ("height", height)):
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0
        ):
            raise CameraError(f"image {key} must be a positive integer, got {value!r}")
    text, label = load_spec(spec, CameraError, "intrinsics")

    def parse() -> dict[str, tuple[Camera, LensDistortion]]:
        if text.lstrip().startswith(("{", "[")):
            return {"": _lens_from_json(parse_json(text), width, height)}
        return _camera_entries(text, width, height)

    entries = labelled(label, parse)
    if list(entries) == [""]:
        camera, distortion = entries[""]
    else:
        camera, distortion = labelled(label, pick_entry, entries, name, CameraError, "camera")
    if photo is not None:
        check_fits_photo(camera, label, photo)
    camera = labelled(label, _resampled, camera, width, height)
    labelled(label, distortion.check, camera)
    return camera, distortion
