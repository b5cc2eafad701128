"""basic_shapes.verify against analytic references (no Blender here)."""

import math

import numpy as np
import pytest

from basic_shapes import analytic, meshcheck, primitives, verify


def box(extents, center=(0.0, 0.0, 0.0)):
    """Closed, outward-oriented triangulated box."""
    e = np.asarray(extents, float) / 2
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * e
    f = np.array(
        [
            [0, 1, 3],
            [0, 3, 2],
            [4, 6, 7],
            [4, 7, 5],
            [0, 4, 5],
            [0, 5, 1],
            [2, 3, 7],
            [2, 7, 6],
            [0, 2, 6],
            [0, 6, 4],
            [1, 5, 7],
            [1, 7, 3],
        ]
    )
    return v + np.asarray(center), f


def prism(n, radius=1.0, height=2.0, phase=0.0):
    """Regular n-gon prism (vertices on the circle), caps fanned from their centres."""
    t = phase + 2 * np.pi * np.arange(n) / n
    ring = np.column_stack([radius * np.cos(t), radius * np.sin(t)])
    v = np.vstack(
        [
            np.column_stack([ring, np.full(n, -height / 2)]),
            np.column_stack([ring, np.full(n, height / 2)]),
            [[0, 0, -height / 2], [0, 0, height / 2]],
        ]
    )
    f = []
    for i in range(n):
        j = (i + 1) % n
        f += [[i, j, n + j], [i, n + j, n + i], [2 * n, j, i], [2 * n + 1, n + i, n + j]]
    return v, np.array(f)


def test_identical_meshes_are_at_distance_zero():
    v, f = prism(16)
    assert verify.hausdorff(v, f, v, f) < 1e-12  # round-off of the centroid samples


def test_nested_boxes_match_the_corner_to_corner_distance():
    va, fa = box((1.0, 2.0, 3.0))
    vb, fb = box((1.5, 2.2, 3.9))
    expected = np.linalg.norm(np.array([0.5, 0.2, 0.9]) / 2) / np.linalg.norm([1.0, 2.0, 3.0])
    assert verify.hausdorff(va, fa, vb, fb) == pytest.approx(expected, rel=1e-6)


def test_face_interiors_are_sampled():
    # Same vertices, top face (not flat: one corner raised) split along the other diagonal:
    # every vertex of each mesh lies on the other, only face samples see the difference.
    va, fa = box((2.0, 2.0, 2.0))
    va[7, 2] += 1.0
    fb = fa.copy()
    top = [i for i, tri in enumerate(fa) if set(tri) <= {1, 3, 5, 7}]
    fb[top] = [[1, 5, 3], [5, 7, 3]]
    assert meshcheck.defect(va, fa, euler=2) is None and meshcheck.defect(va, fb, euler=2) is None
    assert verify.hausdorff(va, fa, va, fb) > 0.01


def test_polygon_sagitta_is_measured_exactly():
    # A 2n-gon prism and an n-gon prism sharing every other vertex: the 2n-gon's extra
    # vertices lie 1 - cos(pi/n) from the n-gon's side faces, and nothing is farther.
    n = 12
    va, fa = prism(2 * n)
    vb, fb = prism(n)
    expected = (1 - math.cos(math.pi / n)) / meshcheck.bbox_diagonal(va)
    assert verify.hausdorff(va, fa, vb, fb) == pytest.approx(expected, rel=1e-6)


def test_hausdorff_does_not_depend_on_what_was_measured_before():
    va, fa = prism(24)
    vb, fb = prism(17, phase=0.1)
    first = verify.hausdorff(va, fa, vb, fb)
    verify.hausdorff(*box((1, 2, 3)), *box((2, 2, 2)))
    assert verify.hausdorff(va, fa, vb, fb) == first


def test_far_samples_are_not_dropped():
    va, fa = box((1.0, 1.0, 1.0))
    vb, fb = box((1.0, 1.0, 1.0), center=(30.0, 0.0, 0.0))
    # every sample is ~30 m (17 diagonals) away, beyond MeshLab's default search radius
    assert verify.hausdorff(va, fa, vb, fb) > 17


def test_tolerance_planar_and_curved():
    assert verify.tolerance("cube", {}) == verify.PLANAR_TOLERANCE
    # cylinder: coarsest 24-gon vs the default 32-gon; worst case over scales halves it
    cyl = (1 - math.cos(math.pi / 24)) / 2 + verify.PLANAR_TOLERANCE
    assert verify.tolerance("cylinder", {"resolution": {"vertices": 40}}) == pytest.approx(cyl)
    # UV sphere: every point lies at radius >= cos(pi/segments) cos(pi/(2 rings))
    sph = (1 - math.cos(math.pi / 24) ** 2) / 2 + verify.PLANAR_TOLERANCE
    assert verify.tolerance("sphere", {}) == pytest.approx(sph)
    # torus: not convex, two tessellations' gaps add; the thin z extent (0.5) sets the scale
    gap = 0.25 * (1 - math.cos(math.pi / 12)) + 1.25 * (1 - math.cos(math.pi / 48))
    assert verify.tolerance("torus", {}) == pytest.approx(2 * gap / 0.5 + 1e-6)


