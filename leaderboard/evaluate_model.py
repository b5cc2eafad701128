"""`leaderboard evaluate-model`: the ranked track. The board runs an ONNX model on a held-out build.

A submission to the ranked track is a model file in a data-only format (ONNX: a graph of
standard operators and its tensors; no pickle, no code), never a predictions file: the test
labels of every public version are public, so predictions on them prove nothing. The board

1. validates the file (``benchmark.scoring.onnx_model.inspect``: the ONNX checker, standard
   operator domains only, no external data, the contract's inputs and output) and counts its
   parameters from the graph (every stored tensor element, whatever anyone declares);
2. checks the dataset is a held-out build (``benchmark.scoring.heldout.identify``: a registered
   version's recipe with a secret seed, matching the recorded fingerprints where recorded); a
   public build is refused whatever the flags;
3. runs the model in a child process (``leaderboard.onnx_child``) with onnxruntime, one thread,
   under a memory limit (address space, ``resource.setrlimit``) and a wall-time limit, without
   network where the kernel allows, over every scored test mesh, one mesh per call, and times
   it there: ms per mesh = the mean wall time of the run plus the board-computed inputs the
   model declared (``mesh_inputs``), after one warm-up run;
4. scores the predictions with ``benchmark.scoring.protocol.score`` (the same metrics, reference
   rows and skill as every entry) and writes an entry on the held-out track: the file's
   sha256, the counted parameters and the measured speed, unmarked (the board measured them).

The entry keeps no example sample: it would publish a held-out label.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from tqdm import tqdm

from basic_shapes.infra import utc_timestamp
from benchmark import __version__
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.onnx_model import OnnxModelError, inspect, read_model_bytes
from benchmark.scoring.protocol import Predictions, score
from leaderboard.store import (
    DEFAULT_ENTRIES,
    ENTRY_VERSION,
    EntryError,
    check_link,
    check_metrics,
    check_text,
    dataset_record,
    entries_lock,
    load_entries,
    slug,
    validate_entry,
    write_entry,
)
from leaderboard.submit import DuplicateSubmission, SubmissionError

TIME_LIMIT_S = 600.0  # wall time of one model's whole run (every test mesh)
MEMORY_LIMIT_MIB = 4096  # address space of the child (Python, numpy, h5py and onnxruntime)
CHILD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}


def _refuse(path, exc: BaseException) -> SubmissionError:
    lines = str(exc).strip().splitlines()
    msg = lines[0] if lines else exc.__class__.__name__
    return SubmissionError(msg if str(path) in msg else f"{path}: {msg}")


def heldout_version(data_dir: str | os.PathLike, unregistered: bool = False) -> str | None:
    """The version whose recipe the held-out build ``data_dir`` follows; a public build is
    refused always, any other dataset unless ``unregistered`` (a private board: None)."""
    from benchmark.scoring import heldout

    try:
        return heldout.identify(data_dir).version.name
    except heldout.HeldOutError as exc:
        try:
            follows = heldout.recipe_of(data_dir)
        except (OSError, ValueError):
            follows = None
        if follows is not None:  # a public build, or not the recorded held-out one
            raise SubmissionError(str(exc)) from None
        if not unregistered:
            raise SubmissionError(f"{exc}; pass --unregistered for a private board") from None
        return None
    except (OSError, ValueError) as exc:
        raise _refuse(data_dir, exc) from None


def run_child(
    model: Path,
    data_dir: str | os.PathLike,
    predictions: Path,
    report: Path,
    time_limit: float = TIME_LIMIT_S,
    memory_mib: int = MEMORY_LIMIT_MIB,
    shown: str | os.PathLike | None = None,
) -> dict:
    """Run ``leaderboard.onnx_child`` under the limits; its report, or SubmissionError naming
    ``shown`` (the submitted file; ``model`` is the board's copy of it)."""
    shown = str(shown or model)
    cmd = [
        sys.executable,
        "-m",
        "leaderboard.onnx_child",
        str(model),
        str(data_dir),
        str(predictions),
        str(report),
        str(int(memory_mib)),
        str(int(time_limit) + 1),  # CPU seconds: a backstop below the wall-time limit
    ]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        env={**os.environ, **CHILD_ENV},
        start_new_session=True,  # its own process group: killed as a whole
        text=True,
    )
    try:
        _, err = proc.communicate(timeout=time_limit)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:  # ended meanwhile
            pass
        proc.communicate()
        raise SubmissionError(
            f"{shown}: ran past the time limit of {time_limit:g} s over the test meshes"
        ) from None
    if proc.returncode != 0:
        lines = [line for line in (err or "").strip().splitlines() if line.strip()]
        if proc.returncode < 0:
            why = f"killed by signal {signal.Signals(-proc.returncode).name}"
            if -proc.returncode == signal.SIGXCPU:
                why = f"ran past the CPU-time limit of {int(time_limit) + 1} s"
        else:
            why = lines[-1][:300] if lines else f"exit status {proc.returncode}"
        raise SubmissionError(f"{shown}: running it failed: {why.replace(str(model), shown)}")
    return json.loads(report.read_text())


