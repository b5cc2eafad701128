"""radar_sim against exact answers: flat plate, PO sphere, Mie series, cylinder, dihedral,
trihedral, topology invariance, and the range-profile conventions."""

import numpy as np
import pytest
import trimesh
from scipy import integrate, special
from scipy.spatial import Delaunay

from basic_shapes.geometry import fibonacci_directions
from radar_sim import (
    CHANNELS,
    RadarConfig,
    detect_mode,
    monostatic_field,
    polarimetric_field,
    simulate,
)
from radar_sim.field import C0


def db(x):
    return 10 * np.log10(x)


def plate(a, b, n=1, centre=(0.0, 0.0, 0.0)):
    """a x b rectangle in the z = centre_z plane, normal +z, as a grid of 2n² triangles."""
    x = np.linspace(-a / 2, a / 2, n + 1) + centre[0]
    y = np.linspace(-b / 2, b / 2, n + 1) + centre[1]
    gx, gy = np.meshgrid(x, y, indexing="ij")
    v = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, centre[2])], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a0, a1, b0, b1 = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    f = np.concatenate(
        [np.stack([a0, a1, b1], -1).reshape(-1, 3), np.stack([a0, b1, b0], -1).reshape(-1, 3)]
    )
    return v, f


# --- flat plate ------------------------------------------------------------------------------


@pytest.mark.parametrize("side, freq, expected_dbsm", [(1.5, 3e9, 38.04), (5.0, 1e9, 49.41)])
def test_plate_broadside(side, freq, expected_dbsm):
    v, f = plate(side, side)
    a = monostatic_field(v, f, [freq], [0, 0, 1])[0, 0]
    exact = 4 * np.pi * side**4 / (C0 / freq) ** 2
    assert abs(db(abs(a) ** 2) - db(exact)) <= 0.01
    assert abs(db(abs(a) ** 2) - expected_dbsm) <= 0.005
    back = monostatic_field(v, f, [freq], [0, 0, -1])[0, 0]  # an open plate is two-sided
    assert abs(abs(back) - abs(a)) <= 1e-12 * abs(a)


def test_plate_sinc_pattern():
    """σ(θ) = 4π(ab)²/λ² cos²θ sinc²(ka sinθ) for a tilt in the plane of side a, on a plate
    cut into 128 triangles: within 0.01 dB wherever the pattern is above −60 dB."""
    a, b, freq = 0.4, 0.25, 10e9
    k = 2 * np.pi * freq / C0
    v, f = plate(a, b, n=8)
    theta = np.radians(np.linspace(0, 80, 161))
    dirs = np.stack([np.sin(theta), 0 * theta, np.cos(theta)], axis=1)
    got = np.abs(monostatic_field(v, f, [freq], dirs)[:, 0]) ** 2
    u = k * a * np.sin(theta)
    exact = (
        4 * np.pi * (a * b) ** 2 / (C0 / freq) ** 2 * np.cos(theta) ** 2 * np.sinc(u / np.pi) ** 2
    )
    shown = exact > exact.max() * 1e-6
    assert shown.sum() > 140
    assert np.max(np.abs(db(got[shown]) - db(exact[shown]))) <= 0.01
    assert np.max(np.abs(np.sqrt(got) - np.sqrt(exact))) <= 1e-9 * np.sqrt(exact.max())


# --- spheres ---------------------------------------------------------------------------------


def mie_backscatter(ka):
    """σ/(πa²) of a perfectly conducting sphere (Mie series, scipy spherical Bessel)."""
    out = []
    for x in np.atleast_1d(ka):
        n = np.arange(1, int(x + 4 * x ** (1 / 3) + 12))
        jn, jnp = special.spherical_jn(n, x), special.spherical_jn(n, x, derivative=True)
        yn, ynp = special.spherical_yn(n, x), special.spherical_yn(n, x, derivative=True)
        hn, hnp = jn + 1j * yn, jnp + 1j * ynp
        a_n = jn / hn  # magnetic (TE) coefficient
        b_n = (jn + x * jnp) / (hn + x * hnp)  # electric (TM): [x j_n]'/[x h_n]'
        out.append(abs(np.sum((-1) ** n * (2 * n + 1) * (b_n - a_n))) ** 2 / x**2)
    return np.array(out)


