"""The PO facet integral against an arbitrary-precision (mpmath) reference, hard cases included.

References are computed from the very float64 inputs (vertices, direction, k) with enough
digits for the smallest phase gap, by the divided-difference definition, so they are
independent of the stable algorithms under test.
"""

from contextlib import nullcontext

import mpmath
import numpy as np
import pytest

from basic_shapes.analytic import uv_sphere
from radar_sim import UnitsWarning, facet, monostatic_field
from radar_sim.field import C0

K = 2 * np.pi * np.array([1e9, 8e9, 12e9]) / C0


def dd_ref(x1, x2, x3):
    """exp[j x1, j x2, j x3] for exact float (or mpf) phases."""
    with mpmath.workdps(80):  # keep every digit of mpf inputs
        xs = sorted(+mpmath.mpf(v) for v in (x1, x2, x3))
    gaps = [g for g in (xs[1] - xs[0], xs[2] - xs[1]) if g != 0]
    big = max([abs(v) for v in xs] + [mpmath.mpf(1)])
    small = min(gaps) if gaps else mpmath.mpf(1)
    digits = 40 + int(mpmath.log10(big)) + 2 * max(0, int(-mpmath.log10(small)))
    with mpmath.workdps(digits):
        a, b, c = (mpmath.mpc(0, v) for v in xs)
        f = mpmath.exp

        def d1(p, q):
            return f(p) if p == q else (f(p) - f(q)) / (p - q)

        if a == c:
            return f(a) / 2
        if a == b:
            return (f(a) - d1(a, c)) / (a - c)
        if b == c:
            return (d1(a, c) - f(c)) / (a - c)
        return (d1(a, b) - d1(b, c)) / (a - c)


def field_ref(tri, direction, k, two_sided=True):
    """(k/√π)·2P·exp[j2k r̂·r_i] from the exact float inputs."""
    with mpmath.workdps(80):
        v = [[mpmath.mpf(float(c)) for c in p] for p in tri]
        r = [mpmath.mpf(float(c)) for c in direction]
        e1 = [v[1][i] - v[0][i] for i in range(3)]
        e2 = [v[2][i] - v[0][i] for i in range(3)]
        cross = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ]
        proj = sum(cross[i] * r[i] for i in range(3)) / 2
        proj = abs(proj) if two_sided else max(proj, 0)
        kk = mpmath.mpf(float(k))
        x = [2 * kk * sum(r[i] * p[i] for i in range(3)) for p in v]
    dd = dd_ref(*x)
    with mpmath.workdps(40):
        return complex(2 / mpmath.sqrt(mpmath.pi) * kk * proj * dd), float(
            proj * kk / mpmath.sqrt(mpmath.pi)
        )


def unit(*v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def tilt(angle):
    """Unit vector at ``angle`` from +z, in the x-z plane."""
    return np.array([np.sin(angle), 0.0, np.cos(angle)])


TRI = np.array([[0.02, -0.01, 0.05], [0.11, 0.03, 0.05], [0.04, 0.09, 0.05]])  # z = 0.05 plane
SQUARE_EDGE = np.array([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0], [0.07, 0.03, 0.0]])  # an edge along y

HARD = {
    "exact specular": (TRI, np.array([0.0, 0.0, 1.0])),
    "specular + 1e-12 rad": (TRI, tilt(1e-12)),
    "specular + 1e-8 rad": (TRI, tilt(1e-8)),
    "specular + 1e-4 rad": (TRI, tilt(1e-4)),
    "edge perpendicular to gradient": (SQUARE_EDGE, unit(0.6, 0.0, 0.8)),
    "edge nearly perpendicular 1e-9": (SQUARE_EDGE, unit(0.6, 1e-9, 0.8)),
    "edge nearly perpendicular 1e-5": (SQUARE_EDGE, unit(0.6, 1e-5, 0.8)),
    "grazing 1e-9 above the plane": (TRI, unit(1.0, 0.3, 1e-9)),
    "grazing 1e-3 above the plane": (TRI, unit(1.0, 0.3, 1e-3)),
    "sliver height 1e-9": (
        np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.1, 1e-9, 0.0]]),
        unit(0.3, 0.5, 0.8),
    ),
    "sliver two vertices 1e-12 apart": (
        np.array([[0.0, 0.0, 0.0], [0.1, 0.02, 0.01], [0.1, 0.02, 0.01 + 1e-12]]),
        unit(0.2, 0.1, 1.0),
    ),
    "equal-phase pair, far third": (
        np.array([[0.0, 0.0, 0.0], [0.0, 0.3, 0.0], [0.5, 0.1, 0.0]]),
        unit(1.0, 0.0, 1.0),
    ),
    "1e-4 m facet": (1e-4 * np.array([[0, 0, 0], [1, 0.2, 0], [0.3, 1, 0.1]]), unit(0.1, 0.2, 1.0)),
    "1e3 m facet": (1e3 * np.array([[0, 0, 0], [1, 0.2, 0], [0.3, 1, 0.1]]), unit(0.1, 0.2, 1.0)),
    "1e3 m facet near specular": (
        1e3 * np.array([[0, 0, 0.5], [1, 0.2, 0.5], [0.3, 1, 0.5]]),
        tilt(1e-7),
    ),
    "small facet 1e3 m from origin": (
        np.array([[1e3, 0, 0], [1e3 + 0.1, 0.02, 0], [1e3, 0.1, 0.01]]),
        unit(0.4, 0.3, 0.9),
    ),
    "half-radian spread": (np.array([[0, 0, 0], [1e-4, 0, 0], [0, 1e-4, 0]]), unit(1, 1, 0.01)),
}


