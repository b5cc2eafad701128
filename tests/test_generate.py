"""End-to-end generation with real Blender, real Dask and real HDF5."""

import hashlib
import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh

from basic_shapes import cli
from basic_shapes.generate import GenerateConfig, plan_objects
from basic_shapes.shards import Shard, dataset_fingerprint, iter_objects

SMALL = [
    "--classes",
    "cube,cylinder,sphere",
    "--objects-per-class",
    "2",
    "--variants",
    "3",
    "--objects-per-shard",
    "2",
    "--seed",
    "5",
]


def _digests(d):
    return {
        p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(d.glob("shard-*.h5"))
    }


def _run_cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "basic_shapes.cli", *args], capture_output=True, text=True
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("gen") / "one"
    assert cli.main(["generate", "--data", str(out), "--workers", "1", *SMALL]) == 0
    return out


@pytest.mark.slow  # 1 vs 2 workers is also checked in the default set: tests/test_rebuild.py
def test_bytes_do_not_depend_on_workers(dataset, tmp_path):
    """In process, 1 and 2 worker processes and an existing Dask cluster: the same bytes."""
    assert cli.main(["generate", "--data", str(tmp_path / "two"), "--workers", "2", *SMALL]) == 0
    assert cli.main(["generate", "--data", str(tmp_path / "zero"), "--workers", "0", *SMALL]) == 0
    from basic_shapes.cluster import dask_client

    with dask_client(workers=2) as client:  # an existing cluster, reached through --scheduler
        address = client.scheduler.address
        assert (
            cli.main(
                ["generate", "--data", str(tmp_path / "sched"), "--scheduler", address, *SMALL]
            )
            == 0
        )
    one = _digests(dataset)
    assert len(one) == 3
    assert (
        one
        == _digests(tmp_path / "two")
        == _digests(tmp_path / "zero")
        == _digests(tmp_path / "sched")
    )


def test_dataset_content(dataset):
    seen = set()
    for _, obj, meshes in iter_objects(dataset):
        ood = [900, 901, 902, 925, 926, 927, 950, 951, 952] if obj["split"] == "test" else []
        assert [m[0] for m in meshes] == [0, 1, 2, 3, *ood]  # OOD meshes: test objects only
        v0 = meshes[0][1]
        np.testing.assert_allclose(v0.max(0) - v0.min(0), obj["scale"], rtol=1e-6)
        for _, v, f in meshes:  # same bbox, closed surface, same enclosed volume as the simple mesh
            m = trimesh.Trimesh(v, f, process=False)
            assert m.is_watertight
            np.testing.assert_allclose(v.max(0) - v.min(0), obj["scale"], rtol=2e-2)
        if obj["class"] == "cube":  # planar shape: exact box volume for every variant
            for _, v, f in meshes:
                assert trimesh.Trimesh(v, f).volume == pytest.approx(
                    np.prod(obj["scale"]), rel=1e-5
                )
        seen.add((obj["class"], obj["split"]))
    assert {c for c, _ in seen} == {"cube", "cylinder", "sphere"}
    assert {s for _, s in seen} == {"train", "test"}


def test_split_is_ninety_ten_by_object():
    cfg = GenerateConfig(objects_per_class=50, variants=1)
    plans = plan_objects(cfg)
    for cls in cfg.classes:
        splits = [p.split for p in plans if p.class_name == cls]
        assert (splits.count("test"), splits.count("val")) == (5, 5)
    assert len({p.id for p in plans}) == 150
    no_val = plan_objects(GenerateConfig(objects_per_class=50, variants=1, val_fraction=0.0))
    # the test objects do not depend on the validation fraction; val comes out of train
    assert [p.split == "test" for p in plans] == [p.split == "test" for p in no_val]
    assert {p.split for p in no_val} == {"train", "test"}
    assert [p.scale for p in plans] == [p.scale for p in plan_objects(cfg)]


