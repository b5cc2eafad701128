"""basic_shapes.analytic against exact distances, brute force and independent geometry."""

import math

import numpy as np
import pytest
import trimesh

from basic_shapes import analytic, meshcheck, primitives, verify

SCALES = [(1.0, 1.4, 1.8), (0.2, 2.0, 2.0), (2.0, 2.0, 0.2)]


def brute_force_to(dense, points):
    """Distance from each point to the nearest of ``dense`` (one point at a time: small memory)."""
    out = np.empty(len(points))
    d2 = (dense**2).sum(axis=1)
    for i, p in enumerate(points):
        out[i] = math.sqrt(max(0.0, (d2 - 2 * dense @ p).min() + p @ p))
    return out


def brute_force(solid, points, spacing):
    """Distance to the nearest of dense surface samples: an upper bound within ~spacing."""
    return brute_force_to(analytic.surface_samples(solid, spacing), points)


def test_sphere_distance_is_exact():
    r = 0.7
    solid = analytic.solid_for("sphere", (2 * r,) * 3)
    rng = np.random.default_rng(1)
    p = rng.normal(size=(2000, 3)) * rng.uniform(0.01, 2.0, (2000, 1))
    d = analytic.surface_distance(solid, p)
    np.testing.assert_allclose(d, np.abs(np.linalg.norm(p, axis=1) - r), rtol=0, atol=1e-12)


def test_box_distance_is_exact_inside_and_outside():
    solid = analytic.solid_for("cube", (1.0, 2.0, 3.0))
    p = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [1.5, 2.0, 0.0], [0.5, 1.0, 1.5]])
    np.testing.assert_allclose(
        analytic.surface_distance(solid, p), [0.5, 0.1, math.hypot(1.0, 1.0), 0.0], atol=1e-15
    )


def test_circular_cylinder_and_torus_distances_are_exact():
    rng = np.random.default_rng(2)
    p = rng.uniform(-1.5, 1.5, (2000, 3))
    cyl = analytic.solid_for("cylinder", (2.0, 2.0, 2.0))
    rho, z = np.hypot(p[:, 0], p[:, 1]), p[:, 2]
    side = np.hypot(rho - 1, np.maximum(np.abs(z) - 1, 0))
    cap = np.where(rho <= 1, np.abs(np.abs(z) - 1), np.hypot(rho - 1, np.abs(z) - 1))
    np.testing.assert_allclose(analytic.surface_distance(cyl, p), np.minimum(side, cap), atol=1e-12)
    torus = analytic.solid_for("torus", (2.5, 2.5, 0.5))  # Blender's default: R 1, r 0.25
    exact = np.abs(np.hypot(rho - 1.0, z) - 0.25)
    np.testing.assert_allclose(analytic.surface_distance(torus, p), exact, atol=1e-12)


