"""Metrics against hand-computed values and independent numpy formulae."""

import math

import numpy as np
import pytest
import torch

from benchmark.data import db_target
from benchmark.metrics import COLLAPSE_RATIO, Scorer, intensity_weighted_mse, mse, object_errors, score_arrays


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
    assert r["per_class"]["cube"] == {"simple_mse": 1.0, "complex_mse": 2.0, "variation_mse": 1.0, "n_objects": 1}
    assert r["per_class"]["cylinder"] == {"simple_mse": 2.0, "complex_mse": 0.0, "variation_mse": 2.0, "n_objects": 1}
    assert (r["n_objects"], r["n_meshes"]) == (2, 5)
    # spread: per element, Var_o(preds) = 0 (both simple predictions are [1, 1]) -> collapsed
    assert r["spread_ratio"] == 0.0 and r["mode_collapse"] is True


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
        assert r["per_class"][name]["complex_mse"] == pytest.approx(per_complex[cls == j].mean(), rel=1e-12)
    ratio = np.var(s, axis=0).mean() / np.var(t, axis=0).mean()
    assert r["spread_ratio"] == pytest.approx(ratio, rel=1e-10)


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


def _shrunk(a: float, n: int = 40, seed: int = 2):
    """Targets, and predictions mean + a (T - mean): their spread ratio is exactly a²."""
    t = np.random.default_rng(seed).normal(-40, 15, (n, 4, 3, 6))
    return t, t.mean(axis=0) + a * (t - t.mean(axis=0))


@pytest.mark.parametrize("a, flagged", [(0.0, True), (0.2, True), (0.25, False), (1.0, False)])
def test_mode_collapse_both_ways(a, flagged):
    t, p = _shrunk(a)
    r = score_arrays(np.zeros(len(t), int), t, p, p[:, None], ["cube"])
    assert r["spread_ratio"] == pytest.approx(a * a, abs=1e-12)
    assert r["mode_collapse"] is flagged
    assert r["variation_mse"] == 0.0  # collapsed or not, identical simple/complex predictions


def test_one_response_for_everything_is_flagged_although_it_varies_over_the_grid():
    t, _ = _shrunk(1.0)
    p = np.broadcast_to(np.linspace(-60, 0, t[0].size).reshape(t.shape[1:]), t.shape)
    r = score_arrays(np.zeros(len(t), int), t, p, p[:, None], ["cube"])
    assert r["spread_ratio"] == 0.0 and r["mode_collapse"] and COLLAPSE_RATIO == 0.05


def test_spread_undefined_for_one_object_or_identical_labels():
    s = Scorer(["cube"])
    s.add(0, np.zeros(3), np.ones(3), np.zeros((0, 3)))
    assert s.result()["spread_ratio"] is None and s.result()["mode_collapse"] is False
    s.add(0, np.zeros(3), np.full(3, 2.0), np.zeros((0, 3)))
    assert s.result()["spread_ratio"] is None


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
    assert pred.grad is not None and torch.all(torch.isfinite(pred.grad)) and pred.grad.abs().sum() > 0
