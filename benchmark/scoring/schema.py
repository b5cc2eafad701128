"""The records' one owner: the results JSON (``RESULTS``), its metrics blocks, and the
leaderboard entry (``ENTRY``, with its ``DATASET`` and ``SAMPLE`` blocks) as tables of fields,
checked by one function (``check_fields``) for ``scoring.protocol`` (results JSON) and
``leaderboard.store`` (entries), so that what `evaluate` writes and what `submit` and `render`
accept cannot drift apart. The metric names are declared here and imported everywhere else.

Results and entries are untrusted: every number must be finite and inside a documented range
(docs/BENCHMARK.md, "Results JSON"), every text one printable line of bounded length with no
control or format character (a bidi override would reorder the board around it), and a field
not in the table is refused (never copied onto the board). To add a field, add a row to the
table it belongs to.
"""

from __future__ import annotations

import datetime
import math
import re
import unicodedata
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from basic_shapes.shards import OOD_REMESHERS

MAX_MSE = 1e6  # dB²; the -80 dB floor bounds an honest MSE near 6400 dB²
MAX_PARAMS = 10**12  # parameters of a model
MAX_COUNT = 10**9  # objects or meshes
MAX_MS = 1e9  # milliseconds per mesh
MAX_TEXT = 200
MAX_NAME = 80
MAX_CLASSES = 64
MAX_SEEDS = 16
MAX_EPOCHS = 10_000  # epochs in a training curve


class SchemaError(ValueError):
    """A record breaks the schema (the message names the field)."""


# Unicode categories refused in any text of a record: controls (Cc), format characters such as
# the bidi override U+202E or zero-width spaces (Cf), line and paragraph separators (Zl, Zp)
# and lone surrogates (Cs, not encodable): they reorder or hide what the board shows.
FORBIDDEN_CATEGORIES = frozenset({"Cc", "Cf", "Zl", "Zp", "Cs"})


def hidden_character(text: str) -> str | None:
    """The first character of ``text`` that is invisible or reorders text (a control, a bidi
    override, a zero-width or line separator), as ``U+XXXX``; None if there is none."""
    for c in text:
        if unicodedata.category(c) in FORBIDDEN_CATEGORIES:
            return f"U+{ord(c):04X}"
    return None


def check_hidden(value, where: str = "", top: str = "the record") -> None:
    """Every text in ``value`` (a parsed JSON record; ``top`` names it where ``where`` is
    empty), keys included, free of ``FORBIDDEN_CATEGORIES``; run before the fields are
    checked, so that no error message echoes such a character (an unknown key is named in
    one)."""
    if isinstance(value, str):
        bad = hidden_character(value)
        if bad:
            raise SchemaError(f"{where or top} has the control or format character {bad}")
    elif isinstance(value, dict):
        for k, v in value.items():
            check_hidden(k, f"{where or top} key", top)
            check_hidden(v, f"{where}.{k}" if where else str(k), top)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            check_hidden(v, f"{where}[{i}]", top)


def _shown(value) -> str:
    """A refused value as an error message may quote it: ASCII-escaped, bounded."""
    try:
        text = ascii(value)
    except ValueError:  # an int past Python's digit limit for str()
        return "an integer too long to show"
    return text if len(text) <= 40 else text[:37] + "..."


