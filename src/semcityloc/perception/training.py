"""Training a segmentation head on a frozen backbone: cached features, per-epoch loss/mIoU, best head
saved, resumable.

Why this shape: the backbone never changes, so its features are computed once per image (and once per
mirrored image with ``hflip``) and kept in memory when they fit in ``cache_mb``; an epoch is then only
head passes, which is what makes CPU training practical. Larger sets recompute the backbone per batch.

- Labels are ``SemanticClass`` ids with IGNORE = 255 (what ``semcityloc label`` writes); other values are
  refused (``classes.invalid_class_ids``). Ids the head does not predict map to wall for window/door
  (LoD2 heads merge openings into walls), else to background when the head has it, else (refused when
  the labels hold them: ``check_classes_labelled``) to IGNORE.
- Classes (default): background plus every class present in the training labels, in id order.
- Images and labels are resized to the head's input size (aspect ratio of the first image, the default
  pixel area of the backbone, sides multiples of its stride); labels by nearest neighbour. Read from
  folders (``load_pairs``), each is resized as it is read and only that copy kept.
- Loss: cross-entropy ignoring 255; AdamW; learning rate cosine-decayed over the epochs (a function of
  the epoch number only, so a resumed run follows the same schedule).
- Each epoch logs train loss, validation loss, mIoU and pixel accuracy (``metrics.py``); the best
  validation mIoU (lowest train loss without a validation set) is saved as ``head.safetensors`` +
  ``head.json`` in ``out_dir``; ``checkpoint.pt`` (head, optimiser, epoch, history) is rewritten every
  epoch and ``train_segmenter(..., resume=True)`` continues from it (its classes and input size;
  ``read_checkpoint``); ``history.jsonl`` is rewritten with one line per epoch. A folder holding a head is
  refused unless resumed or ``overwrite`` (``check_out_dir``). A loss or weights not finite stop the
  training (``diverged``), nothing of that epoch saved.
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

from semcityloc.classes import CLASS_NAMES, IGNORE, NUM_CLASSES, SemanticClass, invalid_class_ids
from semcityloc.errors import InputFileError, OutputPathError, ParameterError, counted, parameter, shown_names
from semcityloc.io.files import write_atomic
from semcityloc.io.images import (
    label_maps_beside_photos,
    load_image,
    load_labels_png,
    mask_labels,
    resize_nearest,
)
from semcityloc.perception.base import check_classes, check_image
from semcityloc.perception.files import named_file
from semcityloc.perception.metrics import confusion, mean_iou, pixel_accuracy
from semcityloc.perception.segmenter import (
    HEAD_JSON,
    HEAD_WEIGHTS,
    Segmenter,
    load_segmenter,
    new_segmenter,
    parse_backbone_spec,
    save_head,
)
from semcityloc.perception.torch_utils import (
    device_of,
    fit_size,
    image_tensor,
    labels_tensor,
    require_torch,
    resize_image,
)

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
@dataclass
class Pair:
    """A photo file and its label map file, paired by name (``find_pairs``), not yet read."""

    name: str
    image: Path
    labels: Path


def find_pairs(
    images_dir: str | Path, labels_dir: str | Path, note: Callable[[str], None] | None = None
) -> list[Pair]:
    """Photos in ``images_dir`` paired with their label map in ``labels_dir`` (sorted by name):
    ``<stem>.png``, or ``<name>.png`` (``P0.JPG.png``) as ``run --masks`` finds a mask
    (``perception.files.named_file``; both there is refused).

    Not photos: a label map beside a photo of its stem (``io.images.label_maps_beside_photos``) and a file
    that is another photo's label map (``--images`` and ``--labels`` one folder). Two photos of one stem
    would pair with one label map: refused, naming both. Photos without a label map and label maps without
    a photo are left out, counted in one ``note`` (``left out: 3 of 6 photos in DIR without a label map
    (a.jpg, ...); 2 label maps in DIR without a photo (...)``); no pair at all is an ``InputFileError``."""
    images_dir, labels_dir = Path(images_dir), Path(labels_dir)
    for d, what in ((images_dir, "images"), (labels_dir, "labels")):
        if not d.is_dir():
            raise InputFileError(f"{d}: no such {what} folder")
    files = sorted(p for p in images_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    maps = label_maps_beside_photos(files)
    found = {p: named_file(labels_dir, p.name, (".png",), "label map") for p in files if p not in maps}
    used = {_key(label) for photo, label in found.items() if label is not None and _key(label) != _key(photo)}
    photos = [p for p in found if _key(p) not in used]  # another photo's label map is no photo
    stems: dict[str, Path] = {}
    for photo in photos:
        if photo.stem in stems:
            raise InputFileError(
                f"{images_dir}: {stems[photo.stem].name} and {photo.name} share the stem {photo.stem}, "
                "so both would pair with one label map: rename or remove one"
            )
        stems[photo.stem] = photo
    pairs, unlabelled = [], []
    for photo in photos:
        label = found[photo]
        if label is None:
            unlabelled.append(photo)
        elif _key(label) != _key(photo):  # itself: a label map without its photo, counted with those
            pairs.append(Pair(photo.stem, photo, label))
    taken = {_key(p.labels) for p in pairs} | {_key(p.image) for p in pairs} | {_key(p) for p in unlabelled}
    orphans = sorted(
        p.name
        for p in labels_dir.iterdir()
        if p.is_file() and p.suffix.lower() == ".png" and _key(p) not in taken
    )
    if not pairs:
        raise InputFileError(
            f"no image in {images_dir} has a label map <stem>.png (or <name>.png) in {labels_dir}"
        )
    said = []
    if unlabelled:
        names = shown_names([p.name for p in unlabelled])
        total = len(unlabelled) + len(pairs)
        said.append(f"{len(unlabelled)} of {total} photos in {images_dir} without a label map ({names})")
    if orphans:
        said.append(
            f"{counted(len(orphans), 'label map')} in {labels_dir} without a photo ({shown_names(orphans)})"
        )
    if said and note is not None:
        note("left out: " + "; ".join(said))
    return pairs


def _key(path: Path) -> Path:
    """One spelling of a file's path, to tell whether two paths are one file."""
    return path.resolve()