def test_curved_tolerance_bounds_the_measured_distance_at_extreme_scales():
    # The bound is the worst case over scales: a 24-gon vs 32-gon prism stretched along x.
    for scale in ([3.0, 0.01, 0.01], [1.0, 1.0, 1.0], [0.05, 2.0, 0.05]):
        s = np.array(scale) / 2
        va, fa = prism(32)
        vb, fb = prism(24)
        h = verify.hausdorff(va * s, fa, vb * s, fb)
        assert h <= verify.tolerance("cylinder", {"resolution": {"vertices": 24}})


def test_tolerance_rejects_tessellations_outside_the_bound():
    with pytest.raises(ValueError, match="outside the allowed"):
        verify.tolerance("cylinder", {"resolution": {"vertices": 8}})
    with pytest.raises(ValueError, match="vertices=30"):
        verify.tolerance("cylinder", {"resolution": {"vertices": 30}})
    with pytest.raises(ValueError, match="no tessellation parameter"):
        verify.tolerance("cube", {"resolution": {"segments": 8}})
    with pytest.raises(ValueError, match="unknown primitive class 'dodecahedron'"):
        verify.tolerance("dodecahedron", {})


@pytest.mark.parametrize("name", sorted(primitives.PRIMITIVES))
def test_registry_entries_are_consistent(name):
    spec = primitives.PRIMITIVES[name]
    assert spec.planar == (not spec.resolution)
    assert set(spec.decimation) <= {"collapse", "unsubdiv", "none"}
    for key, res in spec.resolution.items():
        assert res.allows(res.default), key
    assert spec.resolutions() and all(len(r) == len(spec.resolution) for r in spec.resolutions())
    assert 0 < verify.tolerance(name, {}) < 0.1


def test_primitive_distance_of_an_inscribed_prism_is_its_sagitta():
    # A regular n-gon prism inscribed in the unit-radius cylinder of height 2: the farthest
    # surface point is mid-side, 1 - cos(pi/n) from the mesh; nothing on the mesh is farther.
    solid = analytic.solid_for("cylinder", (2.0, 2.0, 2.0))
    for n in (24, 48):
        v, f = prism(n)
        d = verify.Reference(v, f, solid).primitive_distance(v, f) * solid.diagonal
        assert d == pytest.approx(1 - math.cos(math.pi / n), rel=1e-3)


def test_primitive_distance_of_boxes_is_exact_and_two_sided():
    va, fa = box((1.0, 2.0, 3.0))
    exact = analytic.solid_for("cube", (1.0, 2.0, 3.0))
    ref = verify.Reference(va, fa, exact)
    assert ref.primitive_distance(va, fa) < 1e-15
    # a mesh inside the object: only the surface -> mesh half sees the 0.2 m gap (MeshLab
    # measures in float32)
    vb, fb = box((1.0, 2.0, 2.6))
    assert ref.primitive_distance(vb, fb) * exact.diagonal == pytest.approx(0.2, rel=1e-7)
    # and without the Solid there is nothing to compare with
    assert math.isnan(verify.Reference(va, fa).primitive_distance(va, fa))


def test_primitive_tolerance_per_class_and_variant_kind():
    assert verify.primitive_tolerance("cube", {}) == verify.PLANAR_TOLERANCE
    spec = primitives.get("cylinder")
    inscribed = {"resolution": {"vertices": 24}, "decimate": {"kind": "none"}}
    assert verify.primitive_tolerance("cylinder", inscribed) == pytest.approx(
        (1 - math.cos(math.pi / 24)) / 2 + verify.PLANAR_TOLERANCE
    )
    decimated = {"resolution": {"vertices": 24}, "decimate": {"kind": "collapse"}}
    assert verify.primitive_tolerance("cylinder", decimated) == pytest.approx(
        verify.tolerance("cylinder", decimated) + spec.gap(spec.default_resolution()) / 2
    )
    # the simple mesh of the largest object is ~0.5 wavelength from the primitive at 12 GHz
    rel = verify.primitive_tolerance("cylinder", {"resolution": {"vertices": 32}})
    assert verify.in_wavelengths(rel, (2.0, 2.0, 2.0)) == pytest.approx(
        rel * math.sqrt(12) / (299_792_458.0 / 12e9)
    )


