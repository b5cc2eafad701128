"""Metrics, the floor, the no-skill rule and the intervals, against hand-computed values,
independent numpy formulae and normal theory."""

import math

import numpy as np
import pytest
import torch

from benchmark.scoring.data import FLOOR_DB, db_target
from benchmark.scoring.metrics import (
    Scorer,
    intensity_weighted_mse,
    mse,
    object_errors,
    score_arrays,
)
from benchmark.scoring.uncertainty import interval, paired, resamples, verdict


def test_db_target_hand_values():
    amp = np.array([1.0, 10.0, 0.1j, -0.5, 1e-4, 1e-6, 0.0], np.complex64)
    expected = [0.0, 20.0, -20.0, 20 * math.log10(0.5), -80.0, -80.0, -80.0]
    out = db_target(amp)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, expected, atol=1e-5)


def test_mse_hand_value():
    assert mse([0, 1, 2], [1, 1, 4]) == pytest.approx(5 / 3, abs=1e-15)
    with pytest.raises(ValueError, match="shape mismatch"):
        mse(np.zeros(3), np.zeros(4))


def test_two_objects_by_hand():
    # object A (class 0): simple (1+1)/2 = 1; complex mean(4, 0) = 2; variation mean(1, 1) = 1
    # object B (class 1): simple (0+4)/2 = 2; complex 0;              variation (0+4)/2 = 2
    s = Scorer(["cube", "cylinder"])
    s.add(0, np.array([0.0, 0.0]), np.array([1.0, 1.0]), np.array([[2.0, 2.0], [0.0, 0.0]]))
    s.add(1, np.array([1.0, 3.0]), np.array([1.0, 1.0]), np.array([[1.0, 3.0]]))
    r = s.result()
    assert (r["simple_mse"], r["complex_mse"], r["variation_mse"]) == (1.5, 1.0, 1.5)
    assert r["per_class"]["cube"] == {
        "simple_mse": 1.0,
        "complex_mse": 2.0,
        "variation_mse": 1.0,
        "n_objects": 1,
        "simple_mse_ci": [1.0, 1.0],
        "complex_mse_ci": [2.0, 2.0],
        "variation_mse_ci": [1.0, 1.0],
        **dict.fromkeys(
            ("ood_complex_mse", "ood_complex_mse_ci", "ood_variation_mse", "ood_variation_mse_ci")
        ),
        # every bin is within 40 dB of the peak here: the peak-relative metric is the same
        "peak_simple_mse": 1.0,
        "peak_complex_mse": 2.0,
        "peak_simple_mse_ci": [1.0, 1.0],
        "peak_complex_mse_ci": [2.0, 2.0],
    }
    assert r["ood_complex_mse"] is None and r["per_remesher"] == {}  # no OOD meshes
    assert r["per_class"]["cylinder"]["complex_mse"] == 0.0
    assert r["per_class"]["cube"]["simple_mse_ci"] == [1.0, 1.0]  # one object: nothing to draw
    assert (r["n_objects"], r["n_meshes"]) == (2, 5)
    assert r["no_skill"] is None  # no training mean given: the rule cannot be applied


def test_peak_relative_metric_keeps_bins_within_40_db_of_each_profile_peak():
    """Two profiles of three bins: (0, -30, -50) keeps bins 0 and 1; (-80, -10, -45) keeps
    bins 1 and 2 (peak -10, window down to -50). Errors on the dropped bins must not count."""
    target = np.array([[0.0, -30.0, -50.0], [-80.0, -10.0, -45.0]])
    simple = target + np.array([[1.0, 3.0, 100.0], [100.0, 2.0, 4.0]])
    complex_ = np.stack([target + 2.0, target])
    s = Scorer(["cube"])
    s.add(0, target, simple, complex_)
    r = s.result()
    assert r["peak_simple_mse"] == pytest.approx((1 + 9 + 4 + 16) / 4, abs=1e-12)
    assert r["peak_complex_mse"] == pytest.approx((4 + 0) / 2, abs=1e-12)
    assert r["simple_mse"] > 1000  # the paper's metric counts the dropped bins


