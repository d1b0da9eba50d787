"""A frozen DINOv3 ViT from a local Hugging Face checkpoint, returning the tokens a DPT neck wants.

Why this way (measured with ``transformers`` 5.23): ``DPTForSemanticSegmentation`` builds its own ViT and
does not take a DINOv3 backbone, and ``AutoBackbone.from_pretrained(local_dir)`` crashes. What works is
the concrete ``DINOv3ViTBackbone`` with ``out_indices`` (default the last layer of each quarter, e.g.
[3, 6, 9, 12] for 12 layers), ``reshape_hidden_states=False`` and ``config.return_class_token = True`` set
on the config: its feature maps are the patch tokens (register tokens dropped) and ``cls_tokens`` the
class tokens; ``cat([cls, patches])`` is the (B, 1 + N, D) layout ``DPTReassembleStage`` expects.

A model built fresh is in train mode, where DINOv3 randomly shifts/rescales its RoPE patch coordinates:
the backbone is put in eval mode (and kept there) so the same image always gives the same features.

Both ``DINOv3ViTModel`` and ``DINOv3ViTBackbone`` checkpoints load (same parameter names; older
``layer.N`` names are renamed by transformers). Missing or unexpected weights are an error, not a warning.
"""

from __future__ import annotations

from pathlib import Path

from semcityloc.errors import MissingWeightsError, ParameterError, parameter
from semcityloc.perception.base import hub_offline, looks_like_hub_id, weights_dir
from semcityloc.perception.torch_utils import quiet_transformers, require, require_torch
from semcityloc.perception.weight_files import DEFAULT_DINOV3_DIR

torch = require_torch("the DINOv3 backbone")
nn = torch.nn

DOWNLOAD_HINT = (
    "download a DINOv3 ViT checkpoint in Hugging Face format (config.json + model.safetensors), e.g. "
    "facebook/dinov3-vits16-pretrain-lvd1689m (gated: accept its licence on huggingface.co), and pass its "
    f"folder as {parameter('backbone', 'DIR')} or {parameter('train_backbone', 'dinov3:DIR')} (default "
    "folder: {default})"
)


def default_backbone_dir() -> Path:
    """Where the DINOv3 checkpoint is looked for when none is given: its folder under the weights directory
    (``perception.base.weights_dir``: ``$SEMCITYLOC_WEIGHTS`` or the user's cache).
    """
    return weights_dir() / DEFAULT_DINOV3_DIR


def default_out_indices(num_layers: int) -> list[int]:
    """The last layer of each quarter of the network: [3, 6, 9, 12] for 12 layers, [6, 12, 18, 24] for 24."""
    if num_layers < 4:
        raise ParameterError(f"a DINOv3 backbone for a DPT head needs at least 4 layers, got {num_layers}")
    return [round(num_layers * k / 4) for k in (1, 2, 3, 4)]


def _resolve(spec: str | Path | None) -> tuple[str, bool]:
    """(path or hub id, is_local). Raises MissingWeightsError when nothing usable is there."""
    hint = DOWNLOAD_HINT.format(default=default_backbone_dir())
    if spec is None or str(spec) == "":
        path = default_backbone_dir()
        if (path / "config.json").is_file():
            return str(path), True
        raise MissingWeightsError(f"no DINOv3 backbone given and none in {path}: {hint}")
    path = Path(spec).expanduser()
    if path.is_dir():
        if not (path / "config.json").is_file():
            raise MissingWeightsError(f"{path}: no config.json, not a Hugging Face checkpoint folder; {hint}")
        return str(path), True
    if path.exists():
        raise MissingWeightsError(
            f"{path}: a DINOv3 backbone must be a checkpoint folder, not a file; {hint}"
        )
    if looks_like_hub_id(str(spec)):
        return str(spec), False
    raise MissingWeightsError(f"{spec}: no such DINOv3 checkpoint folder; {hint}")


