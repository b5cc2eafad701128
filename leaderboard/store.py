"""Entry files: one JSON file per accepted submission, the board's only source of truth.

Entries reach the repository by pull request, so ``render`` validates every file again: a
hand-edited entry with a non-http link, a missing number or a malformed sample is refused
with a one-line error naming the file, never rendered.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import re
import stat
import unicodedata
from pathlib import Path

from basic_shapes.infra import atomic_path, load_json
from benchmark.scoring import schema

ENTRY_VERSION = 1
DEFAULT_ENTRIES = Path(__file__).resolve().parent / "entries"
KINDS = ("model", "simulator")
METRIC_NAMES = schema.METRIC_NAMES
MAX_NAME = schema.MAX_NAME
MAX_TEXT = schema.MAX_TEXT
ENTRY_MAX_BYTES = 4 << 20
# predictions_content_sha256 covers the data scored (``benchmark.scoring.protocol.content_sha256``);
# predictions_sha256 is the container's, kept for entries made before it existed
# onnx_sha256: the model file a held-out entry's numbers were measured with (evaluate-model)
FILE_HASHES = (
    "results_sha256",
    "predictions_sha256",
    "predictions_content_sha256",
    "onnx_sha256",
)
ENTRY_FIELDS = (
    "entry_version",
    "id",
    "kind",
    "origin",
    "track",
    "name",
    "link",
    "model",
    "params",
    "params_self_reported",
    "benchmark_version",
    "dataset",
    "metrics",
    "speed",
    "seeds",
    "created",
    "submitted",
    "files",
    "sample",
    "complex_mse_source",
)
# Which command wrote an entry, so the board knows what the harness measured itself:
# ``submit`` scores a predictions file and runs no model (its speed and params are claims),
# ``seed`` publishes the maintainers' own `benchmark reproduce` runs (timed and counted by the
# harness), ``simulator`` times radar_sim, ``board`` ran an ONNX model on a held-out build
# (``leaderboard evaluate-model``: speed measured, parameters counted, by the board). Entries
# made before the field read as ``submit``.
ORIGINS = {"model": ("submit", "seed", "board"), "simulator": ("simulator",)}
# ``heldout``: the ranked track, scored on a held-out build whose labels are not published
# (models only through ``evaluate-model``); ``public``: the self-scored track, scored from
# predictions files on a public test split. Entries made before the field are ``public``.
TRACKS = ("heldout", "public")
# Unicode categories refused in any entry text: controls (Cc), format characters such as the
# bidi override U+202E or zero-width spaces (Cf), line and paragraph separators (Zl, Zp) and
# lone surrogates (Cs, not encodable): they reorder or hide what the board shows.
FORBIDDEN_CATEGORIES = frozenset({"Cc", "Cf", "Zl", "Zp", "Cs"})


class EntryError(ValueError):
    """An entry file (or a value bound for one) is malformed."""


def slug(text: str) -> str:
    """File-name-safe lower-case form of a model name."""
    s = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")
    return s[:40] or "model"


def hidden_character(text: str) -> str | None:
    """The first character of ``text`` that is invisible or reorders text (a control, a bidi
    override, a zero-width or line separator), as ``U+XXXX``; None if there is none."""
    for c in text:
        if unicodedata.category(c) in FORBIDDEN_CATEGORIES:
            return f"U+{ord(c):04X}"
    return None


def check_text(value, what: str, max_len: int = MAX_TEXT) -> str:
    if not isinstance(value, str) or not value.strip():
        raise EntryError(f"{what} must be a non-empty string")
    bad = hidden_character(value)
    if len(value) > max_len or bad:
        raise EntryError(
            f"{what} must be one printable line of at most {max_len} characters"
            + (f" (has the control or format character {bad})" if bad else "")
        )
    return value


def _check_strings(value, where: str) -> None:
    """Every text of an entry, keys included, free of ``FORBIDDEN_CATEGORIES``: the schema's
    own check refuses only ASCII controls, and a U+202E in a hardware line or a class name
    would reorder the table around it."""
    if isinstance(value, str):
        bad = hidden_character(value)
        if bad:
            raise EntryError(f"{where} has the control or format character {bad}")
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_strings(k, f"{where or 'entry'} key")
            _check_strings(v, f"{where}.{k}" if where else str(k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_strings(v, f"{where}[{i}]")


def check_link(value) -> str | None:
    """Only absolute http(s) URLs: a link is rendered into the page, so no javascript: etc."""
    if value is None:
        return None
    check_text(value, "link", 500)
    if not re.fullmatch(r"https?://[^\s\"'<>`]+", value):
        raise EntryError(f"link {value!r} is not an http:// or https:// URL")
    return value


def check_number(value, what: str, minimum: float = 0.0, optional: bool = False) -> float | None:
    if value is None and optional:
        return None
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or value < minimum
    ):
        raise EntryError(
            f"{what} must be a finite number >= {minimum:g}{' or null' * optional}, got {value!r}"
        )
    return float(value)


def check_metrics(m, what: str = "metrics") -> dict:
    """The ``metrics`` structure of the results JSON (``benchmark.scoring.schema``)."""
    try:
        return schema.check_metrics(m, what)
    except schema.SchemaError as exc:
        raise EntryError(str(exc)) from None


def _check_schema(check, *args) -> None:
    try:
        check(*args)
    except schema.SchemaError as exc:
        raise EntryError(str(exc)) from None


def _check_image(img, rows: int, cols: int, what: str) -> None:
    if not (
        isinstance(img, list)
        and len(img) == rows
        and all(isinstance(r, list) and len(r) == cols for r in img)
    ):
        raise EntryError(f"{what} must be a {rows} x {cols} list of lists")
    for r in img:
        for v in r:
            check_number(v, what, -1e9)


def check_sample(s) -> dict:
    """Downsampled dB images (aspect x range at one roll) of one test object."""
    if not isinstance(s, dict):
        raise EntryError("sample must be an object")
    for k in ("aspect_deg", "range_m"):
        if not isinstance(s.get(k), list) or not s[k]:
            raise EntryError(f"sample.{k} must be a non-empty list")
    shape = (len(s["aspect_deg"]), len(s["range_m"]))
    check_number(s.get("object_id"), "sample.object_id")
    check_text(s.get("class"), "sample.class", MAX_NAME)
    check_number(s.get("roll_deg"), "sample.roll_deg", -360.0)
    _check_image(s.get("physics_db"), *shape, "sample.physics_db")
    meshes = s.get("meshes")
    if not isinstance(meshes, list) or len(meshes) != 2:
        raise EntryError("sample.meshes must list the simple mesh and one complex mesh")
    for i, mesh in enumerate(meshes):
        if not isinstance(mesh, dict):
            raise EntryError(f"sample.meshes[{i}] must be an object")
        for k in ("mesh_uid", "variant", "n_faces"):
            check_number(mesh.get(k), f"sample.meshes[{i}].{k}")
        _check_image(mesh.get("predicted_db"), *shape, f"sample.meshes[{i}].predicted_db")
    return s


def validate_entry(entry) -> dict:
    """Raise EntryError unless ``entry`` is a complete, renderable entry."""
    if not isinstance(entry, dict):
        raise EntryError("an entry must be a JSON object")
    if entry.get("entry_version") != ENTRY_VERSION:
        raise EntryError(
            f"entry_version must be {ENTRY_VERSION}, got {entry.get('entry_version')!r}"
        )
    if entry.get("kind") not in KINDS:
        raise EntryError(f"kind must be one of {', '.join(KINDS)}")
    if entry.get("origin") is not None and entry["origin"] not in ORIGINS[entry["kind"]]:
        raise EntryError(
            f"origin of a {entry['kind']} entry must be one of {', '.join(ORIGINS[entry['kind']])}"
        )
    _check_strings(entry, "")
    if entry.get("track", "public") not in TRACKS:
        raise EntryError(f"track must be one of {', '.join(TRACKS)}")
    if entry["kind"] == "model" and (origin(entry) == "board") != (track(entry) == "heldout"):
        raise EntryError(
            "the held-out track holds only models the board ran (origin board), and they only it"
        )
    if not re.fullmatch(r"[a-z0-9][a-z0-9-]*", str(entry.get("id", ""))):
        raise EntryError("id must be lower-case letters, digits and dashes")
    check_text(entry.get("name"), "name", MAX_NAME)
    check_link(entry.get("link"))
    dataset = entry.get("dataset")
    if not isinstance(dataset, dict) or not re.fullmatch(
        r"[0-9a-f]{64}", str(dataset.get("fingerprint", ""))
    ):
        raise EntryError("dataset.fingerprint must be a sha256 hex digest")
    if not re.fullmatch(r"[0-9a-f]{64}", str(dataset.get("label_fingerprint", ""))):
        raise EntryError("dataset.label_fingerprint must be a sha256 hex digest")
    classes = dataset.get("classes")
    if (
        not isinstance(classes, list)
        or len(classes) > schema.MAX_CLASSES
        or not all(isinstance(c, str) and len(c) <= MAX_NAME for c in classes)
    ):
        raise EntryError("dataset.classes must be a list of class names")
    version = dataset.get("version")
    if version is not None and not re.fullmatch(r"[a-z0-9][a-z0-9.-]{0,39}", str(version)):
        raise EntryError("dataset.version must be a registered version name or null")
    if set(dataset) - {
        "fingerprint",
        "label_fingerprint",
        "version",
        "classes",
        "test_objects",
        "test_meshes",
    }:
        raise EntryError("dataset has unknown fields")
    unknown = sorted(str(k)[:40] for k in set(entry) - set(ENTRY_FIELDS))
    if unknown:
        raise EntryError(f"unknown field(s) {', '.join(unknown[:5])}")
    for k in ("test_objects", "test_meshes"):
        _check_schema(
            schema.Field("int", 0, schema.MAX_COUNT).check, dataset.get(k), f"dataset.{k}"
        )
    if "model" in entry:
        _check_schema(schema.check_fields, entry["model"], schema.MODEL, "model")
    check_metrics(entry.get("metrics"))
    _check_schema(schema.check_fields, entry.get("speed"), schema.SPEED, "speed", ("source",))
    if entry["speed"].get("source") is not None:
        check_text(entry["speed"]["source"], "speed.source")
    _check_schema(schema.MODEL["params"].check, entry.get("params"), "params")
    if not isinstance(entry.get("params_self_reported", False), bool):
        raise EntryError("params_self_reported must be true or false")
    if entry.get("seeds") is not None:
        _check_schema(schema.check_seeds, entry["seeds"])
    for k in ("benchmark_version", "complex_mse_source"):
        if entry.get(k) is not None:
            check_text(entry[k], k)
    files = entry.get("files", {})
    if (
        not isinstance(files, dict)
        or set(files) - set(FILE_HASHES)
        or not all(re.fullmatch(r"[0-9a-f]{64}", str(v)) for v in files.values())
    ):
        raise EntryError(f"files must map {'/'.join(FILE_HASHES)} to sha256 digests")
    if not re.fullmatch(r"\d{4}-\d\d-\d\d(T[\d:.]+Z)?", str(entry.get("submitted", ""))):
        raise EntryError("submitted must be an ISO date (YYYY-MM-DD or YYYY-MM-DDTHH:MM:SSZ)")
    if entry.get("sample") is not None:
        check_sample(entry["sample"])
    return entry


def read_regular(path: str | os.PathLike, max_bytes: int, error=EntryError) -> bytes:
    """The bytes of ``path`` if it is a regular file and not a symbolic link (opened with
    O_NOFOLLOW, so a link swapped in after a check is refused too; O_NONBLOCK, so a FIFO
    does not hang the read); at most ``max_bytes`` + 1 bytes."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        if os.path.islink(path):
            raise error(
                f"{path}: a symbolic link (never followed: it would publish its target)"
            ) from None
        raise error(f"{path}: {exc.strerror or exc.__class__.__name__}") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            raise error(f"{path}: not a regular file")
        try:
            return fh.read(max_bytes + 1)
        except OSError as exc:
            raise error(f"{path}: cannot read ({exc.strerror or exc})") from None


