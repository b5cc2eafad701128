"""Readers over labelled shards: index, splits, targets, normalization, scale bins, and the
``BasicShapes`` PyTorch dataset with its PyTorch Geometric view."""

import pickle
import shutil

import h5py
import numpy as np
import pytest
import torch

from basic_shapes.shards import ShardError, iter_objects, rewrite_atomically, shard_name
from benchmark.scoring.data import (
    BasicShapes,
    BenchmarkData,
    ScaleBins,
    collate_meshes,
    normalize_mesh,
)
from benchmark_fixture import CLASSES, make_dataset


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("data"), objects_per_class=5, n_val_per_class=1)


@pytest.fixture(scope="module")
def data(data_dir):
    with BenchmarkData(data_dir) as d:
        yield d


def test_index_matches_the_shards(data, data_dir):
    expected = {}
    for _, obj, meshes in iter_objects(data_dir):
        expected[obj["id"]] = (obj["class"], obj["split"], sorted(v for v, _, _ in meshes))
    assert len(data.paths) == 2 and len(data.objects["id"]) == len(expected) == 15
    for row, oid in enumerate(data.objects["id"]):
        cls, split, variants = expected[int(oid)]
        assert CLASSES[data.objects["class_index"][row]] == cls
        assert data.objects["split"][row] == split
        rows = data.meshes_of(row)
        assert list(data.meshes["variant"][rows]) == variants == [0, 1, 2]
        assert list(data.meshes["uid"][rows]) == [int(oid) * 1000 + v for v in variants]
    assert data.target_shape == (7, 5, 16) and data.class_names == CLASSES


def test_splits_are_by_object_and_variant_selection(data):
    test, val, train = (set(data.object_rows(s)) for s in ("test", "val", "train"))
    assert not (test & train or val & train or val & test)
    assert (len(test), len(val), len(train)) == (6, 3, 6)
    simple = data.mesh_rows("train", "simple")
    every = data.mesh_rows("train", "all")
    assert len(simple) == 6 and np.all(data.meshes["variant"][simple] == 0)
    assert len(every) == 18 and set(data.meshes["object"][every]) == train
    assert set(data.meshes["object"][data.mesh_rows("test")]) == test
    assert set(data.meshes["object"][data.mesh_rows("val", "simple")]) == val
    with pytest.raises(ValueError, match="split"):
        data.object_rows("validation")
    with pytest.raises(ValueError, match="variants"):
        data.mesh_rows("train", "ideal")


def raw_labels(data_dir) -> dict:
    """object id -> complex label, read straight from the shards with h5py."""
    out = {}
    for path in sorted(data_dir.glob("shard-*.h5")):
        with h5py.File(path) as f:
            out.update(zip(f["objects/id"][()].tolist(), f["radar/response"][()]))
    return out


def test_target_is_db_of_the_label_with_floor(data, data_dir):
    labels = raw_labels(data_dir)
    for row, oid in enumerate(data.objects["id"]):
        expected = 20 * np.log10(np.maximum(np.abs(labels[int(oid)].astype(np.complex128)), 1e-4))
        t = data.target(row)
        assert t.dtype == np.float32 and t.shape == data.target_shape
        np.testing.assert_allclose(t, expected, atol=1e-4)
    assert t.min() == -80.0  # the fixture's labels underflow far from the object


def test_normalize_mesh_independent_formula():
    v = np.random.default_rng(0).uniform(-3, 5, (50, 3))
    extent = v.max(0) - v.min(0)
    expected = (v - (v.max(0) + v.min(0)) / 2) / extent.max()
    np.testing.assert_allclose(normalize_mesh(v), expected, atol=1e-6)
    np.testing.assert_allclose(
        normalize_mesh(v, scale=[1.0, 10.0, 2.0]), expected * extent.max() / 10, atol=1e-6
    )
    for bad in (np.zeros((0, 3)), np.zeros((4, 2)), np.full((3, 3), np.nan), np.ones((3, 3))):
        with pytest.raises(ValueError):
            normalize_mesh(bad)


