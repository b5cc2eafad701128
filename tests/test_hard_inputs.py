"""Bad and awkward inputs: one-line MeshErrors, or documented behaviour (docs/RADAR.md)."""

import json
import warnings

import numpy as np
import pytest
import trimesh

from radar_sim import (
    MeshError,
    RadarConfig,
    UnitsWarning,
    detect_mode,
    facet,
    monostatic_field,
    simulate,
)
from radar_sim.field import C0

TRI_V = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
TRI_F = np.array([[0, 1, 2]])
UP = np.array([0.0, 0.0, 1.0])


def box(size=(0.3, 0.4, 0.5)):
    m = trimesh.creation.box(size)
    return np.asarray(m.vertices), np.asarray(m.faces)


def stable_sum(v, f, freqs, direction):
    """Σ facet_field over front-facing facets: the per-frequency reference."""
    k = 2 * np.pi * np.asarray(freqs) / C0
    return facet.facet_field(v[f], direction, k).sum(axis=0)


# --- errors ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "vertices, faces, message",
    [
        (np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), TRI_F, "vertex 2 is not finite"),
        (np.array([[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]]), TRI_F, "vertex 1 is not finite"),
        (TRI_V, np.array([[0, 1, 3]]), "face 0 refers to vertex [0, 1, 3]"),
        (TRI_V, np.array([[0, 1, 2], [-1, 1, 2]]), "face 1 refers to vertex [-1, 1, 2]"),
        (np.zeros((0, 3)), np.zeros((0, 3), dtype=int), "mesh is empty"),
        (TRI_V, np.zeros((0, 3), dtype=int), "mesh is empty"),
        (TRI_V[:, :2], TRI_F, "vertices must have shape (V, 3)"),
        (TRI_V, np.array([[0, 1, 2, 0]]), "faces must have shape (F, 3)"),
        (TRI_V, np.array([0, 1, 2]), "faces must have shape (F, 3)"),
        (TRI_V, TRI_F.astype(float), "faces must be integer vertex indices"),
        (TRI_V.astype(complex), TRI_F, "vertices must be real numbers"),
        (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2.0]]), TRI_F, "no face with non-zero area"),
        (TRI_V, np.array([[0, 0, 1]]), "no face with non-zero area"),
    ],
)
def test_bad_meshes_raise_one_line_mesh_errors(vertices, faces, message):
    for call in (
        lambda: monostatic_field(vertices, faces, [1e10], UP),
        lambda: simulate(vertices, faces),
        lambda: detect_mode(vertices, faces),
    ):
        with pytest.raises(MeshError) as info:
            call()
        assert message in str(info.value)
        assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"frequencies_hz": [0.0]}, "positive Hz"),
        ({"frequencies_hz": [np.nan]}, "positive Hz"),
        ({"frequencies_hz": []}, "non-empty"),
        ({"directions": [[0, 0, 2.0]]}, "unit vectors"),
        ({"directions": [[0, 1.0]]}, "shape (n, 3)"),
        ({"mode": "fast"}, "mode must be one of"),
    ],
)
def test_bad_arguments_raise_value_errors(kwargs, message):
    args = {"frequencies_hz": [1e10], "directions": UP, "mode": "auto"} | kwargs
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        monostatic_field(TRI_V, TRI_F, **args)


