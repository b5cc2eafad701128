"""The results and metrics schema: one table of fields, used by ``benchmark.protocol`` (results
JSON) and ``leaderboard.store`` (entries), so that what `evaluate` writes and what `submit` and
`render` accept cannot drift apart.

Results and entries are untrusted: every number must be finite and inside a documented range
(docs/BENCHMARK.md, "Results JSON"), every text one printable line of bounded length, and a
field not in the table is refused (never copied onto the board). To add a field, add a row
to the table it belongs to.
"""

from __future__ import annotations

import datetime
import math
import re
from dataclasses import dataclass

MAX_MSE = 1e6          # dB²; the -80 dB floor bounds an honest MSE near 6400 dB²
MAX_PARAMS = 10**12    # parameters of a model
MAX_COUNT = 10**9      # objects or meshes
MAX_MS = 1e9           # milliseconds per mesh
MAX_TEXT = 200
MAX_NAME = 80
MAX_CLASSES = 64
MAX_SEEDS = 16


class SchemaError(ValueError):
    """A record breaks the schema (the message names the field)."""


@dataclass(frozen=True)
class Field:
    """One field: its kind ("number", "int", "bool", "text", "hex64", "time"), its range or
    length, whether null is allowed and whether it may be absent."""

    kind: str
    lo: float = 0
    hi: float = math.inf
    null: bool = False
    required: bool = True

    def check(self, value, where: str) -> None:
        if value is None:
            if not self.null:
                raise SchemaError(f"{where} is missing or null")
            return
        if self.kind in ("number", "int"):
            is_int = isinstance(value, int) and not isinstance(value, bool)
            if not (is_int or (self.kind == "number" and isinstance(value, float))):
                what = "an integer" if self.kind == "int" else "a number"
                raise SchemaError(f"{where} must be {what}")
            if (not is_int and not math.isfinite(value)) or not self.lo <= value <= self.hi:
                raise SchemaError(f"{where} must be a finite number in [{self.lo:g}, {self.hi:g}]")
        elif self.kind == "bool":
            if not isinstance(value, bool):
                raise SchemaError(f"{where} must be true or false")
        else:
            if not isinstance(value, str) or not value.strip() or len(value) > self.hi \
                    or any(ord(c) < 32 for c in value):
                raise SchemaError(f"{where} must be one printable line of at most "
                                  f"{self.hi:g} characters")
            if self.kind == "hex64" and not re.fullmatch(r"[0-9a-f]{64}", value):
                raise SchemaError(f"{where} is not a sha256 hex digest")
            if self.kind == "time":
                try:
                    datetime.datetime.strptime(value, "%Y-%m-%dT%H:%M:%SZ")
                except ValueError:
                    raise SchemaError(f"{where} is not a UTC timestamp like "
                                      f"2026-01-31T12:00:00Z") from None


def mse(null: bool = True) -> Field:
    return Field("number", 0, MAX_MSE, null=null)


# --- the tables ----------------------------------------------------------------------------
METRIC_BLOCK = {  # overall and per class
    "simple_mse": mse(null=False),
    "complex_mse": mse(),
    "variation_mse": mse(),
    "n_objects": Field("int", 1, MAX_COUNT),
}
METRICS = {  # overall only, besides METRIC_BLOCK and per_class
    "mode_collapse": Field("bool"),
    "spread_ratio": Field("number", 0, MAX_MSE, null=True, required=False),
    "n_meshes": Field("int", 1, MAX_COUNT, required=False),
}
MODEL = {
    "name": Field("text", hi=MAX_NAME),
    "params": Field("int", 0, MAX_PARAMS, null=True, required=False),
    "embedding": Field("text", hi=MAX_NAME, null=True, required=False),
    "regime": Field("text", hi=MAX_NAME, null=True, required=False),
}
SPEED = {
    "ms_per_mesh": Field("number", 0, MAX_MS, null=True),
    "hardware": Field("text", hi=MAX_TEXT, null=True),
}
RESULTS = {
    "benchmark_version": Field("text", hi=40),
    "dataset_fingerprint": Field("hex64"),
    "created": Field("time"),
}
SEED = Field("int", 0, 2**64 - 1, null=True)


def check_fields(record, table: dict[str, Field], where: str, extra: tuple[str, ...] = ()) -> None:
    """``record`` (at dotted path ``where``; "" for the top level) must be an object holding
    the table's fields (and ``extra`` names) only."""
    if not isinstance(record, dict):
        raise SchemaError(f"{where or 'the record'} must be a JSON object")
    unknown = sorted(str(k)[:40] for k in set(record) - set(table) - set(extra))
    if unknown:
        raise SchemaError(f"{where or 'the record'} has unknown field(s) {', '.join(unknown[:5])}")
    for name, spec in table.items():
        if name not in record and not spec.required:
            continue
        spec.check(record.get(name), f"{where}.{name}" if where else name)


def check_metrics(m, where: str = "metrics") -> dict:
    """The metrics block of a results record or an entry (``Scorer.result``)."""
    check_fields(m, {**METRIC_BLOCK, **METRICS}, where, extra=("per_class",))
    if "n_meshes" in m and m["n_meshes"] < m["n_objects"]:
        raise SchemaError(f"{where}.n_meshes must be at least n_objects")
    per_class = m.get("per_class")
    if not isinstance(per_class, dict) or not per_class or len(per_class) > MAX_CLASSES:
        raise SchemaError(f"{where}.per_class must be an object of 1..{MAX_CLASSES} classes")
    for name, block in per_class.items():
        Field("text", hi=MAX_NAME).check(name, f"{where}.per_class key")
        check_fields(block, METRIC_BLOCK, f"{where}.per_class.{name}")
    return m


def check_seeds(seeds, where: str = "seeds") -> dict:
    if not isinstance(seeds, dict) or len(seeds) > MAX_SEEDS:
        raise SchemaError(f"{where} must be an object of at most {MAX_SEEDS} seeds")
    for name, value in seeds.items():
        Field("text", hi=40).check(name, f"{where} key")
        SEED.check(value, f"{where}.{name}")
    return seeds


def check_results(r, source: str = "results") -> dict:
    """A whole results record (docs/ARCHITECTURE.md, "Results JSON"); errors name ``source``."""
    try:
        check_fields(r, RESULTS, "", extra=("model", "metrics", "speed", "seeds"))
        check_fields(r.get("model"), MODEL, "model")
        check_metrics(r.get("metrics"), "metrics")
        check_fields(r.get("speed"), SPEED, "speed")
        check_seeds(r.get("seeds"), "seeds")
    except SchemaError as exc:
        raise SchemaError(f"{source}: {exc}") from None
    return r
