"""The HTML report's query views: per query, small images (data URIs) and the cost-volume slices.

Why its own module: the report's query browser shows, for every query of a run, the photo or simulated
view with the model projected at the prior, the estimate and the truth, the query mask beside the
rendered mask, and the coarse cost volume. A run stores the query mask, the camera and the cost volume
only for its first ``keep_details`` queries (``details/qNNNN.npz``); the poses of every query are in
``results.csv``. So the model is rendered here, at report time, from the run's map and the rows' poses,
at ``VIEW_WIDTH`` pixels wide (a few milliseconds a view):

- the camera: the details' camera; for a simulated query without details, the camera its run's query
  config names (``queries.stated_camera``); a real-data query without details has none stored and
  shows its photo (or the run's ``overlays/<stem>.png``) without the model;
- the background: the photo of a real-data query when it is still where the run found it, else the
  query mask (the simulated view the localizer saw);
- per pose (prior, estimate, truth): the rendered mask (``fill``, background transparent) and the
  model's visible edges (``edges``, one colour per pose), drawn over the background in the browser. The
  estimate is drawn on the map it was found on (``found_map``: the map with eaves on its flat roofs where
  the details or the row record it, named in ``estimate_map``), the others on the run's map as it is; and
  with the camera it was found with (``focal_check.found_camera``: the stated focal lengths times the
  row's ``focal_scale`` where the focal check's correction re-found it), the truth with the camera the
  query was made with (``true_camera``: a simulated run told a focal length off by ``focal_error``
  rendered its queries with the true one), the prior with the stated one (``pose_camera``).
"""

from __future__ import annotations

import base64
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from semcityloc.benchmark.found_map import FoundMaps, row_look
from semcityloc.benchmark.queries import stated_camera
from semcityloc.benchmark.results import SKIPPED, row_pose, unreadable_row
from semcityloc.benchmark.runfiles import OVERLAYS_DIR
from semcityloc.classes import IGNORE
from semcityloc.errors import SemCityLocError, as_flags, parameter
from semcityloc.evaluation.metrics import THRESHOLDS
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import wrap_deg
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import load_image, resize_nearest, scaled_size
from semcityloc.localization.focal_check import found_camera, with_focal_scale
from semcityloc.localization.result import LOCALIZED
from semcityloc.render import Renderer
from semcityloc.render.overlay import label_colors, visible_edges

VIEW_WIDTH = 320  # query images are drawn this wide (height in proportion)
JPEG_QUALITY = 80
# Pose name in the page -> (results.csv column prefix, edge colour RGB).
POSES: dict[str, tuple[str, tuple[int, int, int]]] = {
    "prior": ("prior", (60, 120, 255)),
    "estimate": ("est", (255, 0, 255)),
    "truth": ("true", (0, 220, 255)),
}
NO_TRUTH, NOT_LOCALIZED, WORSE = "no truth", "not localized", "worse"
UNREADABLE = "unreadable input"  # not localized because its mask or depth could not be read: no search
QUERY_MASK = "query mask"


def data_uri(image: np.ndarray, fmt: str = "PNG") -> str:
    """``data:image/...;base64,...`` of an (H, W, 3|4) uint8 image: JPEG for photos, else a palette PNG
    (about 40 % smaller than RGB(A) for label images)."""
    buf = io.BytesIO()
    if fmt == "JPEG":
        Image.fromarray(np.asarray(image)[..., :3]).save(buf, "JPEG", quality=JPEG_QUALITY)
    else:  # label colours and edges: a handful of colours, kept exactly by a 256-colour palette
        img = Image.fromarray(np.asarray(image))
        img.quantize(256, method=Image.Quantize.FASTOCTREE).save(buf, "PNG", optimize=True)
    return f"data:image/{fmt.lower()};base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _float(text: str | None) -> float | None:
    try:
        value = float(text) if text not in (None, "") else None
    except ValueError:
        return None
    return value if value is not None and math.isfinite(value) else None


def row_focal_scale(row: dict[str, str]) -> float | None:
    """A ``results.csv`` row's ``focal_scale``: the focal scale its estimate was found with where the focal
    check's correction re-found it (the camera to draw it with: ``focal_check.found_camera``), else None."""
    return _float(row.get("focal_scale"))


def error_bin(row: dict[str, str]) -> str:
    """The row's place among the recall thresholds: ``≤2 m, 2°`` ... ``worse``, or why it has none (not
    localized, its input unreadable, no truth, skipped)."""
    if row["status"] == SKIPPED:
        return SKIPPED
    if unreadable_row(row):
        return UNREADABLE
    if row["status"] != LOCALIZED:
        return NOT_LOCALIZED
    e_m, e_deg = _float(row.get("err_xyz_m")), _float(row.get("err_rot_deg"))
    if e_m is None or e_deg is None:
        return NO_TRUTH
    for m, d in THRESHOLDS:
        if e_m <= m and e_deg <= d:
            return threshold_label(m, d)
    return WORSE


