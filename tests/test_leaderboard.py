"""leaderboard: submissions are re-scored by the real benchmark scorer, refused unless they agree.

The test dataset is written with ``basic_shapes.shards.write_shard`` from trimesh meshes (three
classes; each object has a simple mesh and two complex meshes of the same shape) and carries an
analytic /radar label, so that the expected metrics are known exactly: a prediction equal to the
label's dB target plus a per-class offset ``s`` (simple mesh) or ``c`` (complex meshes) has
Simple MSE s^2, Complex MSE c^2 and Variation MSE (s - c)^2. The label's magnitude never drops
below 1e-3, so the benchmark's -80 dB floor never clips it. Every mesh also gets the physics on
it (/radar/mesh_response): the object's label raised by ``SIMPLE_DB`` decibels on the simple mesh
and by ``VARIANT_DB`` on complex meshes, so the simulator-on-the-mesh point has Simple MSE
SIMPLE_DB^2, Complex MSE VARIANT_DB^2 and Variation MSE (VARIANT_DB - SIMPLE_DB)^2.
"""

from __future__ import annotations

import json
import re
import shutil
import struct
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh

from basic_shapes.shards import (
    MeshRecord,
    ObjectRecord,
    dataset_fingerprint,
    label_fingerprint,
    mesh_uid,
    rewrite_atomically,
    write_radar,
    write_shard,
)
from benchmark.scoring import versions
from leaderboard import cli, store
from leaderboard.submit import REL_TOL

CLASSES = ["cube", "cylinder", "sphere"]
ASPECT = np.linspace(0.0, 180.0, 9)
ROLL = np.array([0.0, 90.0, 180.0, 270.0])
RANGE = np.linspace(-1.0, 1.0, 20)
OFFSETS = {"cube": (1.0, 3.0), "cylinder": (2.0, 5.0), "sphere": (0.5, 4.0)}  # (simple, complex) dB
VARIANT_DB = 0.5
SIMPLE_DB = 0.25
TEST_OBJECTS = (1, 2, 4, 5, 7, 8)  # two per class; objects 0, 3, 6 are training objects


def _meshes(cls: str, scale: np.ndarray) -> list[trimesh.Trimesh]:
    if cls == "cube":
        base = trimesh.creation.box()
        out = [base, base.subdivide(), base.subdivide().subdivide()]
    elif cls == "cylinder":
        out = [trimesh.creation.cylinder(0.5, 1.0, sections=n) for n in (16, 24, 32)]
    else:
        out = [trimesh.creation.icosphere(n, radius=0.5) for n in (1, 2, 3)]
    for m in out:
        m.apply_scale(scale)
    return out


def response(scale: np.ndarray, object_id: int) -> np.ndarray:
    """Analytic range profiles (aspect, roll, range): a peak at the projected half-extent."""
    th = np.radians(ASPECT)[:, None, None]
    ph = np.radians(ROLL)[None, :, None]
    r = RANGE[None, None, :]
    centre = 0.5 * (
        scale[0] * np.sin(th) * np.cos(ph)
        + scale[1] * np.sin(th) * np.sin(ph)
        + scale[2] * np.cos(th)
    )
    amp = np.linalg.norm(scale) * (1 + np.cos(th) ** 2) * np.exp(-(((r + centre) / 0.15) ** 2))
    return ((1e-3 + amp) * np.exp(2j * np.pi * r * (object_id + 1))).astype(np.complex64)


def target_db(x: np.ndarray) -> np.ndarray:
    return 20.0 * np.log10(np.maximum(np.abs(x.astype(np.complex128)), 1e-4))


def _scale(object_id: int, salt: int) -> np.ndarray:
    return np.array([0.5 + 0.1 * object_id, 0.7 + 0.05 * salt, 0.9 - 0.03 * object_id])


