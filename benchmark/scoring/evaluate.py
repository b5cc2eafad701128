"""Evaluate a model or a predictions file on the test split and build the results record.

Both paths meet in one place: a model's predictions are first written to a predictions file
(float32, the same bytes a third party would submit) and that file is then scored, so a model
and its predictions file give identical metrics.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from basic_shapes.infra import hardware
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.metrics import METRIC_NAMES, OOD_METRIC_NAMES
from benchmark.scoring.protocol import (
    Model,
    ModelError,
    Predictions,
    PredictionsError,
    PredictionsWriter,
    check_prediction,
    make_results,
    score,
    scored_mesh_rows,
    why,
)

MODEL_FIELDS = ("name", "params", "embedding", "regime")


def speed_block(
    ms_per_mesh: float | None, threads: int | None = None, self_reported: bool = False
) -> dict:
    """Results ``speed``: ms per mesh and how it was measured; a speed given by a submitter
    (``self_reported``) carries no machine description, since none was measured."""
    if ms_per_mesh is None:
        return {"ms_per_mesh": None, "hardware": None, "self_reported": False}
    if self_reported:
        return {"ms_per_mesh": float(ms_per_mesh), "hardware": None, "self_reported": True}
    hw = hardware(threads)
    return {
        "ms_per_mesh": float(ms_per_mesh),
        "hardware": hw["text"],
        "cpu": hw["cpu"],
        "threads": hw["threads"],
        "load_avg_1m": hw["load_avg_1m"],
        "gpu": hw["gpu"],
        "self_reported": False,
    }


def face_count_batches(data: BenchmarkData, rows: np.ndarray, batch_size: int) -> list:
    """``rows`` in blocks of similar face count (stable order). A batch is padded to its
    largest mesh: in the test split's stored order that padding is 2.5x the faces and 3.8x
    the attention work of the meshes themselves (cpu-v1), in face-count order 1.01x."""
    order = rows[np.argsort(np.asarray(data.meshes["n_faces"])[rows], kind="stable")]
    return [order[s : s + batch_size] for s in range(0, len(order), batch_size)]


def predict_test_split(
    model: Model,
    data: BenchmarkData,
    path: str | os.PathLike,
    batch_size: int = 16,
    who: str = "model",
    progress: bool = True,
) -> float:
    """Run ``model.predict`` over every test mesh (the OOD meshes included), write a
    predictions file; return ms per mesh.

    The time counted is the wall time inside ``predict`` only (not reading meshes). Meshes
    go in batches of similar face count, so the file's rows are in that order (scoring reads
    them by mesh uid).
    """
    rows = scored_mesh_rows(data)  # refuses a dataset without a test split
    elapsed = 0.0
    with PredictionsWriter(
        path,
        data.fingerprint,
        len(rows),
        data.target_shape,
        label_fingerprint=data.label_fingerprint,
    ) as writer:
        with tqdm(total=len(rows), desc="predict", unit="mesh", disable=not progress) as bar:
            for chunk in face_count_batches(data, rows, batch_size):
                batch = data.batch(chunk)
                t0 = time.perf_counter()
                try:
                    out = model.predict(batch)
                except (Exception, SystemExit) as exc:  # sys.exit(0) in a model is no success
                    raise ModelError(f"{who}: predict failed: {why(exc)}") from exc
                elapsed += time.perf_counter() - t0
                writer.write(
                    data.meshes["uid"][chunk],
                    check_prediction(out, len(chunk), data.target_shape, who),
                )
                bar.update(len(chunk))
    return 1000.0 * elapsed / max(len(rows), 1)


def model_info(model: Model | None, overrides: dict) -> dict:
    """Results ``model`` block: the model's own attributes, overridden by non-None values."""
    info = {k: getattr(model, k, None) for k in MODEL_FIELDS}
    if info["name"] is None and model is not None:
        info["name"] = type(model).__name__
    info.update({k: v for k, v in overrides.items() if v is not None})
    return info


