"""The HTML report's interactive plots (plotly): error curves, recall lines, risk-coverage, the 3D city.

Why plotly: a well-kept library that writes figures as JSON for plotly.js, which the report embeds once,
so the page opens from disk with no network. Every point of a per-query plot carries the query's key
(``customdata``) so hovering names the query and clicking opens it in the query browser. plotly is an
optional dependency (extra ``plots``), imported only when a figure is made.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from semcityloc.benchmark.report_runs import RunData
from semcityloc.benchmark.results import cell_float
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import CLASS_NAMES, PALETTE
from semcityloc.errors import OptionalDependencyError
from semcityloc.evaluation.metrics import THRESHOLDS, threshold_key
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose

MAX_MESH_TRIANGLES = 60_000  # the 3D view keeps the largest triangles of a bigger model
FRUSTUM_FRACTION = 0.3  # a frustum is drawn this deep, as a share of the median camera height
POSE_COLORS = {"prior": "rgb(60,120,255)", "estimate": "rgb(255,0,255)", "truth": "rgb(0,190,230)"}


def graph_objects():
    """``plotly.graph_objects``, or a one-line install hint."""
    try:
        import plotly.graph_objects as go  # optional dependency, loaded only when used
    except ImportError as exc:
        raise OptionalDependencyError("plotly", "plots", "the HTML report") from exc
    return go


def _layout(go, xlabel: str, ylabel: str, **extra) -> dict:
    return dict(
        xaxis_title=xlabel,
        yaxis_title=ylabel,
        margin=dict(l=60, r=20, t=30, b=50),
        height=380,
        legend=dict(font=dict(size=10)),
        template="plotly_white",
        **extra,
    )


def cumulative_figure(runs: list[RunData], keys: list[list[str]], column: str, xlabel: str, x_max: float):
    """Percent of a run's evaluated queries with error <= x, one step line per run; a point per localized
    query (hover: its id and error; click: opens it). ``keys[i]``: the page key of each row of run i."""
    go = graph_objects()
    fig = go.Figure()
    for run, run_keys in zip(runs, keys, strict=True):
        points = []
        evaluated = 0
        for row, key in zip(run.rows, run_keys, strict=True):
            if row["status"] == "skipped":
                continue
            evaluated += 1
            value = row.get(column, "")
            if row["status"] == "localized" and value not in ("", "inf", "nan"):
                points.append((float(value), row["query_id"], key))
        points.sort()
        if not evaluated or not points:
            continue
        x = [0.0] + [p[0] for p in points]
        y = [0.0] + [100.0 * (n + 1) / evaluated for n in range(len(points))]
        fig.add_trace(
            go.Scatter(
                x=x,
                y=y,
                mode="lines+markers",
                line_shape="hv",
                name=run.label,
                text=[""] + [p[1] for p in points],
                customdata=[""] + [p[2] for p in points],
                hovertemplate="%{text}: %{x:.2f}<br>%{y:.0f} % of queries<extra>%{fullData.name}</extra>",
                marker=dict(size=5),
            )
        )
    for m, _ in THRESHOLDS:
        fig.add_vline(x=m, line=dict(color="#bbb", width=1, dash="dot"))
    fig.update_layout(
        **_layout(go, xlabel, "queries with error ≤ x (%)"), xaxis_range=[0, x_max], yaxis_range=[0, 100]
    )
    return fig


def recall_lines_figure(groups: dict[str, list[RunData]], x_of: Callable[[RunData], float], xlabel: str):
    """Recall (≤) at each threshold against ``x_of(run)``, one colour per group (hover: the run)."""
    go = graph_objects()
    fig = go.Figure()
    dashes = ("solid", "dash", "dot")
    for name, members in groups.items():
        members = sorted(members, key=x_of)
        for (m, d), dash in zip(THRESHOLDS, dashes, strict=False):
            fig.add_trace(
                go.Scatter(
                    x=[x_of(r) for r in members],
                    y=[r.summary.get(threshold_key(m, d), math.nan) for r in members],
                    mode="lines+markers",
                    line=dict(dash=dash),
                    name=f"{name} {m:g} m, {d:g}°",
                    text=[r.label for r in members],
                    hovertemplate="%{text}<br>recall %{y:.1f} %<extra></extra>",
                )
            )
    fig.update_layout(**_layout(go, xlabel, "recall (%)"), yaxis_range=[0, 100])
    return fig


def self_figure(runs: list[RunData], keys: list[list[str]]):
    """Runs without ground truth: a point per localized query, its calibrated probability against how far
    its pose lies from the prior (horizontal, m; hover: the query and its stated 1-sigma; click: opens
    it). A refused query keeps no pose to measure from. ``keys[i]``: the page key of each row of run i."""
    go = graph_objects()
    fig = go.Figure()
    for run, run_keys in zip(runs, keys, strict=True):
        points = [_self_point(row, key) for row, key in zip(run.rows, run_keys, strict=True)]
        points = [p for p in points if p is not None]
        if points:
            fig.add_trace(
                go.Scatter(
                    x=[p[0] for p in points],
                    y=[p[1] for p in points],
                    mode="markers",
                    marker=dict(size=7),
                    name=run.label,
                    text=[p[2] for p in points],
                    customdata=[p[3] for p in points],
                    hovertemplate="%{text}<br>p %{x:.2f}, %{y:.1f} m from the prior<extra></extra>",
                )
            )
    fig.update_layout(
        **_layout(
            go, "calibrated probability (pose within 5 m / 5°)", "shift from the prior, horizontal (m)"
        ),
        xaxis_range=[0, 1.02],
    )
    return fig


def _self_point(row: dict[str, str], key: str) -> tuple[float, float, str, str] | None:
    """(probability, horizontal shift from the prior in m, hover text, page key) of a localized row, or
    None (not localized, or a value missing)."""
    if row["status"] != "localized":
        return None
    try:
        p, sigma = cell_float(row.get("probability")), cell_float(row.get("sigma_xy_m"))
        est = [cell_float(row.get(f"est_{k}")) for k in "xy"]
        prior = [cell_float(row.get(f"prior_{k}")) for k in "xy"]
    except ValueError:
        return None
    shift = math.hypot(est[0] - prior[0], est[1] - prior[1])
    if not (math.isfinite(p) and math.isfinite(shift)):
        return None
    stated = f", stated 1σ xy {sigma:.2f} m" if math.isfinite(sigma) else ""
    return p, shift, f"{row['query_id']}{stated}", key


def risk_coverage_figure(curves: dict[str, list[tuple[float, float, float]]]):
    """Precision of accepted poses against the share accepted (``localization.confidence.risk_coverage``
    curves by run label; hover: the probability threshold)."""
    go = graph_objects()
    fig = go.Figure()
    for label, curve in curves.items():
        fig.add_trace(
            go.Scatter(
                x=[c for _, c, _ in curve],
                y=[100 * p for _, _, p in curve],
                mode="lines",
                name=label,
                text=[f"p ≥ {t:.2f}" for t, _, _ in curve],
                hovertemplate="%{text}: coverage %{x:.2f}, precision %{y:.0f} %<extra></extra>",
            )
        )
    fig.update_layout(
        **_layout(go, "coverage (share of queries accepted)", "precision of accepted poses (%)"),
        xaxis_range=[0, 1],
    )
    return fig


# ------------------------------------------------------------------------------------------- 3D view
def frustum_depth(centers: list[np.ndarray], model: CityModel) -> float:
    """How deep frusta are drawn: a share of the median camera height above the model's lowest point."""
    ground = float(model.vertices[:, 2].min()) if model.num_triangles else 0.0
    heights = [float(c[2]) - ground for c in centers]
    return max(2.0, FRUSTUM_FRACTION * float(np.median(heights))) if heights else 10.0