def test_radar_config_files(tmp_path):
    good = tmp_path / "c.json"
    config = RadarConfig(name="small", n_aspect=5, n_roll=4, n_freq=64, n_range=33)
    good.write_text(config.to_json())
    assert RadarConfig.from_file(good) == config
    assert RadarConfig.from_file(good).directions().shape == (20, 3)
    v3 = RadarConfig.named("xband-v3").with_grid(n_aspect=5)  # every later field set
    good.write_text(v3.to_json())
    assert RadarConfig.from_file(good) == v3 and v3.simulation_rule == 2
    cases = {
        "notjson": "{",
        "list": "[1, 2]",
        "unknown": json.dumps({"colour": "red"}),
        "bad": json.dumps({"name": "x", "n_freq": 1}),
        "even": json.dumps({"name": "x", "n_range": 100}),
        "fraction": json.dumps({"name": "x", "n_roll": 2.5}),
        "nameless": json.dumps({"n_roll": 4}),
        "reserved": json.dumps({"name": "xband-v1", "n_roll": 4}),
        "huge grid": json.dumps({"name": "x", "n_aspect": 3601, "n_roll": 7200}),
        "huge axis": json.dumps({"name": "x", "n_aspect": 10**8}),
        "infinite band": '{"name": "x", "f_stop_hz": Infinity}',
        "overflow": '{"name": "x", "f_stop_hz": 1e999}',
        "terahertz": json.dumps({"name": "x", "f_stop_hz": 2e12}),
        "null": json.dumps({"name": "x", "n_roll": None}),
        "rule": json.dumps({"name": "x", "simulation_rule": 9}),
        "rule fraction": json.dumps({"name": "x", "simulation_rule": 1.5}),
        "transform": json.dumps({"name": "x", "transform": "fftw"}),
        "deep": '{"name": ' + "[" * 5000 + "]" * 5000 + "}",
    }
    for name, text in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(text)
        with pytest.raises(ValueError) as info:
            RadarConfig.from_file(path)
        assert str(path) in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(ValueError, match="unknown radar config"):
        RadarConfig.named("nope")


def test_stored_radar_config_names_load_their_config():
    """The config name stamped on a recorded version's labels loads that exact config (the
    text the labels are fingerprinted with), grid suffix included."""
    from benchmark.scoring.versions import VERSIONS

    recorded = [v for v in VERSIONS.values() if v.manifest_path.exists()]
    assert {"demo-v2", "tiny-v1"} <= {v.name for v in recorded}
    for version in recorded:
        config = version.radar_config()
        assert RadarConfig.named(config.name) == config, version.name
        assert RadarConfig.named(config.name).to_json() == config.to_json(), version.name
    assert RadarConfig.named("xband-v2-31x7x107").name == "xband-v2-31x7x107"
    twice = RadarConfig.named("xband-v1").with_grid(n_aspect=31).with_grid(n_roll=3)
    assert RadarConfig.named(twice.name) == twice
    for name in ("nope-31x7x107", "xband-v1-31x7", "xband-v1-031x7x107", "xband-v1-0x7x107"):
        with pytest.raises(ValueError, match=f"unknown radar config '{name}'"):
            RadarConfig.named(name)
    with pytest.raises(ValueError, match="n_range odd"):
        RadarConfig.named("xband-v1-31x7x106")


def test_radar_config_size_bounds_follow_memory():
    """docs/RADAR.md "Config bounds": at most MAX_GRID_SAMPLES grid samples (48 B each)."""
    from radar_sim.config import MAX_GRID_SAMPLES

    assert RadarConfig(name="big", n_aspect=2048, n_roll=64, n_freq=128).n_aspect == 2048
    assert 2048 * 64 * 128 == MAX_GRID_SAMPLES
    with pytest.raises(ValueError, match="memory"):
        RadarConfig(name="big", n_aspect=2048, n_roll=65, n_freq=128)
    with pytest.raises(ValueError, match="f_stop_hz"):
        RadarConfig(name="inf", f_stop_hz=float("inf"))


# --- documented behaviours -------------------------------------------------------------------


def test_zero_area_and_duplicate_faces_are_dropped():
    v, f = box()
    extra_v = np.concatenate([v, [[0.05, 0.05, 0.25], [0.1, 0.1, 0.25]]])
    junk = np.array([[0, 0, 1], [8, 8, 9]])  # repeated indices
    collinear = np.array([[0.0, 0.0, 0.25], [0.05, 0.05, 0.25], [0.1, 0.1, 0.25]])
    extra_v = np.concatenate([extra_v, collinear])
    junk = np.concatenate([junk, [[10, 11, 12]], f[:3], f[:2, ::-1]])  # collinear, duplicates
    freqs = np.linspace(8e9, 12e9, 16)
    dirs = np.array([[0.3, 0.4, np.sqrt(0.75)], [0.0, 0.0, 1.0], [-0.6, 0.0, -0.8]])
    clean = monostatic_field(v, f, freqs, dirs)
    messy = monostatic_field(extra_v, np.concatenate([f, junk]), freqs, dirs)
    assert np.array_equal(clean, messy)
    assert detect_mode(extra_v, np.concatenate([f, junk])) == "convex"