def po_sphere(ka):
    """σ/(πa²) of the physical-optics sphere: |1 + j(1 − e^{−j2ka})/(2ka)|²."""
    return np.abs(1 + 1j * (1 - np.exp(-2j * ka)) / (2 * ka)) ** 2


def test_mie_series_limits():
    """The Mie code itself: Rayleigh 9(ka)⁴ for ka << 1, optical limit 1 for ka >> 1."""
    assert np.allclose(
        mie_backscatter([1e-3, 1e-2]) / (9 * np.array([1e-3, 1e-2]) ** 4), 1, rtol=1e-3
    )
    assert abs(mie_backscatter([300.0])[0] - 1) < 0.02


def sphere_response(subdivisions, a, ka):
    mesh = trimesh.creation.icosphere(subdivisions, radius=a)
    edge = mesh.edges_unique_length.max()
    freq = ka * C0 / (2 * np.pi * a)
    assert edge <= C0 / freq.max() / 8, "mesh must have edges <= λ/8"
    dirs = np.array([[0.0, 0.0, 1.0], [0.3, -0.5, 0.81], [-0.71, 0.2, -0.6]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    assert detect_mode(mesh.vertices, mesh.faces) == "convex"
    a_field = monostatic_field(mesh.vertices, mesh.faces, freq, dirs)
    return np.abs(a_field) ** 2 / (np.pi * a**2)


def test_sphere_po_closed_form_and_mie():
    """Icosphere (edges <= λ/8), 20 <= ka <= 37: within 0.05 dB of the PO closed form and
    within 0.45 dB of the Mie series (PO's own ripple sets that bound)."""
    ka = np.linspace(20, 37, 35)
    sigma = sphere_response(6, 0.1, ka)
    assert np.max(np.abs(db(sigma / po_sphere(ka)))) <= 0.05
    assert np.max(np.abs(db(sigma / mie_backscatter(ka)))) <= 0.45


@pytest.mark.slow
def test_sphere_mie_up_to_ka_100():
    """20 <= ka <= 50 within 0.45 dB, 50 <= ka <= 100 within 0.15 dB of Mie; PO closed form
    within 0.05 dB throughout (icosphere of 1.3 M faces)."""
    ka = np.concatenate([np.linspace(20, 50, 31), np.linspace(50, 100, 51)])
    sigma = sphere_response(8, 0.1, ka)
    err = np.abs(db(sigma / mie_backscatter(ka)))
    assert np.max(err[:, ka <= 50]) <= 0.45
    assert np.max(err[:, ka >= 50]) <= 0.15
    assert np.max(np.abs(db(sigma / po_sphere(ka)))) <= 0.05


# --- cylinder --------------------------------------------------------------------------------


def test_cylinder_broadside():
    """σ = 2πaL²/λ at broadside (ka = 50); the faceted mesh also matches the smooth-surface PO
    integral (k/√π) L a ∫ cos φ e^{j2ka cos φ} dφ."""
    a, length, freq = 0.15, 0.6, 16e9
    k, lam = 2 * np.pi * freq / C0, C0 / freq
    sections = int(np.ceil(2 * np.pi * a / (lam / 8)))
    mesh = trimesh.creation.cylinder(radius=a, height=length, sections=sections)
    dirs = np.array([[1.0, 0.0, 0.0], [np.cos(0.3), np.sin(0.3), 0.0]])
    got = monostatic_field(mesh.vertices, mesh.faces, [freq], dirs)[:, 0]
    parts = [
        integrate.quad(
            lambda p, g=g: np.cos(p) * g(2 * k * a * np.cos(p)), -np.pi / 2, np.pi / 2, limit=500
        )[0]
        for g in (np.cos, np.sin)
    ]
    smooth = k / np.sqrt(np.pi) * length * a * (parts[0] + 1j * parts[1])
    assert np.all(np.abs(db(np.abs(got) ** 2 / abs(smooth) ** 2)) <= 0.005)
    assert np.all(np.abs(db(np.abs(got) ** 2 / (2 * np.pi * a * length**2 / lam))) <= 0.02)


# --- multiple bounces ------------------------------------------------------------------------


def test_dihedral_peak_with_second_bounce():
    """90° dihedral of two a x b plates, seen along the bisector: σ = 8πa²b²/λ² within 0.2 dB."""
    a, b, freq = 0.3, 0.4, 10e9
    v, f = _dihedral(a, b)
    assert detect_mode(v, f) == "bounce2"
    los = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    exact = 8 * np.pi * a**2 * b**2 / (C0 / freq) ** 2
    got = abs(monostatic_field(v, f, [freq], los)[0, 0]) ** 2
    assert abs(db(got / exact)) <= 0.2
    single = abs(monostatic_field(v, f, [freq], los, mode="shadowed")[0, 0]) ** 2
    assert db(exact / single) > 30  # the peak is the double bounce


def _dihedral(a: float, b: float):
    """Two a x b plates meeting at 90° along the z axis (the fold), open towards x = y > 0."""
    v = np.array(
        [
            [0, 0, -b / 2],
            [0, 0, b / 2],
            [0, a, b / 2],
            [0, a, -b / 2],
            [a, 0, b / 2],
            [a, 0, -b / 2],
        ]
    )
    return v, np.array([[0, 1, 2], [0, 2, 3], [0, 4, 1], [0, 5, 4]])


def test_dihedral_channels_follow_the_fold():
    """Double bounce: E along the fold comes back as sent, E across it reversed, so VV = -HH
    and HV = 0 with the fold vertical; turned 45° about the line of sight the dihedral
    twists the polarization: HV takes the whole peak 8πa²b²/λ² and HH, VV vanish."""
    a, b, freq = 0.3, 0.4, 10e9
    v, f = _dihedral(a, b)
    los = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)  # aspect 90°, roll 45°: V = θ̂ = -z
    exact = 8 * np.pi * a**2 * b**2 / (C0 / freq) ** 2
    hh, vv, hv = polarimetric_field(v, f, [freq], los, mode="bounce2")[0, :, 0]
    assert CHANNELS == ("HH", "VV", "HV")
    assert abs(db(abs(vv) ** 2 / exact)) <= 0.2 and abs(db(abs(hh) ** 2 / exact)) <= 0.2
    assert abs(vv + hh) <= 0.05 * abs(vv)  # opposite phase
    assert abs(hv) ** 2 <= 1e-3 * exact
    assert vv == monostatic_field(v, f, [freq], los, mode="bounce2")[0, 0]  # same numbers
    turn = np.radians(45.0)
    k_ = los  # Rodrigues rotation about the line of sight
    rot = (
        np.cos(turn) * np.eye(3)
        + np.sin(turn) * np.array([[0, -k_[2], k_[1]], [k_[2], 0, -k_[0]], [-k_[1], k_[0], 0]])
        + (1 - np.cos(turn)) * np.outer(k_, k_)
    )
    hh, vv, hv = polarimetric_field(v @ rot.T, f, [freq], los, mode="bounce2")[0, :, 0]
    assert abs(db(abs(hv) ** 2 / exact)) <= 0.2
    assert abs(hh) ** 2 <= 1e-2 * exact and abs(vv) ** 2 <= 1e-2 * exact


def test_single_bounce_is_blind_to_polarization():
    """Monostatic single-bounce PO: HH = VV exactly and HV = 0 (the PO current projects
    onto the receive polarization as -(n·k̂) whatever the polarization)."""
    mesh = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
    dirs = fibonacci_directions(40)
    hh, vv, hv = np.moveaxis(polarimetric_field(mesh.vertices, mesh.faces, [9e9, 11e9], dirs), 1, 0)
    assert np.array_equal(hh, vv) and not np.any(hv)
    assert np.array_equal(vv, monostatic_field(mesh.vertices, mesh.faces, [9e9, 11e9], dirs))


def test_triangular_trihedral_peak():
    """Three mutually perpendicular right triangles of leg L, on the symmetry axis:
    σ = 4πL⁴/(3λ²) within 0.2 dB (a triple bounce)."""
    side, freq = 0.3, 10e9
    v = np.array([[0, 0, 0], [side, 0, 0], [0, side, 0], [0, 0, side]], dtype=float)
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1]])
    los = np.ones(3) / np.sqrt(3)
    exact = 4 * np.pi * side**4 / (3 * (C0 / freq) ** 2)
    got = abs(monostatic_field(v, f, [freq], los, mode="bounce2")[0, 0]) ** 2
    assert abs(db(got / exact)) <= 0.2


