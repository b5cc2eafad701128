"""The hidden-parameter track's second family: the rounded box, whose edge radius class + scale
cannot tell, and the OOD meshes of hidden-parameter classes.

Checked against references that share no code with basic_shapes.analytic: Steiner's closed
forms for the area and volume of a box plus a ball, the distance along outward normals, a
dense surface sample built here from the box's pieces, and the stored radius read off the
simple mesh's flat faces.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from basic_shapes import analytic, verify
from basic_shapes.analytic import hidden_params
from basic_shapes.generate import GenerateConfig, generate, plan_objects
from basic_shapes.shards import Shard, is_ood_variant, list_shards, ood_remesher
from radar_sim import edges
from test_hidden import stored_simple_meshes


def roundbox(scale, ratio):
    return analytic.solid_for("roundbox", scale, {"round_ratio": ratio})


def steiner(scale, ratio):
    """(area, volume) of a box of extents ``scale`` whose edges are rounded with radius
    ratio x min(scale): the inner box, its faces pushed out, quarter cylinders, a ball."""
    r = ratio * min(scale)
    a, b, c = (s - 2 * r for s in scale)
    area = 2 * (a * b + b * c + c * a) + 2 * math.pi * r * (a + b + c) + 4 * math.pi * r * r
    volume = a * b * c + 2 * r * (a * b + b * c + c * a) + math.pi * r * r * (a + b + c)
    return area, volume + 4 / 3 * math.pi * r**3


def area_volume(v, f):
    t = v[f]
    cross = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    volume = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0
    return np.linalg.norm(cross, axis=1).sum() / 2, volume


def dense_surface(scale, ratio, step):
    """Points on the rounded box about ``step`` apart, piece by piece: six flat rectangles,
    twelve quarter cylinders, eight sphere octants (directions with all components >= 0)."""
    h = np.asarray(scale, np.float64) / 2
    r = ratio * min(scale)
    b = h - r
    pts = []
    g = np.random.default_rng(0).normal(size=(int(40 * (r / step) ** 2) + 100, 3))
    octant = np.abs(g) / np.linalg.norm(g, axis=1, keepdims=True)
    for signs in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3):
        pts.append(signs * (b + r * octant))
    for a in range(3):
        o = [k for k in range(3) if k != a]
        u = np.linspace(-b[o[0]], b[o[0]], int(2 * b[o[0]] / step) + 2)
        w = np.linspace(-b[o[1]], b[o[1]], int(2 * b[o[1]] / step) + 2)
        t = np.linspace(-b[a], b[a], int(2 * b[a] / step) + 2)
        phi = np.linspace(0, np.pi / 2, int(r / step) + 3)
        for s in (-1, 1):
            face = np.zeros((len(u), len(w), 3))
            face[..., a] = s * h[a]
            face[..., o[0]], face[..., o[1]] = np.meshgrid(u, w, indexing="ij")
            pts.append(face.reshape(-1, 3))
            for s2 in (-1, 1):
                strip = np.zeros((len(t), len(phi), 3))
                strip[..., a] = t[:, None]
                strip[..., o[0]] = s * (b[o[0]] + r * np.cos(phi))
                strip[..., o[1]] = s2 * (b[o[1]] + r * np.sin(phi))
                pts.append(strip.reshape(-1, 3))
    return np.concatenate(pts)


@pytest.mark.parametrize(
    "scale, ratio", [((0.7, 0.4, 0.5), 0.05), ((0.3, 0.9, 0.6), 0.25), ((0.6, 0.6, 0.6), 0.45)]
)
def test_simulation_mesh_area_and_volume_against_steiner(scale, ratio):
    """Inscribed (every vertex on the surface): area and volume just below the closed forms;
    the flat faces (normals along an axis) exactly the inner box's faces."""
    v, f = analytic.simulation_mesh(roundbox(scale, ratio), 12e9)
    area, volume = area_volume(v, f)
    exact_area, exact_volume = steiner(scale, ratio)
    assert exact_area * 0.998 <= area <= exact_area
    assert exact_volume * 0.998 <= volume <= exact_volume
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    axial = np.max(np.abs(n), axis=1) >= (1 - 1e-12) * np.linalg.norm(n, axis=1)
    r = ratio * min(scale)
    a, b, c = (s - 2 * r for s in scale)
    assert np.linalg.norm(n[axial], axis=1).sum() / 2 == pytest.approx(
        2 * (a * b + b * c + c * a), rel=1e-9
    )
    assert np.array_equal(v.max(axis=0) - v.min(axis=0), np.asarray(scale))