def load_entry(path: Path) -> dict:
    """One entry file, validated (bounded JSON, never through a symbolic link); EntryError
    naming the file."""
    try:
        raw = read_regular(path, ENTRY_MAX_BYTES)
        entry = validate_entry(
            load_json(raw, what=str(path), max_bytes=ENTRY_MAX_BYTES, error=EntryError)
        )
    except EntryError as exc:
        raise EntryError(str(exc) if str(exc).startswith(str(path)) else f"{path}: {exc}") from None
    if path.stem != entry["id"]:
        raise EntryError(f"{path}: file name does not match the entry id {entry['id']!r}")
    return entry


def load_entries(directory: str | os.PathLike = DEFAULT_ENTRIES, on_error=None) -> list[dict]:
    """Every ``*.json`` entry of ``directory``, validated, in file-name order.

    A bad entry (a symbolic link included: its target is not a reviewed entry) raises
    EntryError, or, with ``on_error``, is passed to ``on_error(message)`` and skipped: one
    broken file must not take the whole board down.
    """
    d = Path(directory)
    if not d.is_dir():
        raise EntryError(f"{d}: no such entries directory")
    entries = []
    names = sorted(n for n in os.listdir(d) if n.endswith(".json") and not n.startswith("."))
    for name in names:
        try:
            entries.append(load_entry(d / name))
        except EntryError as exc:
            if on_error is None:
                raise
            on_error(str(exc))
    return entries