# --- topology invariance ---------------------------------------------------------------------


def subdivided_box(size, n_grid, n_random, seed):
    """A closed box whose faces are Delaunay triangulations of a shared boundary grid (exact
    binary fractions, so neighbouring faces weld) plus random interior points."""
    rng = np.random.default_rng(seed)
    half = np.asarray(size) / 2
    verts, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_ax, v_ax = [a for a in range(3) if a != axis]
            t = np.linspace(-1, 1, n_grid + 1)
            border = np.array([(x, y) for x in t for y in t if abs(x) == 1 or abs(y) == 1])
            inner = rng.uniform(-0.98, 0.98, size=(n_random, 2))
            uv = np.concatenate([border, inner])
            tri = Delaunay(uv).simplices
            p = np.zeros((len(uv), 3))
            p[:, axis] = sign * half[axis]
            p[:, u_ax] = uv[:, 0] * half[u_ax]
            p[:, v_ax] = uv[:, 1] * half[v_ax]
            normal = np.zeros(3)
            normal[axis] = sign
            e = np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]) @ normal
            tri[e < 0] = tri[e < 0][:, ::-1]
            faces.append(tri + sum(len(x) for x in verts))
            verts.append(p)
    return np.concatenate(verts), np.concatenate(faces)


def test_box_topology_invariance():
    """12 big triangles vs ~2,000 coplanar ones: the same response on a 153-direction grid at
    128 frequencies, to round-off (1e-11 of the largest amplitude; measured 6e-14)."""
    size = (0.5, 0.75, 1.0)
    simple = trimesh.creation.box(size)
    v2, f2 = subdivided_box(size, 8, 150, seed=0)
    assert len(f2) > 1500
    assert detect_mode(v2, f2) == "convex"
    config = RadarConfig(name="test-17x9", n_aspect=17, n_roll=9)
    r1 = simulate(simple.vertices, simple.faces, config).frequency_response
    r2 = simulate(v2, f2, config).frequency_response
    assert np.max(np.abs(r1 - r2)) <= 1e-11 * np.max(np.abs(r1))