@pytest.mark.parametrize("name", sorted(HARD))
def test_facet_field_matches_mpmath_on_hard_cases(name):
    tri, direction = HARD[name]
    got = facet.facet_field(tri[None], direction, K, two_sided=True)[0]
    for k, g in zip(K, got):
        ref, _ = field_ref(tri, direction, k)
        assert abs(g - ref) <= 1e-12 * abs(ref), (name, k, g, ref)


@pytest.mark.parametrize("name", sorted(HARD))
def test_fast_path_matches_mpmath_on_hard_cases(name):
    """monostatic_field (vertex weights, confluent forms, switch rule) on one triangle: error
    within tol of the facet's broadside magnitude A k/√π, plus the phase conditioning of a
    float64 position (eps·2kR·|A_f|, negligible for facets near the origin)."""
    tri, direction = HARD[name]
    freqs = K * C0 / (2 * np.pi)
    with pytest.warns(UnitsWarning) if np.abs(tri).max() > 100 else nullcontext():
        got = monostatic_field(tri, [[0, 1, 2]], freqs, direction, mode="convex", tol=1e-13)[0]
    radius = np.linalg.norm(tri, axis=1).max()
    area = np.linalg.norm(facet.area_vectors(tri))
    for k, g in zip(K, got):
        ref, _ = field_ref(tri, direction, k)
        bound = 1e-12 * area * k / np.sqrt(np.pi) + 8 * np.finfo(float).eps * 2 * k * radius * abs(
            ref
        )
        assert abs(g - ref) <= bound, (name, k, g, ref, abs(g - ref) / bound)


def test_facet_field_random_triangles():
    """Random sizes (1e-4 .. 10 m), positions and directions, 8-12 GHz."""
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(150):
        size = 10 ** rng.uniform(-4, 1)
        tri = rng.normal(size=3) + size * rng.normal(size=(3, 3))
        direction = unit(*rng.normal(size=3))
        k = 2 * np.pi * rng.uniform(8e9, 12e9) / C0
        got = facet.facet_field(tri[None], direction, [k], two_sided=True)[0, 0]
        ref, spec = field_ref(tri, direction, k)
        worst = max(worst, abs(got - ref) / abs(ref))
    assert worst <= 1e-12


def test_divided_difference_hard_phases():
    """Coincident, nearly coincident, branch-boundary and huge phases."""
    cases = []
    for base in (0.0, 1.0, 123.456, -400.0, 3.0e5):
        for gap in (0.0, 1e-300, 1e-16, 1e-10, 1e-5, 0.2499, 0.2501, 0.4999, 0.5001, 1.0, 3.0, 1e3):
            cases += [
                (base, base, base + gap),
                (base, base + gap, base + gap),
                (base, base + gap, base + 2 * gap),
                (base + gap, base, base - gap / 3),
            ]
    x = np.array(cases)
    got = facet.exp_divided_difference(x[:, 0], x[:, 1], x[:, 2])
    for xi, g in zip(x, got):
        ref = complex(dd_ref(*xi))
        assert abs(g - ref) <= 1e-12 * abs(ref), (xi, g, ref)


def test_divided_difference_at_its_own_zero():
    """exp[0, j2π, j4π] vanishes (to the rounding of 2π); the error is absolute, ~eps/D."""
    got = facet.exp_divided_difference(0.0, 2 * np.pi, 4 * np.pi)
    ref = complex(dd_ref(0.0, 2 * np.pi, 4 * np.pi))
    assert abs(ref) < 1e-30
    assert abs(got - ref) <= 1e-15


def test_cis_matches_mpmath_including_fallback_range():
    rng = np.random.default_rng(0)
    x = np.concatenate(
        [
            rng.uniform(-1e3, 1e3, 300),
            rng.uniform(-6e6, 6e6, 100),
            [0.0, np.pi, -np.pi / 2, 1e7, -3e7],
            rng.uniform(-1e-3, 1e-3, 20),
        ]
    )
    lo = rng.uniform(-1e-12, 1e-12, len(x))
    with mpmath.workdps(40):
        ref = np.array(
            [
                complex(mpmath.expj(mpmath.mpf(float(a)) + mpmath.mpf(float(b))))
                for a, b in zip(x, lo)
            ]
        )
    assert np.max(np.abs(facet.cis(x, lo) - ref)) <= 4e-16 + 2e-16 * np.abs(lo).max()
    assert np.max(np.abs(facet.cis(x[:320]) - np.exp(1j * x[:320]))) < 1e-15