def test_the_writer_stores_primitive_distances_and_object_params(tmp_path):
    import h5py

    from basic_shapes.shards import MeshRecord, ObjectRecord, write_shard

    v, f = box((1.0, 2.0, 3.0))
    meshes = [MeshRecord(0, v, f, 0.0, {}, 1e-9), MeshRecord(1, v, f, 2e-7, {}, 3e-8)]
    path = tmp_path / "s.h5"
    write_shard(
        path,
        [ObjectRecord(0, 0, np.array([1.0, 2.0, 3.0]), 1, "train", meshes)],
        ["cube"],
        {},
        "test",
    )
    with h5py.File(path) as h5:
        assert h5["meshes/primitive_distance"][()].tolist() == [1e-9, 3e-8]
        assert h5["objects/params"].asstr()[()].tolist() == ["{}"]


def _meshlab_per_sample(samples, v, f):
    """MeshLab's distance from every sample to the mesh (its saved per-sample quality) and the
    maximum it reports."""
    pm = verify._pymeshlab()
    ms = pm.MeshSet()
    ms.add_mesh(pm.Mesh(vertex_matrix=np.asarray(v, float), face_matrix=np.asarray(f, np.int32)))
    ms.add_mesh(pm.Mesh(vertex_matrix=samples))
    r = ms.get_hausdorff_distance(
        sampledmesh=1,
        targetmesh=0,
        samplevert=True,
        sampleedge=False,
        sampleface=False,
        samplenum=len(samples),
        savesample=True,
        maxdist=pm.PureValue(1e30),
    )
    return ms.mesh(2).vertex_scalar_array(), r["max"]


def _test_meshes():
    """Coarse inscribed meshes of each class (sagittas on curved ones, rounding on the box), the
    same meshes with their vertices moved off the surface (non-convex), and a box cut into
    slivers whose edges run through the surface samples (MeshLab's near-edge rule); float32
    vertices, as generated meshes have."""
    rng = np.random.default_rng(7)
    for kind, scale in [
        ("cube", (0.3, 1.1, 0.7)),
        ("cylinder", (1.0, 0.4, 1.6)),
        ("sphere", (0.5, 1.2, 0.9)),
    ]:
        solid = analytic.solid_for(kind, scale)
        v, f = analytic.simulation_mesh(solid, 3e8)
        yield solid, v.astype(np.float32), f
        yield solid, (v * (1 + 0.01 * rng.standard_normal((len(v), 1)))).astype(np.float32), f
    solid = analytic.solid_for("cube", (0.3, 1.1, 0.7))
    yield solid, *strip_box((0.3, 1.1, 0.7), np.linspace(-0.15, 0.15, 9))  # cuts through samples


def strip_box(extents, xs):
    """A box cut into strips at x = xs (float32 vertices): rings of 4 vertices, 2 caps."""
    _, b, c = np.asarray(extents, float) / 2
    v = np.array([[x, y, z] for x in xs for y, z in ((-b, -c), (b, -c), (b, c), (-b, c))])
    f = []
    for i in range(len(xs) - 1):
        for k in range(4):
            a0, a1, b0, b1 = 4 * i + k, 4 * i + (k + 1) % 4, 4 * i + 4 + k, 4 * i + 4 + (k + 1) % 4
            f += [[a0, a1, b1], [a0, b1, b0]]
    last = 4 * (len(xs) - 1)
    f += [[0, 3, 2], [0, 2, 1], [last, last + 1, last + 2], [last, last + 2, last + 3]]
    return v.astype(np.float32), np.array(f)


def test_meshlab_bounds_bracket_meshlab_and_keep_its_maximum():
    """Per sample, MeshLab's value lies within the float64 bounds, and MeshLab's maximum over
    the candidate samples, measured to the candidate faces only, is its maximum over all
    samples to the whole mesh, bit for bit."""
    from basic_shapes import meshlab_bounds

    for solid, v, f in _test_meshes():
        samples = analytic.surface_samples(solid, solid.diagonal * verify.SURFACE_SPACING)
        bounds = meshlab_bounds.SampleBounds(samples, solid.diagonal)
        per_sample, top = _meshlab_per_sample(samples, v, f)
        ff = np.asarray(f, np.int64)
        vv = np.asarray(v, float)
        planes = meshlab_bounds._planes(vv, ff)
        tau = meshlab_bounds.TAU * solid.diagonal**2
        rho = meshlab_bounds.RHO * solid.diagonal
        lower = meshlab_bounds._lower(samples, vv, ff, planes, tau, rho)
        assert np.all(lower - rho <= per_sample)
        cells = bounds.cells
        start, items = meshlab_bounds._face_cells(vv, ff, bounds.origin, bounds.cell, bounds.dims)
        first = meshlab_bounds._first_inside(samples, cells, planes, start, items, tau)
        every = np.arange(len(samples))
        upper = meshlab_bounds._upper(
            samples, cells, every, first, vv, ff, planes, start, items, tau
        )
        assert np.all(per_sample <= upper + rho)
        picked, near = bounds.candidates(v, f)
        assert len(picked) < len(samples) / 4
        assert _meshlab_per_sample(samples[picked], v, np.asarray(f)[near])[1] == top
