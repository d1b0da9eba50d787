"""Training a segmentation head on a frozen backbone: cached features, per-epoch loss/mIoU, best head
saved, resumable.

Why this shape: the backbone never changes, so its features are computed once per image (and once per
mirrored image with ``hflip``) and kept in memory when they fit in ``cache_mb``; an epoch is then only
head passes, which is what makes CPU training practical. Larger sets recompute the backbone per batch.

- Labels are ``SemanticClass`` ids with IGNORE = 255 (what ``semcityloc label`` writes). Ids the head
  does not predict map to wall for window/door (LoD2 heads merge openings into walls), else to IGNORE.
- Classes (default): background plus every class present in the training labels, in id order.
- Images and labels are resized to the head's input size (aspect ratio of the first image, the default
  pixel area of the backbone, sides multiples of its stride); labels by nearest neighbour.
- Loss: cross-entropy ignoring 255; AdamW; learning rate cosine-decayed over the epochs (a function of
  the epoch number only, so a resumed run follows the same schedule).
- Each epoch logs train loss, validation loss, mIoU and pixel accuracy (``metrics.py``); the best
  validation mIoU (lowest train loss without a validation set) is saved as ``head.safetensors`` +
  ``head.json`` in ``out_dir``; ``checkpoint.pt`` (head, optimiser, epoch, history) is rewritten every
  epoch and ``train_segmenter(..., resume=True)`` continues from it; ``history.jsonl`` keeps one line per
  epoch.
- Threads: ``threads`` is applied when training starts, i.e. after any rendering. numba's OpenMP
  threading layer resets the process's OpenMP thread count the first time a parallel kernel runs (the
  renderer), and torch's and numba's thread pools then compete for the cores: measured here, a frozen
  MobileNetV2 pass ran 10x slower with 2 torch threads beside a loaded machine than with 1.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from semcityloc.classes import CLASS_NAMES, IGNORE, SemanticClass
from semcityloc.errors import InputFileError, ParameterError
from semcityloc.io.images import load_image, load_labels_png
from semcityloc.perception.base import check_classes, check_image
from semcityloc.perception.metrics import confusion, mean_iou, pixel_accuracy
from semcityloc.perception.segmenter import Segmenter, new_segmenter, parse_backbone_spec, save_head
from semcityloc.perception.torch_utils import device_of, fit_size, image_tensor, labels_tensor, require_torch

torch = require_torch("training a segmentation head")
F = torch.nn.functional

CHECKPOINT = "checkpoint.pt"
HISTORY = "history.jsonl"
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


@dataclass
class Sample:
    """One training pair: a photo's name, its RGB image and its label mask (class ids, 255 = ignore)."""

    name: str
    image: np.ndarray  # (H, W, 3) uint8
    labels: np.ndarray  # (H, W) uint8 class ids, 255 = ignore


@dataclass
class TrainConfig:
    """How a head is trained: epochs, batch size, learning rate and weight decay, mirrored copies, the feature
    cache's memory, the seed, the classes and the network input size. Checked before a training starts
    (``check``) and kept in its resume checkpoint.
    """

    epochs: int = 20
    batch_size: int = 8
    lr: float = 2e-3
    weight_decay: float = 1e-4
    hflip: bool = True
    cache_mb: float = 2048.0
    seed: int = 0
    classes: tuple[str, ...] | None = None
    input_size: tuple[int, int] | None = None
    head_params: dict = field(default_factory=dict)
    device: str | None = None
    threads: int | None = None  # torch CPU threads, set when training starts (see module docstring)

    def check(self) -> None:
        """ParameterError naming a setting out of range, before any data is loaded or trained on."""
        if int(self.epochs) < 1 or int(self.batch_size) < 1:
            raise ParameterError(f"epochs and batch_size must be >= 1, got {self.epochs}, {self.batch_size}")
        if not (self.lr > 0 and math.isfinite(self.lr)) or self.weight_decay < 0:
            raise ParameterError(f"lr must be > 0 and weight_decay >= 0, got {self.lr}, {self.weight_decay}")
        if self.threads is not None and int(self.threads) < 1:
            raise ParameterError(f"threads must be >= 1, got {self.threads}")
        if not (0.0 <= self.cache_mb < math.inf):
            raise ParameterError(f"cache_mb must be a number of megabytes >= 0, got {self.cache_mb}")


@dataclass
class TrainResult:
    """What a training left: the output folder, the per-epoch history (loss, mIoU), the best epoch and its
    mIoU, and the segmenter with the best head loaded.
    """

    out_dir: Path
    history: list[dict]
    best_epoch: int
    best_miou: float
    segmenter: Segmenter