def make_dataset(
    directory: Path, salt: int = 0, config: str = "analytic-test", variants: int = 3
) -> Path:
    """Two labelled shards (objects 0-4 and 5-8), written by the real shard writer; labels
    stamped with radar config ``config``; ``variants`` meshes per object, the simple one
    first (1: no complex meshes)."""
    directory.mkdir(parents=True)
    ids = list(range(9))
    for shard, chunk in enumerate((ids[:5], ids[5:])):
        objects = []
        for oid in chunk:
            scale = _scale(oid, salt)
            meshes = [
                MeshRecord(
                    v, m.vertices.astype(np.float32), m.faces.astype(np.int32), 0.0, {"variant": v}
                )
                for v, m in enumerate(_meshes(CLASSES[oid // 3], scale)[:variants])
            ]
            objects.append(
                ObjectRecord(
                    oid,
                    oid // 3,
                    scale,
                    1000 + oid,
                    "test" if oid in TEST_OBJECTS else "train",
                    meshes,
                )
            )
        path = directory / f"shard-{shard:05d}.h5"
        write_shard(path, objects, CLASSES, {"salt": salt}, "test")

        def add_radar(f, objects=objects):
            rows = [(k, m.variant) for k, o in enumerate(objects) for m in o.meshes]
            gain = {
                v: np.float32(10 ** ((SIMPLE_DB if v == 0 else VARIANT_DB) / 20)) for _, v in rows
            }
            write_radar(
                f,
                attrs={
                    "config": json.dumps({"name": config}),
                    "simulation_rule": json.dumps({"test": True}),
                },
                coordinates={
                    "aspect_deg": ASPECT,
                    "roll_deg": ROLL,
                    "range_m": RANGE,
                    "frequency_hz": np.linspace(8e9, 12e9, len(RANGE)),
                },
                object_ids=[o.id for o in objects],
                modes=["convex"] * len(objects),
                responses=(response(o.scale, o.id) for o in objects),
                mesh_index=np.arange(len(rows)),
                mesh_modes=["convex"] * len(rows),
                mesh_responses=(
                    response(objects[k].scale, objects[k].id) * gain[v] for k, v in rows
                ),
            )

        rewrite_atomically(path, add_radar)
    return directory


def write_predictions(
    path: Path,
    data: Path,
    offsets=OFFSETS,
    drop: int = 0,
    fingerprint: str | None = None,
    collapse: bool = False,
    variants: int = 3,
) -> Path:
    """Predictions = exact dB target + per-class offset; ``drop`` omits the last test meshes."""
    uids, rows = [], []
    for oid in TEST_OBJECTS:
        t = target_db(response(_scale(oid, 0), oid))
        s, c = offsets[CLASSES[oid // 3]]
        for v in range(variants):
            uids.append(mesh_uid(oid, v))
            rows.append(np.full_like(t, -30.0) if collapse else t + (s if v == 0 else c))
    if drop:
        uids, rows = uids[:-drop], rows[:-drop]
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "basic-shapes-predictions"
        f.attrs["version"] = 1
        f.attrs["dataset_fingerprint"] = fingerprint or dataset_fingerprint(data)
        f.attrs["label_fingerprint"] = label_fingerprint(data)
        f.create_dataset("mesh_uid", data=np.array(uids, np.int64))
        f.create_dataset("target_db", data=np.array(rows, np.float32))
    return path


def write_results(
    path: Path,
    data: Path,
    predictions: Path,
    name: str = "graph-ae",
    metrics: dict | None = None,
    ms_per_mesh: float = 1.25,
) -> Path:
    """A results JSON as `benchmark evaluate` writes it, metrics from the real scorer."""
    from benchmark.scoring.protocol import score_predictions

    results = {
        "benchmark_version": "0.1.0",
        "dataset_fingerprint": dataset_fingerprint(data),
        "label_fingerprint": label_fingerprint(data),
        "model": {"name": name, "params": 1234567, "embedding": "graph", "regime": "autoencoder"},
        "metrics": metrics if metrics is not None else score_predictions(data, predictions),
        "speed": {"ms_per_mesh": ms_per_mesh, "hardware": "cpu: test (2 cores)"},
        "seeds": {"train": 0, "dataset": 0},
        "created": "2026-11-21T12:00:00Z",
    }
    path.write_text(json.dumps(results, default=float))
    return path


def expected_metrics(offsets=OFFSETS) -> dict:
    """Exact metrics of ``write_predictions`` (equal mesh counts per class: pooled = class mean)."""
    per_class = {
        c: {"simple_mse": s * s, "complex_mse": k * k, "variation_mse": (s - k) ** 2}
        for c, (s, k) in offsets.items()
    }
    return {
        m: float(np.mean([row[m] for row in per_class.values()]))
        for m in ("simple_mse", "complex_mse", "variation_mse")
    } | {"per_class": per_class}


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("lb") / "data")


@pytest.fixture(scope="module")
def submission(data, tmp_path_factory):
    d = tmp_path_factory.mktemp("sub")
    pred = write_predictions(d / "predictions.h5", data)
    return write_results(d / "results.json", data, pred), pred


def run(*args) -> None:
    """The CLI; submissions of these fixture datasets (no registered version) go to a
    private board (``--unregistered``)."""
    extra = ["--unregistered"] if args[0] in ("submit", "seed") else []
    cli.main([str(a) for a in args] + extra)


def refused(*args) -> str:
    with pytest.raises(SystemExit) as exc:
        run(*args)
    msg = str(exc.value.code)
    assert exc.value.code not in (0, None) and "\n" not in msg, msg
    return msg


def close(a: float, b: float, rel: float = 1e-4) -> bool:
    return abs(a - b) <= 1e-6 + rel * abs(b)


# --- accepted submissions ---------------------------------------------------------------


def test_accepted_submission_is_rescored_and_written(data, submission, tmp_path):
    results, pred = submission
    entries = tmp_path / "entries"
    run(
        "submit",
        results,
        "--predictions",
        pred,
        "--data",
        data,
        "--entries",
        entries,
        "--name",
        "Graph AE <b>",
        "--link",
        "https://example.org/paper?a=1&b=2",
    )
    (path,) = entries.glob("*.json")
    entry = json.loads(path.read_text())
    assert entry["name"] == "Graph AE <b>" and entry["link"] == "https://example.org/paper?a=1&b=2"
    assert entry["params"] == 1234567 and entry["speed"]["ms_per_mesh"] == 1.25
    assert entry["dataset"]["fingerprint"] == dataset_fingerprint(data)
    assert entry["dataset"]["test_objects"] == 6 and entry["dataset"]["test_meshes"] == 18
    expected = expected_metrics()
    m = entry["metrics"]
    assert m["no_skill"] is False and "train-mean" in m["references"]
    for k in ("simple_mse", "complex_mse", "variation_mse"):
        assert close(m[k], expected[k]), (k, m[k], expected[k])
        for c in CLASSES:
            assert close(m["per_class"][c][k], expected["per_class"][c][k]), (c, k)
    # the example: lowest-id test object, its simple mesh and its complex mesh with most faces
    s = entry["sample"]
    assert s["object_id"] == 1 and s["class"] == "cube"
    assert [(x["variant"], x["n_faces"]) for x in s["meshes"]] == [(0, 12), (2, 192)]
    t = target_db(response(_scale(1, 0), 1))[:, 0, :]
    np.testing.assert_allclose(s["physics_db"], t, atol=0.051)
    np.testing.assert_allclose(s["meshes"][1]["predicted_db"], t + OFFSETS["cube"][1], atol=0.051)
    assert store.load_entries(entries)[0]["id"] == path.stem


def test_tolerance_accepts_a_rounding_level_difference(data, submission, tmp_path):
    results, pred = submission
    claimed = json.loads(Path(results).read_text())
    claimed["metrics"]["complex_mse"] *= 1 + REL_TOL / 10
    tweaked = tmp_path / "results.json"
    tweaked.write_text(json.dumps(claimed))
    run("submit", tweaked, "--predictions", pred, "--data", data, "--entries", tmp_path / "e")
    assert len(list((tmp_path / "e").glob("*.json"))) == 1


# --- refused submissions: one-line error, nothing written --------------------------------


def _tamper(results: Path, out: Path, edit) -> Path:
    r = json.loads(results.read_text())
    edit(r)
    out.write_text(json.dumps(r))
    return out


TAMPERS = {
    "simple": (
        lambda r: r["metrics"].__setitem__(
            "simple_mse", r["metrics"]["simple_mse"] * (1 - 10 * REL_TOL)
        ),
        "claimed simple_mse",
    ),
    "per-class": (
        lambda r: r["metrics"]["per_class"]["sphere"].__setitem__("complex_mse", 1.0),
        "claimed per_class.sphere.complex_mse",
    ),
    "no-skill": (lambda r: r["metrics"].__setitem__("no_skill", True), "claimed no_skill"),
    # every claimed number is re-scored, not only the paper's three
    "ood": (lambda r: r["metrics"].__setitem__("ood_complex_mse", 100.0), "ood_complex_mse"),
    "interval": (
        lambda r: r["metrics"].__setitem__("complex_mse_ci", [1.0, 2.0]),
        "claimed complex_mse_ci",
    ),
    "fingerprint": (lambda r: r.__setitem__("dataset_fingerprint", "ab" * 32), "another dataset"),
    "labels": (lambda r: r.__setitem__("label_fingerprint", "ab" * 32), "belongs to other labels"),
    "no-metrics": (lambda r: r.pop("metrics"), "results.json"),
    "bad-params": (lambda r: r["model"].__setitem__("params", "many"), "params"),
    "long-hardware": (lambda r: r["speed"].__setitem__("hardware", "x" * 500), "speed.hardware"),
    "curve-past-end": (
        lambda r: r.__setitem__(
            "training", {"val_curves": [[9.0, 8.0]], "epochs_to_plateau": [3], "capped": [False]}
        ),
        "training.epochs_to_plateau[0] is past the end of its curve",
    ),
    "curve-seeds": (
        lambda r: r.__setitem__(
            "training", {"val_curves": [[9.0], [8.0]], "epochs_to_plateau": [1], "capped": [None]}
        ),
        "must list the same seeds",
    ),
    "curve-nan": (
        lambda r: r.__setitem__(
            "training", {"val_curves": [[-1.0]], "epochs_to_plateau": [1], "capped": [False]}
        ),
        "training.val_curves[0][0]",
    ),
}


@pytest.mark.parametrize("case", sorted(TAMPERS))
def test_tampered_results_are_refused(case, data, submission, tmp_path):
    results, pred = submission
    edit, phrase = TAMPERS[case]
    bad = _tamper(Path(results), tmp_path / "results.json", edit)
    entries = tmp_path / "entries"
    msg = refused("submit", bad, "--predictions", pred, "--data", data, "--entries", entries)
    assert phrase in msg and str(bad) in msg, msg
    assert not entries.exists()


def test_compare_checks_every_claimed_value_and_takes_the_re_scores_nulls():
    from leaderboard.submit import compare

    rescored = {
        "simple_mse": 1.0,
        "complex_mse": 2.0,
        "variation_mse": 0.5,
        "complex_mse_ci": [1.5, 2.5],
        "no_skill": None,  # no training mean to test against
        "no_skill_test": None,
        "per_class": {"cube": {"simple_mse": 1.0, "n_objects": 3}},
    }
    assert compare(json.loads(json.dumps(rescored)), rescored) == []
    assert compare({**rescored, "complex_mse_ci": [1.5, 2.6]}, rescored) == [
        "claimed complex_mse_ci[1] 2.6 differs from the re-score 2.5"
    ]
    assert compare({**rescored, "no_skill": False}, rescored) == [
        "claimed no_skill False differs from the re-score None"
    ]
    edited = {**rescored, "per_class": {"cube": {"simple_mse": 1.0, "n_objects": 4}}}
    assert compare(edited, rescored) == [
        "claimed per_class.cube.n_objects 4 differs from the re-score 3"
    ]


def test_the_answer_key_is_refused(data, tmp_path):
    """The test labels handed back as predictions are no model: refused, whatever the
    results claim."""
    exact = {c: (0.0, 0.0) for c in OFFSETS}
    pred = write_predictions(tmp_path / "key.h5", data, offsets=exact)
    results = write_results(tmp_path / "results.json", data, pred)
    entries = tmp_path / "entries"
    msg = refused("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    assert "the test labels themselves" in msg and str(pred) in msg, msg
    assert not entries.exists()


def test_the_answer_key_is_refused_without_complex_meshes(tmp_path):
    """Only simple meshes (no Complex MSE to compare): the key is still refused."""
    data = make_dataset(tmp_path / "simple-only", variants=1)
    exact = {c: (0.0, 0.0) for c in OFFSETS}
    pred = write_predictions(tmp_path / "key.h5", data, offsets=exact, variants=1)
    results = write_results(tmp_path / "results.json", data, pred)
    assert json.loads(results.read_text())["metrics"]["complex_mse"] is None
    entries = tmp_path / "entries"
    msg = refused("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    assert "the test labels themselves" in msg, msg
    assert not entries.exists()


def _truncated(path: Path, out: Path) -> Path:
    out.write_bytes(path.read_bytes()[:300])
    return out


def test_malformed_and_mismatched_files_are_refused(data, submission, tmp_path):
    results, pred = submission
    entries = tmp_path / "entries"
    entries.mkdir()
    (entries / "keep.txt").write_text("already here")
    other = make_dataset(tmp_path / "other", salt=1)
    cases = [
        # (results, predictions, data, expected phrase)
        (_truncated(Path(results), tmp_path / "trunc.json"), pred, data, "trunc.json"),
        (results, _truncated(Path(pred), tmp_path / "trunc.h5"), data, "trunc.h5"),
        (results, pred, other, "another dataset"),
        (
            results,
            write_predictions(tmp_path / "fp.h5", data, fingerprint="cd" * 32),
            data,
            "fp.h5: made for dataset cdcdcd",
        ),
        (
            results,
            write_predictions(tmp_path / "missing.h5", data, drop=2),
            data,
            "missing.h5: missing 2 of 18 test meshes",
        ),
        (results, tmp_path / "absent.h5", data, "absent.h5"),
        (results, pred, tmp_path / "nowhere", "nowhere"),
    ]
    with h5py.File(tmp_path / "shape.h5", "w") as f:
        with h5py.File(pred) as g:
            for k, v in g.attrs.items():
                f.attrs[k] = v
            f["mesh_uid"] = g["mesh_uid"][()]
            f["target_db"] = g["target_db"][:, :, :2]
    cases.append((results, tmp_path / "shape.h5", data, "shape.h5: /target_db is float32"))
    nan = write_predictions(tmp_path / "nan.h5", data)
    with h5py.File(nan, "r+") as f:
        f["target_db"][0, 0, 0, 0] = np.nan
    cases.append((results, nan, data, "nan.h5: non-finite prediction"))
    for res, p, d, phrase in cases:
        msg = refused("submit", res, "--predictions", p, "--data", d, "--entries", entries)
        assert phrase in msg, (phrase, msg)
    assert sorted(x.name for x in entries.iterdir()) == ["keep.txt"]


def test_bad_link_and_duplicate_are_refused(data, submission, tmp_path):
    results, pred = submission
    entries = tmp_path / "entries"
    msg = refused(
        "submit",
        results,
        "--predictions",
        pred,
        "--data",
        data,
        "--entries",
        entries,
        "--link",
        "javascript:alert(1)",
    )
    assert "not an http" in msg and not entries.exists()
    run("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    before = {p: p.read_bytes() for p in entries.iterdir()}
    msg = refused("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    assert "already on the board" in msg
    assert {p: p.read_bytes() for p in entries.iterdir()} == before


# --- seeding from a `benchmark reproduce` output directory --------------------------------


def test_seed_submits_every_row_and_reports_the_rest(data, submission, tmp_path):
    results, pred = submission
    rows = tmp_path / "reproduce"
    for name in ("basic-direct", "ideal-graph"):
        (rows / name).mkdir(parents=True)
    shutil.copy(pred, rows / "basic-direct" / "predictions.h5")
    write_results(rows / "basic-direct" / "results.json", data, pred, name="direct")
    collapsed = write_predictions(rows / "ideal-graph" / "predictions.h5", data, collapse=True)
    write_results(rows / "ideal-graph" / "results.json", data, collapsed, name="graph")
    (rows / "no-predictions").mkdir()
    shutil.copy(results, rows / "no-predictions" / "results.json")
    entries = tmp_path / "entries"
    msg = refused("seed", "--from", rows, "--data", data, "--entries", entries)
    assert "no-predictions" in msg and "1 refused" in msg, msg
    names = sorted(e["name"] for e in store.load_entries(entries))
    assert names == ["basic-direct", "ideal-graph"]
    flags = {e["name"]: e["metrics"]["no_skill"] for e in store.load_entries(entries)}
    assert flags == {"basic-direct": False, "ideal-graph": True}
    shutil.rmtree(rows / "no-predictions")
    before = {p: p.read_bytes() for p in entries.iterdir()}
    run("seed", "--from", rows, "--data", data, "--entries", entries)  # duplicates are skipped
    assert {p: p.read_bytes() for p in entries.iterdir()} == before


# --- rendering -----------------------------------------------------------------------------


def png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR", path
    return struct.unpack(">II", head[16:24])


def test_render_shows_accepted_entries_in_html_and_markdown(data, submission, tmp_path):
    results, pred = submission
    entries = tmp_path / "entries"
    run(
        "submit",
        results,
        "--predictions",
        pred,
        "--data",
        data,
        "--entries",
        entries,
        "--name",
        "Graph AE <b>",
        "--link",
        "https://example.org/paper?a=1&b=2",
    )
    worse = write_predictions(
        tmp_path / "worse.h5", data, offsets={c: (s + 1, k + 1) for c, (s, k) in OFFSETS.items()}
    )
    worse_results = write_results(
        tmp_path / "worse.json", data, worse, name="direct $\\frac{$", ms_per_mesh=0.1
    )
    r = json.loads(worse_results.read_text())
    r["speed"] = {"ms_per_mesh": 0.1, "hardware": None, "self_reported": True}  # --speed-ms
    curves = {"val_curves": [[9.0, 7.0, 7.5], None], "epochs_to_plateau": [2, None]}
    r["training"] = {**curves, "capped": [False, None]}
    r["seeds"]["train_all"] = [0, 1]
    worse_results.write_text(json.dumps(r))
    run("submit", worse_results, "--predictions", worse, "--data", data, "--entries", entries)
    run(
        "simulator",
        "--data",
        data,
        "--entries",
        entries,
        "--ms-per-mesh",
        "250",
        "--hardware",
        "cpu: test",
    )
    site = tmp_path / "site"
    site.mkdir()
    (site / "example-000000000000.png").write_bytes(b"stale figure of a dataset no longer shown")
    run("render", "--out", site, "--entries", entries)
    assert not (site / "example-000000000000.png").exists()
    html = (site / "index.html").read_text()
    assert "Graph AE &lt;b&gt;" in html and "Graph AE <b>" not in html  # escaped, never injected
    assert 'href="https://example.org/paper?a=1&amp;b=2"' in html
    exp = expected_metrics()
    worse_exp = expected_metrics({c: (s + 1, k + 1) for c, (s, k) in OFFSETS.items()})
    body = re.search(r"<tbody>(.*?)</tbody>", html, re.S).group(1)
    rows = re.findall(r"<tr(?! class=\"reference\")[^>]*>(.*?)</tr>", body, re.S)
    refs = re.findall(r"<tr class=\"reference\">(.*?)</tr>", body, re.S)
    assert len(rows) == 2 and "Graph AE" in rows[0] and "direct" in rows[1]  # by Complex MSE
    assert {re.search(r"reference: ([a-z-]+)", r).group(1) for r in refs} == {
        "train-mean",
        "class-mean",
        "nearest-scale",
        "class-scale-nn",
    }
    # every row, reference or entry, stands in Complex MSE order (its cell's data-value)
    order = [
        float(re.findall(r'<td class="num" data-value="([^"]*)"', r)[2])  # #, Simple, Complex
        for r in re.findall(r"<tr[^>]*>(.*?)</tr>", body, re.S)
    ]
    assert order == sorted(order)
    # submitted entries: speed and params are claims, marked whatever the results JSON says
    assert "0.100 (self-reported)" in rows[1] and "1.25 (self-reported)" in rows[0]
    assert "1.23 M (self-reported)" in rows[0]
    ci = json.loads(next(entries.glob("graph-ae*.json")).read_text())["metrics"]["complex_mse_ci"]
    assert (
        f'{exp["complex_mse"]:.2f}<br><small class="ci">[{ci[0]:.2f}, {ci[1]:.2f}]</small>'
        in rows[0]
    )
    assert f"{exp['complex_mse']:.2f}" in rows[0] and f"{worse_exp['complex_mse']:.2f}" in rows[1]
    for img in re.findall(r'<img src="([^"]+)"', html):
        assert png_size(site / img)[0] > 100
    # the curves the results carried are on the entry and drawn (the entry without: left out)
    (worse_entry,) = [e for e in store.load_entries(entries) if e["name"].startswith("direct")]
    assert worse_entry["training"]["val_curves"] == curves["val_curves"]
    assert "<h3>Training curves</h3>" in html and len(list(site.glob("curves-*.png"))) == 1
    assert not re.search(r'(src|href)="(?!https://example.org/|data:,")[a-z]+:', html)  # all local
    md = (site / "LEADERBOARD.md").read_text()
    table = [line for line in md.splitlines() if line.startswith("| 1 ")]
    assert table and "[Graph AE \\<b\\>](https://example.org/paper?a=1&b=2)" in table[0], md
    assert md.count("| ref | reference: ") == 4 and "0.100 (self-reported)" in md
    assert f"{exp['complex_mse']:.2f}" in table[0]
    assert (
        f"250 (self-reported) ms per mesh on cpu: test; Complex MSE {VARIANT_DB**2:.2f} dB²" in md
    )  # given by hand (--ms-per-mesh), not timed


def test_render_skips_a_bad_entry_file_with_a_warning(data, submission, tmp_path, capsys):
    results, pred = submission
    entries = tmp_path / "entries"
    run("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    (path,) = entries.glob("*.json")
    entry = json.loads(path.read_text())
    entry["link"] = "javascript:alert(1)"
    path.write_text(json.dumps(entry))
    site = tmp_path / "site"
    capsys.readouterr()
    run("render", "--out", site, "--entries", entries, "--quiet")  # warnings still print
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and path.name in err[0] and "link" in err[0] and "skipped" in err[0]
    html = (site / "index.html").read_text()
    assert "javascript:" not in html and entry["name"] not in html


def test_results_without_speed_are_accepted_and_left_off_the_chart(data, tmp_path):
    pred = write_predictions(tmp_path / "p.h5", data)
    results = write_results(tmp_path / "r.json", data, pred, name="no-speed")
    r = json.loads(results.read_text())
    r["speed"] = {"ms_per_mesh": None, "hardware": None}
    results.write_text(json.dumps(r))
    entries, site = tmp_path / "entries", tmp_path / "site"
    run("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    run("render", "--out", site, "--entries", entries)
    html = (site / "index.html").read_text()
    assert (
        "no-speed" in html
        and "Not on the chart (no speed or no Complex MSE reported): no-speed" in html
    )
    short = f"{dataset_fingerprint(data)[:12]}-{label_fingerprint(data)[:8]}"
    assert png_size(site / f"speed-vs-error-{short}.png")[0] > 100


def test_simulator_point_is_the_physics_on_representation_meshes(data, tmp_path):
    from leaderboard.simulator import MEASURED

    entries = tmp_path / "entries"
    run("simulator", "--data", data, "--entries", entries, "--ms-per-mesh", "250")
    (path,) = entries.glob("physics-*.json")
    e = json.loads(path.read_text())
    assert e["kind"] == "simulator" and e["complex_mse_source"].startswith(MEASURED)
    assert e["speed"]["ms_per_mesh"] == 250.0
    assert e["dataset"]["label_fingerprint"] == label_fingerprint(data)
    for block in [e["metrics"], *e["metrics"]["per_class"].values()]:
        assert close(block["simple_mse"], SIMPLE_DB**2)
        assert close(block["complex_mse"], VARIANT_DB**2)
        assert close(block["variation_mse"], (VARIANT_DB - SIMPLE_DB) ** 2)
    bare = tmp_path / "bare"
    shutil.copytree(data, bare)

    def drop_mesh_labels(f):
        del f["radar/mesh_response"], f["radar/mesh_mode"], f["radar/mesh"]

    for shard in sorted(bare.glob("shard-*.h5")):
        rewrite_atomically(shard, drop_mesh_labels)
    assert "--mesh-labels all" in refused(
        "simulator", "--data", bare, "--entries", entries, "--ms-per-mesh", "300"
    )
    assert json.loads(path.read_text())["speed"]["ms_per_mesh"] == 250.0  # kept


def test_simulator_and_render_show_progress_on_stderr_unless_quiet(data, tmp_path, capsys):
    entries, site = tmp_path / "entries", tmp_path / "site"
    run("simulator", "--data", data, "--entries", entries, "--ms-per-mesh", "250")
    assert "simulator: score" in capsys.readouterr().err
    run("simulator", "--data", data, "--entries", entries, "--ms-per-mesh", "250", "--quiet")
    assert capsys.readouterr().err == ""
    run("render", "--out", site, "--entries", entries)
    out = capsys.readouterr()
    assert "render" in out.err and "figure" in out.err and out.out.startswith("rendered")
    run("render", "--out", site, "--entries", entries, "--quiet")
    assert capsys.readouterr().err == ""


def test_simulator_point_measured_with_radar_sim(data, tmp_path, capsys):
    """Real physics labels (radar-sim label, coarse grid, every mesh), then timing radar_sim."""
    import time

    import radar_sim
    from radar_sim.cli import main as radar_sim_main

    real = tmp_path / "real"
    shutil.copytree(data, real)

    def drop_labels(f):
        del f["radar"]

    for shard in sorted(real.glob("shard-*.h5")):
        rewrite_atomically(shard, drop_labels)
    config = {"name": "coarse-test", "n_aspect": 7, "n_roll": 4, "n_freq": 64, "n_range": 51}
    (tmp_path / "coarse.json").write_text(json.dumps(config))
    radar_sim_main(
        [
            "label",
            "--data",
            str(real),
            "--config",
            str(tmp_path / "coarse.json"),
            "--mesh-labels",
            "all",
            "--workers",
            "1",
        ]
    )
    entries = tmp_path / "entries"
    capsys.readouterr()
    run("simulator", "--data", real, "--entries", entries)
    assert "simulator: time: 100%" in capsys.readouterr().err  # the child's meshes, as timed
    e = json.loads(next(entries.glob("physics-*.json")).read_text())
    assert e["name"] == "radar_sim on the representation mesh coarse-test"
    assert e["speed"]["source"].startswith("measured") and "one thread" in e["speed"]["source"]
    assert e["speed"]["threads"] == 1

    per_object, per_mesh_seconds = {}, []
    cfg = radar_sim.RadarConfig(**config)
    box = trimesh.creation.box((0.3, 0.2, 0.1))
    radar_sim.simulate(box.vertices, box.faces, cfg)  # warm (compiled), as the entry's timing
    for shard in sorted(real.glob("shard-*.h5")):
        with h5py.File(shard) as f:
            ids, split = f["objects/id"][()], f["objects/split"][()]
            owner = f["meshes/object_index"][()]
            variant = f["meshes/variant"][()]
            for j, row in enumerate(f["radar/mesh"][()]):
                k = owner[row]
                if split[k] == b"test" and variant[row] > 0:
                    d = target_db(f["radar/response"][k]) - target_db(f["radar/mesh_response"][j])
                    per_object.setdefault(int(ids[k]), []).append(np.mean(d**2))
            # every test mesh, timed ourselves (so does the entry, in a one-thread child)
            for row in np.flatnonzero(split[owner] == b"test"):
                v0, v1 = f["meshes/vertex_offset"][row : row + 2]
                f0, f1 = f["meshes/face_offset"][row : row + 2]
                t0 = time.perf_counter()
                radar_sim.simulate(f["meshes/vertices"][v0:v1], f["meshes/faces"][f0:f1], cfg)
                per_mesh_seconds.append(time.perf_counter() - t0)
    expected = np.mean([np.mean(v) for v in per_object.values()])
    assert len(per_object) == 6 and expected > 0
    assert close(e["metrics"]["complex_mse"], expected, rel=1e-6)
    ours = 1000 * np.mean(per_mesh_seconds)
    assert ours / 10 < e["speed"]["ms_per_mesh"] < ours * 10, (e["speed"]["ms_per_mesh"], ours)


def test_what_benchmark_evaluate_writes_is_accepted(data, tmp_path):
    """The harness's own output (a reference model run by `benchmark evaluate`) is on the board."""
    from benchmark.cli import main as benchmark_main

    results, pred = tmp_path / "results.json", tmp_path / "predictions.h5"
    benchmark_main(
        [
            "evaluate",
            "--data",
            str(data),
            "--model",
            "benchmark.scoring.protocol:NearestScaleModel",
            "--model-arg",
            f"data_dir={data}",
            "--out",
            str(results),
            "--write-predictions",
            str(pred),
        ]
    )
    entries = tmp_path / "entries"
    run("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    (entry,) = store.load_entries(entries)
    claimed = json.loads(results.read_text())
    assert entry["name"] == "nearest-scale" and entry["metrics"] == claimed["metrics"]
    assert entry["speed"]["ms_per_mesh"] == claimed["speed"]["ms_per_mesh"] > 0


def test_unregistered_dataset_is_refused_unless_asked(data, tmp_path):
    """Only registered dataset versions reach the public board; a private board says so."""
    pred = write_predictions(tmp_path / "p.h5", data)
    results = write_results(tmp_path / "results.json", data, pred)
    entries = tmp_path / "e"
    with pytest.raises(SystemExit) as exc:
        cli.main(
            [
                "submit",
                str(results),
                "--predictions",
                str(pred),
                "--data",
                str(data),
                "--entries",
                str(entries),
            ]
        )
    assert "not a registered dataset version" in str(exc.value.code)
    assert not entries.exists()
    with pytest.raises(SystemExit) as exc:  # nothing is written into the repository by default
        cli.main(["submit", str(results), "--predictions", str(pred), "--data", str(data)])
    assert exc.value.code == 2
    run("submit", results, "--predictions", pred, "--data", data, "--entries", entries)
    (entry,) = entries.glob("*.json")
    assert json.loads(entry.read_text())["dataset"]["version"] is None


def test_board_names_the_dataset_version_with_its_grid_and_config():
    from leaderboard.render import describe

    split = {"classes": ["cube"], "test_objects": 3, "test_meshes": 9}
    text = describe({**split, "version": "cpu-v1"})
    assert "version cpu-v1" in text and "31 aspects x 7 rolls x 107 range bins" in text
    assert "xband-v1-31x7x107" in text and "benchmark dataset cpu-v1" in text
    assert describe({**split, "version": None}).startswith("not a registered dataset version")
    recorded = {
        **split,
        "version": "cpu-v1",
        "fingerprint": versions.get("cpu-v1").fingerprints["mesh"],
    }
    assert "earlier build" not in describe(recorded)
    assert "Scored on an earlier build of cpu-v1 (mesh 390cf5dc" in describe(
        {**recorded, "fingerprint": "390cf5dc" + "0" * 56}
    )
    relabelled = {**recorded, "label_fingerprint": "c92860b2" + "0" * 56}
    assert "NOT cpu-v1's recorded ones (label c92860b2" in describe(relabelled)
    label = versions.get("cpu-v1").fingerprints["label"]
    assert "NOT" not in describe({**recorded, "label_fingerprint": label})


def test_simple_mesh_physics_computed_like_the_labeller_stores_it(data, tmp_path):
    """Objects whose simple mesh's physics was not stored (``--mesh-labels sample:K``) get it
    simulated by the board's physics point: the same numbers ``radar-sim label`` stores."""
    from benchmark.scoring.data import BenchmarkData
    from leaderboard.simulator import _simple_physics
    from radar_sim.cli import main as radar_sim_main

    real = tmp_path / "real"
    shutil.copytree(data, real)
    for shard in sorted(real.glob("shard-*.h5")):
        rewrite_atomically(shard, lambda f: f.__delitem__("radar"))
    config = {"name": "coarse-test", "n_aspect": 7, "n_roll": 4, "n_freq": 64, "n_range": 51}
    (tmp_path / "coarse.json").write_text(json.dumps(config))
    radar_sim_main(
        [
            "label",
            "--data",
            str(real),
            "--config",
            str(tmp_path / "coarse.json"),
            "--mesh-labels",
            "all",
            "--workers",
            "0",
            "--quiet",
        ]
    )
    with BenchmarkData(real) as d, h5py.File(d.paths[0]) as f:
        simple_row = int(f["meshes/variant"][()].tolist().index(0))  # object 0's simple mesh
        j = f["radar/mesh"][()].tolist().index(simple_row)
        stored = f["radar/mesh_response"][j]
        obj = int(
            d.meshes["object"][
                np.flatnonzero((d.meshes["shard"] == 0) & (d.meshes["row"] == simple_row))[0]
            ]
        )
        np.testing.assert_allclose(
            _simple_physics(d, obj), stored, rtol=0, atol=1e-6 * abs(stored).max()
        )


def test_board_shows_the_labels_physics_budget_of_the_version():
    """Each registered version's classes get their labels' error against the exact answer,
    under the version's own physics (PO for v1, PO + edges for v2), from the committed
    budget that perf/budget_summary.py makes; an unregistered dataset gets none."""
    import json

    from benchmark.scoring import budget as physics_budget
    from leaderboard import render

    classes = ["cube", "cylinder", "sphere"]
    v1 = render.budget({"version": "demo-v1", "classes": classes})
    v2 = render.budget({"version": "demo-v2", "classes": classes})
    assert [r[0] for r in v1] == classes and {"cylinder", "sphere"} <= {r[0] for r in v2}
    stored = json.loads(physics_budget.PATH.read_text())["physics"]["xband-v1"]["sphere"]
    lo, hi = stored["all_bins_db2"]
    assert v1[2][1] == f"{lo:.3g}–{hi:.3g}" and "Mie" in v1[2][3]
    assert render.budget({"version": None, "classes": classes}) == []
    assert "Physics error budget" in render.html_budget({"version": "demo-v1", "classes": classes})


def test_versions_sharing_meshes_are_separate_groups(data, tmp_path):
    """cpu-v2 and cpu-v3 share their meshes and differ in labels: their entries are never
    ranked together, and each keeps its own simulator entry (one no longer replaces the
    other)."""
    from leaderboard.render import datasets

    relabelled = make_dataset(tmp_path / "relabelled", config="analytic-test-v2")
    assert dataset_fingerprint(relabelled) == dataset_fingerprint(data)
    assert label_fingerprint(relabelled) != label_fingerprint(data)
    entries = tmp_path / "entries"
    for d in (data, relabelled):
        run("simulator", "--data", d, "--entries", entries, "--ms-per-mesh", "250")
    found = [json.loads(p.read_text()) for p in sorted(entries.glob("physics-*.json"))]
    assert (
        len(found) == 2 and found[0]["dataset"]["fingerprint"] == found[1]["dataset"]["fingerprint"]
    )
    groups = datasets(found)
    assert len(groups) == 2 and len({g["short"] for g in groups}) == 2
    assert all(g["simulator"] is not None for g in groups)
