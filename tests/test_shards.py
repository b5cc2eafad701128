import hashlib

import h5py
import numpy as np
import pytest
import trimesh

from basic_shapes.shards import (
    MeshRecord,
    ObjectRecord,
    Shard,
    ShardError,
    find_object,
    iter_objects,
    label_fingerprint,
    mesh_uid,
    rewrite_atomically,
    write_radar,
    write_shard,
)


def _objects():
    box = trimesh.creation.box((1.0, 2.0, 0.5))
    fine = box.subdivide().subdivide()
    meshes = [
        MeshRecord(0, box.vertices, box.faces, 0.0, {"kind": "simple"}),
        MeshRecord(1, fine.vertices, fine.faces, 1e-7, {"kind": "subdivided"}),
    ]
    return [
        ObjectRecord(7, 0, np.array([1.0, 2.0, 0.5]), 42, "train", meshes),
        ObjectRecord(8, 0, np.array([1.0, 2.0, 0.5]), 43, "test", meshes[:1]),
    ]


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
        assert [(o, var, len(f)) for o, var, _, f in s.iter_meshes()] == [
            (0, 0, 12),
            (0, 1, 192),
            (1, 0, 12),
        ]
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


GRID = {
    "aspect_deg": np.array([0.0, 90.0]),
    "roll_deg": np.array([0.0, 120.0, 240.0]),
    "range_m": np.linspace(-1, 1, 5),
    "frequency_hz": np.linspace(8e9, 12e9, 7),
}
ATTRS = {"config": '{"name": "t"}', "simulation_rule": '{"rule": 1}', "options": "{}"}


def _labelled(path, responses, attrs=ATTRS, mesh_index=(0, 2)):
    """A two-object shard with labels ``responses`` (2, 2, 3, 5) and physics on two meshes."""
    write_shard(path, _objects(), ["cube"], {"seed": 0}, "0.1.0")
    rewrite_atomically(
        path,
        lambda f: write_radar(
            f,
            attrs=attrs,
            coordinates=GRID,
            object_ids=[7, 8],
            modes=["convex", "shadowed"],
            responses=iter(responses),
            mesh_index=np.array(mesh_index),
            mesh_modes=["convex"] * len(mesh_index),
            mesh_responses=responses[: len(mesh_index)],
        ),
    )
    return path


def _responses(seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(2, 2, 3, 5)) + 1j * rng.normal(size=(2, 2, 3, 5))).astype(np.complex64)


def test_radar_round_trip_and_fingerprint(tmp_path):
    resp = _responses()
    with Shard(_labelled(tmp_path / "shard-00000.h5", resp)) as s:
        r = s.radar
        assert r.modes == ["convex", "shadowed"] and list(r.object_ids) == [7, 8]
        for name, value in GRID.items():
            np.testing.assert_array_equal(r.coordinates[name], value)
        np.testing.assert_array_equal(r.response(1), resp[1])
        assert list(r.mesh_index) == [0, 2] and r.mesh_modes == ["convex", "convex"]
        np.testing.assert_array_equal(r.mesh_response(1), resp[1])
        assert not r.has_frequency_response and r.config == {"name": "t"}
        # sha256 over config, rule, the label bytes and the per-mesh physics (its rows, then
        # its responses), written independently here
        h = hashlib.sha256(
            b'{"name": "t"}\0{"rule": 1}\0'
            + resp.tobytes()
            + b"\0mesh\0"
            + np.array([0, 2], np.int64).tobytes()
            + resp[:2].tobytes()
        ).hexdigest()
        assert r.fingerprint == r.computed_fingerprint() == h
    assert label_fingerprint(tmp_path) == hashlib.sha256(h.encode()).hexdigest()
    again = _labelled(tmp_path / "again.h5", resp)
    assert again.read_bytes() == (tmp_path / "shard-00000.h5").read_bytes()
    other = [
        _labelled(tmp_path / "b.h5", _responses(1)),
        _labelled(tmp_path / "c.h5", resp, {**ATTRS, "config": '{"name": "u"}'}),
        _labelled(tmp_path / "d.h5", resp, {**ATTRS, "simulation_rule": '{"rule": 2}'}),
    ]
    fingerprints = set()
    with Shard(again) as s:
        meshes = s.fingerprint
    for p in other:
        with Shard(p) as s:
            assert s.fingerprint == meshes  # the meshes are the same, the labels are not
            fingerprints.add(s.radar.fingerprint)
    assert len(fingerprints) == 3 and h not in fingerprints


@pytest.mark.parametrize(
    "edit, problem",
    [
        (lambda g: g.__delitem__("mode"), "truncated /radar group, missing mode"),
        (
            lambda g: (
                g.__delitem__("response"),
                g.create_dataset("response", data=np.zeros((2, 2, 3, 4), np.complex64)),
            ),
            r"/radar/response is complex64\(2, 2, 3, 4\), expected",
        ),
        (
            lambda g: g["object"].__setitem__(0, 99),
            "/radar/object does not list the shard's objects",
        ),
        (lambda g: g["mesh"].__setitem__(1, 3), r"/radar/mesh holds rows outside 0\.\.2"),
        (lambda g: g.attrs.__delitem__("label_fingerprint"), "no label_fingerprint"),
    ],
)
def test_malformed_radar_groups_are_refused(tmp_path, edit, problem):
    path = _labelled(tmp_path / "shard-00000.h5", _responses())
    rewrite_atomically(path, lambda f: edit(f["radar"]))
    with Shard(path) as s, pytest.raises(ShardError, match=problem) as err:
        s.radar.fingerprint  # noqa: B018 - the property read is what refuses
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)


def test_unlabelled_shard_has_no_radar(tmp_path):
    p = tmp_path / "shard-00000.h5"
    write_shard(p, _objects(), ["cube"], {"seed": 0}, "0.1.0")
    with Shard(p) as s, pytest.raises(ShardError, match="no radar labels"):
        s.radar  # noqa: B018 - the property read is what refuses
    with pytest.raises(ShardError, match="no radar labels"):
        label_fingerprint(tmp_path)