def test_batch_feeds_normalized_meshes_with_object_scale(data):
    rows = data.mesh_rows("test")
    b = data.batch(rows)
    assert set(b) == {"vertices", "faces", "scale_bins", "scale_m"} and len(b["vertices"]) == len(
        rows
    )
    for r, v, f, s, bins in zip(rows, b["vertices"], b["faces"], b["scale_m"], b["scale_bins"]):
        raw_v, raw_f = data.mesh(int(r))
        obj_scale = data.objects["scale"][data.meshes["object"][r]]
        np.testing.assert_array_equal(s, obj_scale)
        np.testing.assert_array_equal(f, raw_f)
        assert v.dtype == np.float32 and f.dtype == np.int64 and bins.dtype == np.int64
        np.testing.assert_allclose((v.max(0) + v.min(0)) / 2, 0, atol=1e-6)
        assert np.abs(v).max() <= 0.5 + 1e-6
        np.testing.assert_array_equal(bins, data.scale_bins.index(obj_scale))
        if CLASSES[data.objects["class_index"][data.meshes["object"][r]]] == "cube":
            np.testing.assert_allclose(v.max(0) - v.min(0), obj_scale / obj_scale.max(), atol=1e-6)


def test_scale_bins_are_log_spaced_over_the_generator_range(data):
    bins = ScaleBins(0.2, 2.0, 32)
    assert data.scale_bins == bins  # the fixture's config has no scale_range: the generator default
    assert ScaleBins.for_config({"scale_range": [0.5, 8.0]}, n=4) == ScaleBins(0.5, 8.0, 4)
    np.testing.assert_allclose(bins.edges, 0.2 * 10 ** (np.arange(33) / 32), rtol=1e-12)
    s = np.random.default_rng(0).uniform(0.2, 2.0, 1000)
    np.testing.assert_array_equal(bins.index(s), np.floor(32 * np.log10(s / 0.2)).astype(int))
    assert list(bins.index([0.01, 0.2, 1.999, 2.0, 50.0])) == [0, 0, 31, 31, 31]
    np.testing.assert_array_equal(bins.index(bins.centre(np.arange(32))), np.arange(32))
    assert bins.index(np.ones((5, 3))).shape == (5, 3)
    with pytest.raises(ValueError):
        ScaleBins(2.0, 0.2)


def test_torch_dataset_items_and_collate(data, data_dir):
    basic = BasicShapes(data_dir, split="train", variants="simple")
    ideal = BasicShapes(data, split="train", variants="all")
    assert len(basic) == 6 and len(ideal) == 18 and len(BasicShapes(data, split="val")) == 3
    item = ideal[4]
    row = int(ideal.rows[4])
    obj = int(data.meshes["object"][row])
    assert item["vertices"].dtype == torch.float32 and item["faces"].dtype == torch.int64
    assert item["target"].shape == data.target_shape
    assert int(item["mesh_uid"]) == int(data.meshes["uid"][row])
    assert int(item["class_index"]) == int(data.objects["class_index"][obj])
    assert int(item["object_id"]) == int(data.objects["id"][obj])
    np.testing.assert_array_equal(item["target"].numpy(), data.target(obj))
    np.testing.assert_array_equal(
        item["scale_bins"].numpy(), data.scale_bins.index(data.objects["scale"][obj])
    )
    batch = collate_meshes([ideal[i] for i in range(3)])
    assert isinstance(batch["vertices"], list) and batch["target"].shape == (3, *data.target_shape)
    assert batch["mesh_uid"].shape == (3,)


def test_dataloader_workers_open_their_own_files(data_dir):
    ds = BasicShapes(data_dir, split="test", variants="all")
    ds[0]  # the parent opens a handle before forking
    loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=2, collate_fn=collate_meshes)
    uids = torch.cat([b["mesh_uid"] for b in loader])
    assert sorted(uids.tolist()) == sorted(ds.data.meshes["uid"][ds.rows].tolist())
    assert pickle.loads(pickle.dumps(ds)).data.target(0).shape == (7, 5, 16)


def test_pyg_view_batches_with_pyg_loader(data):
    from torch_geometric.loader import DataLoader

    ds = BasicShapes(data, split="test", variants="all", transform=BasicShapes.to_pyg)
    g = ds[1]
    plain = BasicShapes(data, split="test", variants="all")[1]
    assert torch.equal(g.pos, plain["vertices"]) and torch.equal(g.face.t(), plain["faces"])
    assert g.num_nodes == len(plain["vertices"]) and g.y.shape == (1, *data.target_shape)
    batch = next(iter(DataLoader(ds, batch_size=4)))
    assert batch.num_graphs == 4 and batch.y.shape == (4, *data.target_shape)
    # faces are offset per graph by PyG, so they still index their own graph's vertices
    assert batch.face.max() < batch.pos.shape[0] and batch.mesh_uid.tolist() == [
        int(data.meshes["uid"][r]) for r in ds.rows[:4]
    ]


