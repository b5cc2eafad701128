"""The paper's topology-sensitivity metrics, the floor, a no-skill rule, and the training loss.

All errors are MSE over the whole response (every aspect, roll and range bin) in dB², on the
target T of ``benchmark.scoring.data.db_target``. For one test object with label R, prediction R̂_s
on its simple mesh and R̂_c on its complex meshes c = 1..C:

    simple    = MSE(R, R̂_s)
    complex   = mean_c MSE(R, R̂_c)
    variation = mean_c MSE(R̂_s, R̂_c)

and the reported numbers are the means over test objects (per class: over that class's
objects), each with a 95% interval (``benchmark.scoring.uncertainty``: bootstrap over test objects,
stratified by class). Objects without complex meshes count only towards Simple MSE.

**Out-of-distribution meshes.** Test objects also carry meshes o = 1..K made by remeshers that
never make training variants (``basic_shapes.shards.OOD_REMESHERS``, variants 900-999); with
R̂_o the prediction on each:

    ood_complex   = mean_o MSE(R, R̂_o)
    ood_variation = mean_o MSE(R̂_s, R̂_o)

reported beside the three, overall, per class and per remesher (the same means restricted to
that remesher's meshes, over the objects that have some), with the same intervals. They ask
whether a model that is invariant on Blender's meshes stays invariant on meshes made another
way. Objects without OOD meshes do not count towards them (None when no object has any).

**Peak-relative (secondary).** The paper's metric weighs every bin alike, and most bins of a
range profile lie far below its peak, where physical optics itself is least right (docs/
RESULTS.md, "Physics error budget"). Beside it, over the bins within PEAK_WINDOW_DB (40 dB)
of each target profile's own peak (per aspect and roll):

    peak_simple  = MSE over those bins of (R, R̂_s)
    peak_complex = mean_c MSE over those bins of (R, R̂_c)

The paper's metric stays the ranked one.

**One floor.** Targets are floored at FLOOR_DB (-80 dB); predictions are clipped at the same
floor before scoring. A value below the floor is never closer to a target than the floor
itself (every target is >= the floor), so unclipped predictions were penalized for nothing
and clipping improved every metric for free; scoring the clipped prediction removes that.

**No skill** (replaces the paper's mode-collapse asterisk, which in effect was R² < 0.05 and
was fooled both ways). Let m be the training-set mean response (the cheapest prediction
there is). Per test object o, on its simple mesh, with d = T - m and p = R̂_s - m:

    MSE_o(R̂_s) = A_o + B_o - 2 C_o,   A_o = mean_e d², B_o = mean_e p², C_o = mean_e d·p

A_o is MSE_o of the training mean itself. The gain over the training mean is therefore
G_o = A_o - MSE_o = 2 C_o - B_o: a prediction earns only through C (moving with the truth,
away from the mean) and pays B (every departure from the mean). ``no_skill`` is set when the
95% interval of mean_o G_o (bootstrap over test objects) does not lie above 0: the model does
not beat the training mean by more than the sampling noise. Adding variance cannot game the
rule: noise independent of the truth raises B and leaves C unchanged, so it lowers G. A
constant (any constant; the mean itself gives G = 0 exactly) has C ≈ 0 and B >= 0; the mean
plus per-object noise has G = -B < 0; honest shrinkage m + k(T - m), 0 < k < 1, has
G = (2k - k²) A > 0, and the oracle G = A. The correlation C / sqrt(A B) is reported beside
it (pooled over elements, against the training mean). A model that beats the training mean
only as much as the per-class mean does is not flagged; the ``skill`` block against the
class-mean reference says how much of its skill the class alone explains.

Only ``intensity_weighted_mse`` needs torch, and imports it when called.
"""

from __future__ import annotations

import numpy as np

from basic_shapes.shards import OOD_REMESHERS
from benchmark.scoring.data import FLOOR_DB
from benchmark.scoring.schema import (  # the records' owner declares them
    METRIC_NAMES,
    OOD_METRIC_NAMES,
    PEAK_METRIC_NAMES,
)
from benchmark.scoring.uncertainty import interval

INTENSITY_TAU_DB = 10.0
PEAK_WINDOW_DB = 40.0


def remesher_key(metric: str, remesher: str) -> str:
    """Per-object array name of an OOD metric restricted to one remesher's meshes."""
    return f"{metric}:{remesher}"


def ood_keys() -> tuple[str, ...]:
    """Every OOD per-object array name: the two metrics, then per remesher (slot order)."""
    return OOD_METRIC_NAMES + tuple(
        remesher_key(m, r) for r in OOD_REMESHERS for m in OOD_METRIC_NAMES
    )


