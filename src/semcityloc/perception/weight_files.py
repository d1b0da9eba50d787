"""The files a torch backend's weights are in, found and checked without torch: a trained head's folder
(``head.json`` + ``head.safetensors``) and its spec, the backbone it was trained on, a MoGe-2 ``model.pt``.

Why without torch: a command checks that a backend's weights are there before it loads a city model (a
missing head is said at once, not after a minute of parsing), and a photo run keeps the weights'
fingerprints in its ``run.json`` (``backend_weight_files`` through ``perception.registry``), so that a
head retrained at the same path is another run, not a reason to keep the old poses. Reading ``head.json``
needs no torch; loading the weights does (``perception.segmenter``, ``perception.moge_depth``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from semcityloc.errors import InputFileError, MissingWeightsError, parameter
from semcityloc.perception.base import weights_dir

HEAD_FORMAT = "semcityloc-segmentation-head"
HEAD_VERSION = 1
HEAD_JSON = "head.json"
HEAD_WEIGHTS = "head.safetensors"
DEFAULT_HEAD_DIRS = {"dinov3": "dinov3-dpt-head", "mobilenetv2": "mobilenetv2-head"}
DEFAULT_DINOV3_DIR = "dinov3-vits16"
DEFAULT_MOGE_DIR = "moge-2-vits-normal"
# The weights file of a Hugging Face DINOv3 folder (what its fingerprint is taken of).
DINOV3_WEIGHTS = ("model.safetensors", "pytorch_model.bin")


def head_folder(head: str | Path | None, kind: str) -> Path:
    """The folder of the trained head that ``head`` names: the default one of backbone ``kind``
    (``weights_dir()/DEFAULT_HEAD_DIRS[kind]``) when None; a path to one of its two files is taken as
    the folder holding it (``head=runs/h/head.json`` is the head in ``runs/h``)."""
    if head in (None, ""):
        return weights_dir() / DEFAULT_HEAD_DIRS[kind]
    path = Path(head).expanduser()
    if path.name in (HEAD_JSON, HEAD_WEIGHTS) and path.is_file():
        return path.parent
    return path


def read_head_spec(head_dir: str | Path) -> dict[str, Any]:
    """The spec (``head.json``) of a trained head folder, checked: a ``MissingWeightsError`` saying how to
    train one when the folder lacks its two files, an ``InputFileError`` when the spec is unreadable, not
    ours, of a newer version or incomplete.
    """
    head_dir = Path(head_dir)
    path = head_dir / HEAD_JSON
    if not path.is_file() or not (head_dir / HEAD_WEIGHTS).is_file():
        raise MissingWeightsError(
            f"{head_dir}: no trained segmentation head ({HEAD_JSON} + {HEAD_WEIGHTS}); train one with "
            f"{parameter('train_segmenter')} and pass its folder as {parameter('head', 'DIR')}"
        )
    try:
        spec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFileError(f"{path}: unreadable head description ({exc})") from exc
    if not isinstance(spec, dict) or spec.get("format") != HEAD_FORMAT:
        raise InputFileError(f"{path}: not a semcityloc segmentation head (format {spec.get('format')!r})")
    if int(spec.get("version", 0)) > HEAD_VERSION:
        raise InputFileError(f"{path}: head version {spec['version']} is newer than this semcityloc reads")
    for key in ("backbone", "head", "classes", "input_size", "stride"):
        if key not in spec:
            raise InputFileError(f"{path}: missing key {key!r}")
    return spec