def test_any_grid_size(tmp_path):
    d = BenchmarkData(
        make_dataset(tmp_path, objects_per_class=2, n_test_per_class=1, n_shards=1, grid=(4, 3, 9))
    )
    assert d.target_shape == (4, 3, 9) and d.target(0).shape == (4, 3, 9)


def test_unlabelled_and_inconsistent_shards_are_refused(tmp_path):
    src = make_dataset(tmp_path / "a", objects_per_class=2, n_test_per_class=1)
    plain = tmp_path / "plain"
    plain.mkdir()
    shutil.copy(src / shard_name(0), plain / shard_name(0))
    rewrite_atomically(plain / shard_name(0), lambda f: f.__delitem__("radar"))
    with pytest.raises(ShardError, match=r"shard-00000.h5: no radar labels"):
        BenchmarkData(plain)
    rewrite_atomically(src / shard_name(1), lambda f: f["radar/range"].__setitem__(0, -9.0))
    with pytest.raises(ShardError, match="radar grid differs"):
        BenchmarkData(src)
    with pytest.raises(ShardError, match="no such dataset directory"):
        BenchmarkData(tmp_path / "nowhere")


def test_wrong_label_shape_is_refused(tmp_path):
    src = make_dataset(tmp_path, objects_per_class=2, n_test_per_class=1, n_shards=1)

    def shrink(f: h5py.File):
        resp = f["radar/response"][:, :, :, :3]
        del f["radar/response"]
        f["radar/response"] = resp

    rewrite_atomically(src / shard_name(0), shrink)
    with pytest.raises(ShardError, match=r"/radar/response is complex64\(6, 7, 5, 3\), expected"):
        BenchmarkData(src)


def test_broken_mesh_is_named(tmp_path):
    src = make_dataset(tmp_path, objects_per_class=1, n_test_per_class=1, n_shards=1)
    rewrite_atomically(
        src / shard_name(0), lambda f: f["meshes/vertices"].__setitem__(0, [np.nan] * 3)
    )
    with (
        BenchmarkData(src) as d,
        pytest.raises(ShardError, match=r"shard-00000.h5: mesh_uid 0: .*non-finite"),
    ):
        d.batch(d.mesh_rows("test"))


def test_evaluator_scores_arrays_through_the_harness_path(data, data_dir, tmp_path):
    from benchmark import Evaluator
    from benchmark.scoring.protocol import PredictionsError, score_predictions, write_predictions

    test = BasicShapes(data, split="test", variants="all")
    items = [test[i] for i in range(len(test))]
    uid = torch.stack([it["mesh_uid"] for it in items])
    oracle = torch.stack([it["target"] for it in items])
    ev = Evaluator(data_dir)
    fmt = ev.expected_input_format
    assert f"(M = {len(test)}" in fmt and "7, 5, 16" in fmt
    perfect = ev.eval({"mesh_uid": uid, "target_db": oracle})
    assert perfect["simple_mse"] == perfect["complex_mse"] == perfect["variation_mse"] == 0.0
    assert perfect["no_skill"] is False and perfect["simple_mse_ci"] == [0.0, 0.0]
    # any order, numpy too; identical to scoring the same predictions file with the harness
    rng = np.random.default_rng(0)
    noisy = oracle.numpy() + rng.normal(0, 3, oracle.shape).astype(np.float32)
    order = rng.permutation(len(uid))
    got = ev.eval({"mesh_uid": uid.numpy()[order], "target_db": noisy[order]})
    write_predictions(
        tmp_path / "p.h5",
        data.fingerprint,
        uid.numpy(),
        noisy,
        label_fingerprint=data.label_fingerprint,
    )
    assert got == score_predictions(data_dir, tmp_path / "p.h5")
    with pytest.raises(PredictionsError, match="missing 1 of"):
        ev.eval({"mesh_uid": uid[1:], "target_db": oracle[1:]})
    with pytest.raises(PredictionsError, match="input lacks target_db"):
        ev.eval({"mesh_uid": uid})
