"""Pretraining corpus: procedural families, corpus files, ShapeNetCore v2 loader.

Closedness, orientation and bounding boxes are checked with trimesh and plain numpy, not with
the module's own helpers.
"""

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh

from benchmark.training import corpus as C

ROOT = Path(__file__).resolve().parents[1]


def digest(meshes) -> str:
    h = hashlib.sha256()
    for v, f, c in meshes:
        h.update(np.ascontiguousarray(v).tobytes())
        h.update(np.ascontiguousarray(f).tobytes())
        h.update(int(c).to_bytes(4, "little"))
    return h.hexdigest()


def assert_unit_bbox(v):
    lo, hi = v.min(axis=0).astype(np.float64), v.max(axis=0).astype(np.float64)
    assert abs((hi - lo).max() - 1.0) < 1e-6
    np.testing.assert_allclose((hi + lo) / 2, 0.0, atol=1e-6)


@pytest.fixture(scope="module")
def corpus():
    return C.procedural_corpus(5 * len(C.FAMILIES), seed=3)


# --------------------------------------------------------------------------- families


def test_at_least_eight_named_families():
    assert len(C.FAMILIES) >= 8
    assert len(set(C.FAMILIES)) == len(C.FAMILIES) == len(C.WATERTIGHT)


def test_every_family_builds_valid_closed_meshes(corpus):
    seen = set()
    for v, f, c in corpus:
        seen.add(c)
        assert v.dtype == np.float32 and v.ndim == 2 and v.shape[1] == 3
        assert f.dtype == np.int32 and f.ndim == 2 and f.shape[1] == 3
        assert C.MIN_FACES <= len(f) <= 800
        assert f.min() == 0 and f.max() == len(v) - 1  # in range, no unused vertices
        assert np.isfinite(v).all()
        assert_unit_bbox(v)
        if C.WATERTIGHT[c]:
            mesh = trimesh.Trimesh(v.astype(np.float64), f, process=False)
            assert mesh.is_watertight and mesh.is_winding_consistent, C.FAMILIES[c]
            assert mesh.volume > 0, f"{C.FAMILIES[c]}: faces point inwards"
            assert mesh.body_count == 1, f"{C.FAMILIES[c]}: more than one piece"
    assert seen == set(range(len(C.FAMILIES)))


def test_families_are_balanced_and_labelled_round_robin():
    n = 3 * len(C.FAMILIES) + 4
    labels = [c for _, _, c in C.procedural_corpus(n, seed=1, max_faces=64)]
    assert labels == [i % len(C.FAMILIES) for i in range(n)]
    counts = np.bincount(labels, minlength=len(C.FAMILIES))
    assert counts.max() - counts.min() <= 1


@pytest.mark.parametrize("max_faces", [C.MIN_BUDGET, 100])
def test_face_limit_holds_for_small_budgets(max_faces):
    for v, f, c in C.procedural_corpus(2 * len(C.FAMILIES), seed=5, max_faces=max_faces):
        assert C.MIN_FACES <= len(f) <= max_faces
        assert trimesh.Trimesh(v, f, process=False).is_watertight, C.FAMILIES[c]


def test_face_counts_vary_within_a_family(corpus):
    counts = {}
    for _, f, c in corpus:
        counts.setdefault(c, set()).add(len(f))
    assert sum(len(s) > 1 for s in counts.values()) >= len(C.FAMILIES) - 1


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="max_faces must be at least"):
        C.procedural_corpus(3, seed=0, max_faces=C.MIN_BUDGET - 1)
    with pytest.raises(ValueError, match="n_meshes"):
        C.procedural_corpus(-1, seed=0)


# --------------------------------------------------------------------------- reproducibility


def test_same_seed_same_bytes_other_seed_other_bytes():
    a = C.procedural_corpus(2 * len(C.FAMILIES), seed=11, max_faces=200)
    b = C.procedural_corpus(2 * len(C.FAMILIES), seed=11, max_faces=200)
    other = C.procedural_corpus(2 * len(C.FAMILIES), seed=12, max_faces=200)
    assert digest(a) == digest(b)
    assert all(not np.array_equal(x[0], y[0]) for x, y in zip(a, other))


def test_a_corpus_is_a_prefix_of_a_larger_one():
    small = C.procedural_corpus(7, seed=2, max_faces=200)
    large = C.procedural_corpus(15, seed=2, max_faces=200)
    assert digest(small) == digest(large[:7])


def test_same_bytes_in_a_fresh_process():
    code = (
        "import sys; sys.path.insert(0, 'tests'); from test_corpus import digest\n"
        "from benchmark.training.corpus import procedural_corpus\n"
        "print(digest(procedural_corpus(12, 9, 200)))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == digest(C.procedural_corpus(12, seed=9, max_faces=200))


# --------------------------------------------------------------------------- mesh helpers


TETRA_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int32)


