"""The third-party model protocol, predictions files and results JSON (docs/BENCHMARK.md).

A model is any object with ``predict(batch) -> np.ndarray``; ``batch`` is a dict of numpy
data for B meshes (``BenchmarkData.batch``: lists of normalized ``vertices`` and ``faces``,
``scale_bins`` (B,3) int64, ``scale_m`` (B,3) float64) and the result is
(B, n_aspect, n_roll, n_range) dB targets. Optional attributes ``name``, ``params``,
``embedding`` and ``regime`` fill the results.

Predictions files and results JSON are untrusted input: they are read with h5py and json
only (never unpickled) and validated, with one-line errors naming the file.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import os
import re
import sys
from pathlib import Path
from typing import Protocol

import h5py
import numpy as np

from basic_shapes.infra import (
    atomic_path,
    load_json,
    one_line,
    open_hdf5,
    require_dataset,
    utc_timestamp,
)
from basic_shapes.shards import ood_remesher
from benchmark import __version__
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.metrics import METRIC_NAMES, Scorer, ood_keys
from benchmark.scoring.schema import PEAK_METRIC_NAMES, SchemaError, check_results

RESULTS_MAX_BYTES = 1 << 20

PREDICTIONS_FORMAT = "basic-shapes-predictions"
PREDICTIONS_VERSION = 1


class ModelError(ValueError):
    """A model could not be loaded, or returned something that is not a valid prediction."""


class PredictionsError(ValueError):
    """A predictions file is foreign, malformed, or does not match the dataset."""


class ResultsError(ValueError):
    """A results JSON is malformed."""


class Model(Protocol):
    def predict(self, batch: dict) -> np.ndarray: ...


def why(exc: BaseException) -> str:
    """An exception as one line: its class and the first line of its message."""
    lines = str(exc).strip().splitlines()
    return f"{exc.__class__.__name__}: {lines[0]}" if lines else exc.__class__.__name__


# --- models -----------------------------------------------------------------------------------
def load_model(spec: str, kwargs: dict | None = None) -> Model:
    """Instantiate ``module:Class`` or ``path/to/file.py:Class`` with ``kwargs``.

    This runs the model's code: for untrusted submissions, score a predictions file instead.
    """
    target, sep, cls_name = spec.rpartition(":")
    if not sep or not target or not cls_name.isidentifier():
        raise ModelError(f"{spec}: model must be given as module:Class or path/to/file.py:Class")
    if target.endswith(".py") or os.sep in target or "/" in target:
        path = Path(target)
        if not path.is_file():
            raise ModelError(f"{spec}: no such file {path}")
        mod_name = "benchmark_user_model_" + re.sub(r"\W", "_", str(path.resolve()))
        module_spec = importlib.util.spec_from_file_location(mod_name, path)
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[mod_name] = module  # dataclasses and typing look their module up there
        try:
            module_spec.loader.exec_module(module)
        except (Exception, SystemExit) as exc:
            sys.modules.pop(mod_name, None)
            raise ModelError(f"{spec}: importing {path} failed: {why(exc)}") from None
    else:
        try:
            module = importlib.import_module(target)
        except ImportError as exc:
            raise ModelError(f"{spec}: cannot import module {target} ({why(exc)})") from None
        except (Exception, SystemExit) as exc:
            raise ModelError(f"{spec}: importing {target} failed: {why(exc)}") from None
    cls = getattr(module, cls_name, None)
    if cls is None:
        raise ModelError(f"{spec}: module {target} has no {cls_name}")
    try:
        model = cls(**(kwargs or {}))
    except (Exception, SystemExit) as exc:
        raise ModelError(f"{spec}: constructing {cls_name} failed: {why(exc)}") from None
    if not callable(getattr(model, "predict", None)):
        raise ModelError(f"{spec}: {cls_name} has no predict(batch) method")
    return model


def check_prediction(out, n: int, target_shape: tuple[int, ...], who: str) -> np.ndarray:
    """Validate one ``predict`` result; return it as float32 (n, *target_shape)."""
    try:
        arr = np.asarray(out)
    except Exception as exc:
        raise ModelError(
            f"{who}: predict returned {type(out).__name__}, not an array ({why(exc)})"
        ) from None
    if arr.shape != (n, *target_shape) or arr.dtype.kind not in "fiu":
        raise ModelError(
            f"{who}: predict returned {arr.dtype}{arr.shape}, expected a real "
            f"array of shape {(n, *target_shape)}"
        )
    arr = arr.astype(np.float32)
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{who}: predict returned non-finite values")
    return arr


class MeanResponseModel:
    """Reference: the mean training target over simple meshes, for every mesh.

    The canonical no-skill model: Variation MSE is exactly 0 and ``no_skill`` flags it.
    """

    name, params, embedding, regime = "mean-response", 0, "none", "basic"

    def __init__(self, data_dir: str):
        with BenchmarkData(data_dir) as data:
            rows = data.object_rows("train")
            self.mean = sum(data.target(o).astype(np.float64) for o in rows) / len(rows)

    def predict(self, batch: dict) -> np.ndarray:
        return np.broadcast_to(self.mean, (len(batch["scale_m"]), *self.mean.shape)).astype(
            np.float32
        )


class NearestScaleModel:
    """Reference: mean training target of the ``k`` objects nearest in log scale.

    Sees only the scale, never the mesh: topology-invariant by construction (Variation MSE 0)
    and it has skill when scale predicts the response.
    """

    name, params, embedding, regime = "nearest-scale", 0, "none", "basic"

    def __init__(self, data_dir: str, k: int | str = 3):
        self.k = int(k)
        with BenchmarkData(data_dir) as data:
            rows = data.object_rows("train")
            self.log_scale = np.log(data.objects["scale"][rows])
            self.targets = np.stack([data.target(o) for o in rows])

    def predict(self, batch: dict) -> np.ndarray:
        d = np.linalg.norm(np.log(batch["scale_m"])[:, None] - self.log_scale[None], axis=-1)
        nearest = np.argsort(d, axis=1, kind="stable")[:, : self.k]
        return self.targets[nearest].mean(axis=1, dtype=np.float64).astype(np.float32)


# --- predictions files ------------------------------------------------------------------------
def scored_mesh_rows(data: BenchmarkData, ood: bool = True) -> np.ndarray:
    """Global rows of every mesh a predictions file must cover: per test object its regular
    meshes (simple first), then (``ood``) its out-of-distribution meshes."""
    rows = [
        np.concatenate([data.meshes_of(o), data.ood_meshes_of(o)]) if ood else data.meshes_of(o)
        for o in data.test_objects()
    ]
    return np.concatenate(rows)


class PredictionsWriter:
    """Write a predictions file row block by row block; the file appears only when complete."""

    def __init__(
        self,
        path: str | os.PathLike,
        dataset_fingerprint: str,
        n_meshes: int,
        target_shape: tuple[int, ...],
        *,
        label_fingerprint: str,
    ):
        self.path, self.fingerprint = Path(path), dataset_fingerprint
        self.label_fingerprint = label_fingerprint
        self.n, self.shape, self.filled = n_meshes, tuple(target_shape), 0

    def __enter__(self) -> PredictionsWriter:
        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        self.file = h5py.File(tmp, "w", libver="earliest")
        self.file.attrs["format"] = PREDICTIONS_FORMAT
        self.file.attrs["version"] = PREDICTIONS_VERSION
        self.file.attrs["dataset_fingerprint"] = self.fingerprint
        self.file.attrs["label_fingerprint"] = self.label_fingerprint
        self.uid = self.file.create_dataset("mesh_uid", (self.n,), np.int64, track_times=False)
        self.target = self.file.create_dataset(
            "target_db",
            (self.n, *self.shape),
            np.float32,
            chunks=(1, *self.shape),
            track_times=False,
        )
        return self

    def write(self, uids: np.ndarray, target_db: np.ndarray) -> None:
        k, target_db = len(uids), np.asarray(target_db)
        if target_db.shape != (k, *self.shape):
            raise PredictionsError(
                f"{self.path}: {k} mesh uids but predictions of shape "
                f"{target_db.shape}, expected {(k, *self.shape)}"
            )
        if self.filled + k > self.n:
            raise PredictionsError(f"{self.path}: more than the declared {self.n} rows written")
        rows = np.asarray(target_db, np.float32)
        bad = ~np.isfinite(rows).reshape(k, -1).all(axis=1)
        if bad.any():  # refused here, not only when scored
            raise PredictionsError(
                f"{self.path}: non-finite prediction for mesh_uid {uids[np.flatnonzero(bad)[0]]}"
            )
        self.uid[self.filled : self.filled + k] = np.asarray(uids, np.int64)
        self.target[self.filled : self.filled + k] = rows
        self.filled += k

    def __exit__(self, exc_type, exc, tb) -> None:
        self.file.close()
        if exc is None and self.filled != self.n:
            exc = PredictionsError(f"{self.path}: {self.filled} of {self.n} rows written")
        if exc is None:
            self._atomic.__exit__(None, None, None)
            return
        self._atomic.__exit__(type(exc), exc, exc.__traceback__)  # removes the temporary file
        if exc_type is None:
            raise exc


def write_predictions(
    path: str | os.PathLike,
    dataset_fingerprint: str,
    mesh_uid: np.ndarray,
    target_db: np.ndarray,
    *,
    label_fingerprint: str,
) -> None:
    """Write a whole predictions file at once (for third parties with arrays in memory)."""
    target_db = np.asarray(target_db)
    with PredictionsWriter(
        path,
        dataset_fingerprint,
        len(mesh_uid),
        target_db.shape[1:],
        label_fingerprint=label_fingerprint,
    ) as w:
        w.write(mesh_uid, target_db)


class Predictions:
    """A validated predictions file for ``data``'s test split; rows read by mesh_uid."""

    def __init__(self, path: str | os.PathLike, data: BenchmarkData):
        self.path = Path(path)
        self.file = open_hdf5(self.path, PredictionsError)
        try:
            self._validate(data)
        except Exception:
            self.file.close()
            raise

    def _fail(self, problem: str):
        raise PredictionsError(f"{self.path}: {problem}")

    def _validate(self, data: BenchmarkData) -> None:
        """Attributes, layout, then the uids; ``open_hdf5`` already refused external storage,
        links and declared sizes the file does not store."""
        f = self.file
        if _attr(f, "format") != PREDICTIONS_FORMAT:
            self._fail(f"not a predictions file (format attribute is not {PREDICTIONS_FORMAT!r})")
        if _attr(f, "version") != str(PREDICTIONS_VERSION):
            self._fail(
                f"predictions format version {_attr(f, 'version')} is not {PREDICTIONS_VERSION}"
            )
        if _attr(f, "dataset_fingerprint") != data.fingerprint:
            self._fail(
                f"made for dataset {str(_attr(f, 'dataset_fingerprint'))[:64]}, not for "
                f"{data.directory} ({data.fingerprint})"
            )
        if _attr(f, "label_fingerprint") != data.label_fingerprint:
            self._fail(
                f"made for labels {_attr(f, 'label_fingerprint')}, not for the labels of "
                f"{data.directory} ({data.label_fingerprint}): relabelled since?"
            )
        for name in ("mesh_uid", "target_db"):
            if not isinstance(f.get(name), h5py.Dataset):
                self._fail(f"/{name} is missing or not a plain dataset")
        uid, tgt = f["mesh_uid"], f["target_db"]
        if uid.ndim != 1 or uid.dtype != np.int64:
            self._fail(f"/mesh_uid is {uid.dtype}{uid.shape}, expected int64 (m,)")
        expected = (len(uid), *data.target_shape)
        if tgt.shape != expected or tgt.dtype != np.float32:
            self._fail(f"/target_db is {tgt.dtype}{tgt.shape}, expected float32{expected}")
        test = data.meshes["uid"][scored_mesh_rows(data)]
        if len(uid) > 2 * len(test) + 1:  # never read more uids than could be meant
            self._fail(f"{len(uid)} rows for {len(test)} test meshes")
        uids = require_dataset(f, "mesh_uid", "i", 1, PredictionsError, self.path)[()]
        self.order = np.argsort(uids, kind="stable")
        self.sorted_uids = uids[self.order]
        dup = self.sorted_uids[1:][self.sorted_uids[1:] == self.sorted_uids[:-1]]
        if len(dup):
            self._fail(f"{len(dup)} duplicated mesh_uid rows (first {dup[0]})")
        regular = data.meshes["uid"][scored_mesh_rows(data, ood=False)]
        missing = np.setdiff1d(regular, self.sorted_uids)
        if len(missing):
            self._fail(
                f"missing {len(missing)} of {len(regular)} test meshes (first mesh_uid "
                f"{missing[0]})"
            )
        missing = np.setdiff1d(test, self.sorted_uids)
        if len(missing):
            self._fail(
                f"missing {len(missing)} of {len(test) - len(regular)} out-of-distribution "
                f"test meshes (variants 900-999, first mesh_uid {missing[0]}); predict "
                f"them too (BenchmarkData.ood_meshes_of lists them)"
            )
        extra = np.setdiff1d(self.sorted_uids, test)
        if len(extra):
            self._fail(
                f"{len(extra)} rows are not test-split meshes of the dataset "
                f"(first mesh_uid {extra[0]})"
            )

    def read(self, uids: np.ndarray) -> np.ndarray:
        """Predictions (len(uids), *target_shape) float32 for these mesh uids, in that order."""
        rows = self.order[np.searchsorted(self.sorted_uids, uids)]
        perm = np.argsort(rows)
        out = np.empty((len(rows), *self.file["target_db"].shape[1:]), np.float32)
        try:
            out[perm] = self.file["target_db"][rows[perm]]
        except OSError as exc:  # a checksum (fletcher32) or a compressed chunk that fails
            self._fail(f"/target_db cannot be read ({one_line(exc)})")
        bad = ~np.isfinite(out).reshape(len(out), -1).all(axis=1)
        if bad.any():
            self._fail(f"non-finite prediction for mesh_uid {uids[np.flatnonzero(bad)[0]]}")
        # a dB response always has bins far below 0 dB (the -80 dB floor); a row without one
        # is linear magnitude |A| (or intensity), the most common unit slip. A constant row
        # (a trivial predictor, np.zeros) is dB of one value, not a slip.
        flat = out.reshape(len(out), -1)
        linear = (flat >= 0).all(axis=1) & (flat.max(axis=1) > flat.min(axis=1))
        if linear.any():
            self._fail(
                f"every predicted value for mesh_uid {uids[np.flatnonzero(linear)[0]]} "
                f"is >= 0: these look like linear magnitudes, not dB; store "
                f"20*log10(max(|A|, 1e-4)) (docs/BENCHMARK.md)"
            )
        return out

    def content_sha256(self, chunk: int = 64) -> str:
        """sha256 of the data scored: the uids in increasing order, then their target rows in
        that order. Attributes, layout, chunking and row order of the container do not change
        it, so the same predictions re-packaged are recognised as the same."""
        h = hashlib.sha256(f"{PREDICTIONS_FORMAT}-{PREDICTIONS_VERSION}".encode())
        h.update(self.sorted_uids.astype("<i8").tobytes())
        for start in range(0, len(self.sorted_uids), chunk):
            block = self.read(self.sorted_uids[start : start + chunk]) + np.float32(0)  # -0 -> 0
            h.update(block.astype("<f4").tobytes())
        return h.hexdigest()

    def close(self) -> None:
        self.file.close()

    def __enter__(self) -> Predictions:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _attr(f: h5py.File, name: str) -> str | None:
    value = f.attrs.get(name)
    if isinstance(value, bytes):
        value = value.decode(errors="replace")
    return None if value is None else str(value)