@contextlib.contextmanager
def entries_lock(directory: str | os.PathLike):
    """Hold an exclusive lock on the entries folder (flock on the directory itself, so no lock
    file lands in the repository): a submission's duplicate check and its write are one step,
    and two concurrent submissions of the same predictions cannot both land. Creates the
    folder. Not reentrant: take it once per check-and-write."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    fd = os.open(d, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield d
    finally:
        os.close(fd)  # releases the lock


def origin(entry: dict) -> str:
    """The command that wrote ``entry``; an entry made before ``origin`` existed reads as
    ``submit`` (a model) or ``simulator``: the reading that claims the least."""
    return entry.get("origin") or ("simulator" if entry["kind"] == "simulator" else "submit")


def track(entry: dict) -> str:
    """``heldout`` (the ranked track) or ``public`` (self-scored; entries made before tracks)."""
    return entry.get("track") or "public"


def speed_self_reported(entry: dict) -> bool:
    """Whether the entry's ms per mesh is a claim the harness did not measure: always for
    ``submit`` (a predictions file is scored, no model is run), whatever its results JSON
    says; otherwise unless the entry says it was measured (``self_reported: false``)."""
    return origin(entry) == "submit" or entry["speed"].get("self_reported", True) is not False


def params_self_reported(entry: dict) -> bool:
    """Whether the parameter count is a claim the harness did not count (as for speed)."""
    return origin(entry) == "submit" or entry.get("params_self_reported", True) is not False


def dumps(entry: dict) -> str:
    """Readable, diff-friendly JSON: sorted keys, arrays of numbers kept on one line."""
    text = json.dumps(entry, indent=1, sort_keys=True, ensure_ascii=False, allow_nan=False)
    number = r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
    return (
        re.sub(
            rf"\[\s*((?:{number},\s*)*{number})\s*\]",
            lambda m: "[" + re.sub(r",\s*", ", ", m.group(1)) + "]",
            text,
        )
        + "\n"
    )


def write_entry(directory: str | os.PathLike, entry: dict, replace: bool = False) -> Path:
    """Validate and write ``<id>.json`` atomically; an existing id is refused unless ``replace``."""
    validate_entry(entry)
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"{entry['id']}.json"
    if path.exists() and not replace:
        raise EntryError(f"{path}: an entry with this id is already on the board")
    with atomic_path(path) as tmp:
        tmp.write_text(dumps(entry), encoding="utf-8")
    return path