def frustum_lines(pose_local: Pose, camera: Camera, depth: float) -> list[list[float | None]]:
    """[x, y, z] lists of a frustum's 8 edges (apex to the image corners at ``depth``, then the image
    rectangle), segments separated by None, rounded to 0.1 m."""
    w, h = camera.width, camera.height
    corners_cam = camera.unproject(np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]), depth)
    corners_local = (pose_local.world_from_cam[:3, :3] @ corners_cam.T).T + pose_local.center
    c = pose_local.center
    points: list = []
    for k in range(4):
        points += [c, corners_local[k], None]
    points += [corners_local[0], corners_local[1], corners_local[2], corners_local[3], corners_local[0], None]
    return [[None if p is None else round(float(p[axis]), 1) for p in points] for axis in range(3)]


def mesh_selection(
    model: CityModel, centers: list[np.ndarray], limit: int = MAX_MESH_TRIANGLES
) -> np.ndarray:
    """Indices of the triangles the 3D view draws: all of a small model; of a bigger one, those near the
    cameras (within their height of the box around their centres), and of those the ``limit`` largest."""
    if model.num_triangles <= limit:
        return np.arange(model.num_triangles)
    candidates = np.arange(model.num_triangles)
    if centers:
        c = np.asarray(centers, dtype=np.float64)
        ground = float(model.vertices[:, 2].min())
        margin = max(50.0, float(np.max(c[:, 2]) - ground))
        lo, hi = c[:, :2].min(axis=0) - margin, c[:, :2].max(axis=0) + margin
        mid = model.triangle_corners().mean(axis=1)[:, :2]
        candidates = np.flatnonzero(np.all((mid >= lo) & (mid <= hi), axis=1))
    if len(candidates) > limit:
        candidates = candidates[np.argsort(model.triangle_areas()[candidates])[::-1][:limit]]
    return np.sort(candidates)


