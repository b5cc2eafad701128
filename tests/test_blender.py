"""basic_shapes.blender with real Blender, checked against independent references.

Shapes are checked with a brute-force point-to-triangle distance written here (not with
pymeshlab), the cube also with exact geometry (every triangle in a face of the box, exact
area and volume); closedness with trimesh; topology with a degree sequence computed here.
"""

import hashlib
import importlib.util
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from basic_shapes import blender, primitives, verify

ROOT = Path(__file__).resolve().parents[1]
SCALE = np.array([0.6, 1.7, 1.1])


@pytest.fixture(scope="module")
def objects():
    """Two objects of every default class, 30 variants each."""
    return {
        (name, seed): blender.object_meshes(name, SCALE, seed, 30)
        for name in primitives.DEFAULT_CLASSES
        for seed in (1, 2)
    }


@pytest.fixture(scope="module")
def cubes():
    """Five cubes with the default 99 variants: the face-count spread."""
    rng = np.random.default_rng(0)
    return [blender.object_meshes("cube", rng.uniform(0.5, 2.0, 3), seed, 99) for seed in range(5)]


# --- independent references ------------------------------------------------------------------
def point_triangle_distance(p, a, b, c):
    """Distance from points p to triangles (a, b, c), broadcast (Ericson's closest-point
    regions)."""
    ab, ac = b - a, c - a
    ap, bp, cp = p - a, p - b, p - c
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        q = a + ab * (vb / denom)[..., None] + ac * (vc / denom)[..., None]
        # regions in reverse order of Ericson's tests, so that the first test that holds wins
        w = ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[..., None]
        q = np.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[..., None], b + w * (c - b), q)
        q = np.where(
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0))[..., None], a + ac * (d2 / (d2 - d6))[..., None], q
        )
        q = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, q)
        q = np.where(
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0))[..., None], a + ab * (d1 / (d1 - d3))[..., None], q
        )
        q = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, q)
        q = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, q)
    return np.sqrt(((p - q) ** 2).sum(-1))


def surface_distance(points, v, f):
    """Exact distance from each point to the surface (v, f).

    A triangle with centroid c and circumscribing radius r is no closer than |p - c| - r,
    and the nearest vertex bounds the answer from above, so per group of triangles of similar
    radius only those whose centroid lies within (upper bound + the group's largest r) count.
    """
    tri = v[f]
    centroid = tri.mean(axis=1)
    radius = np.sqrt(((tri - centroid[:, None]) ** 2).sum(-1)).max(axis=1)
    best = np.minimum(cKDTree(v).query(points)[0], cKDTree(centroid).query(points)[0])
    group = np.floor(np.log2(radius / radius.max() + 1e-300)).clip(-8, 0)
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        near = cKDTree(centroid[members]).query_ball_point(points, best + radius[members].max())
        which = np.repeat(np.arange(len(points)), [len(n) for n in near])
        if len(which):
            cand = tri[members[np.concatenate(near).astype(np.int64)]]
            np.minimum.at(
                best, which, point_triangle_distance(points[which], *cand.transpose(1, 0, 2))
            )
    return best