# --- range profiles --------------------------------------------------------------------------


@pytest.mark.parametrize("physics", ["xband-v1", "xband-v3"])  # numpy's FFT, portable DFT
def test_range_profile_point_scatterer_convention(physics):
    """A 1 m² point scatterer at p has A(f) = exp(+j2k r̂·p); its profile peaks at exactly 1 in
    the bin at range −r̂·p (positive range points away from the radar)."""
    config = RadarConfig.named(physics)
    k = 2 * np.pi * config.frequency_hz / C0
    dr = config.range_resolution_m
    for m in (0, 7, -20):
        profile = config.range_profiles(np.exp(2j * k * (-m * dr)))  # r̂·p = −m·dr
        peak = np.argmax(np.abs(profile))
        assert config.range_m[peak] == pytest.approx(m * dr)
        assert abs(profile[peak] - 1) <= 1e-12
    assert len(config.range_m) == 107 and config.range_m[53] == 0.0
    assert dr == pytest.approx(0.03718, abs=1e-5)


def test_portable_transform_is_the_inverse_fft_of_the_kept_bins():
    """The portable DFT (xband-v3) and numpy's FFT (through xband-v2) are the same sum: on any
    response, every window and an odd grid, they agree to round-off (1e-13 of the largest
    amplitude), and both are linear in the response's leading axes."""
    rng = np.random.default_rng(0)
    for window, n_freq, n_range in (("hann", 128, 107), ("none", 37, 9)):
        fft = RadarConfig(name="t", window=window, n_freq=n_freq, n_range=n_range)
        dft = RadarConfig(
            name="t", window=window, n_freq=n_freq, n_range=n_range, transform="portable-dft"
        )
        response = rng.normal(size=(2, 3, n_freq)) + 1j * rng.normal(size=(2, 3, n_freq))
        a, b = fft.range_profiles(response), dft.range_profiles(response)
        assert b.shape == (2, 3, n_range)
        assert np.max(np.abs(a - b)) <= 1e-13 * np.max(np.abs(a))