def evaluate(
    data_dir: str | os.PathLike,
    *,
    model: Model | None = None,
    predictions: str | os.PathLike | None = None,
    write_predictions: str | os.PathLike | None = None,
    overrides: dict | None = None,
    train_seed: int | None = None,
    batch_size: int = 16,
    progress: bool = True,
    scratch_dir: str | os.PathLike | None = None,
    speed_ms: float | None = None,
) -> dict:
    """Results record for exactly one of ``model`` or ``predictions``.

    A model's predictions go to ``write_predictions`` if given, else to a temporary file in
    ``scratch_dir`` (default: the system's), deleted afterwards. ``speed_ms`` is a
    submitter's own ms per mesh for a predictions file, recorded as self-reported.
    """
    if (model is None) == (predictions is None):
        raise ValueError("give exactly one of a model or a predictions file")
    if speed_ms is not None and (model is not None or not speed_ms >= 0):
        raise ValueError("a self-reported speed goes with a predictions file and is >= 0")
    overrides = dict(overrides or {})
    with BenchmarkData(data_dir) as data:
        speed = (
            speed_block(speed_ms, self_reported=True) if speed_ms is not None else speed_block(None)
        )
        if model is not None:
            with contextlib.ExitStack() as stack:
                path = (
                    Path(write_predictions)
                    if write_predictions
                    else Path(stack.enter_context(tempfile.TemporaryDirectory(dir=scratch_dir)))
                    / "predictions.h5"
                )
                who = str(
                    overrides.get("name") or getattr(model, "name", None) or type(model).__name__
                )
                ms = predict_test_split(model, data, path, batch_size, who, progress)
                speed = speed_block(ms)
                try:
                    with Predictions(path, data) as preds:
                        metrics = score(data, preds, per_object=True)
                except PredictionsError as exc:  # name the model, not a scratch file
                    if write_predictions:
                        raise
                    named = str(exc).replace(str(path), f"{who}'s predict output")
                    raise PredictionsError(named) from None
        else:
            overrides["name"] = overrides.get("name") or Path(predictions).stem
            with Predictions(predictions, data) as preds:
                metrics = score(data, preds, per_object=True)
        dataset_seed = data.config.get("seed")
        seeds = {
            "dataset": dataset_seed if isinstance(dataset_seed, int) else None,
            "train": train_seed,
        }
        per_object = metrics.pop("per_object")
        results = make_results(
            data.fingerprint,
            metrics,
            model_info(model, overrides),
            speed,
            seeds,
            label_fingerprint=data.label_fingerprint,
        )
        results["per_object"] = per_object
        return results


def _ci(x, ci) -> str:
    if x is None:
        return "-"
    return f"{x:.2f}" + (f" [{ci[0]:.2f}, {ci[1]:.2f}]" if ci else "")


VERDICT_WORDS = {"holds": "better", "reversed": "worse", "inconclusive": "not distinguishable"}


def format_metrics(results: dict) -> str:
    """A plain-text table: the model and the reference rows with 95% intervals, per class,
    its skill against the strongest reference, and its speed."""
    m = results["metrics"]
    keys = METRIC_NAMES + OOD_METRIC_NAMES
    head = (
        f"{'':20} "
        + " ".join(
            f"{t:>24}" for t in ("simple", "complex", "variation", "OOD complex", "OOD variation")
        )
        + f" {'objects':>7}"
    )

    def line(label, block):
        return (
            f"{label:20} "
            + " ".join(f"{_ci(block.get(k), block.get(k + '_ci')):>24}" for k in keys)
            + f" {block['n_objects']:>7}"
        )

    lines = [head, line(str(results["model"]["name"])[:20], m)]
    lines += [line(f"  {c}"[:20], b) for c, b in m["per_class"].items()]
    lines += [line(f"  OOD {r}"[:20], b) for r, b in m.get("per_remesher", {}).items()]
    for name, block in m.get("references", {}).items():
        lines.append(line(f"ref {name}"[:20], block))
    sk = m.get("skill")
    if sk:
        for k, v in sk["vs_reference"].items():
            lines.append(
                f"vs strongest reference ({sk['reference']}), {k}: {v['diff']:+.2f} "
                f"[{v['ci'][0]:+.2f}, {v['ci'][1]:+.2f}] dB², skill {v['skill']:.3f}: "
                f"{VERDICT_WORDS[v['verdict']]}"
            )
        if sk["explained_by_class"] and not m.get("no_skill"):
            lines.append("no better than the per-class mean: its skill is explained by the class")
    t = m.get("no_skill_test")
    if t:
        gain = _ci(t["gain_vs_train_mean"], t["gain_vs_train_mean_ci"])
        lines.append(
            f"gain over the training mean {gain} dB², correlation "
            f"{t['correlation']:.3f}; no skill: "
            f"{'YES' if m['no_skill'] else 'no'}"
        )
    sp = results["speed"]
    if sp["ms_per_mesh"] is not None:
        where = "self-reported" if sp.get("self_reported") else f"on {sp['hardware']}"
        lines.append(f"speed {sp['ms_per_mesh']:.3f} ms/mesh {where}")
    return "\n".join(lines)