def test_resume_after_kill_is_byte_identical(tmp_path):
    args = [
        "--classes",
        "cube",
        "--objects-per-class",
        "3",
        "--variants",
        "40",
        "--objects-per-shard",
        "1",
        "--seed",
        "9",
        "--workers",
        "0",
    ]
    assert cli.main(["generate", "--data", str(tmp_path / "ref"), *args]) == 0
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-m", "basic_shapes.cli", "generate", "--data", str(out), *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while not list(out.glob("shard-*.h5")) and time.time() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = _digests(out)
    assert 1 <= len(done) < 3, "the kill should land between shards"
    r = _run_cli("generate", "--data", str(out), *args)
    assert r.returncode == 0, r.stderr
    assert f"({len(done)} already done)" in r.stdout
    assert _digests(out) == _digests(tmp_path / "ref")
    assert not list(out.glob("*.tmp"))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--classes", "cube,pyramid"], "unknown class pyramid"),
        (["--objects-per-class", "0"], "argument --objects-per-class: '0' must be >= 1"),
        (["--variants", "-1"], "argument --variants: '-1' must be >= 0"),
        (["--variants", "900"], "900-999 for OOD meshes"),
        (["--ood-variants", "26"], "argument --ood-variants: '26' must be <= 25"),
        (["--objects-per-class", "100000", "--scale-range", "1.0", "1.1"], "dissimilar scales"),
    ],
)
def test_bad_generate_arguments(tmp_path, args, message):
    sizes = ["--objects-per-class", "1", "--variants", "0"]  # the last of a flag wins
    r = _run_cli("generate", "--data", str(tmp_path / "x"), *sizes, *args)
    assert r.returncode != 0
    assert message in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_other_config_in_out_dir_is_refused_and_kept(dataset):
    before = _digests(dataset)
    r = _run_cli("generate", "--data", str(dataset), *SMALL[:-1], "6")
    assert r.returncode != 0 and "different config (seed differ)" in r.stderr
    assert _digests(dataset) == before


def test_truncated_shard_is_reported_by_info(dataset, tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    raw = (dataset / "shard-00000.h5").read_bytes()
    (bad / "shard-00000.h5").write_bytes(raw[: len(raw) // 3])
    r = _run_cli("info", "--data", str(bad))
    assert r.returncode != 0 and "shard-00000.h5: not a readable HDF5 shard" in r.stderr


def test_info_statistics_count_every_mesh_once(dataset):
    """The figure's histograms hold every mesh of the shards once, in its kind: variant 0 is
    the simple mesh, OOD variants apart (counted here from the raw mesh table)."""
    from basic_shapes.info import KINDS, statistics
    from basic_shapes.shards import OOD_FIRST, list_shards

    _, per_class = statistics(dataset)
    counted = {k: sum(len(d.of("faces", k)) for d in per_class.values()) for k in KINDS}
    variants = []
    for p in list_shards(dataset):
        with Shard(p) as s:
            variants.extend(s.mesh_table()["variant"])
    variants = np.asarray(variants)
    assert counted == {
        "simple": int(np.sum(variants == 0)),
        "complex": int(np.sum((variants > 0) & (variants < OOD_FIRST))),
        "OOD": int(np.sum(variants >= OOD_FIRST)),
    }
    assert sum(d.objects for d in per_class.values()) == counted["simple"]


def test_info_show_export(dataset, tmp_path):
    r = _run_cli("info", "--data", str(dataset))
    assert r.returncode == 0, r.stderr
    assert "cube: 2 objects (1 train / 0 val / 1 test), 8 meshes" in r.stdout
    assert dataset_fingerprint(dataset) in r.stdout
    figure = tmp_path / "info.png"
    assert cli.main(["info", "--data", str(dataset), "--figure", str(figure)]) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    png = tmp_path / "o.png"
    assert cli.main(["show", "--data", str(dataset), "--object", "2", "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (
        cli.main(
            [
                "export",
                "--data",
                str(dataset),
                "--format",
                "stl",
                "--out",
                str(tmp_path / "e"),
                "--object",
                "0",
            ]
        )
        == 0
    )
    files = sorted((tmp_path / "e").rglob("*.stl"))
    assert len(files) == 4 + 9  # object 0 is a test object: its 9 OOD meshes too
    with Shard(dataset / "shard-00000.h5") as s:
        v, f = s.mesh(3)
    m = trimesh.load(files[3])
    assert m.volume == pytest.approx(trimesh.Trimesh(v, f).volume, rel=1e-6)
    assert json.loads((dataset / "dataset.json").read_text())["seed"] == 5


def test_the_plan_line_counts_what_is_written(tmp_path, capsys):
    """The line printed before a run counts the meshes (OOD ones included) and the shards it
    will write, here a slice of the dataset: the written shard holds exactly that."""
    import re

    from basic_shapes.generate import generate

    cfg = GenerateConfig(
        classes=("cube",), objects_per_class=20, variants=1, objects_per_shard=10, seed=5
    )
    generate(tmp_path / "d", cfg, workers=0, shards=[1])
    plan = capsys.readouterr().out.splitlines()[0]
    found = re.search(r"(\d+) objects \(cube\), (\d+) meshes, 1 of 2 shards", plan)
    assert found, plan
    with Shard(tmp_path / "d" / "shard-00001.h5") as s:
        objects = len(s.objects()["id"])
        assert int(found[1]) == objects
        assert int(found[2]) == len(s.mesh_table()["n_faces"]) > 2 * objects  # OOD meshes too