def test_fast_path_matches_stable_sum_on_a_mesh():
    """Vertex weights summed on a tessellated surface at many directions (including exactly
    axis-aligned ones) agree with Σ facet_field within tol of Σ specular magnitudes."""
    import trimesh

    mesh = trimesh.creation.icosphere(2, radius=0.3)
    v, f = mesh.vertices, mesh.faces
    rng = np.random.default_rng(1)
    dirs = np.concatenate([np.eye(3), -np.eye(3), rng.normal(size=(20, 3))])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freqs = np.linspace(8e9, 12e9, 128)
    k = 2 * np.pi * freqs / C0
    fast = monostatic_field(v, f, freqs, dirs, mode="convex")
    tri = v[f]
    for d, row in zip(dirs, fast):
        ref = facet.facet_field(tri, d, k).sum(axis=0)
        proj = np.maximum(0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) @ d, 0)
        scale = proj.sum() * k / np.sqrt(np.pi)
        assert np.all(np.abs(row - ref) <= 1e-10 * scale)


def rotation(seed):
    """A rotation in general orientation (no axis-aligned edges or normals)."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q


@pytest.mark.parametrize("angle", [1e-12, 1e-9, 1e-6, 1e-3])
def test_grazing_facet_in_general_orientation(angle):
    """A facet seen ``angle`` rad above its plane, both in general orientation: the projected
    area r̂·A is ~angle·|A|, so a float64 r̂·A alone would carry a relative error ~eps/angle;
    both paths must keep relative precision against mpmath (bound relative to |P| k/√π)."""
    rot = rotation(7)
    tri = TRI @ rot.T
    normal = np.array([0.0, 0.0, 1.0]) @ rot.T
    along = unit(1.0, 0.3, 0.0) @ rot.T
    direction = unit(*(np.cos(angle) * along + np.sin(angle) * normal))
    freqs = K * C0 / (2 * np.pi)
    fast = monostatic_field(tri, [[0, 1, 2]], freqs, direction, mode="convex", tol=1e-13)[0]
    stable = facet.facet_field(tri[None], direction, K, two_sided=True)[0]
    for k, g, s in zip(K, fast, stable):
        ref, spec = field_ref(tri, direction, k)
        assert 0.1 * angle < spec / (np.linalg.norm(facet.area_vectors(tri)) * k / np.sqrt(np.pi))
        assert abs(s - ref) <= 1e-12 * abs(ref), (k, s, ref)
        assert abs(g - ref) <= 1e-12 * spec, (k, g, ref, abs(g - ref) / spec)


@pytest.mark.parametrize("grid", ["uniform", "irregular"])
def test_fast_path_matches_stable_sum_on_a_uv_ellipsoid(grid):
    """The same on a fine UV ellipsoid with exactly axis-aligned views (whole rings of
    equal-phase pairs), near-specular facets and general views, on a uniform frequency grid
    (phasor recurrences of the special facets) and an irregular one."""
    v, f = uv_sphere(48, 40, (0.5, 0.7, 0.9))
    rng = np.random.default_rng(4)
    dirs = np.concatenate(
        [np.eye(3), -np.eye(3), [unit(1, 1, 0), unit(0, 1, 1)], rng.normal(size=(8, 3))]
    )
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freqs = np.linspace(8e9, 12e9, 64)
    if grid == "irregular":
        freqs = np.sort(rng.uniform(8e9, 12e9, 64))
    k = 2 * np.pi * freqs / C0
    fast = monostatic_field(v, f, freqs, dirs, mode="convex")
    tri = v[f]
    for d, row in zip(dirs, fast):
        ref = facet.facet_field(tri, d, k).sum(axis=0)
        proj = np.maximum(facet.area_vectors(tri) @ d, 0)
        scale = proj.sum() * k / np.sqrt(np.pi)
        assert np.all(np.abs(row - ref) <= 1e-10 * scale), np.max(np.abs(row - ref) / scale)


def test_the_kernels_set_up_in_chunks_gives_the_same_bytes():
    """The per-mesh area vectors (double-double) are formed in chunks of faces: bit for bit
    what one call over the whole mesh gives, across chunk boundaries and in the last chunk."""
    from radar_sim import field, scene

    v, f = uv_sphere(100, 100, (0.5, 0.7, 0.9))
    mesh = scene.prepare(v, f)
    assert len(mesh.faces) > field.SETUP_CHUNK and len(mesh.faces) % field.SETUP_CHUNK
    geo = field._Geometry(mesh)
    area, area_lo = facet.area_vectors_split(np.asarray(mesh.vertices)[np.asarray(mesh.faces)])
    assert geo.area.tobytes() == area.tobytes() and geo.area_lo.tobytes() == area_lo.tobytes()