def test_random_arrays_against_vectorized_formulae():
    rng = np.random.default_rng(1)
    n, k, shape = 9, 4, (3, 2, 5)
    cls = np.array([0, 1, 2] * 3)
    t = rng.normal(-30, 10, (n, *shape))
    s = t + rng.normal(0, 2, (n, *shape))
    c = s[:, None] + rng.normal(0, 3, (n, k, *shape))
    r = score_arrays(cls, t, s, c, ["a", "b", "c"])
    axes = tuple(range(1, 1 + len(shape)))
    per_simple = ((t - s) ** 2).mean(axis=axes)
    per_complex = ((t[:, None] - c) ** 2).mean(axis=tuple(a + 1 for a in axes)).mean(axis=1)
    per_var = ((s[:, None] - c) ** 2).mean(axis=tuple(a + 1 for a in axes)).mean(axis=1)
    assert r["simple_mse"] == pytest.approx(per_simple.mean(), rel=1e-12)
    assert r["complex_mse"] == pytest.approx(per_complex.mean(), rel=1e-12)
    assert r["variation_mse"] == pytest.approx(per_var.mean(), rel=1e-12)
    for j, name in enumerate("abc"):
        assert r["per_class"][name]["complex_mse"] == pytest.approx(
            per_complex[cls == j].mean(), rel=1e-12
        )
    lo, hi = r["simple_mse_ci"]
    assert lo < r["simple_mse"] < hi


def test_objects_without_complex_meshes_count_only_for_simple():
    assert object_errors(np.zeros(2), np.ones(2), np.zeros((0, 2))) == (1.0, None, None)
    s = Scorer(["cube"])
    s.add(0, np.zeros(2), np.ones(2), np.zeros((0, 2)))
    s.add(0, np.zeros(2), np.zeros(2), np.full((1, 2), 3.0))
    r = s.result()
    assert (r["simple_mse"], r["complex_mse"], r["variation_mse"]) == (0.5, 9.0, 9.0)
    only_simple = Scorer(["cube"])
    only_simple.add(0, np.zeros(2), np.ones(2), np.zeros((0, 2)))
    assert only_simple.result()["complex_mse"] is None


def test_predictions_are_clipped_at_the_targets_floor():
    # target at the floor and above; a prediction below the floor scores as the floor itself
    t = np.array([FLOOR_DB, FLOOR_DB, -20.0])
    below = np.array([-200.0, -81.0, -30.0])
    at = np.array([FLOOR_DB, FLOOR_DB, -30.0])
    assert object_errors(t, below, below[None]) == object_errors(t, at, at[None])
    assert object_errors(t, below, below[None])[0] == pytest.approx(100 / 3, abs=1e-12)
    # variation compares clipped predictions too: two sub-floor values do not differ
    assert object_errors(t, below, at[None])[2] == 0.0


def _probe_world(n: int = 60, seed: int = 2):
    """Train and test responses of 3 classes: class offset + per-object structure, floored."""
    rng = np.random.default_rng(seed)
    shape = (4, 3, 6)
    offsets = rng.normal(0, 8, (3, *shape))

    def draw(k):
        cls = np.arange(k) % 3
        t = -45 + offsets[cls] + rng.normal(0, 10, (k, *shape))
        return cls, np.maximum(t, FLOOR_DB)

    (c_train, train), (c_test, test) = draw(300), draw(n)
    return c_train, train, c_test, test, rng


def _score(cls, t, p, train_mean):
    return score_arrays(cls, t, p, p[:, None], ["a", "b", "c"], train_mean=train_mean)


