"""Every hash is checked where its data is trusted, and no command overwrites its inputs.

A flipped bit in a shard's meshes (fingerprint kept) or a scaled label is refused by every
reader: scoring, info, export, show, radar-sim plot; `radar-sim label` redoes tampered labels
instead of skipping the shard as done. Outputs that name an input, lie inside the dataset or
name each other are refused by the parser's rules (exit 2) before any work. Training flags out
of range are refused by the parser too.
"""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import pytest

from basic_shapes.shards import Shard, ShardError, dataset_fingerprint, label_fingerprint
from benchmark.scoring.protocol import MeanResponseModel
from benchmark_fixture import make_dataset
from test_hostile import ROOT, cli


def refused_by_parser(tool: str, args, phrase: str, capsys, watch=()) -> None:
    """A CLI run in this process (flag refusals need no subprocess): exit 2, one stderr line
    naming ``phrase``, no traceback, nothing written under ``watch``."""
    import importlib

    from test_hostile import snapshot

    before = snapshot(*watch)
    main = importlib.import_module(f"{tool}.cli").main
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in args])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert exc.value.code == 2, err
    assert len(lines) == 1 and "Traceback" not in err and phrase in lines[0], err
    assert snapshot(*watch) == before, "something was written"


@pytest.fixture
def data(tmp_path):
    return make_dataset(tmp_path / "data", objects_per_class=2, n_test_per_class=1)


def flip_vertex(directory, shard="shard-00000.h5", row=3):
    with h5py.File(directory / shard, "r+") as f:
        v = f["meshes/vertices"][row]
        f["meshes/vertices"][row] = np.nextafter(v, np.float32(np.inf))


def scale_labels(directory, shard="shard-00000.h5", factor=10):
    with h5py.File(directory / shard, "r+") as f:
        f["radar/response"][0] = f["radar/response"][0] * np.complex64(factor)


def test_fingerprints_refuse_edited_content(data):
    mesh, labels = dataset_fingerprint(data), label_fingerprint(data)
    scale_labels(data)
    assert dataset_fingerprint(data) == mesh  # the meshes did not change
    with pytest.raises(ShardError, match="labels .* do not match"):
        label_fingerprint(data)
    flip_vertex(data)
    with pytest.raises(ShardError, match="does not match its stored fingerprint"):
        dataset_fingerprint(data)
    assert labels


def test_every_array_of_an_object_is_in_the_mesh_fingerprint(data):
    """object_index, params, hausdorff: none of them can change unnoticed (issue 20)."""
    for name in ("meshes/object_index", "objects/params", "meshes/hausdorff", "objects/seed"):
        copy = data.parent / name.replace("/", "-")
        import shutil

        shutil.copytree(data, copy)
        with h5py.File(copy / "shard-00000.h5", "r+") as f:
            d = f[name]
            if d.dtype.kind == "O":
                d[0] = b'{"x": 1}'
            else:
                d[0] = d[0] + 1
        with Shard(copy / "shard-00000.h5") as s, pytest.raises(ShardError):
            s.verify()


def test_scoring_refuses_tampered_labels(data, tmp_path):
    scale_labels(data)
    cli(
        "benchmark",
        "evaluate",
        "--data",
        data,
        "--model",
        f"benchmark.scoring.protocol:{MeanResponseModel.__name__}",
        "--model-arg",
        f"data_dir={data}",
        "--out",
        tmp_path / "r.json",
        phrase="do not match their stored fingerprint",
        watch=[data, tmp_path],
    )


@pytest.mark.parametrize(
    "tool, args",
    [
        ("basic-shapes", ("info", "--data", "{data}")),
        ("basic-shapes", ("export", "--data", "{data}", "--format", "obj", "--out", "{out}")),
        ("basic-shapes", ("export", "--data", "{data}", "--format", "g2s", "--out", "{out}")),
        ("basic-shapes", ("show", "--data", "{data}", "--object", "0", "--out", "{tmp}/s.png")),
        ("radar-sim", ("plot", "--data", "{data}", "--object", "0", "--out", "{tmp}/r.png")),
    ],
)
def test_readers_refuse_a_flipped_vertex(data, tmp_path, tool, args):
    flip_vertex(data)
    out = tmp_path / "out"
    module = tool.replace("-", "_") if tool != "radar-sim" else "radar_sim"
    cli(
        module,
        *(a.format(data=data, out=out, tmp=tmp_path) for a in args),
        phrase="does not match its stored fingerprint",
        watch=[data, tmp_path],
    )
    assert not out.exists() and not list(tmp_path.glob("*.png"))