def score(data: BenchmarkData, predictions: Predictions, per_object: bool = False) -> dict:
    """Metrics of a validated predictions file, streamed object by object, with the
    dataset's reference rows and the model's skill against them (``benchmark.scoring.references``);
    ``per_object`` adds the per-object errors (what paired comparisons resample)."""
    from benchmark.scoring import references

    train_mean, ref_scorers = references.reference_scores(data)
    scorer = Scorer(data.class_names, train_mean)
    for obj in data.test_objects():
        rows, ood = data.meshes_of(obj), data.ood_meshes_of(obj)
        pred = predictions.read(data.meshes["uid"][np.concatenate([rows, ood])])
        scorer.add(
            data.objects["class_index"][obj],
            data.target(obj),
            pred[0],
            pred[1 : len(rows)],
            int(data.objects["id"][obj]),
            ood=pred[len(rows) :],
            ood_remeshers=[ood_remesher(v) for v in data.meshes["variant"][ood]],
        )
    metrics = scorer.result()
    po = scorer.per_object()
    metrics["references"] = {n: references.summary(s) for n, s in ref_scorers.items()}
    metrics["skill"] = references.skill(po, ref_scorers, metrics["references"])
    if per_object:
        metrics["per_object"] = per_object_json(po)
    return metrics


