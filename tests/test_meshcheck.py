"""basic_shapes.meshcheck against hand-made meshes whose answers are known by construction."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from basic_shapes import meshcheck
from test_verify import box, prism

ROOT = Path(__file__).resolve().parents[1]
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int32)


def test_defect_accepts_closed_meshes_and_names_each_problem():
    v, f = box((1, 2, 3))
    assert meshcheck.defect(v, f, euler=2) is None
    assert meshcheck.defect(*prism(9), euler=2) is None
    assert "open boundary" in meshcheck.defect(v, f[1:], euler=2)
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    assert "same direction" in meshcheck.defect(v, flipped, euler=2)
    assert "Euler characteristic 2" in meshcheck.defect(v, f, euler=0)
    two = np.vstack([f, f + 8])
    assert "Euler characteristic 4" in meshcheck.defect(np.vstack([v, v + 5]), two, euler=2)
    flat = v.copy()
    flat[:, 0] = 0.0  # every face parallel to x collapses
    assert "zero-area" in meshcheck.defect(flat, f, euler=2)
    assert "unreferenced" in meshcheck.defect(np.vstack([v, [[9, 9, 9]]]), f, euler=2)
    assert "out of range" in meshcheck.defect(v, f + 1, euler=2)
    assert "finite" in meshcheck.defect(np.where(v > 0, np.nan, v), f, euler=2)
    assert "repeated vertex" in meshcheck.defect(v, np.vstack([f, [[0, 0, 1]]]), euler=2)


def test_topology_key_ignores_labels_but_sees_connectivity():
    v, f = box((1, 1, 1))
    perm = np.random.default_rng(0).permutation(8)
    relabelled = np.argsort(perm)[f]
    assert meshcheck.topology_key(relabelled, 8) == meshcheck.topology_key(f, 8)
    # the same cube with the diagonals of two faces flipped: other vertex degrees
    g = f.copy()
    g[0:2] = [[0, 1, 2], [1, 3, 2]]
    g[2:4] = [[4, 6, 5], [6, 7, 5]]
    assert meshcheck.defect(v, g, euler=2) is None
    assert meshcheck.topology_key(g, 8) != meshcheck.topology_key(f, 8)


def test_is_closed_against_hand_made_cases():
    assert meshcheck.is_closed(TETRA_F)
    assert not meshcheck.is_closed(TETRA_F[:3])  # open
    flipped = TETRA_F.copy()
    flipped[0] = flipped[0, ::-1]
    assert not meshcheck.is_closed(flipped)  # inconsistent orientation
    fin = np.vstack([TETRA_F, [[0, 1, 2], [0, 2, 1]]])
    assert not meshcheck.is_closed(fin)  # an edge shared by four faces
    # a face repeating a vertex pairs its own edges, so only the explicit test rejects it
    assert not meshcheck.is_closed(np.vstack([TETRA_F[:3], [[1, 1, 3]]]))
    assert not meshcheck.is_closed(np.zeros((0, 3), int))


def test_edge_partner_pairs_each_directed_edge_with_its_reverse():
    v, f = prism(7)
    directed = meshcheck.directed_edges(f)
    n = len(f)
    for k in range(3):  # row k * F + i is face i's edge from corner k to corner k + 1
        np.testing.assert_array_equal(directed[k * n : (k + 1) * n], f[:, [k, (k + 1) % 3]])
    partner = meshcheck.edge_partner(f)
    np.testing.assert_array_equal(directed[partner], directed[:, ::-1])
    np.testing.assert_array_equal(partner[partner], np.arange(3 * n))
    assert meshcheck.edge_partner(f[1:]) is None  # open
    assert meshcheck.edge_partner(np.vstack([f, f[:1]])) is None  # an edge used twice
    with pytest.raises(ValueError, match="non-empty"):
        meshcheck.edge_partner(np.zeros((0, 3), int))


def test_signed_volume_of_a_box_and_its_mirror_winding():
    v, f = box((1.0, 2.0, 3.0), center=(5.0, -7.0, 2.0))  # away from the origin on purpose
    assert meshcheck.signed_volume(v, f) == pytest.approx(6.0, rel=1e-12)
    assert meshcheck.signed_volume(v, f[:, ::-1]) == pytest.approx(-6.0, rel=1e-12)


def test_weld_merges_a_triangle_soup_back_into_a_closed_box():
    v, f = box((1.0, 2.0, 3.0))
    soup = v[f].reshape(-1, 3)  # every face with its own three vertices: 36 vertices, all open
    assert meshcheck.edge_partner(np.arange(36).reshape(-1, 3)) is None
    wv, wf = meshcheck.weld(soup, np.arange(36).reshape(-1, 3))
    assert len(wv) == 8 and wf.dtype == np.int64
    np.testing.assert_array_equal(wv[wf], v[f])  # every corner keeps its coordinates
    np.testing.assert_array_equal(wv, np.unique(v, axis=0))  # sorted by (x, y, z)
    assert meshcheck.defect(wv, wf, euler=2) is None


def test_weld_with_decimals_keeps_the_first_original_vertex():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [1.0000004, 0, 0], [0, 1, 0], [-0.0000004, 0, 0]])
    f = np.array([[0, 1, 3], [4, 2, 3]])
    exact_v, exact_f = meshcheck.weld(v, f)
    assert len(exact_v) == 5
    wv, wf = meshcheck.weld(v, f, decimals=6)
    np.testing.assert_array_equal(wv, [[0, 0, 0], [0, 1, 0], [1, 0, 0]])  # -0.0 joins 0.0
    np.testing.assert_array_equal(wf, [[0, 2, 1], [0, 2, 1]])


def test_face_repeats_counts_either_winding():
    f = np.array([[0, 1, 2], [2, 1, 0], [0, 1, 3], [1, 2, 0], [3, 4, 5]])
    first, count = meshcheck.face_repeats(f)
    np.testing.assert_array_equal(first, [True, False, True, False, True])
    np.testing.assert_array_equal(count, [3, 3, 1, 3, 1])
    first, count = meshcheck.face_repeats(np.zeros((0, 3), int))
    assert first.shape == count.shape == (0,)


def test_drop_unreferenced_renumbers_in_vertex_order():
    v = np.arange(15.0).reshape(5, 3)
    cv, cf = meshcheck.drop_unreferenced(v, np.array([[4, 2, 0], [0, 4, 2]]))
    np.testing.assert_array_equal(cv, v[[0, 2, 4]])
    np.testing.assert_array_equal(cf, [[2, 1, 0], [0, 2, 1]])


def test_as_arrays_returns_float64_and_int64_and_one_error_type():
    from benchmark.training.corpus import SimplifyError
    from radar_sim import MeshError

    v, f = meshcheck.as_arrays(np.eye(3, dtype=np.float32), np.array([[0, 1, 2]], np.int32))
    assert v.dtype == np.float64 and f.dtype == np.int64
    assert MeshError is meshcheck.MeshError and issubclass(SimplifyError, MeshError)
    with pytest.raises(MeshError, match=r"^face 0 refers to vertex \[0, 1, 3\]"):
        meshcheck.as_arrays(np.eye(3), [[0, 1, 3]])


def test_meshcheck_imports_neither_bpy_nor_torch_nor_pymeshlab():
    code = (
        "import sys, basic_shapes.meshcheck\n"
        "print(sorted(m for m in ('bpy', 'torch', 'pymeshlab') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert out.stdout.strip() == "[]"
