"""Entry files: one JSON file per accepted submission, the board's only source of truth.

Entries reach the repository by pull request, so ``render`` validates every file again: a
hand-edited entry with a non-http link, a missing number or a malformed sample is refused
with a one-line error naming the file, never rendered. The entry record (its fields, their
bounds and the rules between them) is declared once, in ``benchmark.scoring.schema``
(``ENTRY``, ``DATASET``, ``SAMPLE``, ``check_entry``); this module reads and writes it.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import stat
from pathlib import Path

from basic_shapes.infra import atomic_path, load_json
from benchmark.scoring import schema
from benchmark.scoring.schema import ENTRY_VERSION as ENTRY_VERSION  # the record's owner
from benchmark.scoring.schema import MAX_TEXT
from benchmark.scoring.schema import METRIC_NAMES as METRIC_NAMES

DEFAULT_ENTRIES = Path(__file__).resolve().parent / "entries"
ENTRY_MAX_BYTES = 4 << 20


class EntryError(ValueError):
    """An entry file (or a value bound for one) is malformed."""


def slug(text: str) -> str:
    """File-name-safe lower-case form of a model name."""
    s = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")
    return s[:40] or "model"


def _schema_check(check, *args):
    try:
        return check(*args)
    except schema.SchemaError as exc:
        raise EntryError(str(exc)) from None


def check_text(value, what: str, max_len: int = MAX_TEXT) -> str:
    """One printable line of at most ``max_len`` characters (a name, a label; as in entries)."""
    _schema_check(schema.Field("text", hi=max_len).check, value, what)
    return value


def check_link(value) -> str | None:
    """Only absolute http(s) URLs: a link is rendered into the page, so no javascript: etc."""
    _schema_check(schema.ENTRY["link"].check, value, "link")
    return value


def check_metrics(m, what: str = "metrics") -> dict:
    """The ``metrics`` structure of the results JSON (``benchmark.scoring.schema``)."""
    return _schema_check(schema.check_metrics, m, what)


def dataset_record(data, **version) -> dict:
    """The ``dataset`` block of an entry (``schema.DATASET``) for an open ``BenchmarkData``;
    ``version=`` the registered version name (or None) where the command knows it."""
    return {
        "fingerprint": data.fingerprint,
        "label_fingerprint": data.label_fingerprint,
        **version,
        "classes": data.class_names,
        "test_objects": len(data.object_rows("test")),
        "test_meshes": len(data.mesh_rows("test")),
    }


def validate_entry(entry) -> dict:
    """Raise EntryError unless ``entry`` is a complete, renderable entry
    (``benchmark.scoring.schema.check_entry``)."""
    return _schema_check(schema.check_entry, entry)


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