@dataclass(frozen=True)
class Field:
    """One field: its kind, its range or length, whether null is allowed and whether it may be
    absent. Kinds:

    - "number", "int": finite, in [lo, hi];
    - "bool";
    - "text": one printable line of at most ``hi`` characters, with no control or format
      character; "hex64" (a sha256 hex digest), "time" (``2026-01-31T12:00:00Z``) and "url"
      (http or https) are texts too;
    - "interval": a [lo, hi] pair of numbers in the range with lo <= hi;
    - "list": a list of ``lo``..``hi`` values, each an ``item`` field;
    - "record": an object checked by ``check_fields`` against ``table``, or by ``checker``
      (a nested block with rules of its own, e.g. ``check_metrics``).

    ``choices`` limits a value to a few (a text or an int); ``pattern`` (a regular expression
    the whole text must match) is described by ``what`` in the error message."""

    kind: str
    lo: float = 0
    hi: float = math.inf
    null: bool = False
    required: bool = True
    choices: tuple = ()
    pattern: str | None = None
    what: str = ""
    item: Field | None = field(default=None, compare=False)
    table: dict | None = field(default=None, compare=False, hash=False)
    checker: Callable | None = field(default=None, compare=False)

    def check(self, value, where: str) -> None:
        if value is None:
            if not self.null:
                raise SchemaError(f"{where} is missing or null")
            return
        if self.kind in ("number", "int"):
            self._check_number(value, where)
        elif self.kind == "interval":
            self._check_interval(value, where)
        elif self.kind == "bool":
            if not isinstance(value, bool):
                raise SchemaError(f"{where} must be true or false")
        elif self.kind == "list":
            if not isinstance(value, list) or not self.lo <= len(value) <= self.hi:
                raise SchemaError(
                    f"{where} must be {self.what or f'a list of {self.lo:g} to {self.hi:g} values'}"
                )
            for i, x in enumerate(value):
                self.item.check(x, f"{where}[{i}]")
        elif self.kind == "record":
            if self.checker is not None:
                self.checker(value, where)
            else:
                check_fields(value, self.table, where)
        else:
            self._check_text(value, where)
        if self.choices and value not in self.choices:
            raise SchemaError(
                f"{where} must be one of {', '.join(map(str, self.choices))}, got {_shown(value)}"
            )

    def _check_number(self, value, where: str) -> None:
        is_int = isinstance(value, int) and not isinstance(value, bool)
        if not (is_int or (self.kind == "number" and isinstance(value, float))):
            what = "an integer" if self.kind == "int" else "a number"
            raise SchemaError(f"{where} must be {what}, got {_shown(value)}")
        if (not is_int and not math.isfinite(value)) or not self.lo <= value <= self.hi:
            raise SchemaError(
                f"{where} must be a finite number in [{self.lo:g}, {self.hi:g}], "
                f"got {_shown(value)}"
            )

    def _check_interval(self, value, where: str) -> None:
        if not (isinstance(value, list) and len(value) == 2):
            raise SchemaError(f"{where} must be an interval [lo, hi]")
        for k, x in enumerate(value):
            Field("number", self.lo, self.hi).check(x, f"{where}[{k}]")
        if value[0] > value[1]:
            raise SchemaError(f"{where} must have lo <= hi")

    def _check_text(self, value, where: str) -> None:
        bad = hidden_character(value) if isinstance(value, str) else None
        if not isinstance(value, str) or not value.strip() or len(value) > self.hi or bad:
            raise SchemaError(
                f"{where} must be one printable line of at most {self.hi:g} characters"
                + (f" (has the control or format character {bad})" if bad else "")
            )
        if self.pattern is not None and not re.fullmatch(self.pattern, value):
            raise SchemaError(f"{where} must be {self.what}{' or null' * self.null}")
        if self.kind == "hex64" and not re.fullmatch(r"[0-9a-f]{64}", value):
            raise SchemaError(f"{where} is not a sha256 hex digest")
        if self.kind == "url" and not re.fullmatch(r"https?://[^\s\"'<>`]+", value):
            raise SchemaError(f"{where} {value!r} is not an http:// or https:// URL")
        if self.kind == "time":
            try:
                datetime.datetime.strptime(value, "%Y-%m-%dT%H:%M:%SZ")
            except ValueError:
                raise SchemaError(
                    f"{where} is not a UTC timestamp like 2026-01-31T12:00:00Z"
                ) from None


def mse(null: bool = True) -> Field:
    return Field("number", 0, MAX_MSE, null=null)


def interval(lo: float = 0, hi: float = MAX_MSE) -> Field:
    return Field("interval", lo, hi, null=True, required=False)


