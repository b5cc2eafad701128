"""Training regimes, determinism, checkpoints, the DDP path and the train CLI."""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import asdict

import numpy as np
import pytest
import torch
import trimesh

from benchmark.cli import main as benchmark_main
from benchmark.reproduction.presets import ROWS
from benchmark.reproduction.report import findings
from benchmark.scoring.data import BenchmarkData, ScaleBins
from benchmark.scoring.protocol import load_results, score_predictions
from benchmark.scoring.schema import METRIC_NAMES, check_training
from benchmark.training import corpus
from benchmark.training.models import (
    FACE_EMBEDDINGS,
    REGISTRY,
    ReconstructionHead,
    build_model,
)
from benchmark.training.models.checkpoint import (
    CheckpointError,
    CheckpointModel,
    load_checkpoint,
    save_checkpoint,
    training_record,
)
from benchmark.training.train import (
    PretrainTask,
    TrainConfig,
    benchmark_examples,
    corpus_examples,
    epoch_batches,
    fit,
    train,
)
from benchmark_fixture import make_dataset

TINY = dict(
    dim=16,
    embed_layers=1,
    agg_layers=1,
    n_heads=2,
    decoder_hidden=32,
    codebook_size=16,
    epochs=2,
    batch_size=4,
    pretrain_meshes=20,
    pretrain_epochs=1,
    pretrain_max_faces=100,
)
TINY_LR = TrainConfig().lr


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return make_dataset(
        tmp_path_factory.mktemp("bs"), objects_per_class=4, n_test_per_class=1, grid=(3, 2, 8)
    )


def run(data_dir, **kw):
    with BenchmarkData(data_dir) as data:
        return train(TrainConfig(**{**TINY, **kw}), data, progress=False)


def states_equal_to(model, state: dict) -> bool:
    own = model.state_dict()
    return own.keys() == state.keys() and all(torch.equal(own[k], state[k]) for k in own)


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
        basic, basic_groups = benchmark_examples(data, "basic", (), ScaleBins())
        ideal, groups = benchmark_examples(data, "ideal", (), ScaleBins())
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


@pytest.mark.slow  # minutes of real training / real Blender meshes: CI's slow set
def test_autoencoder_reconstruction_loss_decreases():
    meshes = corpus.procedural_corpus(24, seed=3, max_faces=120)
    examples = corpus_examples(meshes)
    torch.manual_seed(0)
    model = build_model("graph", 4, 4, dim=32, embed_layers=2)
    task = PretrainTask(model, ReconstructionHead(32, hidden=64))
    groups = [np.array([i]) for i in range(len(examples))]
    history = fit(
        task,
        examples,
        groups,
        epochs=30,
        batch_size=8,
        lr=3e-3,
        weight_decay=0.0,
        seed=0,
        desc="ae",
        device=torch.device("cpu"),
        progress=False,
    )
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
        from benchmark.training.models import collate, featurize

        direct = model(
            collate(
                [featurize(v, f) for v, f in zip(batch["vertices"], batch["faces"])],
                scale_bin=batch["scale_bins"],
            )
        )[0]
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
    torch.distributed.init_process_group(
        "gloo", init_method=f"file://{tmp_path / 'store'}", rank=0, world_size=1
    )
    try:
        ddp, _ = run(data_dir, embedding="graph", regime="basic")
    finally:
        torch.distributed.destroy_process_group()
    assert states_equal(single, ddp)


def test_train_cli_writes_checkpoint_and_results(data_dir, tmp_path, capsys):
    flags = [f"--{k.replace('_', '-')}={v}" for k, v in TINY.items()]
    benchmark_main(
        [
            "train",
            "--data",
            str(data_dir),
            "--out",
            str(tmp_path / "ck"),
            "--embedding",
            "direct",
            "--regime",
            "ideal",
            "--results",
            str(tmp_path / "r.json"),
            "--quiet",
            *flags,
        ]
    )
    results = load_results(tmp_path / "r.json")
    assert results["model"] == {
        "name": "direct-ideal",
        "embedding": "direct",
        "regime": "ideal",
        "params": json.loads((tmp_path / "ck" / "config.json").read_text())["params"],
    }
    assert results["seeds"]["train"] == 0 and results["metrics"]["n_objects"] == 3
    assert "training" not in results  # the fixture has no val split: no curve to record
    assert "direct-ideal: checkpoint in" in capsys.readouterr().out
    assert sorted(os.listdir(tmp_path / "ck")) == ["config.json", "model.pt"]  # no resume.pt


class Killed(Exception):
    pass


def killer(at: int):
    """A ``log`` that stops the run at its ``at``-th epoch line, before that epoch is saved."""
    lines = []

    def log(line):
        lines.append(line)
        if len(lines) == at:
            raise Killed(line)

    return log