def test_range_profile_of_an_offset_plate():
    """A plate facing +x at x = +5 bins, seen from aspect 90° roll 0 (r̂ = +x): nearer the
    radar, so its peak sits at range −5 bins, with the window-weighted mean of √σ(f)."""
    config = RadarConfig(
        name="test-3x1", n_aspect=3, n_roll=1, aspect_start_deg=88.0, aspect_stop_deg=92.0
    )
    dr = config.range_resolution_m
    v, f = plate(0.1, 0.1)
    v = v[:, [2, 1, 0]]  # rotate so that the normal is +x
    f = f[:, ::-1]
    v[:, 0] = 5 * dr
    result = simulate(v, f, config)
    profile = result.range_profiles[1, 0]
    peak = np.argmax(np.abs(profile))
    assert result.range_m[peak] == pytest.approx(-5 * dr)
    w = config.window_weights()
    sqrt_sigma = 2 * np.sqrt(np.pi) * 0.01 * config.frequency_hz / C0
    assert abs(profile[peak] - np.sum(w * sqrt_sigma) / w.sum()) <= 1e-9 * abs(profile[peak])


def test_shadowing_hides_an_occluded_plate():
    """A 0.2 m plate 0.2 m behind a 0.4 m plate: seen from the front, "shadowed" gives exactly
    the front plate's 4πS²/λ², while culling alone would add the hidden plate; side by side,
    nothing is hidden and both modes agree."""
    freq = 10e9
    front_v, front_f = plate(0.4, 0.4, n=2, centre=(0.0, 0.0, 0.2))
    back_v, back_f = plate(0.2, 0.2, n=2)
    v = np.concatenate([front_v, back_v])
    f = np.concatenate([front_f, back_f + len(front_v)])
    exact = np.sqrt(4 * np.pi) * 0.4**2 / (C0 / freq)
    shadowed = monostatic_field(v, f, [freq], [0, 0, 1], mode="shadowed")[0, 0]
    culled = monostatic_field(v, f, [freq], [0, 0, 1], mode="convex")[0, 0]
    assert abs(abs(shadowed) - exact) <= 1e-12 * exact
    assert abs(abs(culled) - exact) > 0.1 * exact
    apart = np.concatenate([front_v, back_v + [1.0, 0.0, 0.0]])
    side = [monostatic_field(apart, f, [freq], [0, 0, 1], mode=m) for m in ("shadowed", "convex")]
    assert np.array_equal(side[0], side[1])