# --- the tables ----------------------------------------------------------------------------
METRIC_NAMES = ("simple_mse", "complex_mse", "variation_mse")
OOD_METRIC_NAMES = ("ood_complex_mse", "ood_variation_mse")  # absent in older records
# secondary, peak-relative: bins within PEAK_WINDOW_DB of each target profile's peak
PEAK_METRIC_NAMES = ("peak_simple_mse", "peak_complex_mse")  # absent in older records
OOD_FIELDS = {
    **{
        name: Field("number", 0, MAX_MSE, null=True, required=False)
        for name in OOD_METRIC_NAMES + PEAK_METRIC_NAMES
    },
    **{name + "_ci": interval() for name in OOD_METRIC_NAMES + PEAK_METRIC_NAMES},
}
METRIC_BLOCK = {  # overall, per class and per reference row; intervals absent in old entries
    "simple_mse": mse(null=False),
    "complex_mse": mse(),
    "variation_mse": mse(),
    **{name + "_ci": interval() for name in METRIC_NAMES},
    **OOD_FIELDS,
    "n_objects": Field("int", 1, MAX_COUNT),
}
REMESHER_BLOCK = {**OOD_FIELDS, "n_objects": Field("int", 1, MAX_COUNT)}  # per_remesher
METRICS = {  # overall only, besides METRIC_BLOCK, per_class, no_skill_test, references, skill
    "no_skill": Field("bool", null=True, required=False),
    "mode_collapse": Field("bool", required=False),  # entries made before no_skill replaced it
    "spread_ratio": Field("number", 0, MAX_MSE, null=True, required=False),
    "n_meshes": Field("int", 1, MAX_COUNT, required=False),
}
NO_SKILL_TEST = {  # benchmark.scoring.metrics.skill_test
    "gain_vs_train_mean": Field("number", -MAX_MSE, MAX_MSE),
    "gain_vs_train_mean_ci": interval(-MAX_MSE, MAX_MSE),
    "truth_spread": Field("number", 0, MAX_MSE),
    "prediction_spread": Field("number", 0, MAX_MSE),
    "co_spread": Field("number", -MAX_MSE, MAX_MSE),
    "correlation": Field("number", -1 - 1e-9, 1 + 1e-9),
}
REFERENCE_NAMES = ("train-mean", "class-mean", "nearest-scale", "class-scale-nn")
REFERENCE = {**METRIC_BLOCK, "no_skill": Field("bool", null=True)}  # benchmark.scoring.references
COMPARISON = {  # benchmark.scoring.references.compare, one metric
    "diff": Field("number", -MAX_MSE, MAX_MSE),
    "ci": interval(-MAX_MSE, MAX_MSE),
    "half_width": Field("number", 0, MAX_MSE, null=True),
    "skill": Field("number", -MAX_MSE, 1, null=True),
    "verdict": Field("text", hi=20),
}
VERDICTS = ("holds", "reversed", "inconclusive")
SKILL = {
    "reference": Field("text", hi=MAX_NAME),
    "explained_by_class": Field("bool"),
}
MODEL = {
    "name": Field("text", hi=MAX_NAME),
    "params": Field("int", 0, MAX_PARAMS, null=True, required=False),
    "embedding": Field("text", hi=MAX_NAME, null=True, required=False),
    "regime": Field("text", hi=MAX_NAME, null=True, required=False),
}
SPEED = {  # scoring.evaluate.speed_block; the machine fields are absent when self-reported
    "ms_per_mesh": Field("number", 0, MAX_MS, null=True),
    "hardware": Field("text", hi=MAX_TEXT, null=True),
    "cpu": Field("text", hi=MAX_TEXT, null=True, required=False),
    "threads": Field("int", 1, 1 << 16, null=True, required=False),
    "load_avg_1m": Field("number", 0, 1e6, null=True, required=False),
    "gpu": Field("text", hi=MAX_TEXT, null=True, required=False),
    "self_reported": Field("bool", required=False),
}
RESULTS = {
    "benchmark_version": Field("text", hi=40),
    "dataset_fingerprint": Field("hex64"),
    "label_fingerprint": Field("hex64"),
    "created": Field("time"),
}
SEED = Field("int", 0, 2**64 - 1, null=True)


def check_fields(
    record,
    table: dict[str, Field],
    where: str,
    extra: tuple[str, ...] = (),
    top: str = "the record",
) -> None:
    """``record`` (at dotted path ``where``; "" for the top level, named ``top`` in messages)
    must be an object holding the table's fields (and ``extra`` names) only."""
    if not isinstance(record, dict):
        raise SchemaError(f"{where or top} must be a JSON object")
    unknown = sorted(ascii(str(k))[1:-1][:40] for k in set(record) - set(table) - set(extra))
    if unknown:
        known = [*table, *extra]
        hint = f" (known: {', '.join(known)})" if len(known) <= 8 else ""
        raise SchemaError(f"{where or top} has unknown field(s) {', '.join(unknown[:5])}{hint}")
    for name, spec in table.items():
        if name not in record and not spec.required:
            continue
        spec.check(record.get(name), f"{where}.{name}" if where else name)


