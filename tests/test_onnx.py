"""The ranked track: ONNX models run by the board on a held-out build (issue 19).

A held-out build of tiny-v1 is made from this file's own secret (the real generator and
labeller, as `benchmark dataset` builds it), beside the public tiny-v1. Then:

- every embedding of the registry exports to the ONNX contract and agrees with its PyTorch
  model on every test mesh of the fixture (the export's own check, a stated tolerance);
- the exported baselines go through `leaderboard evaluate-model` (the board runs them, counts
  their parameters from the graph, times them) onto the held-out track;
- a third-party model written from docs/onnx_template.py goes export -> evaluate-model ->
  entry -> render, where the held-out track comes first, measured, with a Pareto front, and
  a self-scored entry is marked self-reported;
- the true labels cannot enter the ranked track: a predictions file is refused by both
  commands, a public build as the ranked dataset too; an ONNX lookup table of the public test
  labels (perfect on the public split) scores no better than the training mean on the
  held-out build;
- a malformed or foreign .onnx file is refused in one line naming it, and parameters are
  counted from the graph, whatever the file declares.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import onnx
import pytest
import torch
from onnx import TensorProto, helper, numpy_helper

from benchmark.cli import main as benchmark_main
from benchmark.scoring import heldout
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.evaluate import evaluate
from benchmark.scoring.onnx_model import INPUTS, OnnxModel, OnnxModelError, inspect
from benchmark.scoring.protocol import scored_mesh_rows, write_predictions, write_results
from benchmark.training.models import REGISTRY, build_model
from benchmark.training.models.checkpoint import save_checkpoint
from benchmark_fixture import make_dataset
from leaderboard import cli, store

ROOT = Path(__file__).resolve().parents[1]
SECRET = "tests/test_onnx.py held-out secret: not the board's"
TOLERANCE_DB = 1e-3  # asked of every export here; measured: a few 1e-6 dB (float32 at -40 dB)


def dataset_cli(*args) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "benchmark.cli", "dataset", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


@pytest.fixture(scope="module")
def builds(tmp_path_factory) -> SimpleNamespace:
    """The public tiny-v1 and its held-out build from SECRET, built side by side."""
    root = tmp_path_factory.mktemp("onnx")
    secret = root / "secret.txt"
    secret.write_text(SECRET + "\n")
    public, held = root / "tiny-v1", root / "heldout-tiny-v1"
    procs = [
        dataset_cli("tiny-v1", "--data", public, "--workers", "0", "--quiet"),
        dataset_cli(
            "tiny-v1", "--data", held, "--secret-seed-file", secret, "--workers", "0", "--quiet"
        ),
    ]
    outs = [p.communicate() for p in procs]
    for p, (_, err) in zip(procs, outs):
        assert p.returncode == 0, err
    return SimpleNamespace(
        root=root, public=public, held=held, secret=secret, report=outs[1][0], entries=root / "e"
    )


def lb(*args) -> None:
    cli.main([str(a) for a in args])


def refused(*args) -> str:
    with pytest.raises(SystemExit) as exc:
        lb(*args)
    msg = str(exc.value.code)
    assert exc.value.code not in (0, None) and "\n" not in msg, msg
    return msg


# --- the held-out build ------------------------------------------------------------------
def test_heldout_build_is_the_recipe_with_a_secret_seed(builds, tmp_path, monkeypatch):
    report = json.loads(builds.report)
    assert report["version"] == "tiny-v1" and report["heldout"] is True
    assert set(report) == {
        "version",
        "heldout",
        "mesh",
        "label",
        "matches_recorded",
        "generate_s",
        "label_s",
    }
    seed = heldout.seed_of(SECRET.encode(), heldout.VERSIONS["tiny-v1"])
    assert str(seed) not in builds.report and SECRET not in builds.report  # never printed
    held = heldout.identify(builds.held)
    assert held.version.name == "tiny-v1" and held.recorded is None  # none in the repository
    with BenchmarkData(builds.public) as pub, BenchmarkData(builds.held) as priv:
        assert priv.fingerprint == report["mesh"] != pub.fingerprint
        assert priv.target_shape == pub.target_shape and priv.class_names == pub.class_names
        assert len(priv.object_rows("test")) == len(pub.object_rows("test"))
    with pytest.raises(heldout.HeldOutError, match="public build of tiny-v1"):
        heldout.identify(builds.public)
    # recorded fingerprints: a build that differs is not the held-out set
    monkeypatch.setattr(heldout, "RECORDS", tmp_path)
    (tmp_path / "tiny-v1.json").write_text(json.dumps({"fingerprints": {"mesh": "0" * 64}}))
    with pytest.raises(heldout.HeldOutError, match="not the recorded held-out build"):
        heldout.identify(builds.held)
    heldout.record(heldout.VERSIONS["tiny-v1"], builds.held)
    assert heldout.identify(builds.held).recorded is True
    assert str(seed) not in (tmp_path / "tiny-v1.json").read_text()
    # another secret: --check says it is not this build; a short secret is refused
    other = tmp_path / "other.txt"
    other.write_text("another secret, long enough to use")
    proc = dataset_cli("tiny-v1", "--data", builds.held, "--secret-seed-file", other, "--check")
    _, err = proc.communicate()
    assert proc.returncode == 1 and "not tiny-v1 built from this secret" in err
    other.write_text("short")
    proc = dataset_cli("tiny-v1", "--data", tmp_path / "x", "--secret-seed-file", other)
    _, err = proc.communicate()
    assert proc.returncode == 1 and "16 to 4096 bytes" in err and not (tmp_path / "x").exists()


# --- export: every embedding -------------------------------------------------------------
@pytest.fixture(scope="module")
def exported(builds) -> SimpleNamespace:
    """One checkpoint per embedding (tiny, randomly initialised, realistic dB offsets), laid
    out as `benchmark reproduce` does, exported by `benchmark export-onnx --from`, checked on
    every test mesh of the fixture dataset."""
    root = builds.root / "rows"
    fixture = make_dataset(root / "fixture", objects_per_class=3, n_test_per_class=2)
    with BenchmarkData(builds.public) as data:
        shape = data.target_shape
    torch.manual_seed(0)
    for name in REGISTRY:
        kwargs = dict(
            n_outputs=int(np.prod(shape)),
            n_scale_bins=32,
            dim=16,
            embed_layers=1,
            agg_layers=2,
            n_heads=2,
            decoder_hidden=32,
            codebook_size=16,
        )
        model = build_model(name, **kwargs)
        with torch.no_grad():
            for p in model.parameters():  # the aggregator's layers start as copies
                p.add_(0.05 * torch.randn_like(p))
            model.decoder.offset.fill_(-45.0)
            model.decoder.spread.fill_(15.0)
        config = {
            "model": {"name": name, **kwargs},
            "target_shape": list(shape),
            "scale_bins": {"lo": 0.2, "hi": 2.0, "n": 32},
            "name": f"{name}-basic",
            "regime": "basic",
        }
        save_checkpoint(root / "out" / "checkpoints" / f"{name}-basic" / "seed-0", model, config)
    onnx_dir = root / "onnx"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = benchmark_main(
            [
                "export-onnx",
                "--from",
                str(root / "out"),
                "--out",
                str(onnx_dir),
                "--check-data",
                str(fixture),
                "--tolerance",
                str(TOLERANCE_DB),
                "--quiet",
            ]
        )
    assert rc == 0
    with BenchmarkData(fixture) as data:
        n_test = len(scored_mesh_rows(data))
    return SimpleNamespace(dir=onnx_dir, n_test=n_test, reports=json.loads(out.getvalue()))


def test_every_embedding_exports_and_agrees_with_pytorch(exported):
    for r in exported.reports:  # onnxruntime (1 thread) against CheckpointModel.predict
        assert r["meshes_checked"] == exported.n_test and r["max_abs_db"] <= TOLERANCE_DB, r
    files = sorted(exported.dir.glob("*.onnx"))
    assert [f.stem for f in files] == sorted(f"{n}-basic" for n in REGISTRY)
    for f in files:
        info = inspect(f)
        meta = dict(info.metadata)
        assert meta["embedding"] == f.stem.split("-")[0] and meta["regime"] == "basic"
        assert set(info.inputs) <= set(INPUTS) - {"vertices", "faces", "scale_bins"}


def test_export_report_states_the_agreement(exported, builds, tmp_path, capsys):
    """`export-onnx CHECKPOINT` on one row prints the agreement it measured; every export in
    the fixture above passed the same check on all fixture test meshes."""
    ckpt = builds.root / "rows" / "out" / "checkpoints" / "graph-basic" / "seed-0"
    capsys.readouterr()
    benchmark_main(["export-onnx", str(ckpt), "--out", str(tmp_path / "g.onnx"), "--quiet"])
    report = json.loads(capsys.readouterr().out)
    assert report["meshes_checked"] == 3 and report["max_abs_db"] <= TOLERANCE_DB
    assert report["params_graph"] == inspect(tmp_path / "g.onnx").params
    # a tolerance the float32 export cannot meet: refused, nothing written
    with pytest.raises(SystemExit) as info:
        benchmark_main(
            ["export-onnx", str(ckpt), "--out", str(tmp_path / "h.onnx"), "--tolerance", "0"]
        )
    assert "differs from the PyTorch model" in str(info.value.code)
    assert not (tmp_path / "h.onnx").exists() and exported.n_test > 0


def test_baselines_seed_the_heldout_track(exported, builds):
    entries = builds.root / "baselines"
    lb("evaluate-model", *sorted(exported.dir.glob("*.onnx")), "--data", builds.held,
       "--entries", entries, "--quiet")  # fmt: skip
    found = {e["name"]: e for e in store.load_entries(entries)}
    assert set(found) == {f"{n}-basic" for n in REGISTRY}
    for name, e in found.items():
        info = inspect(exported.dir / f"{name}.onnx")
        assert e["origin"] == "board" and e["track"] == "heldout"
        assert e["params"] == info.params and not store.params_self_reported(e)
        assert e["speed"]["ms_per_mesh"] > 0 and not store.speed_self_reported(e)
        assert e["speed"]["threads"] == 1 and "measured by the board" in e["speed"]["source"]
        assert e["files"]["onnx_sha256"] == info.sha256 and e["sample"] is None
        assert e["dataset"]["version"] == "tiny-v1" and e["seeds"] is None
        assert e["model"]["embedding"] == name.split("-")[0]
    # the same file again: a duplicate, skipped
    lb("evaluate-model", exported.dir / "blind-basic.onnx", "--data", builds.held,
       "--entries", entries)  # fmt: skip
    assert len(store.load_entries(entries)) == len(REGISTRY)


# --- a third party, end to end -----------------------------------------------------------
def test_template_model_goes_from_export_to_the_rendered_board(builds, tmp_path):
    model = tmp_path / "my-model.onnx"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "onnx_template.py"), "--data", str(builds.public),
         "--out", str(model), "--epochs", "1"],
        capture_output=True, text=True, cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    worst = float(re.search(r"max \|ONNX - PyTorch\| on 8 test meshes: (\S+) dB", proc.stdout)[1])
    assert worst <= TOLERANCE_DB
    entries, site = tmp_path / "entries", tmp_path / "site"
    lb("evaluate-model", model, "--data", builds.held, "--entries", entries,
       "--name", "my-model", "--link", "https://example.org/my-model")  # fmt: skip
    (entry,) = store.load_entries(entries)
    assert entry["params"] == inspect(model).params and entry["track"] == "heldout"
    # the same model self-scored on the public split: a predictions file, submitted
    results = evaluate(builds.public, model=OnnxModel(model), write_predictions=tmp_path / "p.h5")
    write_results(tmp_path / "r.json", results)
    lb("submit", tmp_path / "r.json", "--predictions", tmp_path / "p.h5", "--data",
       builds.public, "--entries", entries, "--name", "my-model-public")  # fmt: skip
    lb("render", "--out", site, "--entries", entries)
    html, md = (site / "index.html").read_text(), (site / "LEADERBOARD.md").read_text()
    sections = re.findall(r'<section id="dataset-[0-9a-f-]+" class="track-(\w+)">', html)
    assert sections == ["heldout", "public"]
    heads = re.findall(r"<h2>(.*?)</h2>", html)
    assert heads[0].startswith("Ranked track (held-out): held-out build of tiny-v1")
    assert heads[1].startswith("Self-scored track: dataset tiny-v1")
    ranked, public = html.split('class="track-public"')
    (row,) = re.findall(r'<tr id="entry-my-model-[0-9a-f]+"[^>]*>(.*?)</tr>', ranked, re.S)
    assert "self-reported" not in row and ">my-model<" in row
    (row,) = re.findall(r'<tr id="entry-my-model-public-[^"]*"[^>]*>(.*?)</tr>', public, re.S)
    assert "(self-reported)" in row
    assert "Pareto front of Complex MSE against board-measured ms per mesh" in ranked
    assert "my-model" in re.search(r"Pareto front of.*?</p>", ranked, re.S)[0]
    assert md.index("## Ranked track (held-out)") < md.index("## Self-scored track")
    short = f"{entry['dataset']['fingerprint'][:12]}-{entry['dataset']['label_fingerprint'][:8]}"
    assert (site / f"speed-vs-error-{short}.png").is_file()


# --- the answer key cannot enter ---------------------------------------------------------
def true_label_predictions(data_dir: Path, path: Path) -> Path:
    with BenchmarkData(data_dir) as data:
        rows = scored_mesh_rows(data)
        targets = np.stack([data.target(int(data.meshes["object"][r])) for r in rows])
        write_predictions(
            path,
            data.fingerprint,
            data.meshes["uid"][rows],
            targets,
            label_fingerprint=data.label_fingerprint,
        )
    return path


def test_predictions_are_refused_on_the_ranked_track(builds, tmp_path):
    truth = true_label_predictions(builds.held, tmp_path / "truth.h5")
    results = evaluate(builds.held, predictions=truth)
    assert results["metrics"]["simple_mse"] == 0.0  # it is the answer key
    write_results(tmp_path / "truth.json", results)
    entries = tmp_path / "entries"
    for extra in ([], ["--unregistered"]):
        msg = refused("submit", tmp_path / "truth.json", "--predictions", truth, "--data",
                      builds.held, "--entries", entries, "--name", "oracle", *extra)  # fmt: skip
        assert "a held-out build of tiny-v1" in msg and "accepts only ONNX models" in msg
    msg = refused("evaluate-model", truth, "--data", builds.held, "--entries", entries)
    assert str(truth) in msg and "an HDF5 file (a predictions file?), not an ONNX model" in msg
    assert not entries.exists()


def lookup_table(data_dir: Path, path: Path) -> Path:
    """An ONNX answer key: the labels of every scored test mesh of ``data_dir``, keyed by the
    mesh's vertex count and the sum of |normalized vertex coordinates| (computed in the
    graph); a miss returns the first stored label."""
    with BenchmarkData(data_dir) as data:
        rows = scored_mesh_rows(data)
        counts, sums, labels = [], [], []
        for r in rows:
            v = data.batch(np.array([r]))["vertices"][0]
            counts.append(len(v))
            sums.append(np.abs(v.astype(np.float64)).sum())
            labels.append(data.target(int(data.meshes["object"][r])))
    init = [
        numpy_helper.from_array(np.array(counts, np.float32), "counts"),
        numpy_helper.from_array(np.array(sums, np.float32), "sums"),
        numpy_helper.from_array(np.stack(labels).astype(np.float32), "labels"),
        numpy_helper.from_array(np.array(1e-4, np.float32), "rel"),
        numpy_helper.from_array(np.array([0], np.int64), "zero"),
    ]
    nodes = [
        helper.make_node("Shape", ["vertices"], ["shape"]),
        helper.make_node("Gather", ["shape", "zero"], ["n64"], axis=0),
        helper.make_node("Cast", ["n64"], ["n"], to=TensorProto.FLOAT),
        helper.make_node("Abs", ["vertices"], ["absv"]),
        helper.make_node("ReduceSum", ["absv"], ["s"], keepdims=0),
        helper.make_node("Equal", ["counts", "n"], ["same_n"]),
        helper.make_node("Sub", ["sums", "s"], ["d"]),
        helper.make_node("Abs", ["d"], ["absd"]),
        helper.make_node("Mul", ["sums", "rel"], ["tol"]),
        helper.make_node("Less", ["absd", "tol"], ["same_s"]),
        helper.make_node("And", ["same_n", "same_s"], ["hit"]),
        helper.make_node("Cast", ["hit"], ["hitf"], to=TensorProto.FLOAT),
        helper.make_node("ArgMax", ["hitf"], ["k"], axis=0, keepdims=0),
        helper.make_node("Gather", ["labels", "k"], ["target_db"], axis=0),
    ]
    graph = helper.make_graph(
        nodes,
        "lookup",
        [helper.make_tensor_value_info("vertices", TensorProto.FLOAT, ["V", 3])],
        [helper.make_tensor_value_info("target_db", TensorProto.FLOAT, list(labels[0].shape))],
        init,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    helper.set_model_props(model, {"params": "1"})  # a declaration the board ignores
    onnx.checker.check_model(model)
    path.write_bytes(model.SerializeToString())
    return path


def test_a_lookup_table_of_the_public_labels_has_no_skill_on_the_heldout_build(builds, tmp_path):
    model = lookup_table(builds.public, tmp_path / "lookup.onnx")
    info = inspect(model)
    with BenchmarkData(builds.public) as data:
        k, size = len(scored_mesh_rows(data)), int(np.prod(data.target_shape))
    assert info.params == 2 * k + k * size + 1 + 1  # counted from the graph, not the "1" declared
    public = evaluate(builds.public, model=OnnxModel(model), progress=False)["metrics"]
    assert public["simple_mse"] < 1e-6 and public["complex_mse"] < 1e-6  # a perfect answer key
    entries = tmp_path / "entries"
    lb("evaluate-model", model, "--data", builds.held, "--entries", entries, "--name", "lookup")
    (e,) = store.load_entries(entries)
    m, ref = e["metrics"], e["metrics"]["references"]["train-mean"]
    assert m["no_skill"] is True
    for key in ("simple_mse", "complex_mse"):
        assert m[key] >= ref[key], (key, m[key], ref[key])
    # and a public build cannot be the ranked track's dataset, whatever the flags
    for extra in ([], ["--unregistered"]):
        msg = refused("evaluate-model", model, "--data", builds.public, "--entries",
                      tmp_path / "e2", *extra)  # fmt: skip
        assert "the public build of tiny-v1" in msg


# --- malformed and foreign files ---------------------------------------------------------
def _model(nodes, inputs, outputs, init=(), opset=(("", 17),)) -> onnx.ModelProto:
    graph = helper.make_graph(nodes, "g", inputs, outputs, list(init))
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid(d, v) for d, v in opset])
    m.ir_version = 8
    return m


SCALE = helper.make_tensor_value_info("scale_m", TensorProto.DOUBLE, [3])
GRID = helper.make_tensor_value_info("out", TensorProto.FLOAT, [7, 3, 107])


def foreign(case: str) -> bytes:
    grid = numpy_helper.from_array(np.full((7, 3, 107), -40.0, np.float32), "grid")
    ident = [helper.make_node("Identity", ["grid"], ["out"])]
    if case == "garbage":
        return b"\x08\x07not an onnx model at all\xff\xfe" * 10
    if case == "custom-op":
        node = helper.make_node("Lookup", ["scale_m"], ["out"], domain="com.example")
        return _model([node], [SCALE], [GRID], opset=(("", 17), ("com.example", 1)))
    if case == "external-data":
        ext = TensorProto(name="grid", data_type=TensorProto.FLOAT, dims=[7, 3, 107])
        ext.data_location = TensorProto.EXTERNAL
        entry = ext.external_data.add()
        entry.key, entry.value = "location", "/etc/passwd"
        return _model(ident, [SCALE], [GRID], [ext])
    if case == "unknown-input":
        labels = helper.make_tensor_value_info("labels", TensorProto.FLOAT, [7, 3, 107])
        return _model([helper.make_node("Identity", ["labels"], ["out"])], [labels], [GRID])
    if case == "wrong-dtype":
        verts = helper.make_tensor_value_info("vertices", TensorProto.DOUBLE, ["V", 3])
        return _model(ident, [verts], [GRID], [grid])
    if case == "two-outputs":
        two = [*ident, helper.make_node("Identity", ["grid"], ["out2"])]
        out2 = helper.make_tensor_value_info("out2", TensorProto.FLOAT, [7, 3, 107])
        return _model(two, [SCALE], [GRID, out2], [grid])
    if case == "checker":
        return _model([helper.make_node("NoSuchOp", ["scale_m"], ["out"])], [SCALE], [GRID])
    raise ValueError(case)


@pytest.mark.parametrize(
    "case, problem",
    [
        ("garbage", "not an ONNX model"),
        ("custom-op", "operator domain 'com.example'"),
        ("external-data", "refers to external data"),
        ("unknown-input", "has the input 'labels', which the contract does not define"),
        ("wrong-dtype", "input vertices must be a float32 tensor"),
        ("two-outputs", "has 2 outputs"),
        ("checker", "fails the ONNX checker"),
    ],
)
def test_a_malformed_or_foreign_file_is_refused_in_one_line(case, problem, tmp_path):
    raw = foreign(case)
    path = tmp_path / f"{case}.onnx"
    path.write_bytes(raw if isinstance(raw, bytes) else raw.SerializeToString())
    with pytest.raises(OnnxModelError):
        inspect(path)
    msg = refused("evaluate-model", path, "--data", tmp_path / "d", "--entries", tmp_path / "e")
    assert str(path) in msg and problem in msg, msg
    assert not (tmp_path / "e").exists()


def test_an_aggregator_of_several_layers_exports():
    """Torch's exporter has no ONNX form of its fused inference path, which an aggregator
    exported on its own took in every layer but the last (before ``aggregator._inner_path``)."""
    from benchmark.training.models.aggregator import Aggregator

    agg = Aggregator(32, 3, n_heads=4).eval()
    emb, mask = torch.randn(1, 20, 32), torch.ones(1, 20, dtype=torch.bool)
    buf = io.BytesIO()
    with torch.no_grad():
        torch.onnx.export(agg, (emb, mask), buf, dynamo=False)
    assert buf.getvalue()


def test_parameters_are_counted_from_the_graph(tmp_path):
    weights = numpy_helper.from_array(np.ones((10, 20), np.float32), "w")
    bias = helper.make_tensor("b", TensorProto.FLOAT, [5], [1.0] * 5)
    nodes = [
        helper.make_node("Constant", [], ["c"], value=bias),  # 5 in a Constant node
        helper.make_node("Constant", [], ["g"], value_floats=[1.0, 2.0]),  # 2 more
        helper.make_node("ReduceSum", ["w"], ["sw"], keepdims=0),
        helper.make_node("ReduceSum", ["c"], ["sc"], keepdims=0),
        helper.make_node("Add", ["sw", "sc"], ["t"]),
        helper.make_node("Expand", ["t", "shape"], ["out"]),
    ]
    shape = numpy_helper.from_array(np.array([7, 3, 107], np.int64), "shape")
    m = _model(nodes, [SCALE], [GRID], [weights, shape])
    helper.set_model_props(m, {"params": "3"})
    path = tmp_path / "counted.onnx"
    path.write_bytes(m.SerializeToString())
    info = inspect(path)
    assert info.params == 200 + 3 + 5 + 2 and info.inputs == ("scale_m",)
    assert dict(info.metadata)["params"] == "3"  # declared, never used
    out = OnnxModel(path).predict(
        {
            "vertices": [np.zeros((3, 3), np.float32)],
            "faces": [np.zeros((1, 3), np.int64)],
            "scale_m": np.ones((1, 3)),
        }  # fmt: skip
    )
    assert out.shape == (1, 7, 3, 107) and np.allclose(out, 205.0)


def test_time_and_memory_limits_refuse_in_one_line(builds, tmp_path):
    """The child that runs a model is killed past the wall-time limit and cannot grow past
    the memory limit; either way one line, nothing written."""
    grid = numpy_helper.from_array(np.full((7, 3, 107), -40.0, np.float32), "grid")
    model = tmp_path / "flat.onnx"
    flat = _model([helper.make_node("Identity", ["grid"], ["out"])], [SCALE], [GRID], [grid])
    model.write_bytes(flat.SerializeToString())
    entries = tmp_path / "entries"
    msg = refused("evaluate-model", model, "--data", builds.held, "--entries", entries,
                  "--time-limit", "0.2")  # fmt: skip
    assert str(model) in msg and "ran past the time limit of 0.2 s" in msg
    hungry = tmp_path / "hungry.onnx"  # 800 MB of zeros at run time, summed into the grid
    size = numpy_helper.from_array(np.array([200_000_000], np.int64), "size")
    nodes = [
        helper.make_node("ConstantOfShape", ["size"], ["zeros"]),
        helper.make_node("ReduceSum", ["zeros"], ["s"], keepdims=0),
        helper.make_node("Add", ["grid", "s"], ["out"]),
    ]
    hungry.write_bytes(_model(nodes, [SCALE], [GRID], [grid, size]).SerializeToString())
    msg = refused("evaluate-model", hungry, "--data", builds.held, "--entries", entries,
                  "--memory-limit", "512")  # fmt: skip
    assert str(hungry) in msg and "ran out of the memory limit of 512 MiB" in msg
    assert not entries.exists()
    lb("evaluate-model", model, "--data", builds.held, "--entries", entries)  # within limits
    (e,) = store.load_entries(entries)
    assert e["params"] == 7 * 3 * 107 and e["metrics"]["no_skill"] is True