def load_dinov3_backbone(spec: str | Path | None, out_indices: list[int] | None = None):
    """``DINOv3ViTBackbone`` from a local folder (or a hub id when not offline), frozen, in eval mode."""
    require("transformers", "transformers", "the DINOv3 backbone")
    quiet_transformers()
    from transformers import DINOv3ViTBackbone, DINOv3ViTConfig  # optional dependency, loaded only when used

    where, local = _resolve(spec)
    hint = DOWNLOAD_HINT.format(default=default_backbone_dir())
    if not local and hub_offline():
        raise MissingWeightsError(f"{where}: not a local folder and HF_HUB_OFFLINE is set; {hint}")
    try:
        config = DINOv3ViTConfig.from_pretrained(where, local_files_only=local or hub_offline())
    except Exception as exc:  # hub client / JSON errors of many types: one line, no hub traceback
        what = "" if local else "no such folder here, and as a Hugging Face hub id: "
        raise MissingWeightsError(
            f"{where}: {what}cannot read the DINOv3 config ({_first_line(exc)}); {hint}"
        ) from None
    if getattr(config, "model_type", None) != "dinov3_vit":
        raise MissingWeightsError(f"{where}: model_type {config.model_type!r} is not a DINOv3 ViT; {hint}")
    indices = list(out_indices) if out_indices is not None else default_out_indices(config.num_hidden_layers)
    if len(indices) != 4 or not all(1 <= int(i) <= config.num_hidden_layers for i in indices):
        raise ParameterError(
            f"out_indices must be 4 layer numbers in 1..{config.num_hidden_layers}, got {list(indices)}"
        )
    try:
        model, info = DINOv3ViTBackbone.from_pretrained(
            where,
            out_indices=[int(i) for i in indices],
            reshape_hidden_states=False,
            output_loading_info=True,
            local_files_only=local or hub_offline(),
        )
    except Exception as exc:
        raise MissingWeightsError(
            f"{where}: cannot load the DINOv3 weights ({_first_line(exc)}); {hint}"
        ) from None
    problems = {
        k: sorted(str(v) for v in info[k])[:3]
        for k in ("missing_keys", "unexpected_keys", "mismatched_keys")
        if info.get(k)
    }
    if problems:
        raise MissingWeightsError(f"{where}: DINOv3 weights do not match the config: {problems}; {hint}")
    model.config.return_class_token = True
    return model


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:200]}" if text else type(exc).__name__


class DINOv3Backbone(nn.Module):
    """Frozen DINOv3 -> 4 token tensors (B, 1 + N, D) (class token first) and the patch grid (h, w)."""

    def __init__(self, spec: str | Path | None = None, out_indices: list[int] | None = None, model=None):
        super().__init__()
        self.vit = model if model is not None else load_dinov3_backbone(spec, out_indices)
        self.vit.config.return_class_token = True
        cfg = self.vit.config
        self.stride = int(cfg.patch_size if isinstance(cfg.patch_size, int) else cfg.patch_size[0])
        self.hidden_size = int(cfg.hidden_size)
        self.out_indices = [int(i) for i in cfg.out_indices]
        self.source = str(spec) if spec is not None else str(getattr(cfg, "_name_or_path", ""))
        self.requires_grad_(False)
        self.eval()

    @property
    def backbone_id(self) -> str:
        """``dinov3:<model>``: which weights the head was trained on, kept in its checkpoint."""
        name = getattr(self.vit.config, "_name_or_path", "") or self.source
        return f"dinov3:{name}"

    def train(self, mode: bool = True):
        """Always eval (module docstring: train mode jitters the position encoding)."""
        return super().train(False)

    def forward(self, x):
        """Tokens (class token first) of the tapped layers and the patch grid (h, w) of ``x``."""
        h, w = x.shape[-2:]
        if h % self.stride or w % self.stride:
            raise ParameterError(f"DINOv3 input sides must be multiples of {self.stride}, got {w}x{h}")
        out = self.vit(pixel_values=x)
        tokens = [
            torch.cat([c[:, None, :], p], dim=1)
            for c, p in zip(out.cls_tokens, out.feature_maps, strict=True)
        ]
        return tokens, (h // self.stride, w // self.stride)