def check_metrics(m, where: str = "metrics") -> dict:
    """The metrics block of a results record or an entry (``benchmark.scoring.protocol.score``)."""
    check_fields(
        m,
        {**METRIC_BLOCK, **METRICS},
        where,
        extra=("per_class", "no_skill_test", "references", "skill", "per_remesher"),
    )
    if m.get("no_skill_test") is not None:
        check_fields(m["no_skill_test"], NO_SKILL_TEST, f"{where}.no_skill_test")
    if "references" in m:
        refs = m["references"]
        if not isinstance(refs, dict) or set(refs) - set(REFERENCE_NAMES):
            raise SchemaError(f"{where}.references must map {', '.join(REFERENCE_NAMES)} to rows")
        for name, block in refs.items():
            check_fields(block, REFERENCE, f"{where}.references.{name}", extra=("per_remesher",))
            if "per_remesher" in block:
                check_per_remesher(block["per_remesher"], f"{where}.references.{name}.per_remesher")
    if "skill" in m:
        check_skill(m["skill"], f"{where}.skill")
    if "per_remesher" in m:
        check_per_remesher(m["per_remesher"], f"{where}.per_remesher")
    if "n_meshes" in m and m["n_meshes"] < m["n_objects"]:
        raise SchemaError(f"{where}.n_meshes must be at least n_objects")
    per_class = m.get("per_class")
    if not isinstance(per_class, dict) or not per_class or len(per_class) > MAX_CLASSES:
        raise SchemaError(f"{where}.per_class must be an object of 1..{MAX_CLASSES} classes")
    for name, block in per_class.items():
        Field("text", hi=MAX_NAME).check(name, f"{where}.per_class key")
        check_fields(block, METRIC_BLOCK, f"{where}.per_class.{name}")
    return m


def check_per_remesher(pr, where: str = "per_remesher") -> dict:
    """OOD metrics per remesher (``benchmark.scoring.metrics.per_remesher``)."""
    if not isinstance(pr, dict) or set(pr) - set(OOD_REMESHERS):
        raise SchemaError(f"{where} must map some of {', '.join(OOD_REMESHERS)} to rows")
    for name, block in pr.items():
        check_fields(block, REMESHER_BLOCK, f"{where}.{name}")
    return pr


def check_skill(sk, where: str = "skill") -> dict:
    """``scoring.references.skill``: paired comparisons with the strongest reference and with
    the class mean, per metric."""
    check_fields(sk, SKILL, where, extra=("vs_reference", "vs_class_mean"))
    if sk["reference"] not in REFERENCE_NAMES:
        raise SchemaError(f"{where}.reference must be one of {', '.join(REFERENCE_NAMES)}")
    for part in ("vs_reference", "vs_class_mean"):
        block = sk.get(part)
        if not isinstance(block, dict) or set(block) - set(METRIC_NAMES[:2]):
            raise SchemaError(f"{where}.{part} must map simple_mse/complex_mse to comparisons")
        for metric, comp in block.items():
            check_fields(comp, COMPARISON, f"{where}.{part}.{metric}")
            if comp["verdict"] not in VERDICTS:
                raise SchemaError(
                    f"{where}.{part}.{metric}.verdict must be one of {', '.join(VERDICTS)}"
                )
    return sk


def check_seeds(seeds, where: str = "seeds") -> dict:
    """Seed names to a seed, null, or a list of seeds (``train_all``: every training seed)."""
    if not isinstance(seeds, dict) or len(seeds) > MAX_SEEDS:
        raise SchemaError(f"{where} must be an object of at most {MAX_SEEDS} seeds")
    for name, value in seeds.items():
        Field("text", hi=40).check(name, f"{where} key")
        if isinstance(value, list):
            if not value or len(value) > MAX_SEEDS:
                raise SchemaError(f"{where}.{name} must list 1..{MAX_SEEDS} seeds")
            for k, v in enumerate(value):
                Field("int", 0, 2**64 - 1).check(v, f"{where}.{name}[{k}]")
        else:
            SEED.check(value, f"{where}.{name}")
    return seeds


TRAINING = {  # per training seed, in the order of seeds.train_all (or [seeds.train])
    "val_curves": Field(  # validation MSE (dB²) after each epoch; null where not kept
        "list", 1, MAX_SEEDS, item=Field("list", 1, MAX_EPOCHS, item=mse(False), null=True)
    ),
    "epochs_to_plateau": Field(  # epochs up to the selected (best) one
        "list", 1, MAX_SEEDS, item=Field("int", 1, MAX_EPOCHS, null=True)
    ),
    "capped": Field("list", 1, MAX_SEEDS, item=Field("bool", null=True)),  # still improving
}


