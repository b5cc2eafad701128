import math

import numpy as np
import pytest

from basic_shapes.scales import (
    MAX_RADIUS,
    SCALE_RANGE,
    ScaleError,
    capacity,
    min_pairwise_distance,
    sample_scales,
)


def test_scales_are_dissimilar_in_range_and_fit_the_radar_window():
    s = sample_scales(1000, np.random.default_rng(1))
    assert s.shape == (1000, 3)
    assert SCALE_RANGE[0] <= s.min() and s.max() <= SCALE_RANGE[1]
    assert (np.linalg.norm(s, axis=1) / 2).max() <= MAX_RADIUS
    # independent brute-force check of the similarity rule (sorted extents, max log ratio)
    logs = np.sort(np.log(s), axis=1)
    worst = min(np.abs(logs[i] - logs[j]).max() for i in range(200) for j in range(i + 1, 1000))
    assert worst >= 0.05
    assert min_pairwise_distance(s) >= 0.05


def test_similarity_ignores_axis_permutation():
    assert min_pairwise_distance(np.array([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]])) == 0.0
    assert min_pairwise_distance(np.array([[1.0, 1.0, 1.0], [1.1, 1.0, 1.0]])) == pytest.approx(
        math.log(1.1)
    )


def test_scales_are_seeded():
    a = sample_scales(50, np.random.default_rng(7))
    b = sample_scales(50, np.random.default_rng(7))
    c = sample_scales(50, np.random.default_rng(8))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_too_many_objects_fail_clearly():
    with pytest.raises(ScaleError, match="at most"):
        sample_scales(capacity((1.0, 1.2), 0.05) + 1, np.random.default_rng(0), (1.0, 1.2), 0.05)
    with pytest.raises(ScaleError, match="placed only"):  # under the bound, but packing fails
        sample_scales(
            capacity((1.0, 1.2), 0.05),
            np.random.default_rng(0),
            (1.0, 1.2),
            0.05,
            max_tries_per_object=20,
        )


def test_scale_range_must_fit_the_radar_window():
    with pytest.raises(ScaleError, match="radar window"):
        sample_scales(3, np.random.default_rng(0), (0.5, 3.0))