# ---------------------------------------------------------------------------------------------- data
def load_samples(images_dir: str | Path, labels_dir: str | Path) -> list[Sample]:
    """Photos in ``images_dir`` paired with ``labels_dir/<stem>.png`` by file stem (sorted by name).

    Photos without a label file are skipped; no pair at all is an ``InputFileError``."""
    images_dir, labels_dir = Path(images_dir), Path(labels_dir)
    for d, what in ((images_dir, "images"), (labels_dir, "labels")):
        if not d.is_dir():
            raise InputFileError(f"{d}: no such {what} folder")
    out = []
    for path in sorted(p for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES):
        label_path = labels_dir / f"{path.stem}.png"
        if not label_path.is_file():
            continue
        image, labels = load_image(path), load_labels_png(label_path)
        if labels.shape != image.shape[:2]:
            raise InputFileError(
                f"{label_path}: label size {labels.shape} differs from image {image.shape[:2]}"
            )
        out.append(Sample(path.stem, image, labels))
    if not out:
        raise InputFileError(f"no image in {images_dir} has a label PNG of the same stem in {labels_dir}")
    return out


def split_samples(
    samples: list[Sample], val_fraction: float, seed: int = 0
) -> tuple[list[Sample], list[Sample]]:
    """Deterministic random split: about ``val_fraction`` of the samples (at least one if > 0) held out."""
    if not 0 <= val_fraction < 1:
        raise ParameterError(f"val_fraction must be in [0, 1), got {val_fraction}")
    n_val = 0 if val_fraction == 0 else max(1, int(round(len(samples) * val_fraction)))
    if n_val >= len(samples):
        raise ParameterError(
            f"{len(samples)} sample(s) are too few to hold out {val_fraction:.0%} for validation"
        )
    order = np.random.default_rng(seed).permutation(len(samples))
    val = set(order[:n_val].tolist())
    return [s for i, s in enumerate(samples) if i not in val], [s for i, s in enumerate(samples) if i in val]


def default_classes(samples: list[Sample]) -> tuple[str, ...]:
    """The classes to train when none are given: those present in the labels, plus background; a
    ``ParameterError`` when fewer than two, since there is nothing to learn.
    """
    present = set()
    for s in samples:
        present.update(int(v) for v in np.unique(s.labels) if v < len(CLASS_NAMES))
    present.add(int(SemanticClass.BACKGROUND))
    if len(present) < 2:
        raise ParameterError("the labels hold fewer than two classes: nothing to learn")
    return tuple(CLASS_NAMES[i] for i in sorted(present))


def label_lut(classes: tuple[str, ...]) -> np.ndarray:
    """uint8 (256,) class id -> head index (IGNORE for ids the head cannot learn)."""
    lut = np.full(256, IGNORE, dtype=np.uint8)
    for i, name in enumerate(classes):
        lut[CLASS_NAMES.index(name)] = i
    if "wall" in classes:
        for opening in (SemanticClass.WINDOW, SemanticClass.DOOR):
            if CLASS_NAMES[opening] not in classes:
                lut[opening] = classes.index("wall")
    return lut