def test_resume_state_restores_the_random_state_and_ignores_other_files(tmp_path):
    from benchmark.training.resume import Resume
    from benchmark.training.train import make_optimizer

    task = torch.nn.Linear(2, 2)
    opt = make_optimizer(task, 1e-3, 0.0)
    path = tmp_path / "resume.pt"
    torch.manual_seed(0)
    torch.rand(3)
    Resume(path, {"run": 1}).save("train", 1, 5, [{"loss": 1.0}], None, task, opt, last=True)
    expected = torch.rand(4)
    torch.manual_seed(123)
    assert Resume(path, {"run": 2}).restore("train", task, opt) == (0, 0, [], None)
    assert Resume(path, {"run": 1}).restore("pretrain", task, opt) == (0, 0, [], None)
    assert Resume(path, {"run": 1}).restore("train", task, opt) == (1, 5, [{"loss": 1.0}], None)
    assert torch.equal(torch.rand(4), expected)  # dropout and sampling continue as they would
    path.write_bytes(path.read_bytes()[:100])  # truncated: start afresh
    assert Resume(path, {"run": 1}).restore("train", task, opt) == (0, 0, [], None)


@pytest.mark.parametrize(
    "embedding,regime,kills",
    [
        ("graph", "basic", [3, 2]),  # twice in training
        ("token", "classification", [2, 2]),  # in pretraining, then in training
        ("direct", "autoencoder", [3]),  # at training's first epoch, pretraining finished
    ],
)
def test_a_killed_run_continues_to_the_same_bytes(tmp_path, monkeypatch, embedding, regime, kills):
    """A run killed between epochs and started again with its state file ends with the
    weights and the history of one uninterrupted run; a state of another config is ignored."""
    from benchmark.training import resume

    monkeypatch.setattr(resume, "EVERY_S", 0.0)  # keep every epoch
    d = make_dataset(
        tmp_path / "v", objects_per_class=4, n_test_per_class=1, n_val_per_class=1, grid=(3, 2, 8)
    )
    cfg = TrainConfig(
        **{**TINY, "epochs": 4, "pretrain_epochs": 2}, embedding=embedding, regime=regime
    )
    state = tmp_path / "ck" / resume.FILE
    with BenchmarkData(d) as data:
        whole, whole_cfg = train(cfg, data, progress=False)
        other, _ = train(TrainConfig(**{**asdict(cfg), "seed": 1}), data, progress=False)
        for at in kills:
            with pytest.raises(Killed):
                train(cfg, data, progress=False, log=killer(at), resume=state)
            assert state.is_file()
        again, again_cfg = train(cfg, data, progress=False, resume=state)
        # the state is cfg's: a run of another seed on the same file starts afresh
        fresh, _ = train(
            TrainConfig(**{**asdict(cfg), "seed": 1}), data, progress=False, resume=state
        )
    assert states_equal(whole, again) and states_equal(other, fresh)
    assert not states_equal(whole, other)
    assert again_cfg["history"] == whole_cfg["history"]
    assert again_cfg["selection"] == whole_cfg["selection"]