def per_object_json(po: dict) -> dict:
    """Per-object arrays as JSON lists (null where an object lacks a metric), the OOD ones
    included (``metric:remesher`` per remesher), and the peak-relative ones."""
    out = {"object_id": po["object_id"].tolist(), "class_index": po["class_index"].tolist()}
    for name in METRIC_NAMES + ood_keys() + PEAK_METRIC_NAMES:
        out[name] = [None if np.isnan(x) else float(x) for x in po[name]]
    return out


def score_predictions(data_dir: str | os.PathLike, predictions_path: str | os.PathLike) -> dict:
    """The metrics dict (``Scorer.result``) of a predictions file against a labelled dataset."""
    with BenchmarkData(data_dir) as data, Predictions(predictions_path, data) as preds:
        return score(data, preds)


# --- results JSON -----------------------------------------------------------------------------
def make_results(
    dataset_fingerprint: str,
    metrics: dict,
    model: dict,
    speed: dict,
    seeds: dict,
    *,
    label_fingerprint: str,
) -> dict:
    """A results record (docs/ARCHITECTURE.md, "Results JSON"), validated."""
    results = {
        "benchmark_version": __version__,
        "dataset_fingerprint": dataset_fingerprint,
        "label_fingerprint": label_fingerprint,
        "model": model,
        "metrics": metrics,
        "speed": speed,
        "seeds": seeds,
        "created": utc_timestamp(),
    }
    validate_results(results, "results")
    return results


def write_results(path: str | os.PathLike, results: dict) -> None:
    """Validate and write atomically."""
    validate_results(results, str(path))
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(results, indent=2, sort_keys=True, allow_nan=False) + "\n")


def load_results(path: str | os.PathLike) -> dict:
    """Read and validate a results JSON; ``ResultsError`` (one line) if anything is wrong.

    Bounded: at most ``RESULTS_MAX_BYTES``, nesting of at most 32, no NaN/Infinity.
    """
    results = load_json(Path(path), max_bytes=RESULTS_MAX_BYTES, error=ResultsError)
    validate_results(results, str(path))
    return results


def validate_results(r, source: str) -> None:
    """Check a results record against ``scoring.schema``; ``ResultsError`` naming ``source``."""
    try:
        check_results(r, source)
    except SchemaError as exc:
        raise ResultsError(str(exc)) from None