@pytest.mark.parametrize(
    "tool, args, phrase",
    [
        (
            "benchmark",
            ("evaluate", "--data", "{data}", "--predictions", "{p}", "--out", "{p}"),
            "--out {p} would overwrite the input --predictions",
        ),
        (
            "benchmark",
            (
                "evaluate",
                "--data",
                "{data}",
                "--predictions",
                "{p}",
                "--out",
                "{data}/shard-00000.h5",
            ),
            "would overwrite the input --data",
        ),
        (
            "benchmark",
            (
                "evaluate",
                "--data",
                "{data}",
                "--model",
                "m:M",
                "--out",
                "{x}",
                "--write-predictions",
                "{x}",
            ),
            "name the same path",
        ),
        (
            "benchmark",
            ("train", "--data", "{data}", "--out", "{data}/ckpt"),
            "would overwrite the input --data",
        ),
        (
            "basic_shapes",
            ("export", "--data", "{data}", "--format", "obj", "--out", "{data}"),
            "would overwrite the input --data",
        ),
        (
            "basic_shapes",
            ("show", "--data", "{data}", "--object", "0", "--out", "{data}/shard-00001.h5"),
            "would overwrite the input --data",
        ),
        (
            "radar_sim",
            ("plot", "--data", "{data}", "--object", "0", "--out", "{data}/x.png"),
            "would overwrite the input --data",
        ),
        (
            "leaderboard",
            ("render", "--entries", "{e}", "--out", "{e}"),
            "would overwrite the input --entries",
        ),
        (
            "leaderboard",
            ("render", "--entries", "{e}/sub", "--out", "{e}"),
            "would overwrite the input --entries",
        ),
    ],
)
def test_outputs_never_overwrite_inputs(data, tmp_path, tool, args, phrase, capsys):
    names = {
        "data": data,
        "p": tmp_path / "p.h5",
        "x": tmp_path / "x.json",
        "e": tmp_path / "entries",
    }
    (tmp_path / "p.h5").write_bytes(b"predictions")
    (tmp_path / "entries" / "sub").mkdir(parents=True)
    refused_by_parser(
        tool,
        [a.format(**names) for a in args],
        phrase.format(**names),
        capsys,
        watch=[data, tmp_path],
    )


@pytest.mark.parametrize(
    "flag, value, phrase",
    [
        ("--epochs", "-1", "must be >= 1"),
        ("--batch-size", "0", "must be >= 1"),
        ("--lr", "nan", "not a finite number"),
        ("--dim", "0", "must be >= 1"),
        ("--dim", "100000000", "must be <= 4096"),
        ("--weight-decay", "-1", "must be >= 0"),
    ],
)
def test_training_flags_are_refused_by_the_parser(data, tmp_path, flag, value, phrase, capsys):
    refused_by_parser(
        "benchmark",
        ["train", "--data", data, "--out", tmp_path / "ck", flag, value],
        phrase,
        capsys,
        watch=[data, tmp_path],
    )


def test_training_flags_that_contradict_each_other(data, tmp_path):
    cli(
        "benchmark",
        "train",
        "--data",
        data,
        "--out",
        tmp_path / "ck",
        "--n-heads",
        "3",
        "--dim",
        "10",
        phrase="multiple of n_heads",
        watch=[data, tmp_path],
    )
    cli(
        "benchmark",
        "train",
        "--data",
        data,
        "--out",
        tmp_path / "ck",
        "--device",
        "cuda:99",
        rc=2,
        phrase="no such CUDA device",
        watch=[data, tmp_path],
    )


def test_predictions_in_linear_magnitude_are_refused(data, tmp_path):
    """|A| stored where 20 log10 |A| is expected: refused with the conversion, exit 1."""
    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.protocol import write_predictions

    with BenchmarkData(data) as d:
        rows = d.mesh_rows("test")  # the fixture has no OOD meshes
        db = np.stack([d.target(int(d.meshes["object"][r])) for r in rows])
        pred = tmp_path / "linear.h5"
        write_predictions(
            pred,
            d.fingerprint,
            d.meshes["uid"][rows],
            10 ** (db / 20),
            label_fingerprint=d.label_fingerprint,
        )
    cli(
        "benchmark",
        "evaluate",
        "--data",
        data,
        "--predictions",
        pred,
        "--out",
        tmp_path / "r.json",
        phrase="look like linear magnitudes",
        watch=[data],
    )


def test_a_constant_zero_db_prediction_is_scored(data, tmp_path):
    """np.zeros, the first predictor one tries, is dB of one value (not a linear-magnitude
    slip): scored, Simple MSE the mean square of the simple meshes' labels."""
    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.evaluate import evaluate
    from benchmark.scoring.protocol import write_predictions

    with BenchmarkData(data) as d:
        rows = d.mesh_rows("test")
        pred = tmp_path / "zeros.h5"
        write_predictions(
            pred,
            d.fingerprint,
            d.meshes["uid"][rows],
            np.zeros((len(rows), *d.target_shape), np.float32),
            label_fingerprint=d.label_fingerprint,
        )
        objects = np.unique(d.meshes["object"][rows])
        expected = np.mean([np.mean(d.target(int(o)).astype(np.float64) ** 2) for o in objects])
    result = evaluate(data, predictions=pred, progress=False)
    assert result["metrics"]["simple_mse"] == pytest.approx(expected, rel=1e-6)