def check_training(t, where: str = "training") -> dict:
    """``TRAINING``: one value per seed in every list, each selected epoch on its curve."""
    check_fields(t, TRAINING, where)
    if len({len(v) for v in t.values()}) != 1:
        raise SchemaError(f"{where}: {', '.join(TRAINING)} must list the same seeds")
    for k, (curve, best) in enumerate(zip(t["val_curves"], t["epochs_to_plateau"])):
        if curve is not None and best is not None and best > len(curve):
            raise SchemaError(f"{where}.epochs_to_plateau[{k}] is past the end of its curve")
    return t


PER_OBJECT_OOD = OOD_METRIC_NAMES + tuple(
    f"{m}:{r}" for r in OOD_REMESHERS for m in OOD_METRIC_NAMES
)  # metrics.ood_keys


def check_per_object(po, n_objects: int, where: str = "per_object") -> dict:
    """Per-object errors (what paired comparisons resample): equal-length lists, one entry per
    scored test object; errors may be null where an object has no complex (OOD) meshes. The
    OOD lists (overall and ``metric:remesher``) and the peak-relative lists each come all
    together or not at all (older records)."""
    keys = ("object_id", "class_index", *METRIC_NAMES)
    for group in (PER_OBJECT_OOD, PEAK_METRIC_NAMES):
        if isinstance(po, dict) and set(group) & set(po):
            keys += group
    if not isinstance(po, dict) or set(po) != set(keys):
        raise SchemaError(f"{where} must hold exactly {', '.join(keys)}")
    for k in keys:
        if not isinstance(po[k], list) or len(po[k]) != n_objects:
            raise SchemaError(f"{where}.{k} must be a list of {n_objects} values")
    for k in ("object_id", "class_index"):
        for i, v in enumerate(po[k]):
            Field("int", 0, 2**63 - 1).check(v, f"{where}.{k}[{i}]")
    for k in keys[2:]:
        for i, v in enumerate(po[k]):
            Field("number", 0, MAX_MSE, null=k != "simple_mse").check(v, f"{where}.{k}[{i}]")
    return po


def check_results(r, source: str = "results") -> dict:
    """A whole results record (docs/ARCHITECTURE.md, "Results JSON"); errors name ``source``."""
    try:
        extra = ("model", "metrics", "speed", "seeds", "per_object", "training")
        check_fields(r, RESULTS, "", extra=extra)
        check_fields(r.get("model"), MODEL, "model")
        check_metrics(r.get("metrics"), "metrics")
        if "per_object" in r:
            check_per_object(r["per_object"], r["metrics"]["n_objects"], "per_object")
        check_fields(r.get("speed"), SPEED, "speed")
        check_seeds(r.get("seeds"), "seeds")
        if "training" in r:
            check_training(r["training"], "training")
    except SchemaError as exc:
        raise SchemaError(f"{source}: {exc}") from None
    return r


# --- the leaderboard entry (leaderboard/store.py reads and writes it) ------------------------
ENTRY_VERSION = 1
KINDS = ("model", "simulator")
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
# predictions_content_sha256 covers the data scored (``benchmark.scoring.protocol.content_sha256``);
# predictions_sha256 is the container's, kept for entries made before it existed;
# onnx_sha256: the model file a held-out entry's numbers were measured with (evaluate-model)
FILE_HASHES = ("results_sha256", "predictions_sha256", "predictions_content_sha256", "onnx_sha256")
MAX_LINK = 500
MAX_SAMPLE_SIDE = 1024  # points per axis of a sample image (leaderboard.example keeps <= 32)
MAX_DB = 1e9  # |dB| of a sample image value; the -80 dB floor bounds honest ones
MAX_ID = 2**63 - 1