@pytest.mark.parametrize(
    "argv,message",
    [
        (["--data", "/nonexistent/bs"], "/nonexistent/bs: no such dataset directory"),
        (
            ["--embedding", "invariant", "--regime", "autoencoder"],
            "has no face embedding to pretrain",
        ),
    ],
)
def test_train_cli_bad_input(data_dir, tmp_path, argv, message):
    base = {"--data": str(data_dir), "--out": str(tmp_path / "ck")}
    for k, v in zip(argv[::2], argv[1::2]):
        base[k] = v
    with pytest.raises(SystemExit, match=message):
        benchmark_main(["train", *[x for kv in base.items() for x in kv], "--quiet"])
    assert not (tmp_path / "ck").exists()


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A `benchmark reproduce --preset tiny` output folder (made once for this module), on
    one thread: the other test process has the other core (with two threads, as reproduce
    sets by default on two cores, this took 50 s instead of 23)."""
    out = tmp_path_factory.mktemp("tiny") / "tiny"
    benchmark_main(
        ["reproduce", "--preset", "tiny", "--out", str(out), "--threads", "1", "--quiet"]
    )
    return out


def test_tiny_preset_end_to_end(tiny, tmp_path):
    """The whole pipeline: `basic-shapes generate` + `radar-sim label` subprocesses, the
    corpus, every row of ROWS trained and evaluated by the harness, table + JSON + plot."""
    out = tiny
    table = json.loads((out / "table.json").read_text())
    names = [r["name"] for r in table["rows"]]
    assert names == [f"{e}-{r}" for e, r in ROWS]
    paper = 4 * len(FACE_EMBEDDINGS)  # basic, classification, autoencoder and ideal of each
    assert names[paper:] == [f"{e}-basic" for e in REGISTRY if e not in FACE_EMBEDDINGS]
    with BenchmarkData(out / "data") as data:
        assert data.target_shape == (7, 3, 107)
        assert table["dataset"]["fingerprint"] == data.fingerprint
        n_test = len(data.object_rows("test"))
    for row in table["rows"]:
        results = load_results(out / "results" / row["name"] / "seed-0" / "results.json")
        assert results["metrics"]["n_objects"] == n_test and row["seeds"] == [0]
        assert row["complex_mse"] == pytest.approx(results["metrics"]["complex_mse"], rel=1e-12)
        board = load_results(out / "results" / row["name"] / "results.json")
        assert board["seeds"]["train_all"] == [0] and board["metrics"] == results["metrics"]
        kept = [c for c in row["val_curves"] if c]  # the tiny dataset may have no val split
        assert board.get("training", {}).get("val_curves", []) == kept
        rescored = score_predictions(out / "data", out / "results" / row["name"] / "predictions.h5")
        assert rescored["complex_mse"] == results["metrics"]["complex_mse"]
        assert row["speed"]["threads"] >= 1
        assert "timed alone on" in row["speed"]["hardware"]
        assert "fastest of 1 pass(es) after a warm-up" in row["speed"]["hardware"]  # tiny: 1
        for cname, block in results["metrics"]["per_class"].items():  # one seed: its own
            assert row["per_class"][cname]["complex_mse"] == pytest.approx(
                block["complex_mse"], rel=1e-12
            )
    by_name = {r["name"]: r for r in table["rows"]}
    assert by_name["blind-basic"]["variation_mse"] == 0.0  # blind to the mesh
    assert set(table["references"]) == {
        "train-mean",
        "class-mean",
        "nearest-scale",
        "class-scale-nn",
    }
    md = (out / "table.md").read_text()
    # the main table, the per-remesher sub-table of the OOD meshes and the peak-relative one
    # (header, 4 refs, every row each); tiny has no val split, so no plateau table or curves
    assert md.count("\n| ") == 3 * (1 + 4 + len(ROWS)) and table["command"] in md
    assert "### Peak-relative MSE (secondary)" in md and "### Training to the plateau" not in md
    for row in table["rows"]:
        assert row["epochs_to_plateau"] == [None] and row["val_curves"] == [None]
        assert row["peak_simple_mse"] is not None
    assert not (out / "training_curves.png").exists()
    assert "reference: train-mean" in md and "### Out-of-distribution meshes per remesher" in md
    assert all(row["ood_complex_mse"] is not None for row in table["rows"])
    assert (out / "speed_vs_error.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "per_class.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for ref in table["references"].values():  # every test object in exactly one class
        assert sum(b["n_objects"] for b in ref["per_class"].values()) == n_test
    assert table["findings"] == [] and "No findings" in md  # the tiny preset decides nothing
    # a rerun reuses every finished row instead of training again
    benchmark_main(["reproduce", "--preset", "tiny", "--out", str(out), "--quiet"])
    assert json.loads((out / "table.json").read_text())["rows"] == table["rows"]
    # the rows are leaderboard submissions as they stand: seed a board and render it
    from leaderboard import cli as leaderboard_cli

    entries, site = tmp_path / "entries", tmp_path / "site"
    assert (
        leaderboard_cli.main(
            [
                "seed",
                "--from",
                str(out / "results"),
                "--data",
                str(out / "data"),
                "--entries",
                str(entries),
            ]
        )
        is None
    )
    assert len(list(entries.glob("*.json"))) == len(ROWS)
    assert {json.loads(p.read_text())["dataset"]["version"] for p in entries.glob("*.json")} == {
        "tiny-v3"
    }  # reproduce built the registered version, and submit identified it
    assert leaderboard_cli.main(["render", "--out", str(site), "--entries", str(entries)]) is None
    assert all(row["name"] in (site / "index.html").read_text() for row in table["rows"])
    page = (site / "index.html").read_text()  # the secondary metric and the physics budget
    assert "Peak-relative MSE" in page and "Physics error budget" in page


def _committed(out, to, configs: bool):
    """What a run commits: the per-seed results JSONs and (``configs``) checkpoint configs."""
    for path in out.glob("results/*/seed-*/results.json"):
        dst = to / path.relative_to(out)
        dst.parent.mkdir(parents=True)
        dst.write_bytes(path.read_bytes())
    for path in out.glob("checkpoints/*/seed-*/config.json") if configs else ():
        dst = to / path.relative_to(out)
        dst.parent.mkdir(parents=True)
        dst.write_bytes(path.read_bytes())
    return to


RESCORED = ("direct-autoencoder", "graph-ideal", "invariant-basic")


def test_released_weights_rescore_the_table(tiny, tmp_path):
    """`benchmark weights --pack` then `--from` (a file:// URL) gives a folder from which
    `benchmark reproduce` trains nothing and rebuilds the rows' numbers (three rows of three
    model families here: each row takes the same path); a corrupted or unverifiable archive
    leaves nothing behind."""
    out = tiny
    table = json.loads((out / "table.json").read_text())
    archive, committed = tmp_path / "weights.tar", tmp_path / "weights.json"
    benchmark_main(["weights", "--out", str(out), "--pack", str(archive), "--quiet"])
    shutil.copy(out / "weights.json", committed)  # what a maintainer commits
    assert len(json.loads(committed.read_text())["files"]) == 2 * len(table["rows"])
    bad = bytearray(archive.read_bytes())
    bad[len(bad) // 2] ^= 0xFF
    (tmp_path / "bad.tar").write_bytes(bytes(bad))
    with pytest.raises(SystemExit, match="does not match the sha256|not a readable tar"):
        benchmark_main(
            [
                "weights",
                "--out",
                str(tmp_path / "x"),
                "--from",
                str(tmp_path / "bad.tar"),
                "--manifest",
                str(committed),
                "--quiet",
            ]
        )
    assert not (tmp_path / "x").exists()
    rescore = tmp_path / "rescore"
    benchmark_main(
        [
            "weights",
            "--out",
            str(rescore),
            "--from",
            archive.as_uri(),
            "--manifest",
            str(committed),
            "--quiet",
        ]
    )
    benchmark_main(
        [
            "reproduce",
            "--preset",
            "tiny",
            "--data",
            str(out / "data"),
            "--out",
            str(rescore),
            "--rows",
            ",".join(RESCORED),
            "--quiet",
        ]
    )
    again = json.loads((rescore / "table.json").read_text())
    assert not (rescore / "corpus.h5").exists()  # nothing was trained again
    assert again["timing"]["rows_trained"] == 0
    assert f"{len(RESCORED)} evaluated from saved weights" in (rescore / "table.md").read_text()
    assert [r["name"] for r in again["rows"]] == list(RESCORED)
    for b in again["rows"]:
        a = next(r for r in table["rows"] if r["name"] == b["name"])
        for key in ("simple_mse", "complex_mse", "variation_mse", "params", "train_seconds"):
            assert b[key] == pytest.approx(a[key], rel=1e-9), (a["name"], key)


def test_report_rebuilds_the_table_from_results_alone(tiny, tmp_path, capsys):
    """`benchmark report` on the results JSONs (no models, no predictions) and the dataset
    gives reproduce's table: the same rows, references and findings; training time from the
    checkpoint configs where they were kept, else "-"."""
    table = json.loads((tiny / "table.json").read_text())
    data = str(tiny / "data")
    for configs in (True, False):
        d = _committed(tiny, tmp_path / f"configs-{configs}", configs)
        benchmark_main(["report", "--preset", "tiny", "--data", data, "--out", str(d), "--quiet"])
        again = json.loads((d / "table.json").read_text())
        for key in (
            "preset",
            "preset_config",
            "dataset",
            "seeds",
            "references",
            "strongest_reference",
            "findings",
            "no_findings",
        ):
            assert again[key] == table[key], key
        assert again["command"].startswith("benchmark report --preset tiny")
        assert again["timing"] is None and again["hardware"] is None
        if configs:
            assert again["rows"] == table["rows"]
        else:
            assert [{**r, "train_seconds": None} for r in table["rows"]] == again["rows"]
        md = (d / "table.md").read_text()
        assert "Rebuilt by `benchmark report`" in md and md in capsys.readouterr().out
        rows = [line for line in md.splitlines() if line.startswith("| direct | none | simple")]
        assert rows[0].endswith(" | - |") != configs
        assert (d / "speed_vs_error.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_refuses_missing_or_misplaced_results_in_one_line(tiny, tmp_path):
    data = str(tiny / "data")
    with pytest.raises(SystemExit) as info:
        benchmark_main(["report", "--preset", "tiny", "--data", data, "--out", str(tmp_path)])
    assert info.value.code == (
        f"benchmark report: error: {tmp_path / 'results'}: no such "
        f"directory (expected the results/ folder of a `benchmark "
        f"reproduce --out`)"
    )
    d = _committed(tiny, tmp_path / "d", configs=False)
    seed0 = d / "results" / "graph-basic" / "seed-0" / "results.json"
    (seed0.parent.parent / "seed-1").mkdir()
    seed0.rename(seed0.parent.parent / "seed-1" / "results.json")  # a file in the wrong place
    with pytest.raises(SystemExit) as info:
        benchmark_main(
            ["report", "--preset", "tiny", "--data", data, "--out", str(d), "--seeds", "0,1"]
        )
    assert info.value.code.endswith(
        "seed-1/results.json: holds the results of graph-basic seed 0, not graph-basic seed 1"
    )
    assert "\n" not in info.value.code and not (d / "table.json").exists()
    d = _committed(tiny, tmp_path / "c", configs=True)
    with pytest.raises(SystemExit) as info:  # the tiny run's results are not the small preset's
        benchmark_main(["report", "--preset", "small", "--data", data, "--out", str(d)])
    assert info.value.code.endswith(
        "seed-0/config.json: trained with dim=16, not the small preset's 32; is --preset right?"
    )
    assert not (d / "table.json").exists()


def _paper_shaped_rows(n: int = 90, seed: int = 0) -> list[dict]:
    """Rows whose per-object errors follow the paper's pattern by construction: a shared
    per-object difficulty times a per-row quality, plus small independent noise."""
    rng = np.random.default_rng(seed)
    hard = rng.gamma(2.0, 10.0, n)
    cls = np.arange(n) % 3
    quality = {"direct": 3.0, "graph": 1.0, "token": 2.0}
    factor = {"autoencoder": 1.0, "classification": 1.5, "basic": 2.0}
    rows = []

    def row(e, r, simple, complex_, variation):
        noisy = [
            list(x * (1 + 0.01 * rng.standard_normal(n))) for x in (simple, complex_, variation)
        ]
        return {
            "name": f"{e}-{r}",
            "embedding": e,
            "regime": r,
            "per_object": {
                "class_index": cls.tolist(),
                "simple_mse": noisy[0],
                "complex_mse": noisy[1],
                "variation_mse": noisy[2],
            },
        }

    for e, r in ROWS[:9]:
        q = quality[e] * factor[r]
        rows.append(row(e, r, q * hard, 2 * q * hard, q * hard))
    for e, r in ROWS[9:12]:
        rows.append(row(e, r, hard, hard, 0.2 * hard))
    return rows


def test_findings_are_decided_by_paired_intervals():
    rows = _paper_shaped_rows()
    f = {x["claim"].split(" (")[0]: x for x in findings(rows)}
    embed = f["graph and token embeddings beat direct"]
    assert embed["verdict"] == "holds" and (embed["holds"], embed["of"]) == (18, 18)
    pretraining = f["autoencoder pretraining beats classification pretraining and none"]
    assert pretraining["verdict"] == "holds"
    assert (
        f["graph + autoencoder is best of the non-Ideal paper rows on all three metrics"]["of"]
        == 24
    )
    ideal = f["every non-Ideal model falls short of its Ideal model on Variation MSE"]
    assert ideal["verdict"] == "holds" and ideal["of"] == 9
    for c in embed["comparisons"]:  # every comparison reports its interval and half-width
        assert c["ci"][0] < c["diff"] < c["ci"][1] < 0
        assert c["half_width"] == pytest.approx((c["ci"][1] - c["ci"][0]) / 2)
    # plant a reversal (token-ideal varies more than every token row) and a tie
    by = {r["name"]: r for r in rows}
    by["token-ideal"]["per_object"]["variation_mse"] = [
        10 * x for x in by["token-basic"]["per_object"]["variation_mse"]
    ]
    by["graph-basic"]["per_object"] = {**by["direct-basic"]["per_object"]}
    f = {x["claim"].split(" (")[0]: x for x in findings(rows)}
    ideal = f["every non-Ideal model falls short of its Ideal model on Variation MSE"]
    assert ideal["verdict"] == "reversed" and ideal["reversed"] == 3
    embed = f["graph and token embeddings beat direct"]
    tied = [c for c in embed["comparisons"] if c["better"] == "graph-basic"]
    assert [c["verdict"] for c in tied] == ["inconclusive"] * 3
    assert embed["verdict"] == "inconclusive"
    partial = findings(rows[9:])  # only the Ideal rows: nothing to compare
    assert [x["verdict"] for x in partial] == [None] * 4
    # a table still running: the token rows missing leave a claim whose present pairs all
    # hold undecided, while a reversal among the present pairs decides it
    running = [r for r in _paper_shaped_rows() if r["embedding"] != "token"]
    embed = findings(running)[0]
    assert (embed["verdict"], embed["holds"], embed["of"], embed["pairs_missing"]) == (
        None,
        9,
        9,
        3,
    )
    by = {r["name"]: r for r in running}
    by["graph-basic"]["per_object"] = {
        k: [3 * x for x in v] if k != "class_index" else v
        for k, v in by["direct-basic"]["per_object"].items()
    }
    assert findings(running)[0]["verdict"] == "reversed"


def test_findings_plan_the_seeds_for_three_db2():
    """With per-seed errors, each Complex MSE comparison says how many seeds per row would
    bring its half-width to ±3 dB²; one seed per row (no seed variance known) says nothing."""
    rows = [r for r in _paper_shaped_rows() if r["embedding"] != "token"]
    assert findings(rows)[0]["complex_seeds_for_3"] is None
    # every row the same per-object errors up to a per-seed offset: the test objects add no
    # variance to a difference, the seeds all of it (variance 24 + 1 of the seed means)
    base = rows[0]["per_object"]
    offsets = {"direct": [4.0, 10.0, 16.0], "graph": [-1.0, 0.0, 1.0]}
    for r in rows:
        r["per_object"] = base
        r["per_seed_object"] = {
            m: [[x + o for x in base[m]] for o in offsets[r["embedding"]]] for m in METRIC_NAMES
        }
    embed = findings(rows)[0]
    complex_ = [c for c in embed["comparisons"] if c["metric"] == "complex_mse"]
    assert all(c["half_width"] > 3 for c in complex_)
    # 1.96 * sqrt((36 + 1) / S) <= 3 from S = 16 on; the t quantile asks a little more
    assert all(16 <= c["seeds_for_3"] <= 19 for c in complex_), complex_
    assert embed["complex_seeds_for_3"] == max(c["seeds_for_3"] for c in complex_)


def test_rows_with_more_seeds_are_averaged_over_their_own_and_the_table_says_so():
    """A row given more seeds (where its seeds spread most) keeps them all: its comparisons
    use each row's own seed count, the table names each row's seeds and each comparison of
    rows with different counts says them."""
    from benchmark.reproduction.report import render_markdown, table_rows
    from benchmark.scoring.metrics import ood_keys
    from benchmark.scoring.uncertainty import paired_seeds

    rng = np.random.default_rng(11)
    n, cls = 30, np.arange(30) % 3
    hard = rng.gamma(2.0, 10.0, n)

    def runs(seeds: range, spread: float) -> dict:
        out = {}
        for seed in seeds:
            offset = rng.normal(0, spread)
            errs = {
                m: hard + offset + rng.normal(0, 1, n)
                for m in ("simple_mse", "complex_mse", "variation_mse", *ood_keys())
            }
            metrics = {m: float(v.mean()) for m, v in errs.items() if ":" not in m}
            po = {m: v.tolist() for m, v in errs.items()}
            out[seed] = {
                "train_seconds": 1.0,
                "results": {
                    "metrics": {**metrics, "no_skill": False, "per_class": {}},
                    "model": {"params": 5},
                    "speed": {"ms_per_mesh": 1.0},
                    "per_object": {"object_id": list(range(n)), "class_index": cls.tolist(), **po},
                },
            }
        return out

    records = {"direct-basic": runs(range(6), 4.0), "graph-basic": runs(range(3), 1.0)}
    rows = table_rows(records)
    assert [r["seeds"] for r in rows] == [list(range(6)), [0, 1, 2]]
    (embed,) = [f for f in findings(rows) if f["claim"].startswith("graph and token")]
    (c,) = [c for c in embed["comparisons"] if c["metric"] == "complex_mse"]
    per_seed = {
        name: [run["results"]["per_object"]["complex_mse"] for run in records[name].values()]
        for name in records
    }
    want = paired_seeds(per_seed["graph-basic"], per_seed["direct-basic"], cls)
    assert c["half_width"] == pytest.approx(want["half_width"]) and want["seeds"] == [3, 6]
    table = {
        **{k: None for k in ("command", "hardware", "timing")},
        "preset": "t",
        "dataset": {"description": "d", "fingerprint": "f"},
        "seeds": list(range(6)),
        "references": {},
        "rows": rows,
        "findings": [embed],
    }
    md = render_markdown(table)
    assert "each row's training seeds (direct-basic 0-5; graph-basic 0-2)" in md
    lines = [x for x in md.splitlines() if x.startswith("  - graph-basic < direct-basic")]
    assert len(lines) == 3 and all(", 3 vs 6 seeds): " in x for x in lines), lines
    # the plan for ±3 dB² (equal seeds per row) is shown only while a Complex pair is wider
    for width, shown in ((3.1, True), (2.9, False)):
        comps = [{**x, "half_width": width} for x in embed["comparisons"]]
        table["findings"] = [{**embed, "complex_seeds_for_3": 20, "comparisons": comps}]
        assert ("would need 20 seeds per row" in render_markdown(table)) == shown, width
    rows[0]["seeds"] = [0, 1, 2]
    assert "the training seeds [0, 1, 2, 3, 4, 5]" in render_markdown(table)


def test_rows_average_seeds_per_object_with_std_and_interval():
    from benchmark.reproduction.report import table_rows
    from benchmark.scoring.uncertainty import interval

    rng = np.random.default_rng(3)
    n, cls = 30, np.arange(30) % 3
    runs = {}
    for seed in (0, 1, 2):
        errs = {m: rng.gamma(2.0, 10.0, n) for m in ("simple_mse", "complex_mse", "variation_mse")}
        metrics = {m: float(v.mean()) for m, v in errs.items()}
        metrics.update(no_skill=seed == 0, per_class={"a": {}, "b": {}, "c": {}})
        runs[seed] = {
            "train_seconds": 10.0 + seed,
            "results": {
                "metrics": metrics,
                "model": {"params": 5},
                "speed": {"ms_per_mesh": 1.0},
                "per_object": {
                    "object_id": list(range(n)),
                    "class_index": cls.tolist(),
                    **{m: v.tolist() for m, v in errs.items()},
                },
            },
        }
    (row,) = table_rows({"graph-basic": runs})
    per_seed = np.array([runs[s]["results"]["per_object"]["complex_mse"] for s in (0, 1, 2)])
    assert row["seeds"] == [0, 1, 2] and row["train_seconds"] == 11.0
    assert row["complex_mse"] == pytest.approx(per_seed.mean(), rel=1e-12)
    assert row["complex_mse_std"] == pytest.approx(per_seed.mean(axis=1).std(ddof=1), rel=1e-12)
    assert row["complex_mse_ci"] == interval(per_seed.mean(axis=0), cls)  # of the seed-mean
    assert row["no_skill_seeds"] == 1 and row["no_skill"] is False  # one seed of three
    assert row["per_class"]["b"]["complex_mse"] == pytest.approx(per_seed[:, cls == 1].mean())


def test_validation_split_selects_the_checkpoint(tmp_path):
    d = make_dataset(
        tmp_path / "v", objects_per_class=4, n_test_per_class=1, n_val_per_class=1, grid=(3, 2, 8)
    )
    with BenchmarkData(d) as data:
        model, config = train(TrainConfig(**{**TINY, "epochs": 4}), data, progress=False)
        val, _ = benchmark_examples(data, "basic", (), data.scale_bins, split="val")
    hist = config["history"]["train"]
    sel = config["selection"]
    assert sel["on"] == "val" and len(val) == 3
    assert sel["val_mse"] == min(h["val_mse"] for h in hist) == hist[sel["epoch"]]["val_mse"]
    from benchmark.training.train import validation_mse

    # the returned weights are the selected epoch's: their val MSE is the recorded one
    again = validation_mse(model, val, 4, torch.device("cpu"))
    assert again == pytest.approx(sel["val_mse"], rel=1e-5)
    # the curve the results carry for the board, in the schema results are checked with
    block = check_training(training_record([config]))
    assert block["val_curves"] == [[h["val_mse"] for h in hist]]
    assert block["epochs_to_plateau"] == [sel["epoch"] + 1] and block["capped"] == [sel["capped"]]
    with BenchmarkData(
        make_dataset(tmp_path / "nv", objects_per_class=3, n_test_per_class=1, grid=(3, 2, 8))
    ) as data:
        _, config = train(TrainConfig(**TINY), data, progress=False)
    assert config["selection"] == {
        "on": "last epoch (no val split)",
        "epoch": 1,
        "val_mse": None,
        "epochs_trained": 2,
        "epochs_to_plateau": None,
        "patience": None,
        "capped": None,
    }
    assert training_record([config]) is None  # no curve: the results carry no training block


@pytest.mark.parametrize(
    "curve,patience,stop_after,best,halvings",
    [
        ([9, 8, 7, 7.5, 7.2, 7.1, 7.3], 3, 6, 2, 1),  # 3 epochs without a new best after epoch 2
        ([5, 5, 5, 5], 2, 3, 0, 1),  # a tie is no improvement: the first epoch stays the best
        ([3, 2, 2.5, 2.6, 1.9, 2, 2.1, 2.2, 2.3], 4, 9, 4, 2),  # halved at each plateau's midpoint
        ([4, 3, 2, 1], 2, None, 3, 0),  # still improving: never stops
    ],
)
def test_plateau_stops_at_the_right_epoch(curve, patience, stop_after, best, halvings):
    from benchmark.training.train import plateau

    stops = [n for n in range(1, len(curve) + 1) if plateau(curve[:n], patience)["stop"]]
    assert (stops[0] if stops else None) == stop_after
    state = plateau(curve[: stop_after or len(curve)], patience)
    assert (state["best"], state["halvings"]) == (best, halvings)


@pytest.mark.parametrize(
    "curve,epochs,trained,capped",
    [
        ([5, 3, 4, 6, 7, 8, 9, 10], 8, 4, False),  # plateau: stopped 2 epochs after the best
        ([5, 4, 3, 2], 4, 4, True),  # the cap ended a run that was still improving
        ([5, 4, 3, 3.5], 4, 4, True),  # the best is within the last `patience` epochs at the cap
        ([5, 3, 4, 4.5], 4, 4, False),  # at the cap, but the plateau had been reached
    ],
)
def test_early_stopping_restores_the_best_epoch_and_flags_the_cap(
    tmp_path, monkeypatch, curve, epochs, trained, capped
):
    """On a scripted validation curve (patience 2): training stops at the plateau, the model
    returned holds the weights of the best epoch, and ``capped`` says whether the cap ended
    a run that was still improving."""
    import benchmark.training.train as train_module

    snapshots = []

    def scripted(model, examples, batch_size, device):
        snapshots.append({k: v.clone() for k, v in model.state_dict().items()})
        return float(curve[len(snapshots) - 1])

    monkeypatch.setattr(train_module, "validation_mse", scripted)
    d = make_dataset(
        tmp_path / "v", objects_per_class=4, n_test_per_class=1, n_val_per_class=1, grid=(3, 2, 8)
    )
    with BenchmarkData(d) as data:
        model, config = train(
            TrainConfig(**{**TINY, "epochs": epochs, "patience": 2}), data, progress=False
        )
    hist, sel = config["history"]["train"], config["selection"]
    best = int(np.argmin(curve[:trained]))
    assert len(hist) == len(snapshots) == trained == sel["epochs_trained"]
    assert [h["val_mse"] for h in hist] == curve[:trained]
    assert (sel["epoch"], sel["epochs_to_plateau"], sel["capped"]) == (best, best + 1, capped)
    assert states_equal_to(model, snapshots[best])
    assert best == trained - 1 or not states_equal_to(model, snapshots[-1])
    assert hist[best]["selected"] and all("loss" in h and "lr" in h for h in hist)


def test_learning_rate_is_halved_at_half_the_patience(tmp_path, monkeypatch):
    import benchmark.training.train as train_module

    curve = iter([5.0, 3.0, 4.0, 4.5, 4.2, 4.1, 4.0])
    monkeypatch.setattr(train_module, "validation_mse", lambda *a: next(curve))
    d = make_dataset(
        tmp_path / "v", objects_per_class=4, n_test_per_class=1, n_val_per_class=1, grid=(3, 2, 8)
    )
    with BenchmarkData(d) as data:
        _, config = train(TrainConfig(**{**TINY, "epochs": 8, "patience": 4}), data, progress=False)
    lr = [h["lr"] for h in config["history"]["train"]]
    assert len(lr) == 6  # stopped once the best (epoch 1) was 4 epochs old
    assert lr[1] == lr[2] == lr[3] == TINY_LR  # after the warm-up (here one step)
    assert lr[4] == lr[5] == TINY_LR / 2  # halved once the best was 2 epochs old (epoch 3)


def test_classification_pretraining_on_a_shapenet_layout(data_dir, tmp_path):
    root = tmp_path / "ShapeNetCore.v2"
    shapes = {
        "02691156": [trimesh.creation.box(), trimesh.creation.icosphere(1)],
        "03001627": [
            trimesh.creation.cylinder(0.5, 1.0, sections=8),
            trimesh.creation.box((1, 2, 3)),
        ],
    }
    for synset, meshes in shapes.items():
        for k, mesh in enumerate(meshes):
            path = root / synset / f"m{k}" / "models" / "model_normalized.obj"
            path.parent.mkdir(parents=True)
            mesh.export(path)
    (root / "taxonomy.json").write_text(
        json.dumps(
            [
                {"synsetId": "02691156", "name": "airplane", "children": []},
                {"synsetId": "03001627", "name": "chair", "children": []},
            ]
        )
    )
    model, config = run(
        data_dir, embedding="graph", regime="classification", shapenet=str(root), pretrain_epochs=3
    )
    assert config["train"]["shapenet"] == str(root) and len(config["history"]["pretrain"]) == 3
    assert set(config["history"]["pretrain"][0]) == {"loss", "ce", "acc", "lr"}


def test_plateau_table_and_validation_curves(tmp_path):
    """Rows with kept checkpoints: epochs to the plateau per seed, capped runs counted, and a
    curves figure with one panel per row (rows without curves are left out of both)."""
    from benchmark.reproduction import report

    rows = [
        {
            "name": "graph-basic",
            "seeds": [0, 1],
            "epochs_to_plateau": [3, 5],
            "capped": [False, True],
            "val_curves": [[9.0, 8.0, 7.5, 7.6, 7.7, 7.8], [9.0, 8.5, 8.0, 7.9, 7.8]],
        },
        {"name": "blind-basic", "seeds": [0], "epochs_to_plateau": [None], "capped": [None]},
    ]
    lines = report.plateau_table(rows)
    assert "| graph-basic | 3, 5 | 1 of 2 |" in lines and not any("blind" in x for x in lines)
    assert report.plot_curves(rows, tmp_path / "c.png", "curves")
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not report.plot_curves(rows[1:], tmp_path / "none.png", "none")


def test_rows_timed_with_fewer_passes_are_timed_again():
    """A resumed run re-times what an older harness (one pass in the evaluation, no count) or a
    cheaper preset timed, and keeps what was timed as asked."""
    from benchmark.reproduction.runner import _timed

    def record(hardware):
        return {"results": {"speed": {"hardware": hardware}}}

    cpu = "cpu: X (2 cores), 2 thread(s), load 0.1"
    assert not _timed(record(f"{cpu}; timed alone"), 1)
    assert not _timed(record(f"{cpu}; timed alone on 480 test meshes"), 1)
    assert not _timed(record(f"{cpu}; timed alone on 57 test meshes, fastest of 1 pass(es)"), 3)
    assert _timed(record(f"{cpu}; timed alone on 57 test meshes, fastest of 3 pass(es)"), 3)
    assert _timed(record(f"{cpu}; timed alone on 57 test meshes, fastest of 3 pass(es)"), 1)
    assert not _timed(record(None), 1)


def test_reproduce_warns_when_the_predictions_will_not_fit(tmp_path, capsys):
    """The paper preset writes 18 GB of predictions per run: said at the start, against the
    real free space of the output folder (an exabyte never fits, a byte always does)."""
    from benchmark.reproduction.reproduce import _warn_disk

    _warn_disk(tmp_path, 1, 1)
    assert capsys.readouterr().err == ""
    _warn_disk(tmp_path, 1000, 10**15)
    err = capsys.readouterr().err
    assert err.startswith("benchmark reproduce: warning: 1000 run(s) will write about ")
    assert f"({10**15 / 1e9:.2f} GB each)" in err and str(tmp_path) in err


@pytest.mark.skipif(torch.cuda.is_available(), reason="the warning is for machines without one")
def test_reproduce_warns_that_the_paper_preset_needs_a_gpu(tmp_path, capsys):
    """Said before anything is built (paper-v3 alone is hours of CPU)."""
    with pytest.raises(SystemExit) as exc:
        benchmark_main(
            ["reproduce", "--preset", "paper", "--data", str(tmp_path / "none"), "--out",
             str(tmp_path / "out"), "--quiet"]
        )  # fmt: skip
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("benchmark reproduce: warning: the paper preset is sized for GPUs")
    assert str(tmp_path / "none") in str(exc.value.code)


def test_every_train_option_is_explained():
    """``benchmark train --help`` describes every TrainConfig field, not only its default."""
    import argparse

    from benchmark.training.train_cli import add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    bare = [a.dest for a in parser._actions if (a.help or "").startswith(" (default")]
    assert not bare, f"options without a description: {bare}"