# ---------------------------------------------------------------------------------------------- features
class _FeatureStore:
    """Backbone features of a fixed set of images, cached in memory or recomputed per batch."""

    def __init__(self, seg: Segmenter, images, labels, flip: bool, cache_mb: float, device, batch: int):
        self.seg, self.device, self.batch = seg, device, batch
        self.images = images  # (N, 3, h, w) normalised float32 tensor (CPU)
        self.labels = labels  # (N, h, w) int64 tensor
        self.flip = flip
        self.cache = None
        n = images.shape[0] * (2 if flip else 1)
        probe, grid = seg.features(images[:1].to(device))
        per_image = sum(f.numel() for f in probe) * 4
        self.grid = grid
        if n * per_image <= cache_mb * 1e6:
            self.cache = [self._compute(i) for i in range(0, n, batch)]

    def __len__(self) -> int:
        return self.images.shape[0] * (2 if self.flip else 1)

    def _batch_inputs(self, idx: np.ndarray):
        n = self.images.shape[0]
        base = torch.as_tensor(idx % n)
        x, y = self.images[base], self.labels[base]
        mirrored = torch.as_tensor(idx >= n)
        if bool(mirrored.any()):
            x = torch.where(mirrored[:, None, None, None], x.flip(-1), x)
            y = torch.where(mirrored[:, None, None], y.flip(-1), y)
        return x, y

    def _compute(self, start: int):
        idx = np.arange(start, min(start + self.batch, len(self)))
        x, _ = self._batch_inputs(idx)
        feats, _ = self.seg.features(x.to(self.device))
        return [f.cpu() for f in feats]

    def get(self, idx: np.ndarray):
        """(features list, labels) for sample indices ``idx`` (into the [originals, mirrored] range)."""
        _, y = self._batch_inputs(idx)
        if self.cache is None:
            x, _ = self._batch_inputs(idx)
            feats, _ = self.seg.features(x.to(self.device))
            return feats, y
        chunks = [self.cache[i // self.batch] for i in idx]
        pos = [i % self.batch for i in idx]
        feats = [
            torch.stack([c[level][p] for c, p in zip(chunks, pos, strict=True)]).to(self.device)
            for level in range(len(chunks[0]))
        ]
        return feats, y


# ---------------------------------------------------------------------------------------------- training
def _prepare(samples: list[Sample], size: tuple[int, int], lut: np.ndarray):
    images = image_tensor([check_image(s.image) for s in samples], size) if samples else None
    labels = (
        labels_tensor([lut[np.asarray(s.labels, dtype=np.uint8)] for s in samples], size) if samples else None
    )
    if images is not None and images.shape[-2:] != labels.shape[-2:]:
        raise ParameterError("images and labels resized to different sizes")
    return images, labels


def _evaluate(seg: Segmenter, store: _FeatureStore | None, num_classes: int, batch: int) -> dict:
    if store is None:
        return {"val_loss": float("nan"), "val_miou": float("nan"), "val_acc": float("nan")}
    seg.head.eval()
    conf = np.zeros((num_classes, num_classes), dtype=np.int64)
    loss_sum, count = 0.0, 0
    with torch.no_grad():
        for start in range(0, len(store), batch):
            idx = np.arange(start, min(start + batch, len(store)))
            feats, y = store.get(idx)
            y = y.to(store.device)
            logits = seg.logits(feats, store.grid, y.shape[-2:])
            valid = int((y != IGNORE).sum())
            if valid:
                loss_sum += float(F.cross_entropy(logits, y, ignore_index=IGNORE, reduction="sum"))
                count += valid
            conf += confusion(logits.argmax(1).cpu().numpy(), y.cpu().numpy(), num_classes)
    return {
        "val_loss": loss_sum / count if count else float("nan"),
        "val_miou": mean_iou(conf),
        "val_acc": pixel_accuracy(conf),
    }


def _lr_at(cfg: TrainConfig, epoch: int) -> float:
    """Cosine decay from ``lr`` to ``lr / 20`` over the epochs (epoch counted from 0)."""
    t = epoch / max(1, int(cfg.epochs) - 1)
    return cfg.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(t, 1.0))))