def samples(v, f):
    """Vertices, edge midpoints and centroids (not the sampling verify.py uses)."""
    edges = np.unique(
        np.sort(np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0
    )
    return np.vstack([v, v[edges].mean(axis=1), v[f].mean(axis=1)])


def brute_hausdorff(va, fa, vb, fb):
    va, vb = va.astype(np.float64), vb.astype(np.float64)
    d = max(
        surface_distance(samples(va, fa), vb, fb).max(),
        surface_distance(samples(vb, fb), va, fa).max(),
    )
    return d / np.linalg.norm(va.max(axis=0) - va.min(axis=0))


def degree_signature(v, f):
    edges = np.unique(
        np.sort(np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0
    )
    return len(v), tuple(np.sort(np.bincount(edges.ravel(), minlength=len(v))))


def test_simple_mesh_is_the_triangulated_default_primitive(objects):
    # Blender's defaults: cube 8 verts; cylinder 32 around with two 32-gon caps (30 triangles
    # each); UV sphere 32 segments x 16 rings = 32*15 + 2 poles.
    expected = {"cube": (8, 12), "cylinder": (64, 2 * 32 + 2 * 30), "sphere": (482, 2 * 480)}
    for (name, _), meshes in objects.items():
        simple = meshes[0]
        assert (simple.variant, simple.hausdorff) == (0, 0.0)
        assert (len(simple.vertices), len(simple.faces)) == expected[name]
        assert simple.vertices.dtype == np.float32 and simple.faces.dtype == np.int32
        extents = simple.vertices.max(axis=0).astype(float) - simple.vertices.min(axis=0)
        np.testing.assert_allclose(extents, SCALE, rtol=1e-6)


def test_every_mesh_is_a_closed_oriented_manifold(objects, cubes):
    meshes = [m for ms in objects.values() for m in ms] + [m for ms in cubes for m in ms]
    for m in meshes:
        t = trimesh.Trimesh(m.vertices, m.faces, process=False)
        assert t.is_watertight and t.is_winding_consistent, m.params
        assert t.euler_number == 2 and t.volume > 0, m.params
        assert len(np.unique(m.faces)) == len(m.vertices)  # no loose vertex


def test_variants_keep_the_shape_by_an_independent_distance(objects):
    for (name, seed), meshes in objects.items():
        v0, f0 = meshes[0].vertices, meshes[0].faces
        for m in meshes[1:] if seed == 1 else meshes[1::10]:  # all of one object per class
            tol = verify.tolerance(name, m.params)
            assert m.params["tolerance"] == tol and 0 <= m.hausdorff <= tol
            assert brute_hausdorff(v0, f0, m.vertices, m.faces) <= tol, (name, m.params)
            extents = m.vertices.max(axis=0).astype(float) - m.vertices.min(axis=0)
            assert np.all(np.abs(extents - SCALE) <= tol * np.linalg.norm(SCALE))


def test_cube_variants_are_exactly_the_box(cubes):
    for meshes in cubes:
        v0 = meshes[0].vertices.astype(float)
        half = (v0.max(axis=0) - v0.min(axis=0)) / 2
        eps = 1e-6 * np.linalg.norm(2 * half)
        for m in meshes:
            tri = m.vertices.astype(float)[m.faces]  # (F, 3, 3)
            assert np.all(np.abs(tri) <= half + eps)
            on_plane = np.abs(np.abs(tri) - half) <= eps  # (F, 3 vertices, 3 axes)
            same_side = np.abs(np.sign(tri).sum(axis=1)) == 3
            assert np.all((on_plane.all(axis=1) & same_side).any(axis=1)), m.params
            t = trimesh.Trimesh(m.vertices, m.faces, process=False)
            a, b, c = 2 * half
            assert t.volume == pytest.approx(a * b * c, rel=1e-6)
            assert t.area == pytest.approx(2 * (a * b + b * c + a * c), rel=1e-6)


def test_cube_face_counts_spread_from_12_to_thousands(cubes):
    faces = np.array([len(m.faces) for meshes in cubes for m in meshes[1:]])
    assert faces.min() == 12 and faces.max() > 2000
    assert np.mean(faces < 100) > 0.2 and np.mean(faces > 1000) > 0.1


def test_all_meshes_of_an_object_differ_in_topology(objects, cubes):
    for meshes in list(objects.values()) + cubes:
        signatures = {degree_signature(m.vertices, m.faces) for m in meshes}
        assert len(signatures) == len(meshes)


def test_params_record_what_was_done(objects):
    for (name, _), meshes in objects.items():
        spec = primitives.PRIMITIVES[name]
        kinds = set()
        for m in meshes[1:]:
            p = json.loads(json.dumps(m.params))
            assert p["loop_cuts"] and all(cuts >= 1 for _, cuts in p["loop_cuts"])
            assert set(p["resolution"]) == set(spec.resolution)
            assert p["decimate"]["kind"] in spec.decimation
            kinds.add(p["decimate"]["kind"])
            if p["decimate"]["kind"] == "collapse":
                assert 0 < p["decimate"]["ratio"] <= 1
        assert {"collapse", "none"} <= kinds
    resolutions = {json.dumps(m.params["resolution"]) for m in objects[("sphere", 1)][1:]}
    assert len(resolutions) > 5  # curved variants vary segments and rings


@pytest.mark.parametrize(
    "name",  # the torus (off by default; 30 s here) runs in the slow set
    [
        pytest.param(n, marks=pytest.mark.slow) if n == "torus" else n
        for n in sorted(primitives.PRIMITIVES)
    ],
)
def test_every_registered_primitive_builds_and_verifies(name):
    spec = primitives.PRIMITIVES[name]
    meshes = blender.object_meshes(name, SCALE, 3, 3)
    for m in meshes:
        t = trimesh.Trimesh(m.vertices, m.faces, process=False)
        assert t.is_watertight and t.euler_number == spec.euler and t.volume > 0
        assert brute_hausdorff(
            meshes[0].vertices, meshes[0].faces, m.vertices, m.faces
        ) <= verify.tolerance(name, m.params)


def test_a_new_primitive_takes_one_registry_entry(monkeypatch):
    prism = primitives.Primitive(
        operator="primitive_cylinder_add",
        planar=True,
        extents=(3**0.5, 2.0, 2.0),
        options={"vertices": 6},
    )
    monkeypatch.setitem(primitives.PRIMITIVES, "hex_prism", prism)
    meshes = blender.object_meshes("hex_prism", SCALE, 0, 10)
    # a regular hexagon of circumradius 1 has area 3 sqrt(3) / 2; scaled to SCALE's x, y
    volume = 3 * 3**0.5 / 2 * (SCALE[0] / 3**0.5) * (SCALE[1] / 2) * SCALE[2]
    for m in meshes:
        t = trimesh.Trimesh(m.vertices, m.faces, process=False)
        assert t.is_watertight and t.volume == pytest.approx(volume, rel=1e-6)
        assert m.hausdorff <= verify.PLANAR_TOLERANCE
    assert len({len(m.faces) for m in meshes}) > 5


def test_same_call_gives_the_same_arrays_whatever_came_before():
    first = blender.object_meshes("cylinder", SCALE, 11, 4)
    blender.object_meshes("sphere", SCALE * 2, 12, 6)
    blender.object_meshes("cube", SCALE, 11, 8)
    again = blender.object_meshes("cylinder", SCALE, 11, 4)
    assert digest(first) == digest(again)


def digest(meshes):
    h = hashlib.sha256()
    for m in meshes:
        h.update(
            m.vertices.tobytes()
            + m.faces.tobytes()
            + repr(m.hausdorff).encode()
            + json.dumps(m.params, sort_keys=True).encode()
        )
    return h.hexdigest()


def test_threads_of_one_process_get_the_same_arrays():
    from concurrent.futures import ThreadPoolExecutor

    calls = [("cube", 21), ("sphere", 22), ("cylinder", 23), ("cube", 24)]
    alone = [digest(blender.object_meshes(name, SCALE, seed, 3)) for name, seed in calls]
    with ThreadPoolExecutor(4) as pool:
        together = list(
            pool.map(lambda c: digest(blender.object_meshes(c[0], SCALE, c[1], 3)), calls)
        )
    assert together == alone


CHILD = """
import hashlib, json, sys
import numpy as np
sys.path.insert(0, {root!r})
from basic_shapes import verify
if sys.argv[1] == "pymeshlab-first":  # verify (pymeshlab) used before Blender starts
    verify.hausdorff(np.eye(3), np.array([[0, 1, 2]]), np.eye(3), np.array([[0, 1, 2]]))
from basic_shapes import blender
if sys.argv[1] == "other-work-first":
    blender.object_meshes("sphere", np.ones(3), 5, 3)
    blender.object_meshes("cube", np.ones(3), 5, 3)
meshes = blender.object_meshes("sphere", np.array({scale}), 7, 5)
h = hashlib.sha256()
for m in meshes:
    h.update(m.vertices.tobytes() + m.faces.tobytes() + repr(m.hausdorff).encode()
             + json.dumps(m.params, sort_keys=True).encode())
print(h.hexdigest())
"""


def test_same_arrays_in_separate_processes_whatever_ran_before(tmp_path):
    script = tmp_path / "child.py"
    script.write_text(textwrap.dedent(CHILD.format(root=str(ROOT), scale=SCALE.tolist())))
    runs = [
        subprocess.run(
            [sys.executable, str(script), mode], capture_output=True, text=True, check=True
        ).stdout.strip()
        for mode in ("plain", "other-work-first", "pymeshlab-first")
    ]
    here = digest(blender.object_meshes("sphere", SCALE, 7, 5))
    assert runs == [here] * 3


def test_stage_benchmark_writes_json_and_refuses_unknown_classes(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("mesh_core", ROOT / "perf/mesh_core.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = tmp_path / "core.json"
    bench.main(["--objects", "1", "--variants", "3", "--classes", "cube", "--out", str(out)])
    (result,) = json.loads(out.read_text())["results"]
    assert result["meshes"] == 4 and set(result["ms_per_mesh"]) == set(bench.STAGES)
    assert "cube" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="unknown primitive class 'prism'"):
        bench.main(["--classes", "cube,prism", "--out", str(out)])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"class_name": "dodecahedron"}, "unknown primitive class"),
        ({"scale": np.array([1.0, -1.0, 1.0])}, "3 positive finite extents"),
        ({"scale": np.array([1.0, np.nan, 1.0])}, "3 positive finite extents"),
        ({"scale": np.ones(2)}, "3 positive finite extents"),
        ({"n_variants": 1000}, "n_variants"),
        ({"seed": -1}, "seed"),
    ],
)
def test_bad_input_is_refused_with_a_clear_message(kwargs, message):
    call = {"class_name": "cube", "scale": np.ones(3), "seed": 0, "n_variants": 1} | kwargs
    with pytest.raises(ValueError, match=message):
        blender.object_meshes(**call)
