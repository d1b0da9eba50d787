"""Optional bridge between ``pycolmap.Reconstruction`` and our ``ColmapModel`` (``datasets/colmap.py``).

Why isolated: pycolmap's Python API moves between releases (image poses were ``qvec`` / ``tvec`` up to
0.4, a ``Rigid3d`` attribute ``cam_from_world`` in 0.5-3.10 and a method ``cam_from_world()`` later; the
camera model is an enum in newer releases and a string ``model_name`` in older ones). Every version
difference is handled here and nowhere else; the rest of the library only knows ``ColmapModel``. Nothing
needs pycolmap: ``colmap.read_model`` / ``write_model`` read and write both file formats on their own.
Without pycolmap installed every function raises ``OptionalDependencyError`` naming the install command.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.datasets.colmap import ColmapCamera, ColmapImage, ColmapModel, read_model
from semcityloc.errors import OptionalDependencyError


def _pycolmap() -> Any:
    try:
        import pycolmap  # optional dependency, loaded only when used
    except ImportError as exc:
        raise OptionalDependencyError("pycolmap", "colmap", "Converting pycolmap reconstructions") from exc
    return pycolmap


def pycolmap_available() -> bool:
    """Whether the optional ``pycolmap`` imports; callers offer the bridge only then, without importing it
    themselves.
    """
    try:
        _pycolmap()
    except OptionalDependencyError:
        return False
    return True


def _model_name(camera: Any) -> str:
    name = getattr(camera, "model_name", None)
    if isinstance(name, str):
        return name
    model = camera.model
    return getattr(model, "name", str(model)).split(".")[-1]


def _qvec_tvec(image: Any) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(image, "qvec") and not hasattr(image, "cam_from_world"):  # pycolmap <= 0.4
        return np.asarray(image.qvec, dtype=np.float64), np.asarray(image.tvec, dtype=np.float64)
    rigid = image.cam_from_world
    if callable(rigid):  # newer releases: a method
        rigid = rigid()
    xyzw = np.asarray(rigid.rotation.quat, dtype=np.float64)
    return xyzw[[3, 0, 1, 2]], np.asarray(rigid.translation, dtype=np.float64)


def from_reconstruction(reconstruction: Any) -> ColmapModel:
    """Cameras and images of a ``pycolmap.Reconstruction`` as a ``ColmapModel`` (3D points left out)."""
    model = ColmapModel()
    for cam_id, cam in sorted(reconstruction.cameras.items()):
        model.cameras[int(cam_id)] = ColmapCamera(
            int(cam_id), _model_name(cam), int(cam.width), int(cam.height), np.asarray(cam.params)
        )
    for image_id, image in sorted(reconstruction.images.items()):
        qvec, tvec = _qvec_tvec(image)
        model.images[int(image_id)] = ColmapImage(int(image_id), qvec, tvec, int(image.camera_id), image.name)
    return model


def read_with_pycolmap(path: str | os.PathLike) -> ColmapModel:
    """Read a model folder through ``pycolmap.Reconstruction`` (any format pycolmap reads)."""
    pycolmap = _pycolmap()
    return from_reconstruction(pycolmap.Reconstruction(str(Path(path))))


def roundtrip_check(path: str | os.PathLike) -> bool:
    """Does pycolmap read the model folder to the same cameras and images as ``colmap.read_model``?"""
    ours = read_model(path)
    theirs = read_with_pycolmap(path)
    return ours.cameras == theirs.cameras and all(
        theirs.images[i].name == im.name
        and np.allclose(theirs.images[i].qvec * np.sign(theirs.images[i].qvec[0] * im.qvec[0] or 1), im.qvec)
        and np.allclose(theirs.images[i].tvec, im.tvec)
        for i, im in ours.images.items()
    )
