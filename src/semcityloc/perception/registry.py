"""The built-in perception backends, registered by name (imported lazily: torch loads only when used).

| kind         | name         | options                                              |
|--------------|--------------|------------------------------------------------------|
| segmentation | dinov3-dpt   | head=DIR, backbone=DIR, device, threads              |
| segmentation | mobilenetv2  | head=DIR, backbone=FILE (ImageNet .pth), device, threads |
| segmentation | files        | masks=DIR or FILE                                    |
| depth        | moge2        | model=PATH, device, num_tokens, resolution_level, fov_x, threads |
| depth        | files        | depth=DIR or FILE                                    |
"""

from __future__ import annotations

from semcityloc.perception.base import register_backend

SEG_OPTIONS = ("head", "backbone", "device", "threads")


def _dinov3_dpt(**options):
    from semcityloc.perception.segmenter import dinov3_dpt_backend

    return dinov3_dpt_backend(**options)


def _mobilenetv2(**options):
    from semcityloc.perception.segmenter import mobilenetv2_backend

    return mobilenetv2_backend(**options)


def _files_seg(**options):
    from semcityloc.perception.files import files_segmentation_backend

    return files_segmentation_backend(**options)


def _moge2(**options):
    from semcityloc.perception.moge_depth import moge2_backend

    return moge2_backend(**options)


def _files_depth(**options):
    from semcityloc.perception.files import files_depth_backend

    return files_depth_backend(**options)


register_backend(
    "segmentation", "dinov3-dpt", _dinov3_dpt, SEG_OPTIONS, "frozen DINOv3 ViT + trained DPT head"
)
register_backend(
    "segmentation", "mobilenetv2", _mobilenetv2, SEG_OPTIONS, "frozen ImageNet MobileNetV2 + FPN head"
)
register_backend("segmentation", "files", _files_seg, ("masks",), "precomputed masks read by image stem")
register_backend(
    "depth",
    "moge2",
    _moge2,
    ("model", "device", "num_tokens", "resolution_level", "fov_x", "threads"),
    "MoGe-2 monocular geometry (dlr-moge)",
)
register_backend("depth", "files", _files_depth, ("depth",), "precomputed depth read by image stem")