def load_pairs(pairs: list[Pair], size: tuple[int, int] | None = None) -> list[Sample]:
    """The photos and label maps of ``pairs`` read, their label ids checked (class ids or 255, else an
    ``InputFileError`` naming the file, the ids and the valid ones: ``io.images.mask_labels``), each resized
    to ``size`` = (w, h) as it is read when given (the photo with the network's filter, its labels by
    nearest neighbour): only these copies are kept, whatever the photos' own sizes."""
    out = []
    for pair in pairs:
        image, labels = load_image(pair.image), load_labels_png(pair.labels)
        if labels.shape != image.shape[:2]:
            raise InputFileError(
                f"{pair.labels}: label size {labels.shape} differs from image {image.shape[:2]}"
            )
        labels = mask_labels(labels, pair.labels)
        if size is not None:
            image, labels = resize_image(image, size), resize_nearest(labels, int(size[0]), int(size[1]))
        out.append(Sample(pair.name, image, labels))
    return out


def load_samples(
    images_dir: str | Path,
    labels_dir: str | Path,
    size: tuple[int, int] | None = None,
    note: Callable[[str], None] | None = None,
) -> list[Sample]:
    """``load_pairs`` of ``find_pairs``: the labelled photos of a folder, resized to ``size`` when given."""
    return load_pairs(find_pairs(images_dir, labels_dir, note), size)


def split_samples(
    samples: list[Sample], val_fraction: float, seed: int = 0
) -> tuple[list[Sample], list[Sample]]:
    """Deterministic random split: about ``val_fraction`` of the samples (at least one if > 0) held out."""
    if not 0 <= val_fraction < 1:
        raise ParameterError(f"val_fraction must be in [0, 1), got {val_fraction}")
    n_val = 0 if val_fraction == 0 else max(1, int(round(len(samples) * val_fraction)))
    if n_val >= len(samples):
        raise ParameterError(
            f"{counted(len(samples), 'labelled photo')} {'is' if len(samples) == 1 else 'are'} too few to "
            f"hold out {val_fraction:.0%} for "
            f"validation: {parameter('val_fraction', 0)} trains without validation"
        )
    order = np.random.default_rng(seed).permutation(len(samples))
    val = set(order[:n_val].tolist())
    return [s for i, s in enumerate(samples) if i not in val], [s for i, s in enumerate(samples) if i in val]


