"""The registry that picks a perception backend by name, and the built-in backends registered in it.

Each torch-based factory imports its backend module when called (torch, transformers and moge load only when
a backend is used, never on ``import semcityloc``).

| kind         | name         | options                                              |
|--------------|--------------|------------------------------------------------------|
| segmentation | dinov3-dpt   | head=DIR, backbone=DIR, device, threads              |
| segmentation | mobilenetv2  | head=DIR, backbone=FILE (ImageNet .pth), device, threads |
| segmentation | files        | masks=DIR or FILE                                    |
| depth        | moge2        | model=PATH, device, num_tokens, resolution_level, fov_x, threads |
| depth        | files        | depth=DIR or FILE                                    |
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from semcityloc.errors import ParameterError, parameter, unknown_choice
from semcityloc.io.stamps import file_fingerprint
from semcityloc.perception.base import DepthBackend, SegmentationBackend
from semcityloc.perception.files import files_depth_backend, files_segmentation_backend
from semcityloc.perception.torch_utils import require_torch
from semcityloc.perception.weight_files import (
    head_classes_warning,
    moge2_weight_files,
    segmenter_weight_files,
)


@dataclass(frozen=True)
class BackendEntry:
    """One registered backend: its kind (segmentation or depth), name, factory, the options it accepts and a
    one-line summary for ``--help`` and error messages.
    """

    kind: str  # "segmentation" | "depth"
    name: str
    factory: Callable[..., Any]
    options: tuple[str, ...]
    summary: str
    # ``weights(**options)`` -> {role: path} of the weight files the backend reads (None where it cannot
    # tell: a hub id); raises the backend's missing-weights error (``backend_weight_files``).
    weights: Callable[..., dict[str, Path | None]] | None = None


_REGISTRY: dict[tuple[str, str], BackendEntry] = {}


def register_backend(
    kind: str,
    name: str,
    factory: Callable[..., Any],
    options: tuple[str, ...],
    summary: str = "",
    weights: Callable[..., dict[str, Path | None]] | None = None,
) -> None:
    """Add a backend: ``factory(**options)`` builds it; ``options`` are the option names it accepts;
    ``weights(**options)`` names the weight files it reads (``backend_weight_files``), if any."""
    if kind not in ("segmentation", "depth"):
        raise ParameterError(f"backend kind must be 'segmentation' or 'depth', got {kind!r}")
    _REGISTRY[(kind, name)] = BackendEntry(kind, name, factory, tuple(options), summary, weights)


def available_backends(kind: str) -> tuple[str, ...]:
    """The names of the registered backends of ``kind``, sorted; what ``--backend`` accepts and what an
    unknown name's error lists.
    """
    return tuple(sorted(n for k, n in _REGISTRY if k == kind))


def backend_entry(kind: str, name: str) -> BackendEntry:
    """The registered backend ``name`` of ``kind``; a ``ParameterError`` listing the known names otherwise."""
    entry = _REGISTRY.get((kind, str(name)))
    if entry is None:
        raise unknown_choice(f"{kind} backend", name, available_backends(kind))
    return entry


def _filter_options(entry: BackendEntry, options: dict[str, Any]) -> dict[str, Any]:
    known_anywhere = {o for e in _REGISTRY.values() for o in e.options}
    unknown = sorted(k for k in options if k not in known_anywhere)
    if unknown:
        raise unknown_choice(f"{entry.kind} backend {entry.name!r} option(s)", unknown, entry.options)
    return {k: v for k, v in options.items() if k in entry.options and v is not None}


# The parameter that selects a backend of each kind (``errors.PARAMETERS``: ``--seg-backend`` on the CLI).
SELECTED_BY = {"segmentation": "seg_backend", "depth": "depth_backend"}


def check_backend_options(seg_backend: str | None, depth_backend: str | None, options) -> None:
    """Refuse, before anything loads, an option (``options``: names, or a mapping / (key, value) pairs) that
    neither selected backend takes: one no backend knows is a typo (``unknown_choice``); one of a backend
    that is not selected (``model=`` without ``--depth-backend moge2``) would be ignored without a word
    (``_filter_options`` drops it), so it is named with its backend and the option that selects it."""
    pairs = options.items() if isinstance(options, dict) else options
    items = [(kv, None) if isinstance(kv, str) else (kv[0], kv[1]) for kv in pairs]
    selected = {
        kind: name for kind, name in (("segmentation", seg_backend), ("depth", depth_backend)) if name
    }
    taken = {o for kind, name in selected.items() for o in backend_entry(kind, name).options}
    for key, value in items:
        if key in taken:
            continue
        owners = [e for e in _REGISTRY.values() if key in e.options]
        if not owners:
            raise unknown_choice(
                "backend option(s)",
                [key],
                sorted(taken) or sorted({o for e in _REGISTRY.values() for o in e.options}),
            )
        given = key if value is None else f"{key}={value}"
        whose = " or ".join(
            f"the {e.kind} backend {e.name} ({parameter(SELECTED_BY[e.kind], e.name)})" for e in owners
        )
        chosen = ", ".join(
            f"the {kind} backend is {selected[kind]}" if kind in selected else f"no {kind} backend is given"
            for kind in SELECTED_BY
        )
        raise ParameterError(
            f"backend option {given} is not used: it is an option of {whose}, but {chosen}; select that "
            "backend or leave the option out"
        )


def get_segmentation_backend(name: str, **options: Any) -> SegmentationBackend:
    """A segmentation backend by name: ``dinov3-dpt``, ``mobilenetv2``, ``files`` (module docstring)."""
    entry = backend_entry("segmentation", name)
    return entry.factory(**_filter_options(entry, options))


def get_depth_backend(name: str, **options: Any) -> DepthBackend:
    """A depth backend by name: ``moge2``, ``files`` (module docstring)."""
    entry = backend_entry("depth", name)
    return entry.factory(**_filter_options(entry, options))


def backend_weight_files(
    seg_backend: str | None, depth_backend: str | None, options
) -> dict[str, Path | None]:
    """{role: path} of the weight files the selected backends read with ``options`` (``head``,
    ``head_spec``, ``backbone``, ``model``; a path None where it cannot be told, e.g. a hub id), found
    without torch and without loading them: a missing head or MoGe-2 file raises its
    ``MissingWeightsError`` here, so a command can call this before it loads a city model. Empty for
    backends without weights (``files``)."""
    options = dict(options)
    out: dict[str, Path | None] = {}
    for kind, name in (("segmentation", seg_backend), ("depth", depth_backend)):
        if name:
            entry = backend_entry(kind, name)
            if entry.weights is not None:
                out.update(entry.weights(**_filter_options(entry, options)))
    return out


def backend_warnings(seg_backend: str | None, options) -> list[str]:
    """What a command says, once, before it runs the segmentation backend ``seg_backend`` with ``options``:
    a trained head that predicts no roof or no wall (``weight_files.head_classes_warning``). Read from
    ``head.json`` without torch."""
    spec = backend_weight_files(seg_backend, None, options).get("head_spec")
    warning = head_classes_warning(spec.parent) if spec is not None else None
    return [warning] if warning else []


def weight_fingerprints(
    seg_backend: str | None, depth_backend: str | None, options
) -> dict[str, dict | None]:
    """``io.stamps.file_fingerprint`` (name, size, SHA-256) of each file of ``backend_weight_files``: what a
    photo run keeps in its ``run.json`` (``perception_weights``), so that a head retrained at the same path
    makes another run. Every file is hashed in full (a streamed SHA-256, kept per process while the file's
    stamp holds): the backend reads it in full right after anyway, and size + modification time would miss
    a file replaced with ``cp -p`` and refuse a run folder copied to another machine."""
    files = backend_weight_files(seg_backend, depth_backend, options)
    return {role: None if path is None else file_fingerprint(path) for role, path in files.items()}


SEG_OPTIONS = ("head", "backbone", "device", "threads")


def _dinov3_dpt(**options):
    # named as asked for (the module imports would name a part of it)
    require_torch("the dinov3-dpt backend")
    # needs torch (optional [perception] extra): imported when the backend is built
    from semcityloc.perception.segmenter import dinov3_dpt_backend

    return dinov3_dpt_backend(**options)


def _mobilenetv2(**options):
    # named as asked for (the module imports would name a part of it)
    require_torch("the mobilenetv2 backend")
    # needs torch (optional [perception] extra): imported when the backend is built
    from semcityloc.perception.segmenter import mobilenetv2_backend

    return mobilenetv2_backend(**options)


def _files_seg(**options):
    return files_segmentation_backend(**options)


def _moge2(**options):
    # named as asked for (the module imports would name a part of it)
    require_torch("the moge2 backend")
    # needs torch (optional [perception] extra): imported when the backend is built
    from semcityloc.perception.moge_depth import moge2_backend

    return moge2_backend(**options)


def _files_depth(**options):
    return files_depth_backend(**options)


register_backend(
    "segmentation",
    "dinov3-dpt",
    _dinov3_dpt,
    SEG_OPTIONS,
    "frozen DINOv3 ViT + trained DPT head",
    functools.partial(segmenter_weight_files, "dinov3"),
)
register_backend(
    "segmentation",
    "mobilenetv2",
    _mobilenetv2,
    SEG_OPTIONS,
    "frozen ImageNet MobileNetV2 + FPN head",
    functools.partial(segmenter_weight_files, "mobilenetv2"),
)
register_backend(
    "segmentation", "files", _files_seg, ("masks", "allow_lossy"), "precomputed masks read by image stem"
)
register_backend(
    "depth",
    "moge2",
    _moge2,
    ("model", "device", "num_tokens", "resolution_level", "fov_x", "threads"),
    "MoGe-2 monocular geometry (dlr-moge)",
    moge2_weight_files,
)
register_backend("depth", "files", _files_depth, ("depth",), "precomputed depth read by image stem")
