"""``radar_sim.rcs`` against closed forms: the flat plate 4πS²/λ² (and its sinc² pattern
swept in roll, which pins the line-of-sight convention) and the PO sphere."""

import numpy as np
import pytest
import trimesh

import radar_sim
from basic_shapes.geometry import line_of_sight

C0 = 299_792_458.0


def db(x):
    return 10 * np.log10(x)


def plate(a, b, n, normal):
    """a x b rectangle through the origin, grid of 2n² triangles. normal "z": sides a along x,
    b along y; normal "x": a along y, b along z; normal "y": a along z, b along x."""
    u = np.linspace(-a / 2, a / 2, n + 1)
    w = np.linspace(-b / 2, b / 2, n + 1)
    gu, gw = np.meshgrid(u, w, indexing="ij")
    flat = np.stack([gu.ravel(), gw.ravel(), np.zeros(gu.size)], axis=1)
    v = {"z": flat, "x": flat[:, [2, 0, 1]], "y": flat[:, [1, 2, 0]]}[normal]
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a0, a1, b0, b1 = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    f = np.concatenate(
        [np.stack([a0, a1, b1], -1).reshape(-1, 3), np.stack([a0, b1, b0], -1).reshape(-1, 3)]
    )
    return v, f


@pytest.mark.parametrize(
    "normal, aspect, roll",
    [
        ("z", 0.0, 0.0),
        ("z", 180.0, 77.0),
        ("x", 90.0, 0.0),
        ("x", 90.0, 180.0),
        ("y", 90.0, 90.0),
        ("y", 90.0, 270.0),
    ],
)
def test_plate_broadside_is_four_pi_area_squared_over_lambda_squared(normal, aspect, roll):
    """Broadside along each axis, reached through the documented (aspect, roll) convention."""
    side = 0.5
    freqs = np.array([3e9, 8e9, 10e9, 12e9])
    v, f = plate(side, side, 1, normal)
    a = radar_sim.rcs(v, f, freqs, aspect, roll)
    assert a.shape == (1, 4) and a.dtype == np.complex128
    exact = 4 * np.pi * side**4 / (C0 / freqs) ** 2
    np.testing.assert_allclose(np.abs(a[0]) ** 2, exact, rtol=1e-9)


def test_plate_sinc_pattern_swept_in_roll():
    """Plate facing +x (side a along y): at aspect 90° the line of sight is (cos φ, sin φ, 0),
    a tilt φ in the plane of side a, so σ(φ) = 4π(ab)²/λ² cos²φ sinc²(ka sin φ)."""
    a, b, freq = 0.4, 0.25, 10e9
    k = 2 * np.pi * freq / C0
    v, f = plate(a, b, 8, "x")
    roll = np.linspace(-80, 80, 161)
    got = np.abs(radar_sim.rcs(v, f, freq, np.full(roll.shape, 90.0), roll)[:, 0]) ** 2
    phi = np.radians(roll)
    exact = (
        4
        * np.pi
        * (a * b) ** 2
        / (C0 / freq) ** 2
        * np.cos(phi) ** 2
        * np.sinc(k * a * np.sin(phi) / np.pi) ** 2
    )
    shown = exact > exact.max() * 1e-6
    assert shown.sum() > 140
    assert np.max(np.abs(db(got[shown]) - db(exact[shown]))) <= 0.01


def test_po_sphere_closed_form():
    """Icosphere (edges <= λ/8), ka 20-30, five aspects at roll 30°: σ/πa² within 0.05 dB of
    |1 + j(1 - e^{-j2ka})/(2ka)|² at every aspect (a sphere looks the same from everywhere)."""
    radius = 0.1
    ka = np.array([20.0, 25.0, 30.0])
    freqs = ka * C0 / (2 * np.pi * radius)
    mesh = trimesh.creation.icosphere(6, radius=radius)
    assert mesh.edges_unique_length.max() <= C0 / freqs.max() / 8
    aspects = [0.0, 37.0, 90.0, 143.0, 180.0]
    sigma = np.abs(radar_sim.rcs(mesh.vertices, mesh.faces, freqs, aspects, 30.0)) ** 2
    assert sigma.shape == (5, 3)
    po = np.abs(1 + 1j * (1 - np.exp(-2j * ka)) / (2 * ka)) ** 2
    assert np.max(np.abs(db(sigma / (np.pi * radius**2) / po))) <= 0.05


def test_same_numbers_as_simulate_on_its_grid():
    """rcs at a config's aspects and one of its rolls reproduces simulate's response."""
    config = radar_sim.RadarConfig(name="rcs-test", n_aspect=13, n_roll=6, n_freq=16, n_range=15)
    box = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
    result = radar_sim.simulate(box.vertices, box.faces, config)
    for r, roll in enumerate(config.roll_deg):
        a = radar_sim.rcs(box.vertices, box.faces, config.frequency_hz, config.aspect_deg, roll)
        peak = np.abs(result.frequency_response).max()
        np.testing.assert_allclose(a, result.frequency_response[:, r], rtol=0, atol=1e-12 * peak)


def test_line_of_sight_convention_and_errors():
    los = line_of_sight([0, 90, 90, 180], [0, 0, 90, 0])
    np.testing.assert_array_equal(los, [[0, 0, 1], [1, 0, 0], [0, 1, 0], [0, 0, -1]])
    t, p = np.radians(30.0), np.radians(200.0)
    np.testing.assert_allclose(
        line_of_sight(30.0, 200.0)[0],
        [np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)],
        rtol=0,
        atol=1e-16,
    )
    with pytest.raises(ValueError, match="roll_deg must be one finite angle or one per aspect"):
        line_of_sight([0, 10, 20], [0, 1])
    with pytest.raises(ValueError, match="aspect_deg must be a non-empty 1-D array"):
        line_of_sight([])
    with pytest.raises(ValueError, match="frequencies must be"):
        radar_sim.rcs(*plate(0.1, 0.1, 1, "z"), -1.0, 0.0)