def test_a_model_returning_linear_values_is_named_not_its_scratch_file(data):
    """The refusal names the model (its predictions went to a deleted temporary file)."""
    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.evaluate import evaluate
    from benchmark.scoring.protocol import PredictionsError

    with BenchmarkData(data) as d:
        target_shape = d.target_shape

    class Linear:
        name = "linear-model"

        def predict(self, batch):
            shape = (len(batch["scale_m"]), *target_shape)
            return np.random.default_rng(0).random(shape).astype(np.float32)

    with pytest.raises(PredictionsError, match="^linear-model's predict output: .* linear"):
        evaluate(data, model=Linear(), progress=False)


LIGHT_CORE = ("numpy", "numpy.libs", "h5py", "h5py.libs", "tqdm")


def light_core_path(tmp_path) -> str:
    """A sys.path holding the repository and the light core's packages (pyproject.toml's
    dependencies) and nothing else installed: with ``python -S`` (no site-packages) it is the
    environment ``pip install basic-shapes`` without extras gives."""
    import numpy

    installed = Path(numpy.__file__).parent.parent
    core = tmp_path / "light-core"
    core.mkdir()
    for name in LIGHT_CORE:
        if (installed / name).exists():
            (core / name).symlink_to(installed / name)
    return os.pathsep.join([str(ROOT), str(core)])


def test_scoring_and_submitting_need_only_the_light_core(data, tmp_path):
    """`benchmark evaluate --predictions` and `leaderboard submit` in an environment of the
    light core alone (numpy, h5py, tqdm; no site-packages): what a submitter installs
    (`pip install basic-shapes`, no extras; pyproject.toml)."""
    import subprocess
    import sys

    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.protocol import write_predictions

    with BenchmarkData(data) as d:
        rows = d.mesh_rows("test")
        db = np.stack([d.target(int(d.meshes["object"][r])) for r in rows]) - 3.0
        write_predictions(
            tmp_path / "p.h5",
            d.fingerprint,
            d.meshes["uid"][rows],
            db,
            label_fingerprint=d.label_fingerprint,
        )
    runs = [
        (
            "benchmark.cli",
            [
                "evaluate",
                "--data",
                str(data),
                "--predictions",
                str(tmp_path / "p.h5"),
                "--out",
                str(tmp_path / "r.json"),
            ],
        ),
        (
            "leaderboard.cli",
            [
                "submit",
                str(tmp_path / "r.json"),
                "--predictions",
                str(tmp_path / "p.h5"),
                "--data",
                str(data),
                "--entries",
                str(tmp_path / "entries"),
                "--unregistered",
            ],
        ),
    ]
    env = {**os.environ, "PYTHONPATH": light_core_path(tmp_path)}
    for module, args in runs:
        proc = subprocess.run(
            [sys.executable, "-S", "-m", module, *args], capture_output=True, text=True, env=env
        )
        assert proc.returncode == 0, proc.stderr
    proc = subprocess.run(  # the environment really is the light core
        [sys.executable, "-S", "-c", "import torch"], capture_output=True, text=True, env=env
    )
    assert "No module named 'torch'" in proc.stderr
    assert len(list((tmp_path / "entries").glob("*.json"))) == 1


def test_one_owner_for_metric_names():
    from benchmark.scoring import metrics, schema
    from leaderboard import render, store

    assert metrics.METRIC_NAMES is schema.METRIC_NAMES is store.METRIC_NAMES
    assert render.COLUMNS == schema.METRIC_NAMES + schema.OOD_METRIC_NAMES


def test_frequency_unit_slips_are_caught(tmp_path):
    """GHz flag given in Hz: refused by the parser with the fix; Hz API given GHz: warned."""
    import warnings

    import trimesh

    import radar_sim

    cube = trimesh.creation.box(extents=(0.3, 0.3, 0.3))
    cube.export(tmp_path / "cube.stl")
    cli(
        "radar_sim",
        "rcs",
        tmp_path / "cube.stl",
        "--freq",
        "10e9",
        "--aspect",
        "0",
        rc=2,
        phrase="looks like Hz (give 10 for 1e+10 Hz)",
        watch=[tmp_path],
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        radar_sim.rcs(cube.vertices, cube.faces, 10.0, [0.0])
    assert any(
        issubclass(w.category, radar_sim.UnitsWarning)
        and "look like GHz" in str(w.message)
        and "pass 1e+10" in str(w.message)
        for w in caught
    )


def test_a_disk_too_full_for_a_shard_is_refused_before_writing(data, tmp_path, monkeypatch):
    """HDF5 that runs out of space mid-write can crash on close: the writers check first."""
    import collections
    import shutil

    from basic_shapes.shards import Shard, rewrite_atomically

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(1 << 30, 1 << 30, 1 << 20))
    shard = data / "shard-00000.h5"
    before = shard.read_bytes()
    with pytest.raises(OSError, match="No space left on device") as err:
        rewrite_atomically(shard, lambda f: None)
    assert err.value.filename == str(shard)
    assert shard.read_bytes() == before and not list(data.glob("*.tmp"))
    with Shard(shard) as s:
        s.verify()