def default_classes(samples: list[Sample]) -> tuple[str, ...]:
    """The classes to train when none are given: those present in the labels, plus background; a
    ``ParameterError`` when fewer than two, since there is nothing to learn.
    """
    present = {int(i) for i in np.nonzero(class_pixels(samples))[0]}
    present.add(int(SemanticClass.BACKGROUND))
    if len(present) < 2:
        raise ParameterError("the labels hold fewer than two classes: nothing to learn")
    return tuple(CLASS_NAMES[i] for i in sorted(present))


def class_pixels(samples: list[Sample]) -> np.ndarray:
    """(NUM_CLASSES,) labelled pixels of each class id in the samples' label maps (IGNORE not counted)."""
    counts = np.zeros(256, dtype=np.int64)
    for s in samples:
        counts += np.bincount(np.asarray(s.labels, dtype=np.uint8).reshape(-1), minlength=256)
    return counts[:NUM_CLASSES]


def label_lut(classes: tuple[str, ...]) -> np.ndarray:
    """uint8 (256,) class id -> head index. A class the head does not predict is trained as background
    when background is one of its classes (background is everything not listed), window/door as wall
    when the head has wall but not them (LoD2 heads merge openings into walls); else, and for ids that
    are no class, IGNORE."""
    lut = np.full(256, IGNORE, dtype=np.uint8)
    if "background" in classes:
        lut[:NUM_CLASSES] = classes.index("background")
    for i, name in enumerate(classes):
        lut[CLASS_NAMES.index(name)] = i
    if "wall" in classes:
        for opening in (SemanticClass.WINDOW, SemanticClass.DOOR):
            if CLASS_NAMES[opening] not in classes:
                lut[opening] = classes.index("wall")
    return lut


def check_classes_labelled(samples: list[Sample], classes: tuple[str, ...]) -> str | None:
    """Whether ``classes`` fit the labels of ``samples``: a class the labels hold that is not trained
    (``label_lut``: not listed, no wall to merge into) needs background to fall into, else a
    ``ParameterError`` names it with its share of the labelled pixels (its pixels would be ignored and
    the head would paint them as whatever it learnt: a head without ground paints the ground as wall).
    Returns a note naming the listed classes (background aside) without any labelled pixel, or None."""
    counts = class_pixels(samples)
    total = max(int(counts.sum()), 1)
    lut = label_lut(classes)
    lost = [i for i in range(NUM_CLASSES) if counts[i] and lut[i] == IGNORE]
    if lost:
        shares = ", ".join(
            f"{CLASS_NAMES[i]} ({100 * counts[i] / total:.0f}% of the labelled pixels)" for i in lost
        )
        raise ParameterError(
            f"{parameter('train_classes', ','.join(classes))} leaves out {shares}, which the labels hold "
            "and nothing would learn: add background (every class not listed is trained as background) "
            "or list them"
        )
    trained = np.bincount(lut[:NUM_CLASSES], weights=counts, minlength=256)
    empty = [c for i, c in enumerate(classes) if c != "background" and trained[i] == 0]
    if not empty:
        return None
    them = "it" if len(empty) == 1 else "them"
    return f"no labelled pixel of {', '.join(empty)} in the training labels: the head will not learn {them}"


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
    """The samples as one normalised image tensor and one label tensor at ``size``: each photo resized on
    its own (photos of different sizes are normal: a thermal and a wide camera of one flight)."""
    if not samples:
        return None, None
    images = torch.cat([image_tensor(check_image(s.image), size) for s in samples])
    labels = torch.cat([labels_tensor(lut[np.asarray(s.labels, dtype=np.uint8)], size) for s in samples])
    if images.shape[-2:] != labels.shape[-2:]:
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


TRAINED_FILES = (HEAD_WEIGHTS, HEAD_JSON, CHECKPOINT, HISTORY)


def check_out_dir(out_dir: str | Path, resume: bool = False, overwrite: bool = False) -> list[Path]:
    """Whether a training may write ``out_dir``: one holding a trained head or a checkpoint
    (``TRAINED_FILES``) is refused (``OutputPathError``) unless the training resumes it or ``overwrite``;
    ``resume`` and ``overwrite`` together are refused. Returns the files a new training in their place
    removes before its first epoch (so ``history.jsonl`` starts afresh), none when it resumes."""
    if resume and overwrite:
        raise ParameterError(f"give {parameter('resume')} or {parameter('overwrite')}, not both")
    out = Path(out_dir)
    held = [name for name in TRAINED_FILES if (out / name).is_file()]
    if not held or resume:
        return []
    if not overwrite:
        raise OutputPathError(
            f"{out} holds a trained head ({', '.join(held)}): {parameter('resume')} goes on training it, "
            f"{parameter('overwrite')} trains a new one in its place"
        )
    return [out / name for name in held]


