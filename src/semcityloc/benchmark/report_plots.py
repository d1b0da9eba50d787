"""The report's PNG figures (matplotlib, Agg): error curves, recall lines, risk-coverage, query figures.

Why its own module: drawing is kept apart from reading runs (``report_runs``) and from choosing what the
report holds (``benchmark.report``). Cumulative position and rotation error curves (one line per run,
``not_localized`` never reaches the curve), recall against the prior noise and against a sweep's values,
the acceptance's precision against coverage, and per saved query (``details/``) the query mask with the
label boundaries of the map rendered at the estimated and true poses (the estimate on the map it was
found on: ``found_map``, with the camera it holds with: ``focal_check.found_camera``), the photo with
the model's edges (real data), and an xy slice and a yaw slice of the coarse cost volume; for runs
without ground truth, what they say of themselves (the calibrated probability, the stated sigmas, the
shift from the prior). matplotlib is an optional dependency (extra
``plots``), imported when a figure is drawn.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from semcityloc.benchmark.found_map import FoundMaps
from semcityloc.benchmark.report_runs import (
    RunData,
    acceptance_data,
    finite_max,
    noise_x,
    prior_noise_groups,
    self_assessment,
    sweep_x,
)
from semcityloc.benchmark.report_views import true_camera
from semcityloc.benchmark.results import SKIPPED
from semcityloc.errors import OptionalDependencyError
from semcityloc.evaluation.metrics import THRESHOLDS, cumulative_curve, threshold_key
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import wrap_deg
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import load_image, resize_nearest, scaled_size
from semcityloc.localization.confidence import risk_coverage
from semcityloc.localization.focal_check import found_camera
from semcityloc.localization.result import LOCALIZED
from semcityloc.render import Renderer
from semcityloc.render.overlay import (
    class_boundaries,
    draw_edges,
    label_colors,
    visible_edges,
)

FIGURE_MAX_WIDTH = 1024  # query figures are drawn at most this wide


def _pyplot():
    try:
        import matplotlib  # optional dependency, loaded only when used
    except ImportError as exc:
        raise OptionalDependencyError("matplotlib", "plots", "the report's plots") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # optional dependency, loaded only when used

    return plt


def _errors(run: RunData, column: str) -> np.ndarray:
    """Per evaluated query (skipped ones left out), inf where not localized."""
    rows = [r for r in run.rows if r["status"] != SKIPPED]
    return np.array([float(r[column]) if r["status"] == LOCALIZED and r[column] else math.inf for r in rows])


def plot_cumulative(runs: list[RunData], column: str, xlabel: str, path: Path, x_max: float = 10.0) -> Path:
    """The cumulative error curve of ``column`` (position or rotation error) for each run, with the recall
    thresholds marked, saved as a PNG at ``path``; queries not localized never reach the curve, so a run's
    curve ends at its share of localized queries.
    """
    plt = _pyplot()
    grid = np.linspace(0.0, x_max, 401)
    fig, ax = plt.subplots(figsize=(6, 4))
    for run in runs:
        ax.plot(grid, cumulative_curve(_errors(run, column), grid), label=run.label)
    for m, _ in THRESHOLDS:
        ax.axvline(m, color="0.8", lw=0.8, ls=":")
    ax.set_xlim(0, x_max)
    ax.set_ylim(0, 100)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("queries with error ≤ x (%)")
    return _save_figure(plt, fig, ax, path, legend_loc="lower right")


def _save_figure(plt, fig, ax, path: Path, legend_loc: str = "best") -> Path:
    """Grid, legend, tight layout, PNG at 120 dpi; the figure is closed."""
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc=legend_loc)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_recall_vs_prior(runs: list[RunData], path: Path) -> Path:
    """Recall (≤) at each threshold against the extra prior noise (bin centre, 0 = base noise only);
    one colour per group of runs that agree on everything but the prior noise (only the runs of such
    comparisons when there are any, else every run)."""
    groups = prior_noise_groups(runs)
    return plot_recall_lines(groups, noise_x, "extra prior noise per axis (m, bin centre)", path)


def plot_recall_lines(groups: dict[str, list[RunData]], x_of, xlabel: str, path: Path) -> Path:
    """Recall (≤) at each threshold against ``x_of(run)``, one colour per group of runs."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    styles = ("-", "--", ":")
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for g, (name, members) in enumerate(groups.items()):
        members = sorted(members, key=x_of)
        x = [x_of(r) for r in members]
        for (m, d), ls in zip(THRESHOLDS, styles, strict=False):
            y = [r.summary.get(threshold_key(m, d), math.nan) for r in members]
            ax.plot(x, y, ls, marker="o", color=colors[g % len(colors)], label=f"{name} {m:g}m,{d:g}°")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("recall (%)")
    ax.set_ylim(0, 100)
    return _save_figure(plt, fig, ax, path)


def plot_recall_vs_sweep(runs: list[RunData], knob: str, path: Path) -> Path:
    """Recall (≤) at each threshold against the values of a sweep (one line per method)."""
    groups: dict[str, list[RunData]] = {}
    for run in runs:
        groups.setdefault(str(run.settings["method"]), []).append(run)
    return plot_recall_lines(groups, lambda r: sweep_x(r.settings["sweep_value"])[0], knob, path)


