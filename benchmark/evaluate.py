"""Evaluate a model or a predictions file on the test split and build the results record.

Both paths meet in one place: a model's predictions are first written to a predictions file
(float32, the same bytes a third party would submit) and that file is then scored, so a model
and its predictions file give identical metrics.
"""

from __future__ import annotations

import contextlib
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from tqdm import tqdm

from benchmark.data import BenchmarkData
from benchmark.protocol import (Model, ModelError, Predictions, PredictionsWriter, check_prediction,
                                make_results, score, why)

MODEL_FIELDS = ("name", "params", "embedding", "regime")


def hardware() -> str:
    """CPU model and core count, plus the GPU when torch is already loaded and sees one."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    text = f"cpu: {cpu} ({os.cpu_count()} cores)"
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_available():
        text += f"; gpu: {torch.cuda.get_device_name(0)}"
    return text


def predict_test_split(model: Model, data: BenchmarkData, path: str | os.PathLike,
                       batch_size: int = 16, who: str = "model", progress: bool = True) -> float:
    """Run ``model.predict`` over every test mesh, write a predictions file; return ms per mesh.

    The time counted is the wall time inside ``predict`` only (not reading meshes).
    """
    data.test_objects()  # refuses a dataset without a test split
    rows = data.mesh_rows("test")
    elapsed = 0.0
    with PredictionsWriter(path, data.fingerprint, len(rows), data.target_shape,
                           label_fingerprint=data.label_fingerprint) as writer:
        with tqdm(total=len(rows), desc="predict", unit="mesh", disable=not progress) as bar:
            for start in range(0, len(rows), batch_size):
                chunk = rows[start:start + batch_size]
                batch = data.batch(chunk)
                t0 = time.perf_counter()
                try:
                    out = model.predict(batch)
                except Exception as exc:
                    raise ModelError(f"{who}: predict failed: {why(exc)}") from exc
                elapsed += time.perf_counter() - t0
                writer.write(data.meshes["uid"][chunk],
                             check_prediction(out, len(chunk), data.target_shape, who))
                bar.update(len(chunk))
    return 1000.0 * elapsed / max(len(rows), 1)


def model_info(model: Model | None, overrides: dict) -> dict:
    """Results ``model`` block: the model's own attributes, overridden by non-None values."""
    info = {k: getattr(model, k, None) for k in MODEL_FIELDS}
    if info["name"] is None and model is not None:
        info["name"] = type(model).__name__
    info.update({k: v for k, v in overrides.items() if v is not None})
    return info


def evaluate(data_dir: str | os.PathLike, *, model: Model | None = None,
             predictions: str | os.PathLike | None = None,
             write_predictions: str | os.PathLike | None = None, overrides: dict | None = None,
             train_seed: int | None = None, batch_size: int = 16, progress: bool = True,
             scratch_dir: str | os.PathLike | None = None) -> dict:
    """Results record for exactly one of ``model`` or ``predictions``.

    A model's predictions go to ``write_predictions`` if given, else to a temporary file in
    ``scratch_dir`` (default: the system's), deleted afterwards.
    """
    if (model is None) == (predictions is None):
        raise ValueError("give exactly one of a model or a predictions file")
    overrides = dict(overrides or {})
    with BenchmarkData(data_dir) as data:
        speed = {"ms_per_mesh": None, "hardware": None}
        if model is not None:
            with contextlib.ExitStack() as stack:
                path = Path(write_predictions) if write_predictions else Path(
                    stack.enter_context(tempfile.TemporaryDirectory(dir=scratch_dir))) / "predictions.h5"
                who = str(overrides.get("name") or getattr(model, "name", None) or type(model).__name__)
                speed = {"ms_per_mesh": predict_test_split(model, data, path, batch_size, who, progress),
                         "hardware": hardware()}
                with Predictions(path, data) as preds:
                    metrics = score(data, preds)
        else:
            overrides["name"] = overrides.get("name") or Path(predictions).stem
            with Predictions(predictions, data) as preds:
                metrics = score(data, preds)
        dataset_seed = data.config.get("seed")
        seeds = {"dataset": dataset_seed if isinstance(dataset_seed, int) else None, "train": train_seed}
        return make_results(data.fingerprint, metrics, model_info(model, overrides), speed, seeds,
                            label_fingerprint=data.label_fingerprint)


def format_metrics(results: dict) -> str:
    """A small plain-text table of the metrics, overall and per class."""
    def cell(x):
        return "-" if x is None else f"{x:.3f}"

    m = results["metrics"]
    lines = [f"{'':10} {'simple':>10} {'complex':>10} {'variation':>10} {'objects':>8}"]
    for label, block in [("all", m), *m["per_class"].items()]:
        lines.append(f"{label:10} {cell(block['simple_mse']):>10} {cell(block['complex_mse']):>10} "
                     f"{cell(block['variation_mse']):>10} {block['n_objects']:>8}")
    rho = m["spread_ratio"]
    lines.append(f"spread ratio {cell(rho)}; mode collapse: {'YES' if m['mode_collapse'] else 'no'}")
    if results["speed"]["ms_per_mesh"] is not None:
        lines.append(f"speed {results['speed']['ms_per_mesh']:.3f} ms/mesh on {results['speed']['hardware']}")
    return "\n".join(lines)