def test_simplify_keeps_a_closed_sphere_closed_and_round():
    mesh = trimesh.creation.icosphere(subdivisions=4)  # 5120 faces, radius 1
    v, f = C.simplify_to(mesh.vertices, mesh.faces, 300, keep_watertight=True)
    assert len(f) <= 300
    out = trimesh.Trimesh(v, f, process=False)
    assert out.is_watertight and out.volume > 0
    radius = np.linalg.norm(v, axis=1)
    assert radius.min() > 0.9 and radius.max() < 1.05


def test_simplify_leaves_small_meshes_alone():
    v, f = C.simplify_to(TETRA_V, TETRA_F, 800)
    np.testing.assert_array_equal(f, TETRA_F)
    np.testing.assert_array_equal(v, TETRA_V)


def test_normalize_refuses_a_flat_point():
    with pytest.raises(ValueError, match="zero extent"):
        C.normalize_mesh(np.zeros((4, 3)))


# --------------------------------------------------------------------------- corpus files


def sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def test_corpus_file_round_trip_and_cache(tmp_path):
    path = tmp_path / "corpus.h5"
    assert C.build_corpus_file(path, 12, seed=4, max_faces=200) == path
    assert digest(C.load_corpus_file(path)) == digest(
        C.procedural_corpus(12, seed=4, max_faces=200)
    )
    meshes, names, meta = C.read_corpus_file(path)
    assert tuple(names) == C.FAMILIES and meta["seed"] == 4 and meta["n_meshes"] == 12

    stamp = os.stat(path).st_mtime_ns, os.stat(path).st_ino
    C.build_corpus_file(path, 12, seed=4, max_faces=200)  # cached: not rewritten
    assert (os.stat(path).st_mtime_ns, os.stat(path).st_ino) == stamp

    C.build_corpus_file(path, 10, seed=4, max_faces=200)  # other arguments: rebuilt
    assert len(C.load_corpus_file(path)) == 10


def test_corpus_file_is_byte_deterministic(tmp_path):
    C.build_corpus_file(tmp_path / "a.h5", 6, seed=8, max_faces=100)
    C.build_corpus_file(tmp_path / "b.h5", 6, seed=8, max_faces=100)
    assert sha(tmp_path / "a.h5") == sha(tmp_path / "b.h5")


def test_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "corpus.h5"
    C.build_corpus_file(path, 5, seed=0, max_faces=100)
    before = sha(path)
    meshes = C.load_corpus_file(path)
    with pytest.raises(TypeError):  # fails after the datasets are written to the temporary file
        C.write_corpus_file(path, meshes, C.FAMILIES, meta={"not json": object()})
    assert sha(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["corpus.h5"]


def test_foreign_and_truncated_files_are_refused(tmp_path):
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as h5:
        h5["x"] = np.arange(3)
    before = sha(foreign)
    with pytest.raises(C.CorpusError, match="foreign.h5: not a basic-shapes-corpus file"):
        C.load_corpus_file(foreign)
    with pytest.raises(C.CorpusError, match="not a basic-shapes-corpus"):
        C.build_corpus_file(foreign, 3, seed=0, max_faces=100)  # never overwritten
    assert sha(foreign) == before

    good = tmp_path / "good.h5"
    C.build_corpus_file(good, 4, seed=0, max_faces=100)
    cut = tmp_path / "cut.h5"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(C.CorpusError, match="cut.h5"):
        C.load_corpus_file(cut)
    with pytest.raises(C.CorpusError, match="missing.h5"):
        C.load_corpus_file(tmp_path / "missing.h5")


def test_write_refuses_out_of_range_faces(tmp_path):
    with pytest.raises(ValueError, match="mesh 0"):
        C.write_corpus_file(tmp_path / "x.h5", [(TETRA_V, TETRA_F + 1, 0)], ["tetra"])
    assert not (tmp_path / "x.h5").exists()


# --------------------------------------------------------------------------- ShapeNetCore v2

CUBE_V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
CUBE_QUADS = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]