TRUE_COLOR, EST_COLOR = (0, 200, 255), (255, 0, 255)


def overlay_image(
    query_labels: np.ndarray, est_labels: np.ndarray | None, true_labels: np.ndarray | None
) -> np.ndarray:
    """RGB uint8: the query mask (palette, faded; IGNORE white) with the label boundaries of the render at
    the true pose (cyan, when there is one) and at the estimated pose (magenta) drawn on top."""
    rgb = (0.55 * label_colors(query_labels) + 0.45 * 255).astype(np.uint8)
    if true_labels is not None:
        rgb[class_boundaries(true_labels)] = TRUE_COLOR
    if est_labels is not None:
        rgb[class_boundaries(est_labels)] = EST_COLOR
    return rgb


def photo_overlay(
    photo: np.ndarray,
    renderer: Renderer,
    camera: Camera,
    true,
    est,
    est_renderer: Renderer | None = None,
    est_camera: Camera | None = None,
) -> np.ndarray:
    """RGB uint8: the photo (at ``camera``'s size) with the model's visible edges at the true pose (cyan)
    and at the estimate (magenta; drawn by ``est_renderer``, the map it was found on, when given, and with
    ``est_camera``, the camera it holds with, ``focal_check.found_camera``, when given)."""
    out = photo
    drawn = (
        (true, TRUE_COLOR, renderer, camera),
        (est, EST_COLOR, est_renderer or renderer, est_camera or camera),
    )
    for pose, color, r, cam in drawn:
        if pose is not None:
            view = r.render(cam, pose, depth=True, face_ids=True)
            out = draw_edges(out, visible_edges(view.face_ids[0], view.depth[0], r.scene), color)
    return out


def _pose(matrix: np.ndarray):
    return None if not np.all(np.isfinite(matrix)) else Pose.from_cam_from_world(matrix)


