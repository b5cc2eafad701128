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

from benchmark.scoring.uncertainty import paired, paired_seeds, seeds_for, t975

DELTA = 1.0
STRATA = np.repeat([0, 1, 2], 50)


def coverage(
    n_seeds: int | tuple[int, int],
    sigma_seed: float | tuple[float, float],
    trials: int = 120,
    noise: float = 3.0,
) -> tuple[float, float, float]:
    """(seed-aware coverage, objects-only coverage, mean seed-aware half-width); a pair of
    seed counts or spreads gives models a and b their own."""
    (n_a, n_b), (sigma_a, sigma_b) = np.broadcast_to(n_seeds, 2), np.broadcast_to(sigma_seed, 2)
    rng = np.random.default_rng(n_a * 1000 + n_b * 100 + int(sigma_a * 10 + sigma_b))
    hits_seeds = hits_objects = 0
    widths = []
    for t in range(trials):
        difficulty = rng.normal(0, 10, len(STRATA))
        a = difficulty + DELTA + rng.normal(0, sigma_a, (n_a, 1))
        a = a + rng.normal(0, noise, a.shape)
        b = difficulty + rng.normal(0, sigma_b, (n_b, 1))
        b = b + rng.normal(0, noise, b.shape)
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


@pytest.mark.parametrize("n_seeds", [(30, 17), (4, 12)])
def test_unequal_seed_counts_and_spreads_are_covered(n_seeds):
    """More seeds for the model whose seeds spread most (as the hidden-cpu-v3-seeds table
    gives direct-basic): each model's seed term is s²/S with its own S, and the
    Welch-Satterthwaite degrees of freedom keep a few seeds of the noisy one honest."""
    seeds_cov, objects_cov, _ = coverage(n_seeds, sigma_seed=(4.8, 2.0), trials=200)
    assert 0.92 <= seeds_cov <= 0.99, seeds_cov
    assert objects_cov <= 0.5, objects_cov


def test_per_object_seed_noise_is_counted_once():
    """Per-object noise that differs by seed is in both the object bootstrap and the seed
    spread; counted twice, the interval would cover the truth nearly always."""
    seeds_cov, _, _ = coverage(3, sigma_seed=0.0, noise=30.0, trials=300)
    assert 0.9 <= seeds_cov <= 0.985, seeds_cov  # 0.993 when counted twice


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


def test_seeds_for_plans_the_half_width_a_simulated_benchmark_then_gets():
    sigma = 3.0
    n = seeds_for(0.0, [sigma**2, sigma**2], 3.0)
    assert n is not None and n > 3  # 3 seeds cannot give ±3 dB² with a 3 dB² seed spread
    _, _, width = coverage(n, sigma_seed=sigma, trials=60)
    _, _, fewer = coverage(n // 2, sigma_seed=sigma, trials=60)
    assert 2.4 <= width <= 3.3 and fewer > 3.3, (n, width, fewer)


def test_seeds_for_is_none_when_the_test_objects_alone_are_too_wide():
    assert seeds_for(4.0, [1.0, 1.0], 3.0) is None  # 1.96 * 2 = 3.9 > 3 with no seed variance
    assert seeds_for(0.0, [0.0, 0.0], 3.0) == 2


def test_seeds_for_counts_per_object_seed_noise_as_what_seeds_remove():
    """Per-object noise that differs by seed (no seed offsets, no object-level difference):
    averaging seeds removes it, so the plan is a seed count, not "more test objects". Each
    model's seed means vary by 30² / 150 = 6; 1.96² x 12 / S <= 9 from S = 5.1 on, a
    little more with the t quantile (7 at 14 df). A 12-seed pilot estimates the variances
    well enough."""
    rng = np.random.default_rng(7)
    a, b = (rng.normal(20, 30, (12, len(STRATA))) for _ in range(2))
    assert 6 <= paired_seeds(a, b, STRATA)["seeds_for_3"] <= 10
