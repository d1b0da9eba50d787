"""What every render engine returns: per-view label masks, and on request z-depth and face ids."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RenderOutput:
    """Images of N views, row-major (N, H, W).

    Attributes:
        labels: uint8 class ids (``SemanticClass``); 0 where no surface is hit (sky / outside the model).
        depth: float32 z-depth along the optical axis in metres, +inf where nothing is hit; None unless
            asked for.
        face_ids: int32 index of the hit triangle in the renderer's scene (``Renderer.scene``), -1 where
            nothing is hit; None unless asked for. ``scene.source_triangle[face_id]`` is the model
            triangle (-1 for the added terrain).
    """

    labels: np.ndarray
    depth: np.ndarray | None = None
    face_ids: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.labels.shape[0])

    def __getitem__(self, index) -> RenderOutput:
        """A subset of the views (an int keeps the leading axis: ``out[3]`` has shape (1, H, W))."""
        if isinstance(index, (int, np.integer)):
            index = slice(int(index), int(index) + 1 if int(index) != -1 else None)
        return RenderOutput(
            labels=self.labels[index],
            depth=None if self.depth is None else self.depth[index],
            face_ids=None if self.face_ids is None else self.face_ids[index],
        )
