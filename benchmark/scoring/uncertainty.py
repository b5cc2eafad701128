"""95% intervals by bootstrap over test objects, stratified by class, and paired verdicts.

Why objects and not meshes or response elements: the test objects are the random sample
(the meshes of one object and the elements of one response are strongly correlated), so an
interval says how much a number would move on another draw of test objects of the same
classes. Resampling within each class keeps the class mix of the test split fixed, as the
generator fixes it. The resampling is deterministic (``SEED``), so the same per-object
errors give the same interval bytes.

Intervals are percentile intervals of the statistic over ``N_BOOT`` resamples. A paired
comparison resamples the *difference* of two models' errors on the same objects, which
removes the object-to-object spread both share (``paired``); its verdict is ``holds`` only
when the whole interval lies on the claimed side of zero (``verdict``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

N_BOOT = 2000
SEED = 20240601
LEVEL = 0.95


def resamples(strata: np.ndarray, n_boot: int = N_BOOT, seed: int = SEED) -> np.ndarray:
    """(n_boot, n) object indices: each row draws, within every class, as many objects as
    the class has, with replacement. Classes of a single test object are resampled together
    as one stratum: alone, such an object would always be drawn and the interval would
    pretend it is known without sampling error."""
    strata = np.asarray(strata)
    rng = np.random.default_rng(seed)
    out = np.empty((n_boot, len(strata)), np.int64)
    labels, counts = np.unique(strata, return_counts=True)
    groups = [np.flatnonzero(strata == s) for s, c in zip(labels, counts) if c > 1]
    single = np.flatnonzero(np.isin(strata, labels[counts == 1]))
    if len(single):
        groups.append(single)
    for members in groups:
        out[:, members] = members[rng.integers(0, len(members), (n_boot, len(members)))]
    return out


def _nanmean_rows(values: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Mean of ``values[idx]`` per resample, ignoring NaN (objects without the metric)."""
    v = values[idx]
    ok = ~np.isnan(v)
    n = ok.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.where(ok, v, 0.0).sum(axis=1) / n, np.nan)


def interval(
    values, strata, statistic: Callable | None = None, n_boot: int = N_BOOT, seed: int = SEED
) -> list[float] | None:
    """[lo, hi] 95% percentile interval of the mean of ``values`` (NaN = missing), or of
    ``statistic(idx) -> (n_boot,)`` when given; None when nothing can be resampled."""
    strata = np.asarray(strata)
    if len(strata) == 0:
        return None
    idx = resamples(strata, n_boot, seed)
    if statistic is None:
        values = np.asarray(values, np.float64)
        if np.all(np.isnan(values)):
            return None
        stats = _nanmean_rows(values, idx)
    else:
        stats = np.asarray(statistic(idx), np.float64)
    stats = stats[np.isfinite(stats)]
    if not len(stats):
        return None
    tail = 100 * (1 - LEVEL) / 2
    lo, hi = np.percentile(stats, [tail, 100 - tail])
    return [float(lo), float(hi)]


def paired(a, b, strata, n_boot: int = N_BOOT, seed: int = SEED) -> dict | None:
    """Mean of a - b over objects that have both, its paired 95% interval and half-width."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    d = a - b
    if np.all(np.isnan(d)):
        return None
    ci = interval(d, strata, n_boot=n_boot, seed=seed)
    return {"diff": float(np.nanmean(d)), "ci": ci, "half_width": (ci[1] - ci[0]) / 2}


# Student-t 0.975 quantiles, df 1..30 (then the normal 1.96): a 95% interval from few seeds
T975 = (
    12.706,
    4.303,
    3.182,
    2.776,
    2.571,
    2.447,
    2.365,
    2.306,
    2.262,
    2.228,
    2.201,
    2.179,
    2.160,
    2.145,
    2.131,
    2.120,
    2.110,
    2.101,
    2.093,
    2.086,
    2.080,
    2.074,
    2.069,
    2.064,
    2.060,
    2.056,
    2.052,
    2.048,
    2.045,
    2.042,
)


def t975(df: float) -> float:
    """The t distribution's 0.975 quantile, linear in 1/df between tabulated degrees."""
    if not np.isfinite(df) or df > 30:
        return 1.96
    df = max(df, 1.0)
    lo = int(np.floor(df))
    if lo == df or lo >= 30:
        return T975[min(lo, 30) - 1]
    w = (1 / lo - 1 / df) / (1 / lo - 1 / (lo + 1))
    return T975[lo - 1] + w * (T975[lo] - T975[lo - 1])