def test_duplicated_vertices_are_welded():
    """A triangle soup (three own vertices per face) is the same closed convex mesh."""
    v, f = box()
    soup_v = v[f].reshape(-1, 3)
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    dirs = np.array([[0.48, 0.6, 0.64], [0.0, -1.0, 0.0]])
    assert detect_mode(soup_v, soup_f) == "convex"
    assert np.array_equal(
        monostatic_field(soup_v, soup_f, [9e9, 1e10], dirs),
        monostatic_field(v, f, [9e9, 1e10], dirs),
    )


def test_open_and_inward_meshes():
    """Open meshes are two-sided thin sheets, never "convex": a plate is "shadowed", a box with
    its lid off is a cavity ("bounce2"); a closed mesh wound inwards is flipped outwards."""
    v, f = box()
    open_f = f[:-2]
    assert detect_mode(TRI_V, TRI_F) == "shadowed"
    assert detect_mode(v, open_f) == "bounce2"
    inward = f[:, ::-1]
    dirs = np.array([[0.48, 0.6, 0.64]])
    assert detect_mode(v, inward) == "convex"
    assert np.array_equal(
        monostatic_field(v, inward, [1e10], dirs), monostatic_field(v, f, [1e10], dirs)
    )
    # through the missing face the radar sees the inside of the opposite wall
    missing = trimesh.Trimesh(v, f[-2:]).face_normals[0]
    seen = monostatic_field(v, open_f, [1e10], missing, mode="shadowed")
    assert np.all(np.isfinite(seen)) and abs(seen[0, 0]) > 0


def test_grazing_switch_is_continuous():
    """Facets switch between lit and unlit where P = 0, so the field is continuous there and
    exactly the remaining faces' field at exact grazing (no NaN, no jump)."""
    v, f = box((0.2, 0.3, 0.4))
    eps_deg = np.array([-1e-6, 0.0, 1e-6])
    theta = np.radians(90.0 + eps_deg)
    dirs = np.stack([np.sin(theta), 0 * theta, np.cos(theta)], axis=1)
    dirs[1] = [1.0, 0.0, 0.0]  # exact grazing for the ±z faces
    freqs = np.linspace(8e9, 12e9, 128)
    got = monostatic_field(v, f, freqs, dirs)
    assert np.all(np.isfinite(got))
    assert np.max(np.abs(got[0] - got[1])) < 1e-4 * np.max(np.abs(got[1]))
    assert np.max(np.abs(got[2] - got[1])) < 1e-4 * np.max(np.abs(got[1]))
    edge_on = monostatic_field(TRI_V, TRI_F, freqs, dirs[1])  # a plate in z = 0
    assert np.all(edge_on == 0)


@pytest.mark.parametrize("size, freq", [(1e-4, 10e9), (1e3, 1e9)])
def test_very_small_and_very_large_objects(size, freq):
    """Broadside plate 4πA²/λ² to 1e-12; a box at an oblique view against the stable
    per-frequency sum. A 1e3 m mesh warns that it may be in millimetres."""
    plate_v = size * np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]])
    plate_f = np.array([[0, 1, 2], [0, 2, 3]])
    v, f = box((size, 0.7 * size, 0.4 * size))
    direction = np.array([0.36, 0.48, 0.8])
    freqs = freq * np.linspace(1, 1.5, 16)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a = monostatic_field(plate_v, plate_f, [freq], UP)[0, 0]
        got = monostatic_field(v, f, freqs, direction)[0]
    assert any(issubclass(w.category, UnitsWarning) for w in caught) == (size > 100)
    exact = np.sqrt(4 * np.pi) * size**2 / (C0 / freq)
    assert abs(abs(a) - exact) <= 1e-12 * exact
    ref = stable_sum(v, f, freqs, direction)
    scale = size**2 * 2 * np.pi * freqs / C0  # facet scale A k
    assert np.max(np.abs(got - ref) / scale) <= 1e-9