def city_mesh_trace(model: CityModel, keep: np.ndarray):
    """The model's triangles (``keep``) as a Mesh3d coloured by class (the label palette)."""
    go = graph_objects()
    tris = model.triangles[keep]
    used, inverse = np.unique(tris.reshape(-1), return_inverse=True)
    faces = inverse.reshape(-1, 3).astype(np.int32)
    v = model.vertices[used]
    n = len(PALETTE) - 1
    scale = [[k / n, f"rgb({r},{g},{b})"] for k, (r, g, b) in enumerate(PALETTE.tolist())]
    classes = model.classes[keep]
    return go.Mesh3d(
        x=v[:, 0],
        y=v[:, 1],
        z=v[:, 2],
        i=faces[:, 0],
        j=faces[:, 1],
        k=faces[:, 2],
        intensity=classes.astype(np.float32),
        intensitymode="cell",
        colorscale=scale,
        cmin=0,
        cmax=n,
        showscale=False,
        flatshading=True,
        lighting=dict(ambient=0.55, diffuse=0.6, specular=0.05),
        name="city model",
        text=[CLASS_NAMES[c] for c in range(len(CLASS_NAMES))],
        hoverinfo="skip",
    )


def lines_trace(xyz: list[list], name: str, color: str, keys: list, texts: list, width: float = 2, **extra):
    """Line segments in 3D (None separates them); ``keys``: the page key of each point's query (a click
    opens it), ``texts``: its hover text."""
    go = graph_objects()
    return go.Scatter3d(
        x=xyz[0],
        y=xyz[1],
        z=xyz[2],
        mode="lines",
        line=dict(color=color, width=width),
        name=name,
        customdata=keys,
        hovertext=texts,
        hoverinfo="text+name",
        **extra,
    )


def city_figure(model: CityModel, keep: np.ndarray, traces: list, title: str):
    """The 3D view: the city mesh, an empty trace the page fills with the selected query's frusta, then
    ``traces`` (frusta and flight paths)."""
    go = graph_objects()
    fig = go.Figure(
        [city_mesh_trace(model, keep), lines_trace([[], [], []], "selected query", "black", [], [], 6)]
    )
    for t in traces:
        fig.add_trace(t)
    fig.update_layout(
        height=600,
        margin=dict(l=0, r=0, t=30, b=0),
        title=dict(text=title, font=dict(size=12)),
        scene=dict(
            aspectmode="data",
            xaxis_title="x (local m)",
            yaxis_title="y (local m)",
            zaxis_title="z (m)",
            camera=dict(eye=dict(x=1.2, y=-1.2, z=0.9)),
        ),
        legend=dict(font=dict(size=10)),
    )
    return fig