def test_surface_distance_along_normals_and_against_a_dense_sample():
    """Outside a convex body, a surface point moved by t along its outward normal is t away;
    everywhere, the distance is at most that to any surface point and within the sample's
    spacing of the nearest one."""
    scale, ratio = (0.5, 0.8, 0.3), 0.3
    solid = roundbox(scale, ratio)
    h, r = np.asarray(scale) / 2, ratio * min(scale)
    rng = np.random.default_rng(3)
    n = rng.normal(size=(400, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)  # no zero component: a corner's normal
    foot = np.sign(n) * (h - r) + r * n
    t = rng.uniform(0.0, 0.4, (400, 1))
    assert np.max(np.abs(analytic.surface_distance(solid, foot + t * n) - t[:, 0])) < 1e-12
    for a in range(3):  # flat faces and their normals
        p = rng.uniform(-1, 1, (50, 3)) * (h - r)
        p[:, a] = h[a] + t[:50, 0]
        assert np.max(np.abs(analytic.surface_distance(solid, p) - t[:50, 0])) < 1e-12
    step = 0.004
    s = dense_surface(scale, ratio, step)
    p = rng.uniform(-0.5, 0.5, (3000, 3))
    nearest = cKDTree(s).query(p)[0]
    d = analytic.surface_distance(solid, p)
    assert np.all(d <= nearest + 1e-12) and np.all(nearest - d < step)


def test_surface_samples_and_closest_points_lie_on_the_surface():
    scale, ratio = (0.5, 0.8, 0.3), 0.2
    solid = roundbox(scale, ratio)
    dense = cKDTree(dense_surface(scale, ratio, 0.003))
    samples = analytic.surface_samples(solid, 0.01)
    assert dense.query(samples)[0].max() < 0.003  # on the surface ...
    probes = dense_surface(scale, ratio, 0.02)
    assert cKDTree(samples).query(probes)[0].max() < 0.01  # ... and covering it
    p = np.random.default_rng(4).uniform(-0.6, 0.6, (2000, 3))
    p[:5] = [[0, 0, 0], [0.01, 0, 0], [0, -0.01, 0], [0, 0, 0.02], [0.1, 0.2, 0.05]]  # inside
    c = analytic.roundbox_closest(solid, p)
    assert np.max(analytic.surface_distance(solid, c)) < 1e-15
    assert np.max(np.abs(np.linalg.norm(p - c, axis=1) - analytic.surface_distance(solid, p))) < (
        1e-12
    )


def test_params_are_validated_and_drawn_without_moving_the_frustums():
    with pytest.raises(ValueError, match="round_ratio must be a number in"):
        roundbox((1, 1, 1), 0.5)
    with pytest.raises(ValueError, match="round_ratio"):
        analytic.solid_for("roundbox", (1, 1, 1), {"top_ratio": 0.2})
    # the frustum's stream is the one hidden-cpu-v1 was built with
    assert hidden_params("frustum", 12345) == {"top_ratio": 0.7786442562941901}
    cfg = GenerateConfig(classes=("roundbox",), objects_per_class=40, variants=1)
    ratios = np.array([p.params["round_ratio"] for p in plan_objects(cfg)])
    assert np.all((ratios >= 0.05) & (ratios <= 0.45)) and ratios.ptp() > 0.3


def test_no_sharp_edges_on_the_simulation_or_simple_mesh():
    """Every seam is tangent-continuous: edge diffraction finds nothing to add."""
    from basic_shapes.blender import object_meshes

    for scale, ratio in (((0.3, 0.4, 0.5), 0.05), ((2.0, 0.2, 1.0), 0.45)):
        v, f = analytic.simulation_mesh(roundbox(scale, ratio), 12e9)
        assert edges.sharp_edges((v, f)).count == 0
        simple = object_meshes("roundbox", np.array(scale), 3, 0, {"round_ratio": ratio})[0]
        assert edges.sharp_edges((simple.vertices.astype(np.float64), simple.faces)).count == 0


def test_blender_meshes_lie_on_their_roundbox_not_another():
    """Simple and complex meshes are within their primitive tolerance of their own rounded
    box (distance by hand: to the inner box minus the radius) and far off one whose radius is
    0.1 x the smallest extent smaller."""
    from basic_shapes.blender import object_meshes

    scale = np.array([0.6, 0.5, 0.4])

    def distance(v, ratio):
        r = ratio * scale.min()
        q = np.abs(v) - (scale / 2 - r)
        inside = np.minimum(q.max(axis=1), 0.0)
        return np.abs(np.linalg.norm(np.maximum(q, 0.0), axis=1) + inside - r)

    diagonal = float(np.linalg.norm(scale))
    for m in object_meshes("roundbox", scale, 7, 6, {"round_ratio": 0.3}):
        v = m.vertices.astype(np.float64)
        bound = verify.primitive_tolerance("roundbox", m.params) * diagonal
        assert distance(v, 0.3).max() <= bound
        assert distance(v, 0.2).max() > 2 * bound
        assert np.allclose(v.max(axis=0) - v.min(axis=0), scale, rtol=1e-6)


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """One train and one test object per hidden class, with OOD meshes for hidden classes."""
    out = tmp_path_factory.mktemp("roundbox")
    cfg = GenerateConfig(
        classes=("frustum", "roundbox"),
        objects_per_class=2,
        variants=2,
        test_fraction=0.5,
        val_fraction=0.0,
        ood_variants_per_remesher=1,
        hidden_ood=True,
    )
    generate(out, cfg, workers=0, progress=False)
    return out, {p.id: p for p in plan_objects(cfg)}


def test_generated_roundboxes_store_their_radius(generated):
    """/objects/params holds the planned ratio, and the simple mesh's flat top face (its
    vertices on the bbox plane) spans the inner box: scale - 2 r along x and y."""
    out, plans = generated
    seen = 0
    for oid, params, scale, v in stored_simple_meshes(out):
        assert params == plans[oid].params
        if plans[oid].class_name != "roundbox":
            continue
        top = v[np.isclose(v[:, 2], scale[2] / 2, rtol=0, atol=1e-6)]
        r = (scale[:2] - (top[:, :2].max(axis=0) - top[:, :2].min(axis=0))) / 2
        assert np.allclose(r / scale.min(), params["round_ratio"], atol=1e-5)
        seen += 1
    assert seen == 2


def test_hidden_test_objects_get_ood_meshes_of_their_own_shape(generated):
    """With hidden_ood, a test frustum gets delaunay meshes and a test rounded box all three
    remeshers', each within the class bound of its own hidden shape; without it (hidden-cpu-v1
    and -v2), none, and the config text is what those versions recorded."""
    out, plans = generated
    found = {}
    for path in list_shards(out):
        with Shard(path) as s:
            f = s.file
            variants, rows = f["meshes/variant"][()], f["meshes/object_index"][()]
            for k, oid in enumerate(f["objects/id"][()]):
                p = plans[int(oid)]
                mine = np.flatnonzero((rows == k) & is_ood_variant(variants))
                assert len(mine) == 0 or p.split == "test"
                solid = analytic.solid_for(p.class_name, p.scale, p.params)
                for m in mine:
                    v, faces = s.mesh(int(m))
                    d = analytic.surface_distance(solid, v.astype(np.float64)).max()
                    assert d <= verify.tolerance(p.class_name, {}) * solid.diagonal
                found.setdefault(p.class_name, set()).update(
                    ood_remesher(int(variants[m])) for m in mine
                )
    assert found == {"frustum": {"delaunay"}, "roundbox": {"isotropic", "qem", "delaunay"}}
    assert "hidden_ood" not in GenerateConfig(classes=("frustum",)).to_dict()
    from basic_shapes.generate import _ood_remeshers

    assert _ood_remeshers("frustum", {}) == 0 and _ood_remeshers("roundbox", {}) == 0
    assert _ood_remeshers("roundbox", {"hidden_ood": True}) == 3