def threshold_label(max_m: float, max_deg: float) -> str:
    """The label of a recall threshold (``≤5 m, 5°``), as the HTML page's error bins and filter name it."""
    return f"≤{max_m:g} m, {max_deg:g}°"


def error_bins() -> list[str]:
    """Every bin ``error_bin`` gives, best first (the page's filter lists them in this order)."""
    why_none = [WORSE, NOT_LOCALIZED, UNREADABLE, NO_TRUTH, SKIPPED]
    return [threshold_label(m, d) for m, d in THRESHOLDS] + why_none


def query_camera(config: dict, details: dict | None) -> Camera | None:
    """The query's camera at full size: the details' or, for a simulated run, its query config's."""
    if details is not None:
        fx, fy, cx, cy, w, h = details["camera"]
        return Camera(float(fx), float(fy), float(cx), float(cy), int(w), int(h))
    qc = config.get("query_config")
    if config.get("mode") is None and qc:
        return stated_camera(**{k: qc[k] for k in ("width", "height", "focal_mm", "focal_error") if k in qc})
    return None


def true_camera(config: dict, camera: Camera) -> Camera:
    """The camera a run's queries were made with, ``camera`` being the stated one (``query_camera``, at any
    size): a simulated run's query config with a ``focal_error`` rendered them with the focal lengths the
    stated ones are ``1 + focal_error`` times (``queries.stated_camera``); otherwise the stated one (real
    data, a run without the error, a run folder without a query config)."""
    qc = config.get("query_config") or {}
    error = _float(str(qc.get("focal_error", ""))) if config.get("mode") is None else None
    return camera if not error else with_focal_scale(camera, 1.0 / (1.0 + error))


def pose_camera(name: str, camera: Camera, config: dict, row: dict[str, str]) -> Camera:
    """The camera to draw pose ``name`` of ``POSES`` with, ``camera`` being the stated one: the estimate
    with the camera it was found with (``focal_check.found_camera``), the truth with the one the query was
    made with (``true_camera``), the prior with the stated one (what the localizer was given)."""
    if name == "estimate":
        return found_camera(camera, row_focal_scale(row))
    return true_camera(config, camera) if name == "truth" else camera


def _query_meta(row: dict[str, str], details: dict | None) -> dict:
    if details is not None and details["meta"].get("query_meta"):
        return details["meta"]["query_meta"]
    try:
        return json.loads(row.get("meta_json") or "{}")
    except ValueError:
        return {}


def _run_overlay(run_path: Path, config: dict, row: dict) -> Path | None:
    """The run's own ``overlays/<stem>.png`` of a photo (``semcityloc run``), when it exists."""
    names = config.get("query_names") or []
    index = int(row["index"])
    if index < len(names):
        overlay = run_path / OVERLAYS_DIR / f"{Path(names[index]).stem}.png"
        if overlay.is_file():
            return overlay
    return None


def _background(
    run_path: Path, config: dict, row: dict, details: dict | None, photo: Path | None, width: int
) -> tuple[np.ndarray | None, str]:
    """(RGB, what it is): without details (no camera to draw the model with) the run's own overlay of
    the photo first; else the photo, the query mask, or (None, why not)."""
    overlay = _run_overlay(run_path, config, row) if details is None else None
    if overlay is not None:
        try:
            return load_image(overlay, max_width=width), "photo with the model at the estimate (run overlay)"
        except SemCityLocError:
            pass  # unreadable: the photo below
    if photo is not None:
        try:
            return load_image(photo, max_width=width), "photo"
        except SemCityLocError:
            pass  # moved or unreadable since the run: fall through to what the run stored
    if details is not None:
        labels = details["labels"]
        size = scaled_size(labels.shape[1], labels.shape[0], width)
        return label_colors(resize_nearest(labels, *size)), QUERY_MASK
    return None, f"no image stored (the run kept no details of this query; see {parameter('keep_details')})"


def _pose_layers(renderer: Renderer, camera: Camera, pose_local: Pose, color) -> dict[str, str]:
    """The rendered mask (background transparent) and the visible model edges of one pose."""
    view = renderer.render(camera, pose_local, depth=True, face_ids=True)
    labels = view.labels[0]
    fill = np.zeros(labels.shape + (4,), np.uint8)
    fill[..., :3] = label_colors(labels)
    fill[..., 3] = np.where((labels > 0) & (labels != IGNORE), 255, 0)
    edges = np.zeros(labels.shape + (4,), np.uint8)
    mask = visible_edges(view.face_ids[0], view.depth[0], renderer.scene)
    edges[mask] = (*color, 255)
    return {"fill": data_uri(fill), "edges": data_uri(edges)}