DATASET = {  # the dataset an entry was scored on
    "fingerprint": Field("hex64"),
    "label_fingerprint": Field("hex64"),
    "version": Field(
        "text",
        hi=40,
        pattern=r"[a-z0-9][a-z0-9.-]*",
        what="a registered version name",
        null=True,
        required=False,
    ),
    "classes": Field(
        "list", hi=MAX_CLASSES, item=Field("text", hi=MAX_NAME), what="a list of class names"
    ),
    "test_objects": Field("int", 0, MAX_COUNT),
    "test_meshes": Field("int", 0, MAX_COUNT),
}
IMAGE = Field(  # aspect x range, dB; its shape is checked against the axes by check_sample
    "list",
    1,
    MAX_SAMPLE_SIDE,
    item=Field("list", 1, MAX_SAMPLE_SIDE, item=Field("number", -MAX_DB, MAX_DB)),
)
SAMPLE_MESH = {  # one of the two meshes of a sample, with this model's prediction for it
    "mesh_uid": Field("int", 0, MAX_ID),
    "variant": Field("int", 0, MAX_COUNT),
    "n_faces": Field("int", 0, MAX_COUNT),
    "predicted_db": IMAGE,
}
SAMPLE = {  # leaderboard.example.sample: downsampled dB images of the example test object
    "object_id": Field("int", 0, MAX_ID),
    "class": Field("text", hi=MAX_NAME),
    "roll_deg": Field("number", -360, 360),
    "aspect_deg": Field("list", 1, MAX_SAMPLE_SIDE, item=Field("number", -360, 360)),
    "range_m": Field("list", 1, MAX_SAMPLE_SIDE, item=Field("number", -1e6, 1e6)),
    "physics_db": IMAGE,
    "meshes": Field(
        "list",
        2,
        2,
        item=Field("record", table=SAMPLE_MESH),
        what="a list of the simple mesh and one complex mesh",
    ),
}


def check_sample(s, where: str = "sample") -> dict:
    """``SAMPLE``, and every image as many rows as aspects and columns as range bins."""
    check_fields(s, SAMPLE, where)
    shape = (len(s["aspect_deg"]), len(s["range_m"]))
    images = [("physics_db", s["physics_db"])] + [
        (f"meshes[{i}].predicted_db", m["predicted_db"]) for i, m in enumerate(s["meshes"])
    ]
    for name, img in images:
        if (len(img), *{len(row) for row in img}) != shape:
            raise SchemaError(f"{where}.{name} must be a {shape[0]} x {shape[1]} list of lists")
    return s


ENTRY = {  # one file of leaderboard/entries (leaderboard/entries/README.md)
    "entry_version": Field("int", choices=(ENTRY_VERSION,)),
    "id": Field(
        "text",
        hi=MAX_NAME,
        pattern=r"[a-z0-9][a-z0-9-]*",
        what="lower-case letters, digits and dashes",
    ),
    "kind": Field("text", choices=KINDS),
    "origin": Field(  # per kind: check_entry
        "text", choices=tuple(o for k in KINDS for o in ORIGINS[k]), null=True, required=False
    ),
    "track": Field("text", choices=TRACKS, required=False),
    "name": Field("text", hi=MAX_NAME),
    "link": Field("url", hi=MAX_LINK, null=True, required=False),
    "model": Field("record", table=MODEL, required=False),
    "params": MODEL["params"],
    "params_self_reported": Field("bool", required=False),
    "benchmark_version": replace(RESULTS["benchmark_version"], null=True, required=False),
    "dataset": Field("record", table=DATASET),
    "metrics": Field("record", checker=check_metrics),
    "speed": Field(
        "record", table={**SPEED, "source": Field("text", hi=MAX_TEXT, null=True, required=False)}
    ),
    "seeds": Field("record", checker=check_seeds, null=True, required=False),
    "training": Field("record", checker=check_training, required=False),
    "created": replace(RESULTS["created"], null=True, required=False),
    "submitted": Field("time"),  # UTC time of acceptance
    "files": Field(
        "record",
        table={name: Field("hex64", required=False) for name in FILE_HASHES},
        required=False,
    ),
    "sample": Field("record", checker=check_sample, null=True, required=False),
    "complex_mse_source": Field("text", hi=MAX_TEXT, null=True, required=False),  # simulator
}


def check_entry(e) -> dict:
    """A whole leaderboard entry: ``ENTRY``, no hidden character in any text (keys included),
    and the rules between fields: an origin allowed for the entry's kind, and the held-out
    track holding exactly the models the board ran."""
    if not isinstance(e, dict):
        raise SchemaError("an entry must be a JSON object")
    check_hidden(e, "", top="the entry")
    check_fields(e, ENTRY, "", top="the entry")
    kind, origin, track = e["kind"], e.get("origin"), e.get("track", "public")
    if origin is not None and origin not in ORIGINS[kind]:
        raise SchemaError(f"origin of a {kind} entry must be one of {', '.join(ORIGINS[kind])}")
    if kind == "model" and (origin == "board") != (track == "heldout"):
        raise SchemaError(
            "the held-out track holds only models the board ran (origin board), and they only it"
        )
    return e
