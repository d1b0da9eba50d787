"""Benchmark the perception backends: seconds per image at 512x384 on CPU, and automatic labelling.

Usage: ``python benchmarks/bench_perception.py [--threads 2] [--repeat 5] [--size 512x384]``.

No foundation-model weights are on this machine, so the DINOv3 and MoGe-2 backends run with RANDOM
weights of the real architectures (inference time does not depend on the values):

- ``dinov3-dpt``: DINOv3 ViT-S/16 (``DINOv3ViTConfig()`` defaults: 12 layers, width 384, 4 register
  tokens), saved with ``save_pretrained`` and loaded by the production loader, + the default DPT head
  (neck 48/96/192/384, fusion 64), 4 classes;
- ``mobilenetv2``: the packaged ImageNet MobileNetV2 + the default FPN head (real weights, random head);
- ``moge2``: MoGe-2 with a ViT-S/14 encoder and a ViT-S-sized neck and heads (points, mask, normal,
  scale; the layout third-party code uses for ``moge-2-vits-normal``), ``use_fp16=False``, at the
  backend's default ``resolution_level`` 0 (1200 tokens) and as ``moge2-3600`` at MoGe's default 9;
- ``files``: reading a palette PNG mask and a .npy depth (the GPU-box route);
- ``autolabel``: ``auto_label`` of the real UAV image (640x512) against its LoD1 OBJ, when
  ``../shared/data/real_uav_lodloc`` is present (the renderer is built once, outside the timing).

The input photo is the real UAV image resized to ``--size`` when present, else a synthetic textured
view. Each figure is the median of ``--repeat`` timed calls after one warm-up call. Prints one JSON
object per backend and the machine's load average (other jobs on a shared box slow everything down).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real_uav_lodloc"
STEM = "DJI_20230513163714_0033_T"

MOGE_VITS_LIKE = {
    "encoder": {"backbone": "dinov2_vits14", "intermediate_layers": [5, 11], "dim_out": 384},
    "neck": {
        "dim_in": [386, 2, 2, 2, 2],
        "dim_out": None,
        "dim_res_blocks": [384, 256, 128, 64, 32],
        "num_res_blocks": [0, 1, 1, 1, 0],
        "res_block_in_norm": "none",
        "res_block_hidden_norm": "none",
        "resamplers": ["conv_transpose", "conv_transpose", "conv_transpose", "bilinear"],
    },
    "remap_output": "exp",
    "num_tokens_range": [1200, 3600],
}


def _moge_head(dim_out: int) -> dict:
    return {
        "dim_in": [384, 256, 128, 64, 32],
        "dim_out": [None, None, None, None, dim_out],
        "dim_res_blocks": [384, 256, 128, 64, 32],
        "num_res_blocks": [0, 1, 1, 1, 0],
        "res_block_in_norm": "none",
        "res_block_hidden_norm": "none",
        "resamplers": ["conv_transpose", "conv_transpose", "conv_transpose", "bilinear"],
    }


def photo(size: tuple[int, int]) -> tuple[np.ndarray, str]:
    from PIL import Image

    path = REAL / "Query_image" / f"{STEM}.JPG"
    if path.is_file():
        with Image.open(path) as img:
            return np.array(img.convert("RGB").resize(size, Image.BILINEAR)), "real UAV image"
    from semcityloc.geometry.camera import Camera
    from semcityloc.perception.synthetic import generated_model, synthetic_views

    view = synthetic_views(generated_model(), 1, camera=Camera.from_fov(size[0], size[1], 65.0))[0]
    return view.image, "synthetic view"


def timed(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def build_backends(tmp: Path, image: np.ndarray) -> dict:
    import torch
    from transformers import DINOv3ViTConfig, DINOv3ViTModel

    from semcityloc.io.images import save_labels_png
    from semcityloc.perception import get_depth_backend, get_segmentation_backend
    from semcityloc.perception.segmenter import new_segmenter, save_head
    from semcityloc.perception.torch_utils import quiet_transformers

    quiet_transformers()
    classes = ["background", "ground", "wall", "roof"]
    backends = {}
    torch.manual_seed(0)
    DINOv3ViTModel(DINOv3ViTConfig(num_register_tokens=4)).save_pretrained(tmp / "dinov3-vits16")
    save_head(new_segmenter(f"dinov3:{tmp / 'dinov3-vits16'}", classes), tmp / "dino-head")
    backends["dinov3-dpt"] = get_segmentation_backend("dinov3-dpt", head=str(tmp / "dino-head"))
    try:
        save_head(new_segmenter("mobilenetv2", classes), tmp / "mnv2-head")
        backends["mobilenetv2"] = get_segmentation_backend("mobilenetv2", head=str(tmp / "mnv2-head"))
    except Exception as exc:  # the weights package may be missing: report, do not stop
        print(json.dumps({"backend": "mobilenetv2", "skipped": str(exc)}))
    try:
        from moge.model.v2 import MoGeModel

        config = dict(MOGE_VITS_LIKE)
        config.update(points_head=_moge_head(3), mask_head=_moge_head(1), normal_head=_moge_head(3))
        config["scale_head"] = {"dims": [384, 384, 1]}
        model = MoGeModel(**config)
        torch.save({"model_config": config, "model": model.state_dict()}, tmp / "model.pt")
        backends["moge2"] = get_depth_backend("moge2", model=str(tmp / "model.pt"))
        backends["moge2-3600"] = get_depth_backend("moge2", model=str(tmp / "model.pt"), resolution_level=9)
    except ImportError as exc:
        print(json.dumps({"backend": "moge2", "skipped": str(exc)}))
    save_labels_png(np.zeros(image.shape[:2], np.uint8), tmp / "masks" / "photo.png")
    (tmp / "depth").mkdir()
    np.save(tmp / "depth" / "photo.npy", np.full(image.shape[:2], 100.0, np.float32))
    backends["files-seg"] = get_segmentation_backend("files", masks=str(tmp / "masks"))
    backends["files-depth"] = get_depth_backend("files", depth=str(tmp / "depth"))
    return backends


def bench_autolabel(repeat: int) -> dict | None:
    if not (REAL / "UAVD4L-LoD1.obj").is_file():
        return None
    from semcityloc.citymodel.io import load_city_model
    from semcityloc.geometry.io import read_intrinsics, read_pose
    from semcityloc.perception.autolabel import auto_label
    from semcityloc.render import Renderer

    model = load_city_model(REAL / "UAVD4L-LoD1.obj")
    camera = read_intrinsics(REAL / "intrinsic" / f"{STEM}_intrinsic.txt", width=640, height=512)
    pose = read_pose(REAL / "GT_pose" / f"{STEM}_pose.txt")
    renderer = Renderer(model, engine="numba")
    s = timed(lambda: auto_label(model, camera, pose, renderer=renderer), repeat)
    return {"backend": "autolabel", "size": "640x512", "s_per_image": round(s, 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--size", default="512x384")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.lower().split("x"))
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import torch

    image, source = photo(size)
    label = bench_autolabel(args.repeat)  # numba first: its OpenMP layer resets the thread count
    torch.set_num_threads(args.threads)
    print(json.dumps({"threads": torch.get_num_threads(), "input": source, "size": args.size}))
    with tempfile.TemporaryDirectory() as tmp:
        backends = build_backends(Path(tmp), image)
        for name, backend in backends.items():
            s = timed(lambda b=backend: b.predict(image, name="photo"), args.repeat)
            print(json.dumps({"backend": name, "size": args.size, "s_per_image": round(s, 4)}))
    if label is not None:
        print(json.dumps(label))
    print(json.dumps({"load_average": [round(v, 2) for v in os.getloadavg()]}))


if __name__ == "__main__":
    main()