def _check_duplicate(entries_dir, model_path, sha: str, fingerprint: str) -> None:
    if not Path(entries_dir).is_dir():
        return
    for e in load_entries(entries_dir, on_error=lambda msg: None):
        if (
            e.get("files", {}).get("onnx_sha256") == sha
            and e["dataset"]["fingerprint"] == fingerprint
        ):
            raise DuplicateSubmission(f"{model_path}: already on the board as {e['id']}")


def evaluate_model(
    model_path: str | os.PathLike,
    data_dir: str | os.PathLike,
    entries_dir: str | os.PathLike = DEFAULT_ENTRIES,
    name: str | None = None,
    link: str | None = None,
    unregistered: bool = False,
    time_limit: float = TIME_LIMIT_S,
    memory_mib: int = MEMORY_LIMIT_MIB,
) -> Path:
    """Run, score and enter one ONNX model on a held-out build; SubmissionError (one line
    naming the file) and nothing written if anything fails."""
    model_path = Path(model_path)
    try:
        raw = read_model_bytes(model_path)
        info = inspect(model_path, raw)
    except OnnxModelError as exc:
        raise _refuse(model_path, exc) from None
    try:
        link = check_link(link)
        name = check_text(name or model_path.stem, "name", 80)
    except EntryError as exc:
        raise _refuse(model_path, exc) from None
    version = heldout_version(data_dir, unregistered)
    try:
        data = BenchmarkData(data_dir)
    except (OSError, ValueError) as exc:
        raise _refuse(data_dir, exc) from None
    with data:
        _check_duplicate(entries_dir, model_path, info.sha256, data.fingerprint)
        with tempfile.TemporaryDirectory(prefix="evaluate-model-") as tmp:
            copy = Path(tmp) / "model.onnx"  # the bytes inspected are the bytes run
            copy.write_bytes(raw)
            pred = Path(tmp) / "predictions.h5"
            report = run_child(
                copy, data_dir, pred, Path(tmp) / "report.json", time_limit, memory_mib, model_path
            )
            try:
                with Predictions(pred, data) as preds:
                    metrics = score(data, preds)
                    content_sha = preds.content_sha256()
            except (OSError, ValueError) as exc:
                raise _refuse(model_path, exc) from None
        dataset = dataset_record(data, version=version)
    hw = report["hardware"]
    declared = dict(info.metadata)  # labels the file declares (shown, never trusted as numbers)
    detail = {}
    for k in ("embedding", "regime"):
        try:
            detail[k] = check_text(declared[k], k, 80) if k in declared else None
        except EntryError:
            detail[k] = None
    entry = {
        "entry_version": ENTRY_VERSION,
        "id": f"{slug(name)}-{info.sha256[:10]}",
        "kind": "model",
        "origin": "board",
        "track": "heldout",
        "name": name,
        "link": link,
        "model": {"name": name, "params": info.params, **detail},
        "params": info.params,
        "params_self_reported": False,
        "benchmark_version": __version__,
        "dataset": dataset,
        "metrics": check_metrics(metrics, "scored metrics"),
        "speed": {
            "ms_per_mesh": report["ms_per_mesh"],
            "hardware": hw["text"],
            "cpu": hw["cpu"],
            "threads": 1,
            "load_avg_1m": hw["load_avg_1m"],
            "gpu": None,
            "self_reported": False,
            "source": (
                f"measured by the board (evaluate-model): onnxruntime {report['onnxruntime']}, "
                f"1 thread{', no network' if report.get('network_isolated') else ''}; mean of "
                f"{report['n_meshes']} test meshes after a warm-up: "
                f"{report['run_ms_per_mesh']:.3g} ms run + {report['inputs_ms_per_mesh']:.3g} ms "
                f"board-computed inputs"
            )[:200],
        },
        "seeds": None,
        "created": utc_timestamp(),
        "submitted": utc_timestamp(),
        "files": {"onnx_sha256": info.sha256, "predictions_content_sha256": content_sha},
        "sample": None,  # an example image would publish a held-out label
    }
    try:
        validate_entry(entry)
        with entries_lock(entries_dir):
            _check_duplicate(entries_dir, model_path, info.sha256, dataset["fingerprint"])
            return write_entry(entries_dir, entry)
    except EntryError as exc:
        raise _refuse(model_path, exc) from None


def evaluate_models(
    models: list,
    data_dir,
    entries_dir,
    name=None,
    link=None,
    unregistered=False,
    time_limit=TIME_LIMIT_S,
    memory_mib=MEMORY_LIMIT_MIB,
    progress: bool = True,
):
    """Each model in turn (named by its file stem, or ``name`` for a single one): (accepted
    paths, skipped duplicate messages, refused messages)."""
    if name is not None and len(models) > 1:
        raise SubmissionError("--name names one model; several are named by their file stems")
    accepted, skipped, refused = [], [], []
    quiet = not progress or len(models) < 2
    for model in tqdm(models, desc="evaluate", unit="model", disable=quiet):
        try:
            accepted.append(
                evaluate_model(
                    model,
                    data_dir,
                    entries_dir,
                    name,
                    link,
                    unregistered,
                    time_limit,
                    memory_mib,
                )
            )
        except DuplicateSubmission as exc:
            skipped.append(str(exc))
        except ValueError as exc:
            refused.append(str(exc))
    return accepted, skipped, refused
