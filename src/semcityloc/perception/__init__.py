"""Perception: the query photo's semantic mask and relative depth, and automatic labels to train on.

- ``base``: ``SegmentationBackend`` / ``DepthBackend`` protocols and their outputs; ``registry``: the
  registry (``get_segmentation_backend("dinov3-dpt" | "mobilenetv2" | "files", **options)``,
  ``get_depth_backend("moge2" | "files", **options)``); ``MissingWeightsError`` (from ``semcityloc.errors``)
  is re-exported here;
- ``autolabel``: ``auto_label(model, camera, pose)`` projects model classes into a photo (IGNORE = 255
  where the model says nothing reliable) and ``label_overlay`` draws them for a person;
- ``segmenter`` / ``heads`` / ``dinov3`` / ``mobilenet``: frozen backbones + trainable heads (torch);
- ``training``: ``train_segmenter`` (frozen backbone, cached features, best head saved, resumable);
- ``synthetic``: rendered city views with procedural textures (a training set with known truth);
- ``moge_depth``: MoGe-2; ``files``: precomputed masks / depth by image stem.

Nothing here imports torch until a torch backend is built: the registry and ``autolabel`` work without
the ``[perception]`` extra.
"""

from semcityloc.classes import IGNORE
from semcityloc.errors import MissingWeightsError
from semcityloc.perception.base import DepthBackend, DepthOutput, SegmentationBackend, SegmentationOutput
from semcityloc.perception.registry import available_backends, get_depth_backend, get_segmentation_backend

__all__ = [
    "IGNORE",
    "DepthBackend",
    "DepthOutput",
    "MissingWeightsError",
    "SegmentationBackend",
    "SegmentationOutput",
    "available_backends",
    "get_depth_backend",
    "get_segmentation_backend",
]