def clip_prediction(pred) -> np.ndarray:
    """Predictions at the target's floor: values below FLOOR_DB become FLOOR_DB (float64)."""
    return np.maximum(np.asarray(pred, np.float64), FLOOR_DB)


def mse(a: np.ndarray, b: np.ndarray) -> float:
    """Mean squared difference over all elements, computed in float64."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"shape mismatch {a.shape} vs {b.shape}")
    return float(np.mean((a - b) ** 2))


def object_errors(
    target: np.ndarray, simple: np.ndarray, complex_: np.ndarray
) -> tuple[float, float | None, float | None]:
    """(simple, complex, variation) MSE of one object; ``complex_`` is (C, ...), C may be 0.

    Predictions are clipped at the floor here, the one place every score passes through.
    """
    simple = clip_prediction(simple)
    s = mse(target, simple)
    if len(complex_) == 0:
        return s, None, None
    complex_ = [clip_prediction(c) for c in complex_]
    return (
        s,
        float(np.mean([mse(target, c) for c in complex_])),
        float(np.mean([mse(simple, c) for c in complex_])),
    )


def peak_errors(target: np.ndarray, simple: np.ndarray, complex_: np.ndarray) -> dict:
    """Peak-relative Simple and Complex MSE of one object (module docstring): over the bins
    within PEAK_WINDOW_DB of the peak of each target range profile (last axis)."""
    target = np.asarray(target, np.float64)
    near = target >= target.max(axis=-1, keepdims=True) - PEAK_WINDOW_DB

    def err(pred):
        return float(np.mean((target[near] - clip_prediction(pred)[near]) ** 2))

    return {
        "peak_simple_mse": err(simple),
        "peak_complex_mse": float(np.mean([err(c) for c in complex_])) if len(complex_) else np.nan,
    }


def ood_errors(
    target: np.ndarray, simple: np.ndarray, ood: np.ndarray, remeshers: list[str]
) -> dict[str, float]:
    """OOD Complex and Variation MSE of one object (module docstring), overall and per
    remesher, keyed as ``ood_keys``; NaN where the object has no such mesh."""
    out = dict.fromkeys(ood_keys(), np.nan)
    if len(ood) != len(remeshers):
        raise ValueError(f"{len(ood)} OOD predictions but {len(remeshers)} remesher names")
    if not len(ood):
        return out
    simple = clip_prediction(simple)
    pairs = [(mse(target, c), mse(simple, c)) for c in map(clip_prediction, ood)]
    out["ood_complex_mse"], out["ood_variation_mse"] = np.mean(pairs, axis=0).tolist()
    for r in set(remeshers):
        sel = [p for p, name in zip(pairs, remeshers) if name == r]
        for m, v in zip(OOD_METRIC_NAMES, np.mean(sel, axis=0).tolist()):
            out[remesher_key(m, r)] = v
    return out


class Scorer:
    """Accumulates objects one at a time (bounded memory) and reports the metrics dict.

    ``train_mean`` (the training-set mean target) enables the no-skill rule; without it
    ``no_skill`` is None.
    """

    def __init__(self, class_names: list[str], train_mean: np.ndarray | None = None):
        self.class_names = list(class_names)
        self.train_mean = None if train_mean is None else np.asarray(train_mean, np.float64)
        self.rows: list[tuple] = []  # (class, simple, complex, variation, A, B, C) per object
        self.ood: list[dict] = []  # ``ood_errors`` and ``peak_errors`` per object
        self.ids: list[int] = []
        self.n_meshes = 0

    def add(
        self,
        class_index: int,
        target: np.ndarray,
        simple: np.ndarray,
        complex_: np.ndarray,
        object_id: int | None = None,
        ood: np.ndarray = (),
        ood_remeshers: list[str] = (),
    ) -> None:
        """One test object: its label, the predictions on its simple mesh, its complex meshes
        (C, ...) and its OOD meshes (K, ...), with the remesher of each OOD mesh."""
        errors = object_errors(target, simple, complex_)
        self.ood.append(
            {
                **ood_errors(target, simple, ood, list(ood_remeshers)),
                **peak_errors(target, simple, complex_),
            }
        )
        abc = (np.nan,) * 3
        if self.train_mean is not None:
            d = np.asarray(target, np.float64) - self.train_mean
            p = clip_prediction(simple) - self.train_mean
            abc = (float(np.mean(d * d)), float(np.mean(p * p)), float(np.mean(d * p)))
        self.rows.append((int(class_index), *errors, *abc))
        self.ids.append(len(self.ids) if object_id is None else int(object_id))
        self.n_meshes += 1 + len(complex_) + len(ood)

    def per_object(self) -> dict:
        """Per-object arrays (NaN where an object lacks a metric): what intervals resample."""
        r = np.array([[np.nan if x is None else x for x in row] for row in self.rows], np.float64)
        return {
            "object_id": np.array(self.ids, np.int64),
            "class_index": r[:, 0].astype(np.int64),
            **{name: r[:, k] for k, name in enumerate(METRIC_NAMES, start=1)},
            "truth_spread": r[:, 4],
            "prediction_spread": r[:, 5],
            "co_spread": r[:, 6],
            **{
                k: np.array([o[k] for o in self.ood], np.float64)
                for k in ood_keys() + PEAK_METRIC_NAMES
            },
        }

    def result(self) -> dict:
        if not self.rows:
            raise ValueError("no objects were scored")
        po = self.per_object()
        cls = po["class_index"]
        out = {
            **metric_block(po, cls),
            "n_meshes": self.n_meshes,
            **skill_test(po, cls),
            "per_class": {},
            "per_remesher": per_remesher(po, cls),
        }
        for c, name in enumerate(self.class_names):
            sel = cls == c
            if sel.any():
                out["per_class"][name] = metric_block({k: v[sel] for k, v in po.items()}, cls[sel])
        return out


def _means(po: dict, strata: np.ndarray, names: dict[str, str]) -> dict:
    """``{name: mean of po[key] over objects that have it (None if none has), name_ci}``."""
    out = {}
    for name, key in names.items():
        v = po[key]
        out[name] = None if np.all(np.isnan(v)) else float(np.nanmean(v))
        out[name + "_ci"] = interval(v, strata)
    return out


def metric_block(po: dict, strata: np.ndarray) -> dict:
    """Mean of each metric over the objects that have it (None if none has), with intervals;
    the OOD metrics when ``po`` has them."""
    names = [n for n in METRIC_NAMES + OOD_METRIC_NAMES + PEAK_METRIC_NAMES if n in po]
    return {**_means(po, strata, {n: n for n in names}), "n_objects": int(len(strata))}


def per_remesher(po: dict, strata: np.ndarray) -> dict:
    """OOD metrics per remesher, over the objects that have that remesher's meshes (intervals
    still stratified by class over all objects, so they match the overall ones)."""
    out = {}
    for r in OOD_REMESHERS:
        key = remesher_key(OOD_METRIC_NAMES[0], r)
        if key in po and not np.all(np.isnan(po[key])):
            out[r] = {
                **_means(po, strata, {m: remesher_key(m, r) for m in OOD_METRIC_NAMES}),
                "n_objects": int(np.sum(~np.isnan(po[key]))),
            }
    return out


def skill_test(po: dict, strata: np.ndarray) -> dict:
    """``no_skill`` and its evidence (module docstring): the gain over the training mean,
    its 95% interval, and the spread decomposition A, B, C with the pooled correlation."""
    a, b, c = po["truth_spread"], po["prediction_spread"], po["co_spread"]
    if np.all(np.isnan(a)):
        return {"no_skill": None, "no_skill_test": None}
    gain = a - po["simple_mse"]
    ci = interval(gain, strata)
    A, B, C = float(np.mean(a)), float(np.mean(b)), float(np.mean(c))
    corr = C / np.sqrt(A * B) if A > 0 and B > 0 else 0.0
    return {
        "no_skill": bool(ci is None or ci[0] <= 0),
        "no_skill_test": {
            "gain_vs_train_mean": float(np.mean(gain)),
            "gain_vs_train_mean_ci": ci,
            "truth_spread": A,
            "prediction_spread": B,
            "co_spread": C,
            "correlation": float(corr),
        },
    }


def score_arrays(
    class_index: np.ndarray,
    targets: np.ndarray,
    simple: np.ndarray,
    complex_: np.ndarray,
    class_names: list[str],
    train_mean: np.ndarray | None = None,
    ood: np.ndarray | None = None,
    ood_remeshers: list[str] = (),
) -> dict:
    """Metrics for in-memory arrays: targets/simple (N, ...), complex_ (N, C, ...), ood
    (N, K, ...) with ``ood_remeshers`` the remesher of each of the K OOD meshes."""
    scorer = Scorer(class_names, train_mean)
    for k, (c, t, s, cx) in enumerate(zip(class_index, targets, simple, complex_)):
        scorer.add(
            c,
            t,
            s,
            cx,
            ood=() if ood is None else ood[k],
            ood_remeshers=(() if ood is None else ood_remeshers),
        )
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