@pytest.mark.parametrize(
    "probe, flagged",
    [
        ("constant", True),
        ("mean+noise", True),
        ("shrinkage", False),
        ("oracle", False),
        ("class-mean", False),
    ],
)
def test_no_skill_probes(probe, flagged):
    c_train, train, cls, t, rng = _probe_world()
    m = train.mean(axis=0)
    p = {
        "constant": np.broadcast_to(m, t.shape),
        "mean+noise": m + rng.normal(0, 10, t.shape),
        "shrinkage": m + 0.2 * (t - m),
        "oracle": t,
        "class-mean": np.stack([train[c_train == c].mean(axis=0) for c in cls]),
    }[probe]
    r = _score(cls, t, p, m)
    assert r["no_skill"] is flagged
    # the decomposition is exact: MSE = A + B - 2C, gain = A - MSE (independent numpy formulae)
    d, q = t - m, np.maximum(p, FLOOR_DB) - m
    ax = (1, 2, 3)
    a, b, c = (d * d).mean(ax), (q * q).mean(ax), (d * q).mean(ax)
    test = r["no_skill_test"]
    assert test["gain_vs_train_mean"] == pytest.approx((2 * c - b).mean(), rel=1e-9, abs=1e-9)
    assert r["simple_mse"] == pytest.approx((a + b - 2 * c).mean(), rel=1e-9)


def test_adding_variance_cannot_buy_skill():
    c_train, train, cls, t, rng = _probe_world()
    m = train.mean(axis=0)
    honest = m + 0.5 * (t - m)
    gains = []
    for sd in (0.0, 3.0, 10.0, 30.0):
        r = _score(cls, t, honest + rng.normal(0, sd, t.shape), m)
        gains.append(r["no_skill_test"]["gain_vs_train_mean"])
    assert gains == sorted(gains, reverse=True)  # every extra spread costs
    assert r["no_skill"] is True  # drowned in noise: flagged although it "varies" a lot


def test_constant_is_flagged_even_if_it_varies_over_the_grid():
    _, train, cls, t, _ = _probe_world()
    p = np.broadcast_to(np.linspace(-60, 0, t[0].size).reshape(t.shape[1:]), t.shape)
    r = _score(cls, t, p, train.mean(axis=0))
    assert r["no_skill"] is True and r["variation_mse"] == 0.0


def test_bootstrap_interval_matches_normal_theory():
    rng = np.random.default_rng(5)
    v = rng.gamma(2.0, 3.0, 600)  # skewed, like per-object MSEs
    strata = np.zeros(len(v), int)
    lo, hi = interval(v, strata)
    half = 1.96 * v.std(ddof=1) / np.sqrt(len(v))
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.1)
    assert lo < v.mean() < hi
    assert interval(v, strata) == [lo, hi]  # deterministic


def test_resamples_are_stratified_by_class():
    strata = np.array([0] * 5 + [1] * 3 + [2] * 1 + [3] * 1)
    idx = resamples(strata, n_boot=200)
    assert np.array_equal(strata[idx[:, :8]], np.broadcast_to(strata[:8], (200, 8)))
    # classes of one object are resampled together, so their interval is not zero-width
    assert set(idx[:, 8:].ravel()) == {8, 9}
    assert interval([1.0, 3.0], [0, 1])[1] > interval([1.0, 3.0], [0, 1])[0]


def test_paired_interval_removes_shared_spread_and_verdicts():
    rng = np.random.default_rng(6)
    base = rng.gamma(2.0, 20.0, 200)  # objects differ a lot ...
    strata = np.arange(200) % 4
    better = base - 1.0 + rng.normal(0, 0.5, 200)  # ... the models by ~1 on each
    p = paired(better, base, strata)
    assert p["ci"][1] < 0 and p["half_width"] < 0.2
    assert p["diff"] == pytest.approx((better - base).mean(), rel=1e-12)
    assert interval(better, strata)[1] > interval(base, strata)[0]  # unpaired: overlap
    assert verdict(p["ci"]) == "holds" and verdict([0.5, 2.0]) == "reversed"
    assert verdict([-1.0, 0.5]) == "inconclusive" and verdict(None) == "inconclusive"
    assert verdict([0.5, 2.0], claimed="higher") == "holds"


def test_empty_scorer_refuses():
    with pytest.raises(ValueError, match="no objects"):
        Scorer(["cube"]).result()


def test_intensity_weighted_mse_by_hand():
    # tau = 1, T = [0, ln 3]: softmax = [1/4, 3/4]; errors [2, 0] -> weighted 4/4 = 1, plain 4/2 = 2
    t = torch.tensor([[0.0, math.log(3.0)]], dtype=torch.float64)
    loss = intensity_weighted_mse(t + torch.tensor([[2.0, 0.0]], dtype=torch.float64), t, tau=1.0)
    assert loss.item() == pytest.approx(3.0, abs=1e-12)