def test_circular_cone_distance_is_exact():
    # Cone of radius 1, apex at z = +1, base at z = -1: in the (rho, z) half plane the side is
    # the segment from (1, -1) to (0, 1); distance = to that segment, the base, or the apex.
    cone = analytic.solid_for("cone", (2.0, 2.0, 2.0))
    rng = np.random.default_rng(3)
    p = rng.uniform(-1.6, 1.6, (3000, 3))
    q = np.column_stack([np.hypot(p[:, 0], p[:, 1]), p[:, 2]])
    a, b = np.array([1.0, -1.0]), np.array([0.0, 1.0])
    t = np.clip(((q - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    side = np.linalg.norm(q - (a + t[:, None] * (b - a)), axis=1)
    base = np.where(q[:, 0] <= 1, np.abs(q[:, 1] + 1), np.hypot(q[:, 0] - 1, q[:, 1] + 1))
    np.testing.assert_allclose(
        analytic.surface_distance(cone, p), np.minimum(side, base), atol=1e-12
    )


@pytest.mark.parametrize("kind", ["cylinder", "sphere", "cone", "torus"])
@pytest.mark.parametrize("scale", SCALES)
def test_distance_matches_brute_force_on_elliptic_shapes(kind, scale):
    solid = analytic.solid_for(kind, scale)
    rng = np.random.default_rng(4)
    p = rng.uniform(-0.6, 0.6, (100, 3)) * np.asarray(scale)
    spacing = 0.01
    d = analytic.surface_distance(solid, p)
    bf = brute_force(solid, p, spacing)
    assert np.all(d <= bf + 1e-9)  # never above a true surface point's distance
    assert np.all(bf - d <= spacing)  # and within the samples' spacing of the nearest


@pytest.mark.parametrize("kind", analytic.KINDS)
@pytest.mark.parametrize("scale", SCALES)
def test_simulation_mesh_is_closed_outward_and_on_the_surface(kind, scale):
    solid = analytic.solid_for(kind, scale)
    v, f = analytic.simulation_mesh(solid, 12e9)
    assert v.dtype == np.float64 and f.dtype == np.int32
    assert meshcheck.defect(v, f, primitives.get(kind).euler) is None
    assert trimesh.Trimesh(v, f, process=False).volume > 0  # outward
    np.testing.assert_allclose(v.max(axis=0) - v.min(axis=0), scale, rtol=1e-12)
    assert analytic.surface_distance(solid, v[:: max(1, len(v) // 3000)]).max() < 1e-12
    again = analytic.simulation_mesh(solid, 12e9)
    assert np.array_equal(v, again[0]) and np.array_equal(f, again[1])


def test_simulation_mesh_volume_converges_to_the_smooth_solid():
    # volumes of the smooth solids: box, elliptic cylinder, ellipsoid, cone, torus
    a, b, c = 0.5, 0.7, 0.9
    exact = {
        "cube": 8 * a * b * c,
        "cylinder": math.pi * a * b * 2 * c,
        "sphere": 4 / 3 * math.pi * a * b * c,
        "cone": math.pi * a * b * 2 * c / 3,
    }
    for kind, volume in exact.items():
        v, f = analytic.simulation_mesh(analytic.solid_for(kind, (2 * a, 2 * b, 2 * c)), 12e9)
        assert trimesh.Trimesh(v, f, process=False).volume == pytest.approx(volume, rel=2e-4)
    s = np.array([1.0, 1.4, 0.3]) / np.array([2.5, 2.5, 0.5])
    torus = 2 * math.pi**2 * 1.0 * 0.25**2 * s.prod()
    v, f = analytic.simulation_mesh(analytic.solid_for("torus", (1.0, 1.4, 0.3)), 12e9)
    assert trimesh.Trimesh(v, f, process=False).volume == pytest.approx(torus, rel=1e-3)


@pytest.mark.parametrize("rule", sorted(analytic.SIMULATION_RULES))
def test_strip_edges_follow_the_rule(rule):
    # cylinder side strips: every rim edge at most strip_edge_half_wavelengths * lambda / 2,
    # divided by the rule's rim refinement (version 2 cuts rims at half the limit)
    spec = analytic.SIMULATION_RULES[rule]
    solid = analytic.solid_for("cylinder", (2.0, 1.0, 1.0))
    v, f = analytic.simulation_mesh(solid, 12e9, rule=rule)
    rim = v[v[:, 2] == -0.5][:-1]
    edges = np.linalg.norm(np.diff(np.vstack([rim, rim[:1]]), axis=0), axis=1)
    limit = spec["strip_edge_half_wavelengths"] * analytic.C0 / 12e9 / 2
    limit /= spec.get("rim_refinement", 1.0)
    assert edges.max() <= limit and edges.max() > 0.7 * limit


def test_smaller_objects_and_lower_frequencies_get_fewer_faces():
    big = analytic.solid_for("sphere", (2.0, 2.0, 2.0))
    small = analytic.solid_for("sphere", (0.2, 0.2, 0.2))
    n = {
        k: len(analytic.simulation_mesh(s, f)[1])
        for k, (s, f) in {"big": (big, 12e9), "small": (small, 12e9), "low": (big, 6e9)}.items()
    }
    assert n["small"] < n["big"] / 50 and n["low"] < n["big"] / 3
    assert len(analytic.simulation_mesh(analytic.solid_for("cube", (2, 2, 2)), 12e9)[1]) == 12


def test_surface_samples_lie_on_the_surface_and_cover_it():
    for kind in analytic.KINDS:
        solid = analytic.solid_for(kind, (0.5, 0.7, 0.3))
        x = analytic.surface_samples(solid, 0.02)
        assert analytic.surface_distance(solid, x).max() < 1e-12
        v, f = analytic.simulation_mesh(solid, 12e9)
        # every point of a fine inscribed mesh is near some sample
        gap = verify.face_samples(v, f, 0.01)[::97]
        assert brute_force_to(x, gap).max() < 0.03


def test_json_rule_and_bad_input():
    import json

    for rule in analytic.SIMULATION_RULES.values():
        assert json.loads(json.dumps(rule)) == rule
    with pytest.raises(ValueError, match="unknown simulation rule 3"):
        analytic.simulation_mesh(analytic.solid_for("cube", (1, 1, 1)), 12e9, rule=3)
    with pytest.raises(ValueError, match="unknown primitive class 'prism'"):
        analytic.solid_for("prism", (1, 1, 1))
    with pytest.raises(ValueError, match="three positive finite"):
        analytic.solid_for("cube", (1, 0, 1))
    with pytest.raises(ValueError, match="shape parameters must be"):
        analytic.solid_for("cone", (1, 1, 1), {"ratio": 0.5})
    with pytest.raises(ValueError, match="f_max_hz"):
        analytic.simulation_mesh(analytic.solid_for("cube", (1, 1, 1)), 0.0)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        analytic.surface_distance(analytic.solid_for("cube", (1, 1, 1)), np.zeros(3))


@pytest.mark.parametrize(
    "kind",  # the torus (off by default; 30 s here) runs in the slow set
    [pytest.param(k, marks=pytest.mark.slow) if k == "torus" else k for k in analytic.KINDS],
)
def test_blender_primitives_lie_on_the_analytic_surface(kind):
    from basic_shapes import blender

    scale = np.array([0.3, 1.7, 0.9])
    meshes = blender.object_meshes(kind, scale, 5, 3)
    solid = analytic.solid_for(kind, scale)
    v0 = meshes[0].vertices
    # every vertex of the simple mesh is on the smooth surface (float32 rounding)
    assert analytic.surface_distance(solid, v0).max() < 1e-6 * solid.diagonal
    for m in meshes:
        assert 0 <= m.primitive_distance <= verify.primitive_tolerance(kind, m.params)
    if kind != "cube":  # inscribed polygons: the simple mesh is a sagitta away, not closer
        assert meshes[0].primitive_distance > 0.2 * verify.primitive_tolerance(kind, {})


def test_unit_shapes_match_the_primitive_registry():
    assert set(analytic.ALL_KINDS) == set(primitives.PRIMITIVES)
    assert analytic.TORUS_EXTENTS == primitives.get("torus").extents
    assert all(primitives.get(k).extents == (2.0, 2.0, 2.0) for k in analytic.KINDS if k != "torus")


def _ellipsoid_implicit(axes):
    """F = sum(x^2 / axes^2) - 1 with its gradient and (diagonal) Hessian, numpy."""
    inv = 1.0 / np.asarray(axes, np.float64) ** 2

    def f(x):
        return (x * x * inv).sum(axis=1) - 1.0, 2.0 * x * inv, np.broadcast_to(2.0 * inv, x.shape)

    return f


@pytest.mark.parametrize(
    "axes", [(0.5, 0.7, 0.9), (0.05, 1.0, 1.0), (1.0, 1.0, 0.1), (0.3, 1.2), (1.0, 0.02)]
)
def test_compiled_newton_is_bit_identical_to_the_numpy_iteration(axes):
    """ellipsoid_closest.closest repeats analytic._closest_on_implicit's arithmetic exactly:
    the stored distances depend on every last bit (dataset fingerprints)."""
    from basic_shapes import ellipsoid_closest

    rng = np.random.default_rng(3)
    a = np.asarray(axes)
    u = rng.standard_normal((4000, len(a)))
    on = u / np.linalg.norm(u / a, axis=1, keepdims=True)  # on the surface
    p = on * rng.uniform(0.0, 2.0, (4000, 1)) ** rng.choice([1, 3], (4000, 1))
    starts = on[rng.permutation(4000)]
    starts[:3000] = on[:3000] + 0.02 * rng.standard_normal((3000, len(a)))  # near, off it
    x_ref, ok_ref = analytic._closest_on_implicit(p, starts, _ellipsoid_implicit(a))
    scale = np.abs(p).max() + np.abs(starts).max() + 1e-300
    x, value = ellipsoid_closest.closest(
        p, starts, 1.0 / a**2, 1e-14 * scale, analytic.NEWTON_STEPS
    )
    ok = (np.abs(value) < 1e-12) & np.all(np.isfinite(x), axis=1)
    assert np.array_equal(x, x_ref, equal_nan=True)
    assert np.array_equal(ok, ok_ref)
    assert ok.mean() > 0.9
