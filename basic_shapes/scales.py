"""Per-axis object scales, sampled so that no two objects of one class look alike.

Scale = the three bounding-box extents of an object in metres, each drawn log-uniformly from
``SCALE_RANGE``. With extents at most 2 m the bounding-sphere radius is at most
sqrt(3) = 1.73 m, inside the radar window (1.9 m).

Similarity: two scales s, t are *similar* when their sorted extents agree within a factor
exp(d) on every axis, i.e. max_i |ln sort(s)_i - ln sort(t)_i| < d (``min_distance`` d).
Sorting makes the rule blind to axis permutations, so a 1x2x3 box and a 3x2x1 box (the same
shape turned) count as similar; this is stricter than needed for cylinders, never looser.
"""

from __future__ import annotations

import math

import numpy as np

from basic_shapes import portable

SCALE_RANGE = (0.2, 2.0)  # metres, per axis
MIN_DISTANCE = 0.05  # about 5 % on every axis
MAX_RADIUS = 1.9  # metres: bounding-sphere radius that still fits the radar range window


class ScaleError(ValueError):
    """The requested number of dissimilar scales cannot be placed."""


def capacity(scale_range=SCALE_RANGE, min_distance=MIN_DISTANCE) -> int:
    """Upper bound on the number of pairwise dissimilar scales.

    Sorted log-scales live in a simplex of volume W^3/6 (W = log width of the range); each
    point owns a disjoint Chebyshev ball of side d clipped to a region grown by d/2 on each
    side, so at most (W + d)^3 / 6 / d^3 points fit.
    """
    width = math.log(scale_range[1] / scale_range[0])
    return int((width + min_distance) ** 3 / 6 / min_distance**3)


def sample_scales(
    n: int,
    rng: np.random.Generator,
    scale_range=SCALE_RANGE,
    min_distance=MIN_DISTANCE,
    max_tries_per_object: int = 1000,
) -> np.ndarray:
    """Draw ``n`` pairwise dissimilar scales (n, 3) by rejection sampling, or raise ScaleError."""
    lo, hi = scale_range
    if not 0 < lo < hi or math.sqrt(3) * hi / 2 > MAX_RADIUS:
        raise ScaleError(
            f"scale range {scale_range} must satisfy 0 < low < high and fit the "
            f"radar window (bounding radius sqrt(3)*high/2 <= {MAX_RADIUS} m)"
        )
    bound = capacity(scale_range, min_distance)
    if n > bound:
        raise ScaleError(
            f"cannot place {n} dissimilar scales in {scale_range} m with minimum "
            f"log-distance {min_distance}: at most {bound} fit"
        )
    logs = np.empty((n, 3))
    sorted_logs = np.empty((n, 3))
    placed = 0
    for _ in range(n * max_tries_per_object):
        if placed == n:
            break
        cand = np.sort(rng.uniform(math.log(lo), math.log(hi), 3))
        if placed == 0 or np.abs(sorted_logs[:placed] - cand).max(axis=1).min() >= min_distance:
            sorted_logs[placed] = cand
            logs[placed] = rng.permutation(cand)
            placed += 1
    if placed < n:
        raise ScaleError(
            f"placed only {placed} of {n} dissimilar scales in {scale_range} m "
            f"(minimum log-distance {min_distance}); ask for fewer objects or a "
            f"smaller --min-scale-distance"
        )
    return portable.exp(logs)


def min_pairwise_distance(scales: np.ndarray) -> float:
    """Smallest similarity distance among ``scales`` (inf for fewer than two)."""
    s = np.sort(portable.log(np.asarray(scales, float)), axis=1)
    if len(s) < 2:
        return math.inf
    d = np.abs(s[:, None, :] - s[None, :, :]).max(axis=2)
    np.fill_diagonal(d, np.inf)
    return float(d.min())