def test_objects_must_fit_the_range_window():
    v, f = box((3.0, 3.0, 3.0))  # radius 2.6 m > 1.97 m
    with pytest.raises(MeshError, match="beyond the ±1.971 m range window of 'xband-v3'$"):
        simulate(v, f)  # the default config: radar_sim.config.NEWEST
    monostatic_field(v, f, [1e10], UP)  # no window there


def test_millimetre_meshes():
    """Rule: simulate refuses meshes beyond the range window and says "millimetres" when a
    factor 1000 would make them fit; monostatic_field warns above 100 m of radius."""
    v, f = box((500.0, 400.0, 300.0))  # a 0.5 m box written in mm
    with pytest.raises(MeshError, match="looks like millimetres"):
        simulate(v, f)
    with pytest.warns(UnitsWarning, match="millimetres"):
        monostatic_field(v, f, [1e10], UP)
    small = simulate(v / 1000.0, f, RadarConfig(name="t", n_aspect=2, n_roll=2))
    assert small.mode == "convex"


def test_float32_meshes_are_not_shadowed_by_themselves():
    """Embree works in float32: shadow rays leave each centroid along its normal, so convex
    objects in "shadowed" mode light exactly the facets back-face culling lights, also for
    float32-rounded coplanar faces, grazing views and objects far from the origin."""
    sphere = trimesh.creation.icosphere(3, radius=0.4)
    cube = trimesh.creation.box((0.5, 0.5, 0.5)).subdivide().subdivide()
    config = RadarConfig(name="t", n_aspect=31, n_roll=7)
    dirs = config.directions()
    freqs = np.linspace(8e9, 12e9, 8)
    for mesh, offset in ((sphere, 0.0), (cube, 0.0), (cube, 90.0)):
        v = (np.asarray(mesh.vertices) + [offset, 0.0, 0.0]).astype(np.float32)
        f = np.asarray(mesh.faces)
        culled = monostatic_field(v, f, freqs, dirs, mode="convex")
        shadowed = monostatic_field(v, f, freqs, dirs, mode="shadowed")
        assert np.array_equal(culled, shadowed)


def test_modes_are_detected_recorded_and_forced():
    """convex: closed convex meshes; bounce2: facets that see each other (an L-prism's inner
    corner, over 1% of the reflected power hits the mesh again); shadowed: other non-convex
    meshes (a shallow dimple reflects 0.04% back onto the mesh)."""
    import manifold3d

    v, f = box()
    config = RadarConfig(name="t", n_aspect=2, n_roll=1)
    assert simulate(v, f, config).mode == "convex"
    assert simulate(v, f, config, mode="shadowed").mode == "shadowed"
    ell = manifold3d.Manifold.cube([0.4, 0.1, 0.3]) + manifold3d.Manifold.cube([0.1, 0.4, 0.3])
    ell = ell.to_mesh()
    assert (
        detect_mode(np.asarray(ell.vert_properties)[:, :3], np.asarray(ell.tri_verts)) == "bounce2"
    )
    dimple = trimesh.creation.box((0.5, 0.5, 0.5)).subdivide().subdivide()
    dv = np.array(dimple.vertices)
    top = np.isclose(dv[:, 2], 0.25)
    dv[top, 2] -= 0.02 * np.clip(1 - np.hypot(dv[top, 0], dv[top, 1]) / 0.15, 0, 1)
    assert detect_mode(dv, dimple.faces) == "shadowed"
    cone = trimesh.creation.cone(0.3, 0.6, sections=32)
    assert detect_mode(cone.vertices, cone.faces) == "convex"


def test_radar_sim_never_imports_bpy_or_torch():
    import subprocess
    import sys

    code = (
        "import sys, numpy as np, radar_sim\n"
        "v = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0.0]])\n"
        "config = radar_sim.RadarConfig(name='t', n_aspect=3, n_roll=2)\n"
        "radar_sim.simulate(v, [[0, 1, 2]], config, mode='bounce2')\n"
        "print(sorted(m for m in ('bpy', 'torch') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=str(__import__("pathlib").Path(__file__).parents[1]),
    )
    assert out.stdout.strip() == "[]"
