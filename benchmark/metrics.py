"""The paper's topology-sensitivity metrics, a mode-collapse detector, and the training loss.

All errors are MSE over the whole response (every aspect, roll and range bin) in dB², on the
target T of ``benchmark.data.db_target``. For one test object with label R, prediction R̂_s
on its simple mesh and R̂_c on its complex meshes c = 1..C:

    simple    = MSE(R, R̂_s)
    complex   = mean_c MSE(R, R̂_c)
    variation = mean_c MSE(R̂_s, R̂_c)

and the reported numbers are the means over test objects (per class: over that class's
objects). Objects without complex meshes count only towards Simple MSE.

Mode collapse (the paper's asterisk): a model that predicts (nearly) one response for every
object gets a low Variation MSE for the wrong reason. The spread ratio

    rho = mean_e Var_o(R̂_s[o, e]) / mean_e Var_o(R[o, e])

compares how much the simple-mesh predictions vary across test objects o, per response
element e (aspect, roll, range bin), with how much the labels do. ``mode_collapse`` is
``rho < COLLAPSE_RATIO`` (predictions spread less than 5% of the labels' variance, i.e. a
standard deviation under about 22% of theirs). rho is None, and nothing is flagged, with
fewer than two test objects or identical labels.

Only ``intensity_weighted_mse`` needs torch, and imports it when called.
"""

from __future__ import annotations

import numpy as np

COLLAPSE_RATIO = 0.05
INTENSITY_TAU_DB = 10.0
METRIC_NAMES = ("simple_mse", "complex_mse", "variation_mse")


def mse(a: np.ndarray, b: np.ndarray) -> float:
    """Mean squared difference over all elements, computed in float64."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"shape mismatch {a.shape} vs {b.shape}")
    return float(np.mean((a - b) ** 2))


def object_errors(target: np.ndarray, simple: np.ndarray,
                  complex_: np.ndarray) -> tuple[float, float | None, float | None]:
    """(simple, complex, variation) MSE of one object; ``complex_`` is (C, ...), C may be 0."""
    s = mse(target, simple)
    if len(complex_) == 0:
        return s, None, None
    return (s, float(np.mean([mse(target, c) for c in complex_])),
            float(np.mean([mse(simple, c) for c in complex_])))


class _Spread:
    """Per-element variance across samples, accumulated with shifted sums (exact for constants)."""

    def __init__(self):
        self.n, self.shift, self.s1, self.s2 = 0, None, 0.0, 0.0

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x, np.float64)
        if self.shift is None:
            self.shift = x.copy()
        d = x - self.shift
        self.n, self.s1, self.s2 = self.n + 1, self.s1 + d, self.s2 + d * d

    def mean_variance(self) -> float:
        """Mean over elements of the population variance across samples."""
        m = self.s1 / self.n
        return float(np.mean(np.maximum(self.s2 / self.n - m * m, 0.0)))


class Scorer:
    """Accumulates objects one at a time (bounded memory) and reports the metrics dict."""

    def __init__(self, class_names: list[str], collapse_ratio: float = COLLAPSE_RATIO):
        self.class_names, self.collapse_ratio = list(class_names), collapse_ratio
        self.rows: list[tuple[int, float, float | None, float | None]] = []
        self.n_meshes = 0
        self._targets, self._preds = _Spread(), _Spread()

    def add(self, class_index: int, target: np.ndarray, simple: np.ndarray,
            complex_: np.ndarray) -> None:
        self.rows.append((int(class_index), *object_errors(target, simple, complex_)))
        self.n_meshes += 1 + len(complex_)
        self._targets.add(target)
        self._preds.add(simple)

    def spread_ratio(self) -> float | None:
        if self._targets.n < 2:
            return None
        t = self._targets.mean_variance()
        return None if t == 0 else self._preds.mean_variance() / t

    def result(self) -> dict:
        if not self.rows:
            raise ValueError("no objects were scored")
        rho = self.spread_ratio()
        out = {**_means(self.rows), "mode_collapse": bool(rho is not None and rho < self.collapse_ratio),
               "spread_ratio": rho, "n_objects": len(self.rows), "n_meshes": self.n_meshes,
               "per_class": {}}
        for c, name in enumerate(self.class_names):
            rows = [r for r in self.rows if r[0] == c]
            if rows:
                out["per_class"][name] = {**_means(rows), "n_objects": len(rows)}
        return out


def _means(rows: list[tuple]) -> dict:
    """Mean of each metric over the objects that have it (None if none has)."""
    out = {}
    for k, name in enumerate(METRIC_NAMES, start=1):
        vals = [r[k] for r in rows if r[k] is not None]
        out[name] = float(np.mean(vals)) if vals else None
    return out


def score_arrays(class_index: np.ndarray, targets: np.ndarray, simple: np.ndarray,
                 complex_: np.ndarray, class_names: list[str]) -> dict:
    """Metrics for in-memory arrays: targets/simple (N, ...), complex_ (N, C, ...)."""
    scorer = Scorer(class_names)
    for c, t, s, cx in zip(class_index, targets, simple, complex_):
        scorer.add(c, t, s, cx)
    return scorer.result()


def intensity_weighted_mse(pred_db, target_db, tau: float = INTENSITY_TAU_DB):
    """Training loss: sum softmax(T/tau over range bins) (T̂-T)² / N + plain MSE (torch).

    Tensors (..., n_range) in dB; N is the number of range profiles, so the first term is
    the mean over profiles of an intensity-weighted average, emphasising the strong bins
    that plain MSE on a -80 dB floor underweights.
    """
    import torch

    sq = (pred_db - target_db) ** 2
    weights = torch.softmax(target_db / tau, dim=-1)
    n_profiles = sq.numel() // sq.shape[-1]
    return (weights * sq).sum() / n_profiles + sq.mean()
