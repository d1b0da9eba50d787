"""A flight's focal length from its own oblique images: the scale of the stated focal length that the
localizer's score prefers, summed over the images that share the camera.

Why: a focal length a few percent off (the EXIF's 35 mm-equivalent value instead of a calibration: 2.4 %
short on the real H20T thermal image) moves the camera by as much along its axis, and the poses are
accepted all the same (``docs/benchmark.md``, "Other cameras and cities": Berlin seed 3 from 97 to 39 % at
2 m / 2 deg). One image cannot settle it: seen from above, focal length and height are one unknown; an
oblique view tells them apart, but per image the best-scoring scale is noisy, and choosing it per image
cost more where the focal length was right than it gained where it was wrong (stop 33, the generated city:
obliques 96 -> 76 % at 2 m with the right focal length). The images of a flight share their camera,
though, and the sum of their score curves peaks where the focal length is right: from 20 oblique queries
of a 100-query flight, within 0.9 % of the right scale on the generated city, Fürth and Berlin seed 3,
with the right focal length and with one 2.4 % short (``docs/benchmark.md``; ``benchmarks/focal_selfcal.py``).

How (``estimate_focal_scale``): each oblique image (the prior's optical axis at least
``MIN_OBLIQUE_DEG`` from nadir; at most ``max_images``, evenly spread) is localized with its camera's
focal lengths times each scale of ``scales``, and its final score kept; an image that any scale leaves
without a score (a search stopped at its volume's edge) is left out. The scores are summed per scale; the
best scale and its two neighbours give a parabola whose vertex is the estimate. No estimate (``reason``
says why) with fewer than ``MIN_IMAGES`` images or a best scale at the end of the grid (the focal length
is further off than the grid reaches, or the images disagree).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from semcityloc.errors import ParameterError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.focal_check import MIN_OBLIQUE_DEG, is_oblique, with_focal_scale
from semcityloc.localization.localize import Localizer

SCALES = tuple(float(s) for s in np.round(np.linspace(0.94, 1.06, 9), 4))  # steps of 1.5 %
MIN_IMAGES = 5
MAX_IMAGES = 20


@dataclass(frozen=True)
class FocalView:
    """One image of the flight as the localizer takes it (poses in the map's local frame)."""

    camera: Camera
    prior_local: Pose
    labels: np.ndarray
    depth: np.ndarray | None = None
    uncertainty: PriorUncertainty | None = None


@dataclass(frozen=True)
class FocalEstimate:
    """``scale``: multiply the stated focal lengths by it (None: no estimate, ``reason`` says why)."""

    scale: float | None
    images: int
    scales: tuple[float, ...]
    curve: tuple[float, ...]  # summed score per scale, minus its largest (0 at the best)
    reason: str | None = None

    def as_dict(self) -> dict:
        """The estimate and its score curve as plain values, for the focal cache and records."""
        return {
            "scale": self.scale,
            "images": self.images,
            "scales": list(self.scales),
            "curve": [round(v, 6) for v in self.curve],
            "reason": self.reason,
        }

    @classmethod
    def from_dict(cls, data: dict) -> FocalEstimate:
        """The estimate ``as_dict`` wrote (a cached one); ``ParameterError`` when it is not one."""
        try:
            scale = None if data["scale"] is None else float(data["scale"])
            return cls(
                scale,
                int(data["images"]),
                tuple(float(s) for s in data["scales"]),
                tuple(float(v) for v in data["curve"]),
                None if data["reason"] is None else str(data["reason"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"not a focal-length estimate: {exc!r}") from exc


def oblique_subset(
    priors: Sequence[Pose], max_images: int = MAX_IMAGES, min_deg: float = MIN_OBLIQUE_DEG
) -> list[int]:
    """Indices of the oblique ones among ``priors`` (``is_oblique``), at most ``max_images`` of them,
    evenly spread over the sequence."""
    oblique = [i for i, prior in enumerate(priors) if is_oblique(prior, min_deg)]
    if len(oblique) > max_images:
        oblique = [oblique[k] for k in np.linspace(0, len(oblique) - 1, max_images).round().astype(int)]
    return oblique


def too_few_obliques(count: int, scales: Sequence[float] = SCALES) -> FocalEstimate:
    """No estimate: ``count`` oblique images are fewer than ``MIN_IMAGES``."""
    reason = f"{count} oblique images ({MIN_OBLIQUE_DEG:g}+ deg from nadir); need {MIN_IMAGES}"
    return FocalEstimate(None, count, tuple(float(s) for s in scales), (), reason)


def estimate_focal_scale(
    localizer: Localizer,
    views: Sequence[FocalView],
    scales: Sequence[float] = SCALES,
    max_images: int = MAX_IMAGES,
    min_oblique_deg: float = MIN_OBLIQUE_DEG,
    progress: Callable[[], None] | None = None,
) -> FocalEstimate:
    """The flight's focal-length scale (module docstring) from ``views`` (all of one camera).
    ``min_oblique_deg`` = 0 takes nadir views too (measured biased: ``benchmarks/focal_selfcal.py
    --views nadir``). ``progress`` is called after each image used."""
    scales = tuple(float(s) for s in scales)
    if len(scales) < 3 or any(b <= a for a, b in zip(scales, scales[1:], strict=False)) or scales[0] <= 0:
        raise ParameterError(f"scales must be at least 3 increasing positive values, got {scales}")
    priors = [v.prior_local for v in views]
    oblique = [views[i] for i in oblique_subset(priors, max_images, min_oblique_deg)]
    if len(oblique) < MIN_IMAGES:
        return too_few_obliques(len(oblique), scales)
    # Each image's own focal check (``focal_check.py``) would only warn on results thrown away here.
    config = replace(localizer.config, focal_check=replace(localizer.config.focal_check, enabled=False))
    curves = []
    for view in oblique:
        scores = []
        for s in scales:
            r = localizer.localize(
                with_focal_scale(view.camera, s),
                view.prior_local,
                view.labels,
                view.depth,
                config=config,
                prior_uncertainty=view.uncertainty,
            )
            scores.append(r.score if r.score is not None and math.isfinite(r.score) else math.nan)
        if np.all(np.isfinite(scores)):
            curves.append(scores)
        if progress is not None:
            progress()
    if len(curves) < MIN_IMAGES:
        reason = (
            f"{len(curves)} oblique images with a score at every scale (of {len(views)}); need {MIN_IMAGES}"
        )
        return FocalEstimate(None, len(curves), scales, (), reason)
    total = np.sum(curves, axis=0)
    curve = tuple(float(v) for v in total - total.max())
    best = int(np.argmax(total))
    if best in (0, len(scales) - 1):
        reason = f"the best scale {scales[best]:g} is at the end of the grid {scales[0]:g}-{scales[-1]:g}"
        return FocalEstimate(None, len(curves), scales, curve, reason)
    y0, y1, y2 = total[best - 1 : best + 2]
    x0, x1, x2 = scales[best - 1 : best + 2]
    denominator = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / denominator
    b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / denominator
    vertex = -b / (2.0 * a) if a < 0 else x1
    return FocalEstimate(float(np.clip(vertex, x0, x2)), len(curves), scales, curve)