def read_checkpoint(out_dir: str | Path, backbone: str, config: TrainConfig | None = None) -> dict:
    """The resume checkpoint in ``out_dir``, checked against the training that resumes it: its backbone
    kind, and the classes and input size of ``config`` when given (a ``ParameterError`` naming both values:
    they are the checkpoint's, not to be changed on resume)."""
    cfg = config or TrainConfig()
    ckpt_path = Path(out_dir) / CHECKPOINT
    if not ckpt_path.is_file():
        raise InputFileError(f"{ckpt_path}: nothing to resume from")
    try:
        state = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        spec = json.loads(state["spec"])
    except Exception as exc:  # pickle / zip errors of many types
        raise InputFileError(f"{ckpt_path}: unreadable checkpoint ({exc})") from None
    kind, _ = parse_backbone_spec(backbone)
    if spec["backbone"]["kind"] != kind:
        raise ParameterError(f"{ckpt_path} was trained on {spec['backbone']['kind']}, not {kind}")
    stored = {"train_classes": tuple(spec["classes"]), "input_size": tuple(spec["input_size"])}
    given = {
        "train_classes": check_classes(cfg.classes) if cfg.classes else None,
        "input_size": tuple(int(v) for v in cfg.input_size) if cfg.input_size else None,
    }
    for name, value in given.items():
        if value is not None and tuple(value) != stored[name]:
            shown = ",".join(value) if name == "train_classes" else "x".join(map(str, value))
            was = ",".join(stored[name]) if name == "train_classes" else "x".join(map(str, stored[name]))
            raise ParameterError(
                f"{parameter(name, shown)} differs from the checkpoint's {was} in {ckpt_path}: a resumed "
                f"training keeps its own; leave it out, or train a new head with {parameter('overwrite')}"
            )
    state["spec_dict"] = spec
    return state


def epochs_done(state: dict) -> int:
    """How many epochs a resume checkpoint (``read_checkpoint``) holds."""
    return int(state["epoch"]) + 1


def nothing_to_train(done: int, epochs: int, out_dir: str | Path) -> str | None:
    """What a resumed training says when ``epochs`` asks for no more than the ``done`` ones, else None."""
    if done < int(epochs):
        return None
    return (
        f"{counted(done, 'epoch')} already done in {out_dir}, nothing to train "
        f"({parameter('epochs', int(epochs))}; a higher one goes on)"
    )


def interrupted_note(out_dir: str | Path, epochs: int, overwrite: bool = False) -> str:
    """What an interrupted training says it keeps (read from ``out_dir``): epochs done of ``epochs``, the
    best head kept, and that the same command with ``resume`` goes on."""
    out = Path(out_dir)
    try:
        done = len((out / HISTORY).read_text(encoding="utf-8").splitlines())
        best = json.loads((out / HEAD_JSON).read_text(encoding="utf-8")).get("metrics", {}).get("best_epoch")
    except (OSError, ValueError):
        done, best = 0, None
    if not done or not (out / CHECKPOINT).is_file():
        return f"interrupted before an epoch was done: nothing kept in {out}"
    how = f"with {parameter('resume')}" + (f" instead of {parameter('overwrite')}" if overwrite else "")
    head = f"the best head (epoch {best}) kept" if best else "the last head kept"
    return f"{done}/{int(epochs)} epochs done, {head} in {out}; the same command {how} goes on"


