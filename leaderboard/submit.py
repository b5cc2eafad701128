"""`leaderboard submit`: accept a result only if re-scoring its predictions gives its numbers.

A submission is untrusted data: a results JSON and a predictions HDF5 file. Nothing in them is
executed (no pickle, no code, no model): the benchmark reads them with json and h5py and
validates them (``benchmark.scoring.protocol.load_results``, ``Predictions``: layout, dataset
fingerprint, every test mesh present, finite values), the predictions are scored again by
``scoring.protocol.score``, and every claimed number must agree with the re-score
within ``REL_TOL`` / ``ABS_TOL``. All checks run before anything is written, and the entry is
written atomically, so a refused submission leaves the entries folder untouched. The duplicate
check and the write hold a lock on the entries folder, so two concurrent submissions of the
same predictions cannot both land.

The board claims only what it checked: the metrics are re-scored, but no model is run, so the
speed and the parameter count of a submission are the submitter's claims and are recorded as
self-reported whatever the results JSON says. Only ``seed`` (the maintainers' own
`benchmark reproduce` runs, timed and counted by the harness) keeps them as measured.
"""

from __future__ import annotations

import os
import reprlib
from pathlib import Path

from tqdm import tqdm

from basic_shapes.infra import utc_timestamp
from basic_shapes.manifest import file_sha256
from basic_shapes.shards import list_shards
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.protocol import Predictions, load_results, score
from leaderboard import example
from leaderboard.store import (
    DEFAULT_ENTRIES,
    ENTRY_VERSION,
    METRIC_NAMES,
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

# A claimed metric x is accepted iff |x - rescored| <= ABS_TOL + REL_TOL * |rescored|:
# re-scoring the same predictions differs at most by summation order (~1e-12 relative), while
# an edit at the fifth significant digit is refused.
REL_TOL = 1e-5
ABS_TOL = 1e-6  # dB^2
# Simple and Complex MSE both at or below this are the test labels handed back (the physics
# simulator itself scores about 25 dB² against the analytic object's labels): refused.
ANSWER_KEY_MSE = 1e-6  # dB^2


class SubmissionError(ValueError):
    """A submission is refused (the message is one line naming the file and the problem)."""


class DuplicateSubmission(SubmissionError):
    """The same predictions file is already on the board."""


def _refuse(path, exc: BaseException) -> SubmissionError:
    lines = str(exc).strip().splitlines()
    msg = lines[0] if lines else exc.__class__.__name__
    return SubmissionError(msg if str(path) in msg else f"{path}: {msg}")


def compare(claimed: dict, rescored: dict) -> list[str]:
    """Human-readable differences between claimed and re-scored metrics (empty if they agree).
    The paper's metrics and the classes must be claimed; every value claimed besides them
    (intervals, OOD and peak metrics, per class and per remesher, references, the no-skill
    test) must be the re-score's as well: a results file cannot carry a number the board's
    re-score would not give."""
    cl, rs = claimed.get("per_class"), rescored["per_class"]
    if not isinstance(cl, dict) or set(cl) != set(rs):
        names = sorted(cl) if isinstance(cl, dict) else _short(cl)
        return [f"claimed per_class classes {names} differ from the re-score's {sorted(rs)}"]
    required = [("", claimed, rescored, (*METRIC_NAMES, "no_skill"))]
    required += [(f"per_class.{c}.", cl[c], rs[c], METRIC_NAMES) for c in sorted(rs)]
    diffs = [
        f"claimed {where}{k} is missing (the re-score is {_short(r[k])})"
        for where, c, r, names in required
        for k in names
        if k not in c and r.get(k) is not None
    ]
    return diffs + _differences(claimed, rescored, "")


def _differences(claimed, rescored, where: str) -> list[str]:
    """Where the claimed value ``claimed`` (at key path ``where``) differs from ``rescored``:
    numbers within ABS_TOL + REL_TOL·|re-score|, anything else equal."""
    if isinstance(claimed, dict) and isinstance(rescored, dict):
        out = []
        for key, value in claimed.items():
            path = f"{where}.{key}" if where else str(key)
            if key not in rescored:
                out.append(f"claimed {path} is not a metric the re-score gives")
            else:
                out += _differences(value, rescored[key], path)
        return out
    if isinstance(claimed, list) and isinstance(rescored, list) and len(claimed) == len(rescored):
        return [
            d
            for i, (c, r) in enumerate(zip(claimed, rescored))
            for d in _differences(c, r, f"{where}[{i}]")
        ]
    if _number(claimed) and _number(rescored):
        if abs(claimed - rescored) <= ABS_TOL + REL_TOL * abs(rescored):
            return []
    elif claimed == rescored and type(claimed) is type(rescored):
        return []
    return [f"claimed {where} {_short(claimed)} differs from the re-score {_short(rescored)}"]


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


_REPR = reprlib.Repr()  # Python 3.11: limits are attributes, not arguments
_REPR.maxlevel, _REPR.maxdict, _REPR.maxlist, _REPR.maxstring = 2, 3, 4, 40


def _short(x) -> str:
    """A value for a one-line message: a whole sub-dict would make the line unreadable."""
    return _REPR.repr(x)


def dataset_version(
    data_dir: str | os.PathLike, fingerprints: tuple[str, str], unregistered: bool = False
) -> str | None:
    """The registered version (``benchmark.scoring.versions``) the dataset is: built by its
    recipe (generator and radar configs, read once) with its public seed, and, where the
    version has a manifest, with its recorded (mesh, label) ``fingerprints``. A held-out build
    is refused: the ranked track scores only models the board runs (``leaderboard
    evaluate-model``), so no predictions file, the true labels included, can enter it. A
    dataset that is no version, or a version's recipe whose bytes are not the recorded ones
    (relabelled or edited, however consistently), is refused unless ``unregistered`` (a
    private board: its entries say so and the site lists them apart)."""
    from benchmark.scoring import heldout

    try:
        follows = heldout.recipe_of(data_dir)
    except (OSError, ValueError) as exc:
        raise _refuse(data_dir, exc) from None
    if follows is not None and follows[1] != follows[0].seed:
        raise SubmissionError(
            f"{data_dir}: a held-out build of {follows[0].name}, the ranked track, which "
            f"accepts only ONNX models run by the board (leaderboard evaluate-model MODEL.onnx), "
            f"never a predictions file"
        )
    recorded = follows[0].fingerprints if follows is not None else {}
    expected = (recorded.get("mesh"), recorded.get("label"))
    if follows is not None and (not recorded or expected == tuple(fingerprints)):
        return follows[0].name
    if unregistered:
        return None
    if follows is not None:
        shards, whole = len(list_shards(data_dir)), len(follows[0].manifest["shards"])
        if shards < whole:
            raise SubmissionError(
                f"{data_dir}: a slice of {follows[0].name} ({shards} of {whole} shards); "
                f"submit on a whole build, or pass --unregistered for a private board"
            )
        raise SubmissionError(
            f"{data_dir}: follows {follows[0].name}'s recipe, but its fingerprints (mesh "
            f"{fingerprints[0][:8]}..., label {fingerprints[1][:8]}...) are not the recorded "
            f"ones (mesh {expected[0][:8]}..., label {expected[1][:8]}...): benchmark dataset "
            f"{follows[0].name} --check --data DIR says where it differs; pass --unregistered "
            f"for a private board"
        )
    raise SubmissionError(
        f"{data_dir}: not a registered dataset version (benchmark dataset --list names them; "
        f"build one with benchmark dataset NAME --data DIR); pass --unregistered for a "
        f"private board"
    )


SPEED_SOURCES = {
    "submit": "self-reported by the submitter (benchmark evaluate), not re-measured",
    "seed": "measured by the benchmark harness (benchmark reproduce, the maintainers' run)",
    "seed-self-reported": "not measured by the harness (self-reported in the results)",
}


def submit(
    results_path: str | os.PathLike,
    predictions_path: str | os.PathLike,
    data_dir: str | os.PathLike,
    entries_dir: str | os.PathLike = DEFAULT_ENTRIES,
    name: str | None = None,
    link: str | None = None,
    unregistered: bool = False,
    origin: str = "submit",
) -> Path:
    """Verify one submission and write its entry; refused: SubmissionError, nothing written.

    ``origin="seed"`` (only ``seed`` passes it) trusts the results' own ``self_reported``
    flag and parameter count: the maintainers' reproduce run measured them. Anything else is
    a submission, whose speed and parameter count are always marked self-reported.
    """
    if origin not in ("submit", "seed"):
        raise ValueError(f"origin must be submit or seed, not {origin!r}")
    try:
        results = load_results(results_path)
    except ValueError as exc:
        raise _refuse(results_path, exc) from None
    try:
        link = check_link(link)
        name = check_text(name or results["model"]["name"], "name", 80)
    except EntryError as exc:
        raise _refuse(results_path, exc) from None
    try:
        data = BenchmarkData(data_dir)
        fingerprint, labels = data.fingerprint, data.label_fingerprint
    except (OSError, ValueError) as exc:
        raise _refuse(data_dir, exc) from None
    with data:  # opened once: the checks, the re-score and the entry's records all read it
        version = dataset_version(data_dir, (fingerprint, labels), unregistered)
        if results["dataset_fingerprint"] != fingerprint:
            raise SubmissionError(
                f"{results_path}: dataset fingerprint {results['dataset_fingerprint'][:16]}..."
                f" belongs to another dataset ({data_dir} is {fingerprint[:16]}...)"
            )
        if results["label_fingerprint"] != labels:
            raise SubmissionError(
                f"{results_path}: label fingerprint "
                f"{results['label_fingerprint'][:16]}... belongs to other labels "
                f"({data_dir} is {labels[:16]}...: relabelled?)"
            )
        try:
            preds = Predictions(predictions_path, data)
        except (OSError, ValueError) as exc:
            raise _refuse(predictions_path, exc) from None
        with preds:
            try:
                rescored = score(data, preds)
            except (OSError, ValueError) as exc:
                raise _refuse(predictions_path, exc) from None
            errors = [rescored[k] for k in ("simple_mse", "complex_mse")]
            errors = [e for e in errors if e is not None]  # no complex meshes: Simple only
            if errors and max(errors) <= ANSWER_KEY_MSE:
                raise SubmissionError(
                    f"{predictions_path}: these predictions are the test labels themselves "
                    f"(MSE {max(errors):.1e} dB² at most): an answer key, not a model"
                )
            diffs = compare(results["metrics"], rescored)
            if diffs:
                more = f" (and {len(diffs) - 1} more differences)" if len(diffs) > 1 else ""
                raise SubmissionError(
                    f"{results_path}: {diffs[0]}{more}; submit the results written with this "
                    f"predictions file, unrounded (benchmark evaluate --predictions)"
                )
            pred_sha = file_sha256(predictions_path)
            content_sha = preds.content_sha256()
            _check_duplicate(entries_dir, predictions_path, pred_sha, content_sha)  # fail early
            sample = example.sample(data, preds)
            dataset = dataset_record(data, version=version)
    measured = origin == "seed" and results["speed"].get("self_reported") is False
    entry = {
        "entry_version": ENTRY_VERSION,
        "id": f"{slug(name)}-{content_sha[:10]}",
        "kind": "model",
        "origin": origin,
        "name": name,
        "link": link,
        "model": results["model"],
        "params": results["model"].get("params"),
        # counted by the harness only in the maintainers' reproduce runs (checkpoint.params)
        "params_self_reported": origin != "seed",
        "benchmark_version": results["benchmark_version"],
        "dataset": dataset,
        "metrics": check_metrics(rescored, "re-scored metrics"),
        "speed": {
            **results["speed"],
            "self_reported": not measured,
            "source": SPEED_SOURCES[
                origin if measured or origin == "submit" else "seed-self-reported"
            ],
        },
        "seeds": results["seeds"],
        "created": results["created"],
        "submitted": utc_timestamp(),
        "files": {
            "results_sha256": file_sha256(results_path),
            "predictions_sha256": pred_sha,
            "predictions_content_sha256": content_sha,
        },
        "sample": sample,
    }
    if "training" in results:  # the validation curves (the submitter's word, as its speed)
        entry["training"] = results["training"]
    try:
        validate_entry(entry)  # before the lock creates the folder: a refusal writes nothing
        with entries_lock(entries_dir):  # the check and the write as one step
            _check_duplicate(entries_dir, predictions_path, pred_sha, content_sha)
            return write_entry(entries_dir, entry)
    except EntryError as exc:  # e.g. a hardware text too long to show
        raise _refuse(results_path, exc) from None


def _check_duplicate(entries_dir, predictions_path, container_sha: str, content_sha: str) -> None:
    """Refuse predictions already on the board: same content (any container), or, for entries
    made before content hashes, the same file. Unreadable entries are skipped here (render
    reports them)."""
    if not Path(entries_dir).is_dir():
        return
    for e in load_entries(entries_dir, on_error=lambda msg: None):
        files = e.get("files", {})
        if content_sha == files.get("predictions_content_sha256") or container_sha == files.get(
            "predictions_sha256"
        ):
            raise DuplicateSubmission(f"{predictions_path}: already on the board as {e['id']}")


def seed(
    from_dir: str | os.PathLike,
    data_dir: str | os.PathLike,
    entries_dir: str | os.PathLike = DEFAULT_ENTRIES,
    link: str | None = None,
    unregistered: bool = False,
    progress: bool = True,
):
    """Submit every ``<row>/results.json`` + ``<row>/predictions.h5`` of a reproduce output dir.

    Each entry is named after its row directory (unique per table row, unlike model names).
    Returns (accepted paths, skipped duplicate messages, refused messages); every row is tried.
    """
    rows = sorted(Path(from_dir).glob("*/results.json"))
    if not rows:
        raise SubmissionError(
            f"{from_dir}: no <row>/results.json files (expected `benchmark reproduce` output)"
        )
    accepted, skipped, refused = [], [], []
    for results in tqdm(rows, desc="submitting", unit="row", disable=not progress):
        predictions = results.with_name("predictions.h5")
        if not predictions.is_file():
            refused.append(f"{results}: no predictions.h5 beside it")
            continue
        try:
            accepted.append(
                submit(
                    results,
                    predictions,
                    data_dir,
                    entries_dir,
                    name=results.parent.name,
                    link=link,
                    unregistered=unregistered,
                    origin="seed",
                )
            )
        except DuplicateSubmission as exc:
            skipped.append(str(exc))
        except ValueError as exc:
            refused.append(str(exc))
    return accepted, skipped, refused
