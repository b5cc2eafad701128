"""Seed-aware paired intervals, checked where the true difference is known.

Simulated per-seed per-object errors of two models on the same 150 test objects (3 classes):
a shared object difficulty (the pairing removes it), per-object noise, and a per-seed offset
(training-seed variance) of standard deviation ``sigma_seed``; model a is worse by exactly
``DELTA``. Over many simulated benchmarks a 95% interval should contain ``DELTA`` about 95%
of the time. The intervals over test objects alone (seed-averaged errors) miss it most of the
time once seeds vary; ``paired_seeds`` must not.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmark.scoring.uncertainty import paired, paired_seeds, t975

DELTA = 1.0
STRATA = np.repeat([0, 1, 2], 50)


def coverage(n_seeds: int, sigma_seed: float, trials: int = 120) -> tuple[float, float, float]:
    """(seed-aware coverage, objects-only coverage, mean seed-aware half-width)."""
    rng = np.random.default_rng(n_seeds * 100 + int(sigma_seed * 10))
    hits_seeds = hits_objects = 0
    widths = []
    for t in range(trials):
        difficulty = rng.normal(0, 10, len(STRATA))
        a = difficulty + DELTA + rng.normal(0, sigma_seed, (n_seeds, 1))
        a = a + rng.normal(0, 3, a.shape)
        b = difficulty + rng.normal(0, sigma_seed, (n_seeds, 1))
        b = b + rng.normal(0, 3, b.shape)
        s = paired_seeds(a, b, STRATA, n_boot=300, seed=t)
        o = paired(a.mean(0), b.mean(0), STRATA, n_boot=300, seed=t)
        hits_seeds += s["ci"][0] <= DELTA <= s["ci"][1]
        hits_objects += o["ci"][0] <= DELTA <= o["ci"][1]
        widths.append(s["half_width"])
    return hits_seeds / trials, hits_objects / trials, float(np.mean(widths))


@pytest.mark.parametrize("n_seeds", [3, 5])
def test_seed_aware_interval_covers_a_known_difference(n_seeds):
    seeds_cov, objects_cov, _ = coverage(n_seeds, sigma_seed=2.0)
    assert seeds_cov >= 0.9, seeds_cov
    assert objects_cov <= 0.5, objects_cov  # what the old findings did: far too sure


def test_without_seed_variance_it_is_not_narrower_than_the_object_interval():
    seeds_cov, objects_cov, width = coverage(3, sigma_seed=0.0)
    assert seeds_cov >= 0.9 and objects_cov >= 0.85
    assert width < 1.0  # still decides real differences of a few dB²


def test_one_seed_falls_back_to_objects_and_says_so():
    rng = np.random.default_rng(1)
    a, b = rng.normal(5, 1, (1, 150)), rng.normal(4, 1, (1, 150))
    got = paired_seeds(a, b, STRATA)
    assert got["seeds"] == [1, 1] and got["ci"] == paired(a[0], b[0], STRATA)["ci"]


def test_t_quantiles():
    assert t975(2) == pytest.approx(4.303) and t975(1e9) == 1.96
    assert t975(2) > t975(2.5) > t975(3)