def test_intensity_weighted_mse_against_numpy_and_has_gradients():
    rng = np.random.default_rng(3)
    t = rng.normal(-40, 20, (2, 3, 4, 7))
    p = t + rng.normal(0, 5, t.shape)
    w = np.exp(t / 10.0 - (t / 10.0).max(axis=-1, keepdims=True))
    w /= w.sum(axis=-1, keepdims=True)
    expected = (w * (p - t) ** 2).sum() / (2 * 3 * 4) + ((p - t) ** 2).mean()
    pred = torch.tensor(p, requires_grad=True)
    loss = intensity_weighted_mse(pred, torch.tensor(t))
    assert loss.item() == pytest.approx(expected, rel=1e-12)
    loss.backward()
    assert (
        pred.grad is not None and torch.all(torch.isfinite(pred.grad)) and pred.grad.abs().sum() > 0
    )


def test_reproduce_rows_average_ood_errors_per_remesher_and_render_them():
    """table_rows averages the OOD per-object errors over seeds (overall and per remesher,
    intervals of the seed-mean) and render_markdown shows the columns and the sub-table."""
    from benchmark.reproduction.report import remesher_table, render_markdown, table_rows
    from benchmark.scoring.metrics import ood_keys

    rng = np.random.default_rng(5)
    n, cls = 12, np.arange(12) % 3
    runs = {}
    for seed in (0, 1):
        errs = {
            m: rng.gamma(2.0, 10.0, n)
            for m in ("simple_mse", "complex_mse", "variation_mse", *ood_keys())
        }
        errs["ood_complex_mse:delaunay"][:] = np.nan  # a remesher without meshes
        metrics = {m: float(np.nanmean(v)) for m, v in errs.items() if ":" not in m}
        metrics.update(no_skill=False, per_class={"a": {}, "b": {}, "c": {}})
        runs[seed] = {
            "train_seconds": 1.0,
            "results": {
                "metrics": metrics,
                "model": {"params": 5},
                "speed": {"ms_per_mesh": 1.0},
                "per_object": {
                    "object_id": list(range(n)),
                    "class_index": cls.tolist(),
                    **{
                        m: [None if np.isnan(x) else x for x in v.tolist()] for m, v in errs.items()
                    },
                },
            },
        }
    (row,) = table_rows({"graph-basic": runs})
    po = [runs[s]["results"]["per_object"] for s in (0, 1)]
    mean = (np.array(po[0]["ood_complex_mse"]) + po[1]["ood_complex_mse"]) / 2
    assert row["ood_complex_mse"] == pytest.approx(mean.mean(), rel=1e-12)
    assert row["ood_complex_mse_ci"] == interval(mean, cls)
    qem = (np.array(po[0]["ood_variation_mse:qem"]) + po[1]["ood_variation_mse:qem"]) / 2
    assert row["per_remesher"]["qem"]["ood_variation_mse"] == pytest.approx(qem.mean())
    assert set(row["per_remesher"]) == {"isotropic", "qem"}
    assert row["per_class"]["b"]["ood_complex_mse"] == pytest.approx(mean[cls == 1].mean())
    sub = remesher_table([row], {})
    assert sub[-1].startswith("| graph | none | simple |") and "qem Variation" in sub[-3]
    assert sub[-1].count("|") == 3 + 4 + 1  # embedding, pretraining, training meshes; 2 x 2
    table = {
        "preset": "t",
        "command": "c",
        "dataset": {"description": "d", "fingerprint": "f"},
        "hardware": "h",
        "seeds": [0, 1],
        "references": {},
        "rows": [row],
        "findings": [],
        "timing": {
            "total_s": 60,
            "rows_trained": 2,
            "rows_reused": 0,
            "rows_s": 1,
            "jobs": 1,
            "threads_per_job": 1,
        },
    }
    md = render_markdown(table)
    assert "| OOD Complex | OOD Variation |" in md
    assert f"{row['ood_complex_mse']:.1f} ± " in md
