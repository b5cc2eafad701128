import hashlib

import h5py
import numpy as np
import pytest
import trimesh

from basic_shapes.shards import MeshRecord, ObjectRecord, Shard, ShardError, find_object, iter_objects, mesh_uid, write_shard


def _objects():
    box = trimesh.creation.box((1.0, 2.0, 0.5))
    fine = box.subdivide().subdivide()
    meshes = [MeshRecord(0, box.vertices, box.faces, 0.0, {"kind": "simple"}),
              MeshRecord(1, fine.vertices, fine.faces, 1e-7, {"kind": "subdivided"})]
    return [ObjectRecord(7, 0, np.array([1.0, 2.0, 0.5]), 42, "train", meshes),
            ObjectRecord(8, 0, np.array([1.0, 2.0, 0.5]), 43, "test", meshes[:1])]


def test_round_trip(tmp_path):
    p = tmp_path / "shard-00000.h5"
    write_shard(p, _objects(), ["cube"], {"seed": 0}, "0.1.0")
    with Shard(p) as s:
        assert s.n_objects == 2 and s.n_meshes == 3
        assert s.config == {"seed": 0} and s.class_names == ["cube"]
        assert list(s.objects()["split"]) == ["train", "test"]
        v, f = s.mesh(1)
        assert v.dtype == np.float32 and f.dtype == np.int32
        np.testing.assert_array_equal(f, _objects()[0].meshes[1].faces)
        assert list(s.simple_mesh_index()) == [0, 2]
        assert s.mesh_params(1) == {"kind": "subdivided"}
        assert [(o, var, len(f)) for o, var, _, f in s.iter_meshes()] == [(0, 0, 12), (0, 1, 192), (1, 0, 12)]
    _, obj, meshes = find_object(tmp_path, 8)
    assert obj["split"] == "test" and [m[0] for m in meshes] == [0]
    assert [o["id"] for _, o, _ in iter_objects(tmp_path, split="train")] == [7]
    assert mesh_uid(8, 3) == 8003


def test_writes_are_byte_deterministic(tmp_path):
    write_shard(tmp_path / "a.h5", _objects(), ["cube"], {"seed": 0}, "0.1.0")
    write_shard(tmp_path / "b.h5", _objects(), ["cube"], {"seed": 0}, "0.1.0")
    digest = [hashlib.sha256((tmp_path / n).read_bytes()).hexdigest() for n in ("a.h5", "b.h5")]
    assert digest[0] == digest[1]


def test_failed_write_leaves_nothing_and_keeps_old_file(tmp_path):
    p = tmp_path / "shard-00000.h5"
    write_shard(p, _objects(), ["cube"], {"seed": 0}, "0.1.0")
    before = p.read_bytes()
    bad = _objects()
    bad[0].meshes[0].faces = np.zeros((2, 4))  # not triangles: the write fails midway
    with pytest.raises(ValueError):
        write_shard(p, bad, ["cube"], {"seed": 1}, "0.1.0")
    assert p.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["shard-00000.h5"]


def test_truncated_and_foreign_files_are_refused(tmp_path):
    p = tmp_path / "shard-00000.h5"
    write_shard(p, _objects(), ["cube"], {"seed": 0}, "0.1.0")
    cut = tmp_path / "cut.h5"
    cut.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    with pytest.raises(ShardError, match="cut.h5: not a readable HDF5 shard"):
        Shard(cut)
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = 1
    with pytest.raises(ShardError, match="foreign.h5: not a basic-shapes shard"):
        Shard(foreign)
    partial = tmp_path / "partial.h5"
    p_bytes = p.read_bytes()
    partial.write_bytes(p_bytes)
    with h5py.File(partial, "r+") as f:
        del f["meshes/faces"]
    with pytest.raises(ShardError, match="missing meshes/faces"):
        Shard(partial)