def train_segmenter(
    train: list[Sample],
    val: list[Sample],
    backbone: str,
    out_dir: str | Path,
    config: TrainConfig | None = None,
    resume: bool = False,
    log: Callable[[str], None] | None = print,
    backbone_module=None,
) -> TrainResult:
    """Train a head on ``train`` (validated on ``val``, may be empty); save it in ``out_dir`` (module
    docstring). ``backbone``: ``"mobilenetv2"`` or ``"dinov3:DIR"`` (``segmenter.parse_backbone_spec``);
    ``backbone_module`` reuses an already built backbone of that kind."""
    cfg = config or TrainConfig()
    cfg.check()
    if not train:
        raise ParameterError("no training samples")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    say = log or (lambda _msg: None)
    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    torch.manual_seed(int(cfg.seed))
    device = device_of(cfg.device)
    kind, _ = parse_backbone_spec(backbone)

    ckpt_path = out / CHECKPOINT
    state = None
    if resume:
        if not ckpt_path.is_file():
            raise InputFileError(f"{ckpt_path}: nothing to resume from")
        try:
            state = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        except Exception as exc:  # pickle / zip errors of many types
            raise InputFileError(f"{ckpt_path}: unreadable checkpoint ({exc})") from None
        spec = json.loads(state["spec"])
        if spec["backbone"]["kind"] != kind:
            raise ParameterError(f"{ckpt_path} was trained on {spec['backbone']['kind']}, not {kind}")
        classes = tuple(spec["classes"])
        size = tuple(spec["input_size"])
        head_params = {
            k: v
            for k, v in spec["head"]["params"].items()
            if k not in ("hidden_size", "in_channels", "num_classes")
        }
    else:
        classes = check_classes(cfg.classes) if cfg.classes else default_classes(train)
        size = None
        head_params = dict(cfg.head_params)
    seg = new_segmenter(
        backbone, classes, input_size=None, head_params=head_params, backbone_module=backbone_module
    )
    if size is None:
        h0, w0 = train[0].image.shape[:2]
        area = (
            cfg.input_size[0] * cfg.input_size[1] if cfg.input_size else seg.input_size[0] * seg.input_size[1]
        )
        size = tuple(cfg.input_size) if cfg.input_size else fit_size(w0, h0, area, seg.stride)
    w, h = (int(v) for v in size)
    if w % seg.stride or h % seg.stride:
        raise ParameterError(f"input size {w}x{h} must be multiples of the backbone stride {seg.stride}")
    seg.spec["input_size"] = [w, h]
    seg.to(device)

    lut = label_lut(classes)
    t0 = time.perf_counter()
    x_tr, y_tr = _prepare(train, (w, h), lut)
    x_va, y_va = _prepare(val, (w, h), lut)
    batch = int(cfg.batch_size)
    train_store = _FeatureStore(seg, x_tr, y_tr, bool(cfg.hflip), cfg.cache_mb, device, batch)
    val_store = _FeatureStore(seg, x_va, y_va, False, cfg.cache_mb, device, batch) if val else None
    say(
        f"backbone {seg.spec['backbone']['id']}; classes {', '.join(classes)}; input {w}x{h}; "
        f"{len(train)} train{f' ({len(train_store)} with mirrored copies)' if cfg.hflip else ''} / "
        f"{len(val)} val images; "
        f"features {'cached' if train_store.cache is not None else 'recomputed per batch'} "
        f"({time.perf_counter() - t0:.1f} s)"
    )

    params = [p for p in seg.head.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    history: list[dict] = []
    start_epoch, best_epoch, best_score = 0, -1, -math.inf
    if state is not None:
        seg.head.load_state_dict(state["head"])
        opt.load_state_dict(state["optimizer"])
        history = json.loads(state["history"])
        start_epoch = int(state["epoch"]) + 1
        best_epoch, best_score = int(state["best_epoch"]), float(state["best_score"])
        say(f"resumed from {ckpt_path} after epoch {start_epoch} (best epoch {best_epoch + 1})")

    rng = np.random.default_rng(int(cfg.seed) + 1000 * start_epoch)
    for epoch in range(start_epoch, int(cfg.epochs)):
        lr = _lr_at(cfg, epoch)
        for group in opt.param_groups:
            group["lr"] = lr
        seg.head.train()
        t_ep = time.perf_counter()
        order = rng.permutation(len(train_store))
        loss_sum, n_batches = 0.0, 0
        for start in range(0, len(order), batch):
            idx = order[start : start + batch]
            feats, y = train_store.get(idx)
            y = y.to(device)
            if not bool((y != IGNORE).any()):
                continue
            logits = seg.logits(feats, train_store.grid, y.shape[-2:])
            loss = F.cross_entropy(logits, y, ignore_index=IGNORE)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            loss_sum += float(loss.detach())
            n_batches += 1
        row = {"epoch": epoch + 1, "lr": lr, "train_loss": loss_sum / max(n_batches, 1)}
        row.update(_evaluate(seg, val_store, len(classes), batch))
        row["seconds"] = round(time.perf_counter() - t_ep, 3)
        history.append(row)
        score = row["val_miou"] if val_store is not None else -row["train_loss"]
        improved = math.isfinite(score) and score > best_score
        if improved:
            best_epoch, best_score = epoch, score
            save_head(seg, out, metrics={"best_epoch": epoch + 1, **{k: row[k] for k in row if k != "lr"}})
        say(
            f"epoch {epoch + 1:3d}/{cfg.epochs}  loss {row['train_loss']:.4f}  "
            f"val loss {row['val_loss']:.4f}  "
            f"val mIoU {row['val_miou']:5.1f}%  acc {row['val_acc']:5.1f}%  ({row['seconds']:.1f} s)"
            + ("  * saved" if improved else "")
        )
        with open(out / HISTORY, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(row) + "\n")
        _save_checkpoint(ckpt_path, seg, opt, epoch, best_epoch, best_score, history, cfg)

    if best_epoch < 0:
        save_head(seg, out, metrics={"best_epoch": None})
    best_miou = history[best_epoch]["val_miou"] if 0 <= best_epoch < len(history) else float("nan")
    return TrainResult(out, history, best_epoch + 1, best_miou, seg)


def _save_checkpoint(
    path: Path, seg: Segmenter, opt, epoch: int, best_epoch: int, best_score: float, history, cfg
) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(
        {
            "head": seg.head.state_dict(),
            "optimizer": opt.state_dict(),
            "epoch": epoch,
            "best_epoch": best_epoch,
            "best_score": best_score,
            "history": json.dumps(history),
            "spec": json.dumps(seg.spec),
            "config": json.dumps(asdict(cfg), default=str),
        },
        tmp,
    )
    tmp.replace(path)