def train_segmenter(
    train: list[Sample],
    val: list[Sample],
    backbone: str,
    out_dir: str | Path,
    config: TrainConfig | None = None,
    resume: bool = False,
    log: Callable[[str], None] | None = print,
    backbone_module=None,
    overwrite: bool = False,
    note: Callable[[str], None] | None = None,
) -> TrainResult:
    """Train a head on ``train`` (validated on ``val``, may be empty); save it in ``out_dir`` (module
    docstring). ``backbone``: ``"mobilenetv2"`` or ``"dinov3:DIR"`` (``segmenter.parse_backbone_spec``);
    ``backbone_module`` reuses an already built backbone of that kind. An ``out_dir`` holding a head is
    refused unless ``resume`` or ``overwrite`` (``check_out_dir``). ``log`` takes the progress lines (the
    classes and input, each epoch), ``note`` the notes (classes without a labelled pixel); without
    ``note`` they go to ``log`` as ``note: ...``."""
    cfg = config or TrainConfig()
    cfg.check()
    if not train:
        raise ParameterError("no training samples")
    for s in [*train, *val]:
        problem = invalid_class_ids(s.labels)
        if problem is not None:
            raise InputFileError(f"{s.name}: {problem}")
    out = Path(out_dir)
    say = log or (lambda _msg: None)
    state = read_checkpoint(out, backbone, cfg) if resume else None
    if state is not None:
        done = nothing_to_train(epochs_done(state), cfg.epochs, out)
        if done is not None:
            say(done)
            history = json.loads(state["history"])
            best_epoch = int(state["best_epoch"])
            best = history[best_epoch]["val_miou"] if 0 <= best_epoch < len(history) else float("nan")
            return TrainResult(out, history, best_epoch + 1, best, load_segmenter(out, device=cfg.device))
    old = check_out_dir(out, resume, overwrite)
    out.mkdir(parents=True, exist_ok=True)
    for path in old:  # a new training in the place of another (``overwrite``)
        path.unlink()
    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    torch.manual_seed(int(cfg.seed))
    device = device_of(cfg.device)
    ckpt_path = out / CHECKPOINT
    if state is not None:
        spec = state["spec_dict"]
        classes = tuple(spec["classes"])
        size = tuple(spec["input_size"])
        head_params = {
            k: v
            for k, v in spec["head"]["params"].items()
            if k not in ("hidden_size", "in_channels", "num_classes")
        }
    else:
        classes = check_classes(cfg.classes) if cfg.classes else default_classes(train)
        unlabelled = check_classes_labelled(train, classes)
        if unlabelled is not None:
            (note or (lambda text: say(f"note: {text}")))(unlabelled)
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
            if not bool(torch.isfinite(loss)):
                raise ParameterError(diverged(float(loss.detach()), epoch + 1, cfg.lr, out))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            loss_sum += float(loss.detach())
            n_batches += 1
        broken = [name for name, p in seg.head.named_parameters() if not bool(torch.isfinite(p).all())]
        if broken:
            raise ParameterError(diverged(f"non-finite weights ({broken[0]})", epoch + 1, cfg.lr, out))
        row = {"epoch": epoch + 1, "lr": lr, "train_loss": loss_sum / max(n_batches, 1)}
        row.update(_evaluate(seg, val_store, len(classes), batch))
        row["seconds"] = round(time.perf_counter() - t_ep, 3)
        history.append(row)
        score = row["val_miou"] if val_store is not None else -row["train_loss"]
        improved = math.isfinite(score) and score > best_score
        if improved:
            best_epoch, best_score = epoch, score
            save_head(seg, out, metrics={"best_epoch": epoch + 1, **{k: row[k] for k in row if k != "lr"}})
        validated = (
            f"val loss {row['val_loss']:.4f}  val mIoU {row['val_miou']:5.1f}%  acc {row['val_acc']:5.1f}%  "
            if val_store is not None
            else ""
        )
        say(
            f"epoch {epoch + 1:3d}/{cfg.epochs}  loss {row['train_loss']:.4f}  {validated}"
            f"({row['seconds']:.1f} s)" + ("  * saved" if improved else "")
        )
        _save_checkpoint(ckpt_path, seg, opt, epoch, best_epoch, best_score, history, cfg)
        # This run's epochs only, the resumed ones with them (a new run into the folder removed the old).
        write_atomic(out / HISTORY, "".join(json.dumps(row) + "\n" for row in history).encode())

    if best_epoch < 0:
        save_head(seg, out, metrics={"best_epoch": None})
    best_miou = history[best_epoch]["val_miou"] if 0 <= best_epoch < len(history) else float("nan")
    return TrainResult(out, history, best_epoch + 1, best_miou, seg)


def diverged(loss: float | str, epoch: int, lr: float, out: Path) -> str:
    """What a training that diverged says: a loss (or weights) not finite at ``epoch``, nothing of it saved,
    and a lower learning rate."""
    return (
        f"training diverged: the loss became {loss} in epoch {epoch}; nothing of that epoch is saved "
        f"in {out}: lower {parameter('lr', f'{lr:g}')}"
    )


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