def paired_seeds(a, b, strata, n_boot: int = N_BOOT, seed: int = SEED) -> dict | None:
    """``paired`` with training-seed variance. ``a`` (S_a, n) and ``b`` (S_b, n) hold each
    training seed's per-object errors on the same test objects. The difference of the two
    seed-mean errors has two sources of variance: which test objects were drawn (the paired
    bootstrap over objects, stratified, of the seed-averaged difference) and which seeds were
    trained (each model's spread of per-seed mean errors, s²/S). Per-object seed noise
    (``_interaction``) is in both and is taken out of the first. The 95% interval is
    diff ± t·sqrt(V_objects + s_a²/S_a + s_b²/S_b), with Welch-Satterthwaite degrees of
    freedom from the seed terms: with 3 seeds a model's seed spread is known poorly, and
    the interval says so. A bootstrap over 3 seeds instead covered a known difference 76%
    of the time; this interval 95-98%, with unequal seed counts and spreads too
    (tests/test_uncertainty.py). With one seed per model the seed terms are unknown: the
    result is ``paired``'s, and ``seeds`` says so."""
    a, b = np.atleast_2d(np.asarray(a, np.float64)), np.atleast_2d(np.asarray(b, np.float64))
    d = np.nanmean(a, axis=0) - np.nanmean(b, axis=0)
    if np.all(np.isnan(d)):
        return None
    obj = paired(np.nanmean(a, axis=0), np.nanmean(b, axis=0), strata, n_boot, seed)
    seeds = [len(a), len(b)]
    if min(seeds) < 2 or obj["ci"] is None:
        return {**obj, "seeds": seeds}
    idx = resamples(np.asarray(strata), n_boot, seed)
    v_obj = float(np.nanvar(_nanmean_rows(d, idx), ddof=1))
    spread = [float(np.var(np.nanmean(x, axis=1), ddof=1)) for x in (a, b)]
    # each object's seed noise is in the seed spread and in v_obj both: count it once
    n = int(np.sum(~np.isnan(d)))
    v_fixed = max(v_obj - sum(_interaction(x) / (len(x) * n) for x in (a, b)), 0.0)
    half, df = _half_width(v_fixed, [v / s for v, s in zip(spread, seeds)], seeds)
    diff = float(np.nanmean(d))
    return {
        "diff": diff,
        "ci": [diff - half, diff + half],
        "half_width": float(half),
        "seeds": seeds,
        "df": float(df),
        "seeds_for_3": seeds_for(v_fixed, spread, TARGET_HALF_WIDTH),
    }


TARGET_HALF_WIDTH = 3.0  # dB²: the paired half-width a finding should reach (seeds_for_3)
MAX_SEEDS = 1000


def _half_width(v_obj: float, terms: list[float], seeds: list[int]) -> tuple[float, float]:
    """(half-width, Welch-Satterthwaite df) of ``paired_seeds``' interval from the object
    variance and each model's seed term s²/S."""
    v = v_obj + sum(terms)
    df = v**2 / sum(t**2 / (s - 1) for t, s in zip(terms, seeds)) if sum(terms) else np.inf
    return float(t975(df) * np.sqrt(v)), float(df)


def _interaction(x: np.ndarray) -> float:
    """Seed-by-object variance of (S, n) errors: what is left of each error after its seed's
    mean and its object's mean (two-way ANOVA residual), i.e. per-object seed noise."""
    r = x - np.nanmean(x, axis=1, keepdims=True) - np.nanmean(x, axis=0) + np.nanmean(x)
    n = np.sum(~np.isnan(x).all(axis=0))
    return float(np.nansum(r**2) / ((len(x) - 1) * max(n - 1, 1)))


def seeds_for(v_fixed: float, spread: list[float], target: float) -> int | None:
    """Training seeds per model at which ``paired_seeds``' half-width would reach ``target``
    if the variances stayed as estimated: the planning figure for a claim's precision.
    ``v_fixed``: the test objects' variance that no seed count removes; ``spread``: each
    model's variance of per-seed mean errors. None when ``v_fixed`` alone is wider than the
    target (more test objects would help, more seeds cannot) or it needs over
    ``MAX_SEEDS``."""
    if t975(np.inf) * np.sqrt(v_fixed) > target:
        return None
    for s in range(2, MAX_SEEDS + 1):
        if _half_width(v_fixed, [x / s for x in spread], [s, s])[0] <= target:
            return s
    return None


def verdict(ci: list[float] | None, claimed: str = "lower") -> str:
    """ "holds" when the interval of (claimed better - other) excludes 0 on the claimed side
    (``lower``: a difference of errors below 0), "reversed" when it excludes 0 on the other
    side, else "inconclusive"."""
    if ci is None:
        return "inconclusive"
    below, above = ci[1] < 0, ci[0] > 0
    if claimed == "higher":
        below, above = above, below
    return "holds" if below else "reversed" if above else "inconclusive"
