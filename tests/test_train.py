"""Training regimes, determinism, checkpoints, the DDP path and the train CLI."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
import trimesh

from benchmark import corpus
from benchmark.cli import main as benchmark_main
from benchmark.data import BenchmarkData, ScaleBins
from benchmark.models import ReconstructionHead, build_model
from benchmark.models.checkpoint import CheckpointError, CheckpointModel, load_checkpoint, save_checkpoint
from benchmark.protocol import load_results, score_predictions
from benchmark.reproduce import ROWS, findings
from benchmark.train import (PretrainTask, TrainConfig, benchmark_examples, corpus_examples,
                             epoch_batches, fit, train)
from tests.benchmark_fixture import make_dataset

TINY = dict(dim=16, embed_layers=1, agg_layers=1, n_heads=2, decoder_hidden=32, codebook_size=16,
            epochs=2, batch_size=4, pretrain_meshes=20, pretrain_epochs=1, pretrain_max_faces=100)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("bs"), objects_per_class=4, n_test_per_class=1,
                        grid=(3, 2, 8))


def run(data_dir, **kw):
    with BenchmarkData(data_dir) as data:
        return train(TrainConfig(**{**TINY, **kw}), data, progress=False)


def states_equal(a, b) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


@pytest.mark.parametrize("embedding,regime", [("graph", "basic"), ("token", "autoencoder")])
def test_training_is_deterministic_for_a_seed(data_dir, embedding, regime):
    a, ca = run(data_dir, embedding=embedding, regime=regime)
    b, cb = run(data_dir, embedding=embedding, regime=regime)
    c, _ = run(data_dir, embedding=embedding, regime=regime, seed=1)
    assert states_equal(a, b) and ca["history"] == cb["history"]
    assert not states_equal(a, c)


def test_basic_sees_simple_meshes_and_ideal_all_meshes(data_dir):
    with BenchmarkData(data_dir) as data:
        train_objects = data.object_rows("train")
        basic, basic_groups = benchmark_examples(data, "basic", False, ScaleBins())
        ideal, groups = benchmark_examples(data, "ideal", False, ScaleBins())
        simple_faces = {len(data.mesh(int(data.meshes_of(o)[0]))[1]) for o in train_objects}
    assert len(basic) == len(basic_groups) == len(train_objects) == len(groups)
    assert {e.features.n_faces for e in basic} == simple_faces
    assert len(ideal) == 3 * len(train_objects)  # the fixture has 3 meshes per object
    seen = set()
    for epoch in range(6):
        chosen = sorted(i for b in epoch_batches(ideal, groups, 4, epoch, 0) for i in b)
        owners = [next(k for k, g in enumerate(groups) if i in g) for i in chosen]
        assert sorted(owners) == list(range(len(groups)))  # each object once per epoch
        seen.update(chosen)
    assert len(seen) > len(groups)  # complex meshes are drawn too


def test_autoencoder_reconstruction_loss_decreases():
    meshes = corpus.procedural_corpus(24, seed=3, max_faces=120)
    examples = corpus_examples(meshes)
    torch.manual_seed(0)
    model = build_model("graph", 4, 4, dim=32, embed_layers=2)
    task = PretrainTask(model, ReconstructionHead(32, hidden=64))
    groups = [np.array([i]) for i in range(len(examples))]
    history = fit(task, examples, groups, epochs=30, batch_size=8, lr=3e-3, weight_decay=0.0,
                  seed=0, desc="ae", device=torch.device("cpu"), progress=False)
    assert history[-1]["ce"] < 0.6 * history[0]["ce"]
    assert history[-1]["acc"] > history[0]["acc"] + 0.3  # 9 coordinates x 128 levels: chance is 1%


def test_checkpoint_round_trip_with_weights_only(data_dir, tmp_path):
    model, config = run(data_dir, embedding="token", regime="basic")
    save_checkpoint(tmp_path / "ck", model, config)
    loaded, cfg = load_checkpoint(tmp_path / "ck")
    assert states_equal(model, loaded) and cfg["target_shape"] == [3, 2, 8]
    with BenchmarkData(data_dir) as data:
        rows = data.mesh_rows("test")
        batch = data.batch(rows)
        adapter = CheckpointModel(tmp_path / "ck", batch_size="2")  # CLI model args are strings
        pred = adapter.predict(batch)
        from benchmark.models import collate, featurize
        direct = model(collate([featurize(v, f) for v, f in zip(batch["vertices"], batch["faces"])],
                               scale_bin=batch["scale_bins"]))[0]
    assert pred.shape == (len(rows), 3, 2, 8)
    np.testing.assert_allclose(pred.reshape(len(rows), -1), direct.detach().numpy(), atol=1e-4)
    assert (adapter.name, adapter.embedding, adapter.regime) == ("token-basic", "token", "basic")


def test_checkpoint_with_pickled_code_is_refused(data_dir, tmp_path):
    model, config = run(data_dir, embedding="direct", regime="basic")
    save_checkpoint(tmp_path / "ck", model, config)
    torch.save({"payload": os.getcwd}, tmp_path / "ck" / "model.pt")  # a global: code on load
    with pytest.raises(CheckpointError, match="model.pt: cannot load weights"):
        load_checkpoint(tmp_path / "ck")
    (tmp_path / "ck" / "config.json").write_text("{}")
    with pytest.raises(CheckpointError, match="config.json: not a basic-shapes-checkpoint"):
        load_checkpoint(tmp_path / "ck")


def test_ddp_world_size_one_matches_single_process(data_dir, tmp_path):
    single, _ = run(data_dir, embedding="graph", regime="basic")
    torch.distributed.init_process_group("gloo", init_method=f"file://{tmp_path / 'store'}",
                                         rank=0, world_size=1)
    try:
        ddp, _ = run(data_dir, embedding="graph", regime="basic")
    finally:
        torch.distributed.destroy_process_group()
    assert states_equal(single, ddp)


def test_train_cli_writes_checkpoint_and_results(data_dir, tmp_path, capsys):
    flags = [f"--{k.replace('_', '-')}={v}" for k, v in TINY.items()]
    benchmark_main(["train", "--data", str(data_dir), "--out", str(tmp_path / "ck"),
                    "--embedding", "direct", "--regime", "ideal", "--results",
                    str(tmp_path / "r.json"), "--quiet", *flags])
    results = load_results(tmp_path / "r.json")
    assert results["model"] == {"name": "direct-ideal", "embedding": "direct", "regime": "ideal",
                                "params": json.loads((tmp_path / "ck" / "config.json").read_text())["params"]}
    assert results["seeds"]["train"] == 0 and results["metrics"]["n_objects"] == 3
    assert "direct-ideal: checkpoint in" in capsys.readouterr().out


@pytest.mark.parametrize("argv,message", [
    (["--data", "/nonexistent/bs"], "/nonexistent/bs: no such dataset directory"),
    (["--embedding", "invariant", "--regime", "autoencoder"], "has no face embedding to pretrain"),
])
def test_train_cli_bad_input(data_dir, tmp_path, argv, message):
    base = {"--data": str(data_dir), "--out": str(tmp_path / "ck")}
    for k, v in zip(argv[::2], argv[1::2]):
        base[k] = v
    with pytest.raises(SystemExit, match=message):
        benchmark_main(["train", *[x for kv in base.items() for x in kv], "--quiet"])
    assert not (tmp_path / "ck").exists()


def test_tiny_preset_end_to_end(tmp_path):
    """The whole pipeline: `basic-shapes generate` + `radar-sim label` subprocesses, the
    corpus, all 13 rows trained and evaluated by the harness, table + JSON + plot."""
    out = tmp_path / "tiny"
    benchmark_main(["reproduce", "--preset", "tiny", "--out", str(out), "--quiet"])
    table = json.loads((out / "table.json").read_text())
    names = [r["name"] for r in table["rows"]]
    assert names == [f"{e}-{r}" for e, r in ROWS] and len(names) == 13
    with BenchmarkData(out / "data") as data:
        assert data.target_shape == (7, 3, 107)
        assert table["dataset"]["fingerprint"] == data.fingerprint
        n_test = len(data.object_rows("test"))
    for row in table["rows"]:
        results = load_results(out / "results" / row["name"] / "results.json")
        assert results["metrics"]["n_objects"] == n_test
        assert row["complex_mse"] == results["metrics"]["complex_mse"]
        rescored = score_predictions(out / "data", out / "results" / row["name"] / "predictions.h5")
        assert rescored["complex_mse"] == results["metrics"]["complex_mse"]
    invariant = table["rows"][-1]
    assert invariant["name"] == "invariant-basic"
    md = (out / "table.md").read_text()
    assert md.count("\n| ") == 14 and table["command"] in md
    assert (out / "speed_vs_error.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert {f["claim"] for f in table["findings"]} >= {
        "every non-Ideal model falls short of its Ideal model on Variation MSE"}
    # a rerun reuses every finished row instead of training again
    benchmark_main(["reproduce", "--preset", "tiny", "--out", str(out), "--quiet"])
    assert json.loads((out / "table.json").read_text())["rows"] == table["rows"]
    # the rows are leaderboard submissions as they stand: seed a board and render it
    from leaderboard import cli as leaderboard_cli

    entries, site = tmp_path / "entries", tmp_path / "site"
    assert leaderboard_cli.main(["seed", "--from", str(out / "results"), "--data", str(out / "data"),
                                 "--entries", str(entries)]) is None
    assert len(list(entries.glob("*.json"))) == 13
    assert leaderboard_cli.main(["render", "--out", str(site), "--entries", str(entries)]) is None
    assert all(row["name"] in (site / "index.html").read_text() for row in table["rows"])


def test_findings_on_a_table_shaped_like_the_paper():
    """The paper's pattern holds by construction here, except one planted violation."""
    quality = {"direct": 3.0, "graph": 1.0, "token": 2.0}
    factor = {"autoencoder": 1.0, "classification": 1.5, "basic": 2.0}
    rows = []
    for e, r in ROWS[:9]:
        s = quality[e] * factor[r] * 10
        rows.append({"name": f"{e}-{r}", "embedding": e, "regime": r, "simple_mse": s,
                     "complex_mse": 2 * s, "variation_mse": s, "mode_collapse": False})
    for e, r in ROWS[9:12]:
        rows.append({"name": f"{e}-{r}", "embedding": e, "regime": r, "simple_mse": 5.0,
                     "complex_mse": 5.0, "variation_mse": 1.0, "mode_collapse": False})
    rows[-1]["variation_mse"] = 100.0  # token-ideal varies more than token-autoencoder
    rows.append({"name": "invariant-basic", "embedding": "invariant", "regime": "basic",
                 "simple_mse": 50.0, "complex_mse": 50.0, "variation_mse": 0.0, "mode_collapse": True})
    f = {x["claim"].split(" (")[0].split(":")[0]: x for x in findings(rows)}
    assert f["graph and token embeddings beat direct"]["holds"]
    assert (f["graph and token embeddings beat direct"]["held"],
            f["graph and token embeddings beat direct"]["of"]) == (18, 18)
    assert f["autoencoder pretraining beats classification pretraining and none"]["holds"]
    assert f["graph + autoencoder is best of the non-Ideal paper rows on all three metrics"]["of"] == 24
    ideal = f["every non-Ideal model falls short of its Ideal model on Variation MSE"]
    assert not ideal["holds"] and (ideal["held"], ideal["of"]) == (6, 9)
    assert ideal["failed"] == ["token-basic", "token-classification", "token-autoencoder"]
    assert f["no row is mode-collapsed"]["failed"] == ["invariant-basic"]
    partial = findings(rows[9:])  # only the Ideal and invariant rows: nothing to compare
    assert [x["holds"] for x in partial[:4]] == [None] * 4 and partial[4]["holds"] is False


def test_classification_pretraining_on_a_shapenet_layout(data_dir, tmp_path):
    root = tmp_path / "ShapeNetCore.v2"
    shapes = {"02691156": [trimesh.creation.box(), trimesh.creation.icosphere(1)],
              "03001627": [trimesh.creation.cylinder(0.5, 1.0, sections=8), trimesh.creation.box((1, 2, 3))]}
    for synset, meshes in shapes.items():
        for k, mesh in enumerate(meshes):
            path = root / synset / f"m{k}" / "models" / "model_normalized.obj"
            path.parent.mkdir(parents=True)
            mesh.export(path)
    (root / "taxonomy.json").write_text(json.dumps([
        {"synsetId": "02691156", "name": "airplane", "children": []},
        {"synsetId": "03001627", "name": "chair", "children": []}]))
    model, config = run(data_dir, embedding="graph", regime="classification", shapenet=str(root),
                        pretrain_epochs=3)
    assert config["train"]["shapenet"] == str(root) and len(config["history"]["pretrain"]) == 3
    assert set(config["history"]["pretrain"][0]) == {"loss", "ce", "acc"}
