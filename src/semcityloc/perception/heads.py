"""The trainable part of a segmenter: a DPT head for ViT tokens, a small FPN head for CNN pyramids.

- ``DPTSegHead`` (the paper's "lightweight DPT decoder"): ``transformers``' ``DPTNeck`` (reassemble the
  four token maps at 4x, 2x, 1x, 1/2x the patch grid, fuse coarse-to-fine) and
  ``DPTSemanticSegmentationHead``, configured through a ``DPTConfig`` whose ``hidden_size`` is the
  backbone's. Its logits come out at the network input size (patch 16: grid x 16).
- ``FPNSegHead``: 1x1 projections of the four maps (strides 4-32) to one width, upsampled to stride 4 and
  summed, a 3x3 conv and a 1x1 classifier. Logits at stride 4.

Both take ``(features, grid)`` as a backbone returns them and give (B, C, h, w) logits; the segmenter
upsamples them to the input size. Their constructor arguments are plain JSON values (``params``), which
is how a saved head is rebuilt (``segmenter.py``).
"""

from __future__ import annotations

from semcityloc.errors import ParameterError, unknown_choice
from semcityloc.perception.torch_utils import require_torch

torch = require_torch("segmentation heads")
nn = torch.nn
F = torch.nn.functional


class DPTSegHead(nn.Module):
    """DPT neck + semantic segmentation head over 4 ViT token maps (module docstring)."""

    kind = "dpt"

    def __init__(
        self,
        hidden_size: int,
        num_classes: int,
        neck_hidden_sizes: tuple[int, ...] = (48, 96, 192, 384),
        fusion_hidden_size: int = 64,
        dropout: float = 0.1,
    ):
        super().__init__()
        # transformers: optional [perception] extra, loaded only when a DPT head is built
        from transformers import DPTConfig
        from transformers.models.dpt.modeling_dpt import DPTNeck, DPTSemanticSegmentationHead  # optional

        if len(neck_hidden_sizes) != 4:
            raise ParameterError(f"neck_hidden_sizes must have 4 entries, got {list(neck_hidden_sizes)}")
        self.params = {
            "hidden_size": int(hidden_size),
            "num_classes": int(num_classes),
            "neck_hidden_sizes": [int(v) for v in neck_hidden_sizes],
            "fusion_hidden_size": int(fusion_hidden_size),
            "dropout": float(dropout),
        }
        config = DPTConfig(
            hidden_size=int(hidden_size),
            neck_hidden_sizes=[int(v) for v in neck_hidden_sizes],
            reassemble_factors=[4, 2, 1, 0.5],
            fusion_hidden_size=int(fusion_hidden_size),
            readout_type="project",
            num_labels=int(num_classes),
            semantic_classifier_dropout=float(dropout),
            hidden_act="gelu",
            is_hybrid=False,
            use_auxiliary_head=False,
        )
        self.neck = DPTNeck(config)
        self.head = DPTSemanticSegmentationHead(config)

    def forward(self, features, grid):
        """Class logits from the ViT tokens reassembled on their patch grid (DPT neck, then head)."""
        if grid is None:
            raise ParameterError("a DPT head needs ViT tokens and their patch grid (use a DINOv3 backbone)")
        fused = self.neck(list(features), grid[0], grid[1])
        return self.head(fused)


class FPNSegHead(nn.Module):
    """Light FPN head over a 4-level CNN pyramid (module docstring)."""

    kind = "fpn"

    def __init__(
        self, in_channels: tuple[int, ...], num_classes: int, channels: int = 64, dropout: float = 0.1
    ):
        super().__init__()
        self.params = {
            "in_channels": [int(c) for c in in_channels],
            "num_classes": int(num_classes),
            "channels": int(channels),
            "dropout": float(dropout),
        }
        self.lateral = nn.ModuleList(
            nn.Sequential(
                nn.Conv2d(int(c), channels, 1, bias=False), nn.BatchNorm2d(channels), nn.ReLU(inplace=True)
            )
            for c in in_channels
        )
        self.fuse = nn.Sequential(
            nn.Conv2d(channels, channels, 3, padding=1, bias=False),
            nn.BatchNorm2d(channels),
            nn.ReLU(inplace=True),
            nn.Dropout2d(float(dropout)),
            nn.Conv2d(channels, int(num_classes), 1),
        )

    def forward(self, features, grid=None):
        """Class logits at the finest feature's resolution: every level added there, then fused."""
        size = features[0].shape[-2:]
        x = self.lateral[0](features[0])
        for lateral, f in zip(self.lateral[1:], features[1:], strict=True):
            x = x + F.interpolate(lateral(f), size=size, mode="bilinear", align_corners=False)
        return self.fuse(x)


HEADS = {"dpt": DPTSegHead, "fpn": FPNSegHead}


def build_head(kind: str, params: dict) -> nn.Module:
    """A head from its kind and the ``params`` dict it was saved with."""
    if kind not in HEADS:
        raise unknown_choice("head type", kind, HEADS)
    try:
        return HEADS[kind](**params)
    except TypeError as exc:
        raise ParameterError(f"head parameters {sorted(params)} do not fit a {kind} head: {exc}") from exc
