"""Realistic relative depth: what a monocular network (MoGe-2-like) gets wrong, beyond scale and shift.

Why: the ``clean`` benchmark's depth (``perception_sim.simulate_depth``) is almost exactly the affine
model the localizer's depth cost fits, so the cost cannot fail on it. Real monocular depth is relative
(unknown scale and shift) and also:

- **non-affine relief**: relief flattened or exaggerated — depth warped by a smooth monotone power law
  about the median, ``d' = m (d / m) ** gamma`` with ``gamma`` log-uniform in ``warp_gamma``
  (default 0.8–1.25). Judgement: MoGe/Depth-Anything outputs on aerial views compress or stretch the
  depth range of tall cities by 10–25 % relative to an affine fit (their affine-invariant errors are
  reported at 5–10 % AbsRel on benchmarks, more on out-of-domain aerial views);
- **low-frequency distortion** ≈ ``distortion`` (default 10 %): a smooth multiplicative field over a
  third of the image (the "bowl" / tilt a network puts on wide planar scenes);
- **pixel noise** ``noise`` (default 3–6 % standard deviation, multiplicative);
- **edges bled** over ``bleed_px`` pixels (default 1–3) at depth discontinuities (> ``jump`` relative):
  the near surface's depth smears over the far one, and pixels on the jump take in-between values
  (flying pixels);
- trees and cars at their own depth (the reality render sees them), sky invalid (NaN).

Every draw comes from the generator passed in (same state, same output).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from semcityloc.benchmark.perception_sim import (
    DEPTH_DISTORTION_CELL,
    DEPTH_MIN_SHARE,
    DEPTH_SCALE_RANGE,
    DEPTH_SHIFT_RANGE,
    clean_depth_input,
    smooth_field,
)
from semcityloc.errors import BenchmarkConfigError, finite_number


@dataclass(frozen=True)
class DepthParams:
    """Magnitudes of the realistic depth errors (module docstring)."""

    warp_gamma: tuple[float, float] = (0.8, 1.25)
    distortion: float = 0.10
    noise: tuple[float, float] = (0.03, 0.06)
    bleed_px: tuple[int, int] = (1, 3)
    jump: float = 0.05

    def __post_init__(self) -> None:
        def bad(name: str, rule: str) -> BenchmarkConfigError:
            return BenchmarkConfigError(f"DepthParams.{name} must be {rule}, got {getattr(self, name)!r}")

        for name, low in (("warp_gamma", 0.0), ("noise", 0.0), ("bleed_px", 0.0)):
            value = getattr(self, name)
            items = list(value) if isinstance(value, (tuple, list, np.ndarray)) else None
            if items is None or not all(finite_number(v) for v in items):  # text, bools, NaN: no numbers here
                raise bad(name, "a (low, high) pair of numbers")
            pair = tuple(float(v) for v in items)
            if len(pair) != 2 or not (low <= pair[0] <= pair[1] < math.inf):
                raise bad(name, f"a pair {low:g} <= low <= high")
            if name == "warp_gamma" and pair[0] <= 0.0:
                raise bad(name, "positive")
            if name == "bleed_px":
                if any(v != int(v) for v in pair):
                    raise bad(name, "whole pixels")
                pair = (int(pair[0]), int(pair[1]))
            object.__setattr__(self, name, pair)
        for name in ("distortion", "jump"):
            value = getattr(self, name)
            if not finite_number(value) or not 0.0 <= value < math.inf:
                raise bad(name, "a number >= 0")
            object.__setattr__(self, name, float(value))


def simulate_depth_realistic(
    clean_depth: np.ndarray, rng: np.random.Generator, params: DepthParams | None = None
) -> np.ndarray:
    """(H, W) float32 relative depth from the rendered z-depth (module docstring); NaN where not finite."""
    p = params or DepthParams()
    d, valid = clean_depth_input(clean_depth)
    out = np.full(d.shape, np.nan, dtype=np.float32)
    if not valid.any():
        return out
    h, w = d.shape
    med = float(np.median(d[valid]))

    gamma = math.exp(rng.uniform(math.log(p.warp_gamma[0]), math.log(p.warp_gamma[1])))
    bleed = int(rng.integers(p.bleed_px[0], p.bleed_px[1] + 1))
    sigma = float(rng.uniform(*p.noise))
    a = math.exp(rng.uniform(math.log(DEPTH_SCALE_RANGE[0]), math.log(DEPTH_SCALE_RANGE[1])))
    field = smooth_field(rng, h, w, DEPTH_DISTORTION_CELL * max(h, w))
    field /= max(float(np.abs(field).max()), 1e-12)
    noise = rng.standard_normal(d.shape, dtype=np.float32)
    shift_share = float(rng.uniform(*DEPTH_SHIFT_RANGE))

    # Edge bleeding: within `bleed` px of a depth jump the nearer depth spreads over the farther one;
    # the pixels on the jump itself get the mean of the two sides (flying pixels).
    far = np.where(valid, d, np.inf)
    if bleed > 0:
        near = ndimage.minimum_filter(far, size=2 * bleed + 1)
        jump = valid & (near < far * (1.0 - p.jump))
        ring = jump & (ndimage.minimum_filter(far, size=3) < far * (1.0 - p.jump))
        bled = np.where(jump, near, d)
        bled = np.where(ring, 0.5 * (near + d), bled)
    else:
        bled = d
    warped = med * np.power(np.where(valid, bled, med) / med, gamma)
    wmin = float(warped[valid].min())
    b = max(shift_share * a * med, DEPTH_MIN_SHARE * a * med - a * wmin)
    rel = (a * warped + b) * (1.0 + p.distortion * field) * np.clip(1.0 + sigma * noise, 0.5, 1.5)
    out[valid] = np.maximum(rel[valid], 1e-6).astype(np.float32)
    return out