def plot_details(
    details: dict,
    map_model,
    path: Path,
    title: str,
    photo_path: Path | None = None,
    maps=None,
    config: dict | None = None,
) -> Path:
    """One query: overlay (``overlay_image``), the photo with the model's edges (``photo_overlay``, when
    ``photo_path`` is given: real-data runs), xy slice at the best (z, yaw) and yaw slice at the best
    (x, y, z) of the coarse cost volume, with the true (green), prior (blue) and estimated (red) poses.
    Drawn at most ``FIGURE_MAX_WIDTH`` wide; a query without a true pose (a user's photo) shows the
    estimate alone. ``maps``: the run's ``found_map.FoundMaps`` (default: the model as it is), so that the
    poses are drawn on the map the run searched (with its eaves) and an estimate found on the map with
    eaves on its flat roofs on that map, and the caption says so. ``config``: the run's ``run.json``, whose
    query config names the camera a simulated query was made with (``report_views.true_camera``: the truth
    is drawn with it; without one, with the stated camera)."""

    plt = _pyplot()
    fx, fy, cx, cy, w, h = details["camera"]
    camera = Camera(fx, fy, cx, cy, int(w), int(h))
    camera = camera.scaled(*scaled_size(camera.width, camera.height, FIGURE_MAX_WIDTH))
    # The estimate holds with the focal lengths times the correction's scale where it re-found the pose.
    focal_scale = details["meta"].get("focal_scale")
    est_camera = found_camera(camera, focal_scale)
    labels = resize_nearest(details["labels"], camera.width, camera.height)
    true, prior, est = (_pose(details[f"{k}_cam_from_world"]) for k in ("true", "prior", "est"))
    maps = maps or FoundMaps(map_model, Renderer(map_model, engine="numba"))
    renderer = maps.searched()
    est_renderer, est_map = maps.for_estimate(details["meta"].get("flat_roof_eaves"))
    true_cam = true_camera(config or {}, camera)  # a simulated focal_error: the query's true camera
    true_lab = renderer.render(true_cam, true).labels[0] if true is not None else None
    est_lab = est_renderer.render(est_camera, est).labels[0] if est is not None else None
    est_note = f"\nestimate drawn on {est_map}" if est is not None and est_map else ""
    if est is not None and focal_scale is not None:  # the camera it was re-found with, on the same line
        est_note = f" (focal length x {focal_scale:.3f})" + est_note
    scores = details["cost_scores"]
    axes_info = details["meta"].get("cost_volume")
    has_volume = scores.size > 0 and axes_info is not None
    photo = load_image(photo_path, max_width=camera.width) if photo_path is not None else None
    if photo is not None and photo.shape[:2] != (camera.height, camera.width):
        photo = None  # not the photo of these details (its size differs): no photo panel

    n_panels = 1 + (photo is not None) + 2 * has_volume
    fig, axes = plt.subplots(1, n_panels, figsize=(5 * n_panels, 4.2), squeeze=False)
    panels = iter(axes[0])
    ax = next(panels)
    ax.imshow(overlay_image(labels, est_lab, true_lab))
    status = details["meta"].get("status")
    truth_note = "cyan = true pose, " if true is not None else "(no true pose) "
    ax.set_title(f"{title}: {status}\nmask; boundaries: {truth_note}magenta = estimate{est_note}", fontsize=8)
    ax.axis("off")
    if photo is not None:
        ax = next(panels)
        ax.imshow(photo_overlay(photo, renderer, camera, true, est, est_renderer, est_camera))
        ax.set_title(f"photo; model edges: {truth_note}magenta = estimate{est_note}", fontsize=8)
        ax.axis("off")
    if has_volume:
        xs, ys, zs, yaws = (np.asarray(axes_info[k]) for k in ("x", "y", "z", "yaw"))
        bi, bj, bk, bl = np.unravel_index(int(np.argmax(scores)), scores.shape)
        poses = {"true": (true, "g", "x"), "prior": (prior, "b", "+"), "estimate": (est, "r", "o")}
        ax = next(panels)
        hx = (xs[-1] - xs[0]) / max(len(xs) - 1, 1) / 2  # cells centred on the samples
        hy = (ys[-1] - ys[0]) / max(len(ys) - 1, 1) / 2
        ext = (xs[0] - hx, xs[-1] + hx, ys[0] - hy, ys[-1] + hy)
        im = ax.imshow(scores[:, :, bk, bl].T, origin="lower", extent=ext, aspect="equal", cmap="viridis")
        fig.colorbar(im, ax=ax, fraction=0.046)
        for name, (pose, color, marker) in poses.items():
            if pose is not None:
                c = pose.center
                ax.plot(c[0], c[1], marker, color=color, mfc="none", ms=9, mew=2, label=name)
        ax.set_title(f"cost volume xy slice (z = {zs[bk]:.1f} m, yaw = {yaws[bl]:.1f}°)", fontsize=8)
        ax.set_xlabel("x (local m)")
        ax.set_ylabel("y (local m)")
        ax.legend(fontsize=7)
        ax = next(panels)
        ax.plot(yaws, scores[bi, bj, bk, :], "k.-")
        mid = yaws[len(yaws) // 2]
        for name, (pose, color, _) in poses.items():
            if pose is not None:
                yaw = float(pose.to_xyz_rpy()[5])
                ax.axvline(mid + wrap_deg(yaw - mid), color=color, ls="--", label=name)
        ax.set_title(f"yaw slice at x = {xs[bi]:.1f}, y = {ys[bj]:.1f}, z = {zs[bk]:.1f}", fontsize=8)
        ax.set_xlabel("yaw (deg)")
        ax.set_ylabel("score (mean class IoU)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_risk_coverage(runs: list[RunData], path: Path) -> Path:
    """Precision of the accepted poses against the share accepted, as the threshold falls."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for run in runs:
        p, y = acceptance_data(run)
        curve = risk_coverage(p, y)
        ax.plot([c for _, c, _ in curve], [100 * pr for _, _, pr in curve], label=run.label)
    ax.set_xlabel("coverage (share of queries accepted)")
    ax.set_ylabel("precision of accepted poses (%; within 5 m / 5°)")
    ax.set_xlim(0, 1)
    return _save_figure(plt, fig, ax, path)


def plot_self_assessment(runs: list[RunData], path: Path) -> Path:
    """Runs without ground truth (``report_runs.self_assessment``), three panels: the calibrated
    probability of the poses found (localized solid, refused dashed), and the share of localized poses
    whose stated 1-sigma, and whose shift from the prior, is at most x (horizontal solid, vertical
    dashed): what can be read of a run whose errors cannot be measured."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    data = [self_assessment(run) for run in runs]
    bins = np.linspace(0.0, 1.0, 21)
    for run, a, color in zip(runs, data, colors * len(runs), strict=False):
        p, accepted = a["probability"], a["accepted"]
        for chosen, ls, kind in ((accepted, "-", "localized"), (~accepted, "--", "refused")):
            if chosen.any():
                axes[0].hist(
                    p[chosen], bins, histtype="step", ls=ls, color=color, label=f"{run.label}: {kind}"
                )
    axes[0].set_xlabel("calibrated probability (pose within 5 m / 5°)")
    axes[0].set_ylabel("queries")
    axes[0].yaxis.get_major_locator().set_params(integer=True)
    panels = ((axes[1], "sigma", "stated 1-sigma (m)"), (axes[2], "shift", "shift from the prior (m)"))
    for ax, key, xlabel in panels:
        x_max = max([finite_max(a[f"{key}_{k}_m"], 0.0) for a in data for k in ("xy", "z")] + [1.0]) * 1.05
        grid = np.linspace(0.0, x_max, 401)
        for run, a, color in zip(runs, data, colors * len(runs), strict=False):
            for k, ls in (("xy", "-"), ("z", "--")):
                values = a[f"{key}_{k}_m"]
                if np.isfinite(values).any():
                    ax.plot(grid, cumulative_curve(values, grid), ls, color=color, label=f"{run.label}: {k}")
        ax.set_xlim(0, x_max)
        ax.set_ylim(0, 100)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("localized poses with value ≤ x (%)")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