def write_cube_obj(path: Path):
    """A ShapeNet-like OBJ: quads, two material groups, vt/vn, vertices duplicated per face."""
    lines = ["mtllib model_normalized.mtl", "vn 0 0 1", "vt 0 0"]
    for k, quad in enumerate(CUBE_QUADS):
        if k % 3 == 0:
            lines.append(f"usemtl material_{k}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in CUBE_V[quad]]
        lines.append("f " + " ".join(f"{-4 + j}/1/1" for j in range(4)))  # relative indices
    path.write_text("\n".join(lines) + "\n")


def write_sphere_obj(path: Path):
    mesh = trimesh.creation.icosphere(subdivisions=3)  # 1280 faces
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    path.write_text("\n".join(lines) + "\n")


def model_path(root: Path, synset: str, model: str) -> Path:
    p = root / synset / model / "models" / "model_normalized.obj"
    p.parent.mkdir(parents=True)
    return p


@pytest.fixture
def shapenet(tmp_path):
    root = tmp_path / "ShapeNetCore.v2"
    write_cube_obj(model_path(root, "02691156", "aaa1"))
    write_sphere_obj(model_path(root, "02691156", "aaa2"))
    write_sphere_obj(model_path(root, "03001627", "bbb1"))
    write_cube_obj(model_path(root, "03001627", "bbb2"))
    model_path(root, "03001627", "bbb3").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")  # broken
    model_path(root, "03001627", "bbb4").write_bytes(b"\x00\x01\xffnot an obj\n")  # garbage
    (root / "taxonomy.json").write_text(
        json.dumps(
            [
                {
                    "synsetId": "02691156",
                    "name": "airplane,aeroplane,plane",
                    "children": [],
                    "numInstances": 2,
                },
                {"synsetId": "03001627", "name": "chair", "children": [], "numInstances": 4},
            ]
        )
    )
    return root


def test_shapenet_loader_reads_the_real_layout(shapenet):
    assert C.shapenet_class_names(shapenet) == ["airplane", "chair"]
    with pytest.warns(UserWarning, match="skipped 2 ShapeNet model"):
        meshes = C.load_shapenet(shapenet, max_faces=200)
    assert [c for _, _, c in meshes] == [0, 0, 1, 1]
    cube, sphere = meshes[0], meshes[1]
    assert len(cube[0]) == 8 and len(cube[1]) == 12  # welded and triangulated
    assert len(sphere[1]) <= 200
    for v, f, _ in meshes:
        assert v.dtype == np.float32 and f.dtype == np.int32
        assert_unit_bbox(v)
        mesh = trimesh.Trimesh(v, f, process=False)
        assert mesh.is_watertight and mesh.volume > 0
    np.testing.assert_allclose(np.sort(np.unique(cube[0])), [-0.5, 0.5])


@pytest.mark.filterwarnings("ignore:.*skipped")  # a subset may or may not meet the broken models
def test_shapenet_limit_is_a_seeded_subset(shapenet):
    full = {digest([m]) for m in C.load_shapenet(shapenet, max_faces=200)}
    picks = set()
    for seed in range(6):
        sub = C.load_shapenet(shapenet, max_faces=200, limit=2, seed=seed)
        assert len(sub) == 2 and {digest([m]) for m in sub} <= full
        assert digest(sub) == digest(C.load_shapenet(shapenet, max_faces=200, limit=2, seed=seed))
        picks.add(digest(sub))
    assert len(picks) > 1


def test_shapenet_without_taxonomy_uses_synset_ids(shapenet):
    (shapenet / "taxonomy.json").unlink()
    assert C.shapenet_class_names(shapenet) == ["02691156", "03001627"]


def test_wrong_layout_is_one_clear_line(tmp_path):
    flat = tmp_path / "flat"
    flat.mkdir()
    write_cube_obj(flat / "model.obj")
    (flat / "02691156").mkdir()  # a synset folder but no models/model_normalized.obj below it
    for path in (flat, tmp_path / "nowhere"):
        for call in (C.load_shapenet, C.shapenet_class_names):
            with pytest.raises(C.CorpusError) as err:
                call(path)
            message = str(err.value)
            assert str(path) in message and "\n" not in message
            assert "<synset_id>/<model_id>/models/model_normalized.obj" in message


def test_shapenet_with_only_broken_models_is_an_error(tmp_path):
    root = tmp_path / "sn"
    model_path(root, "02691156", "x").write_text("v 0 0 0\nf 1 2 3\n")
    with (
        pytest.warns(UserWarning, match="1 unreadable"),
        pytest.raises(C.CorpusError, match="no usable"),
    ):
        C.load_shapenet(root)


def test_shapenet_double_sided_faces_keep_one_copy(tmp_path):
    root = tmp_path / "sn"
    grid = np.array([[x, y, 0.0] for y in (0, 1) for x in (0, 1, 2)])  # a 2 x 1 plate, 4 triangles
    up = [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]]
    lines = [f"v {x} {y} {z}" for x, y, z in grid]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in up + [t[::-1] for t in up]]  # both sides
    model_path(root, "04379243", "t").write_text("\n".join(lines) + "\n")
    ((v, f, c),) = C.load_shapenet(root)
    assert c == 0 and len(v) == 6 and len(f) == 4
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(normals[:, 2] > 0)  # the first-listed side is kept