class Evaluator:
    """OGB-style evaluator of one labelled dataset: a dict of arrays in, a dict of metrics out.

    ``Evaluator(root).eval({"mesh_uid": uids, "target_db": preds})`` scores predictions held in
    memory through exactly the path of ``benchmark evaluate --predictions`` (the arrays are
    written to a temporary predictions file, validated and scored), so the numbers are the
    harness's: Simple/Complex/Variation MSE with 95% intervals, per class, the reference rows,
    skill and the no-skill flag. ``expected_input_format`` says what to pass.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        with BenchmarkData(self.root) as data:
            self.fingerprint = data.fingerprint
            self.target_shape = data.target_shape
            self.test_mesh_uid = data.meshes["uid"][scored_mesh_rows(data)]

    @property
    def expected_input_format(self) -> str:
        return (
            f"==== Expected input format of Evaluator({str(self.root)!r})\n"
            f"{{'mesh_uid': mesh_uid, 'target_db': target_db}}\n"
            f"- mesh_uid: int64 array (M,), every test-split mesh exactly once, any order "
            f"(M = {len(self.test_mesh_uid)}; BasicShapes(root, split='test', "
            f"variants='all') yields every one, out-of-distribution meshes included, as "
            f"item['mesh_uid']; Evaluator.test_mesh_uid holds them all)\n"
            f"- target_db: real array (M, {', '.join(map(str, self.target_shape))}): the "
            f"predicted dB response of each mesh (aspect, roll, range bin), row i for "
            f"mesh_uid[i]; values below -80 dB are scored as -80 dB\n"
            f"numpy arrays or torch tensors (moved to the CPU)"
        )

    @property
    def expected_output_format(self) -> str:
        return (
            "==== Expected output format\n"
            "{'simple_mse', 'complex_mse', 'variation_mse' (dB², None without complex "
            "meshes), 'ood_complex_mse', 'ood_variation_mse' (None without OOD meshes), "
            "each with '<name>_ci' [lo, hi] (95%, bootstrap over test objects), "
            "'n_objects', 'n_meshes', 'per_class', 'per_remesher', 'no_skill', "
            "'no_skill_test', "
            "'references', 'skill'} (docs/BENCHMARK.md, \"Results JSON\")"
        )

    def eval(self, input_dict: dict) -> dict:
        from benchmark.scoring.protocol import write_predictions

        missing = {"mesh_uid", "target_db"} - set(input_dict)
        if missing:
            raise PredictionsError(
                f"Evaluator: input lacks {', '.join(sorted(missing))}; see expected_input_format"
            )
        arrays = {}
        for k in ("mesh_uid", "target_db"):
            v = input_dict[k]
            v = v.detach().cpu().numpy() if hasattr(v, "detach") else np.asarray(v)
            arrays[k] = v
        if arrays["mesh_uid"].dtype.kind not in "iu" or arrays["target_db"].dtype.kind not in "fiu":
            raise PredictionsError(
                "Evaluator: mesh_uid must be integers and target_db real numbers"
            )
        with tempfile.TemporaryDirectory() as tmp, BenchmarkData(self.root) as data:
            path = Path(tmp) / "predictions.h5"
            try:
                write_predictions(
                    path,
                    self.fingerprint,
                    arrays["mesh_uid"].astype(np.int64),
                    arrays["target_db"].astype(np.float32),
                    label_fingerprint=data.label_fingerprint,
                )
                with Predictions(path, data) as preds:
                    return score(data, preds)
            except PredictionsError as exc:  # name the caller's input, not our scratch file
                raise PredictionsError(str(exc).replace(str(path), "Evaluator input")) from None