def cost_slices(details: dict, poses: dict[str, Pose | None]) -> dict | None:
    """The coarse cost volume's xy slice at its best (z, yaw) and yaw slice at its best (x, y, z), with
    where each pose falls (x, y, yaw); None when the run kept no volume."""
    scores = details["cost_scores"]
    axes = details["meta"].get("cost_volume")
    if scores.size == 0 or axes is None:
        return None
    xs, ys, zs, yaws = (np.asarray(axes[k], dtype=np.float64) for k in ("x", "y", "z", "yaw"))
    bi, bj, bk, bl = np.unravel_index(int(np.argmax(scores)), scores.shape)
    mid = float(yaws[len(yaws) // 2])
    marks = {}
    for name, pose in poses.items():
        if pose is not None:
            x, y, _, _, _, yaw = pose.to_xyz_rpy()
            marks[name] = [round(float(x), 2), round(float(y), 2), round(mid + wrap_deg(float(yaw) - mid), 2)]
    return {
        "x": np.round(xs, 2).tolist(),
        "y": np.round(ys, 2).tolist(),
        "xy": np.round(scores[:, :, bk, bl].T.astype(np.float64), 4).tolist(),  # rows = y
        "z": round(float(zs[bk]), 1),
        "yaw_at": round(float(yaws[bl]), 1),
        "yaw": np.round(yaws, 2).tolist(),
        "yaw_scores": np.round(scores[bi, bj, bk, :].astype(np.float64), 4).tolist(),
        "at": [round(float(xs[bi]), 1), round(float(ys[bj]), 1), round(float(zs[bk]), 1)],
        "marks": marks,
    }


NUMBERS = (
    "err_xyz_m",
    "err_rot_deg",
    "err_yaw_deg",
    "prior_err_m",
    "prior_yaw_err_deg",
    "score",
    "semantic",
    "depth_cost",
    "score_margin",
    "spread_m",
    "spread_deg",
    "sigma_xy_m",
    "sigma_z_m",
    "sigma_yaw_deg",
    "building_iou",
    "probability",
    "query_miou",
    "height_m",
    "t_total_s",
)


def query_view(
    run_path: Path,
    config: dict,
    row: dict[str, str],
    details: dict | None,
    maps: FoundMaps | None,
    photo: Path | None,
    width: int = VIEW_WIDTH,
) -> dict[str, Any]:
    """Everything the page shows of one query (JSON-ready): status, numbers, images, cost slices.
    ``maps``: the run's map renderers (None: its map is gone, no model drawn)."""
    poses = {name: row_pose(row, prefix) for name, (prefix, _) in POSES.items()}
    background, background_kind = _background(run_path, config, row, details, photo, width)
    camera = query_camera(config, details)
    layers: dict[str, dict[str, str]] = {}
    estimate_map = None
    if camera is not None and maps is not None:
        if background is not None:
            camera = camera.scaled(background.shape[1], background.shape[0])
        else:
            camera = camera.scaled(*scaled_size(camera.width, camera.height, width))
        look = details["meta"].get("flat_roof_eaves") if details is not None else row_look(row)
        found_on, found_map = maps.for_estimate(look)
        for name, pose in poses.items():
            if pose is not None:  # the estimate on the map it was found on
                renderer = found_on if name == "estimate" else maps.searched()
                drawn_with = pose_camera(name, camera, config, row)
                layers[name] = _pose_layers(renderer, drawn_with, pose, POSES[name][1])
        estimate_map = found_map if "estimate" in layers else None
    mask = data_uri(background) if background_kind == QUERY_MASK else None
    if mask is None and details is not None:
        labels = details["labels"]
        mask = data_uri(
            label_colors(resize_nearest(labels, *scaled_size(labels.shape[1], labels.shape[0], width)))
        )
    meta = _query_meta(row, details)
    return {
        "qid": row["query_id"],
        "index": int(row["index"]),
        "name": meta.get("name") or row["query_id"],
        "status": row["status"],
        "reason": row.get("reason", ""),
        "view": row.get("view") or "unknown",
        "bin": error_bin(row),
        "numbers": {k: _float(row.get(k)) for k in NUMBERS},
        # the query mask is sent once, as ``mask``; the page draws it as the background too
        "background": data_uri(background, "JPEG" if background_kind != QUERY_MASK else "PNG")
        if background is not None and background_kind != QUERY_MASK
        else None,
        "background_kind": as_flags(background_kind),  # the page's words: the command line's (``report``)
        "size": [camera.width, camera.height] if camera is not None and layers else None,
        "layers": layers,
        "estimate_map": estimate_map,  # None: the run's map as it is
        "mask": mask,
        "cost": cost_slices(details, poses) if details is not None else None,
    }
