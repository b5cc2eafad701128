"""`radar-sim rcs` and `radar-sim plot` on real mesh files and real shards."""

import subprocess
import sys

import h5py
import numpy as np
import pytest
import trimesh
from matplotlib.image import imread

from basic_shapes.shards import Shard
from radar_sim.cli import dataset_signature, main
from test_label import write_dataset

C = 299792458.0
SIDE = 0.5  # plate side, metres


def plate(scale=1.0) -> trimesh.Trimesh:
    """A SIDE x SIDE square plate in z = 0, normal +z (seen broadside at aspect 0), 2 triangles."""
    h = SIDE / 2 * scale
    v = [[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]]
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def table(out: str) -> np.ndarray:
    """The dBsm values printed by `radar-sim rcs` (rows: aspects, columns: frequencies)."""
    rows = [
        line.split()
        for line in out.splitlines()
        if line and not line.startswith(("#", "aspect_deg"))
    ]
    return np.array(rows, float)[:, 1:]


def one_line_error(argv) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    message = str(exc.value.code)
    assert message.startswith(f"radar-sim {argv[0]}: error: ") and "\n" not in message
    return message


def test_rcs_of_plate_matches_broadside_formula(tmp_path):
    path = tmp_path / "plate.obj"
    plate().export(path)
    freqs = np.array([8.0, 10.0, 12.0])
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "radar_sim.cli",
            "rcs",
            str(path),
            "--freq",
            "8,10,12",
            "--aspect",
            "0",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "dBsm" in proc.stdout and "units m" in proc.stdout
    lam = C / (freqs * 1e9)
    expected = 10 * np.log10(4 * np.pi * SIDE**4 / lam**2)  # 4 pi A^2 / lambda^2
    np.testing.assert_allclose(table(proc.stdout)[0], expected, atol=0.01)


@pytest.mark.parametrize("fmt", ["stl", "ply"])
def test_units_and_formats_agree(tmp_path, capsys, fmt):
    plate().export(tmp_path / "plate.obj")
    plate(1000.0).export(tmp_path / f"plate_mm.{fmt}")
    args = ["--freq", "9,11", "--aspect", "0,10,20"]
    main(["rcs", str(tmp_path / "plate.obj"), *args])
    metres = table(capsys.readouterr().out)
    main(["rcs", str(tmp_path / f"plate_mm.{fmt}"), "--units", "mm", *args])
    captured = capsys.readouterr()
    np.testing.assert_allclose(table(captured.out), metres, atol=1e-6)
    assert "warning" not in captured.err
    main(["rcs", str(tmp_path / f"plate_mm.{fmt}"), *args])  # millimetres read as metres
    assert "pass --units mm" in capsys.readouterr().err


def test_rcs_bad_files(tmp_path):
    assert "no such file" in one_line_error(
        ["rcs", str(tmp_path / "x.obj"), "--freq", "10", "--aspect", "0"]
    )
    (tmp_path / "junk.stl").write_bytes(b"\x00\x01 not an stl at all")
    message = one_line_error(["rcs", str(tmp_path / "junk.stl"), "--freq", "10", "--aspect", "0"])
    assert str(tmp_path / "junk.stl") in message
    (tmp_path / "m.dae").write_text("<xml/>")
    assert "unsupported mesh format" in one_line_error(
        ["rcs", str(tmp_path / "m.dae"), "--freq", "10", "--aspect", "0"]
    )
    (tmp_path / "nan.obj").write_text("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert "NaN" in one_line_error(
        ["rcs", str(tmp_path / "nan.obj"), "--freq", "10", "--aspect", "0"]
    )


def _check_png(path):
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 300 and image.shape[1] > 600
    assert image[..., :3].std() > 0.05  # not blank


def test_plot_mesh_file_and_dataset(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    sphere.export(tmp_path / "sphere.ply")
    main(["plot", str(tmp_path / "sphere.ply"), "--out", str(tmp_path / "sphere.png")])
    _check_png(tmp_path / "sphere.png")

    data = write_dataset(tmp_path / "data", n_objects=2, objects_per_shard=2)
    main(
        [
            "plot",
            "--data",
            str(data),
            "--object",
            "1",
            "--roll",
            "30",
            "--out",
            str(tmp_path / "o1.png"),
        ]
    )
    _check_png(tmp_path / "o1.png")
    assert "no object with id 7" in one_line_error(
        ["plot", "--data", str(data), "--object", "7", "--out", str(tmp_path / "o7.png")]
    )
    assert "--object" in one_line_error(
        ["plot", "--data", str(data), "--out", str(tmp_path / "o.png")]
    )
    assert "no such file or directory" in one_line_error(
        ["plot", str(tmp_path / "nope"), "--out", str(tmp_path / "n.png")]
    )


def test_plot_uses_stored_labels(tmp_path):
    import radar_sim

    data = write_dataset(tmp_path / "data", n_objects=1)
    _, _, simulated, title = dataset_signature(data, 0, "xband-v1")
    # unlabelled: what labelling with that config would store (a cube: the box itself)
    assert "not labelled; the label xband-v1 would give, the primitive on a 12-face" in title
    main(
        ["label", "--data", str(data), "--workers", "1", "--frequency-response"]
        + ["--config", "xband-v1"]
    )
    coords, profiles, response, title = dataset_signature(data, 0, "xband-v1")
    assert "stored label" in title
    with h5py.File(data / "shard-00000.h5") as f:
        np.testing.assert_array_equal(profiles, f["radar/response"][0])
        np.testing.assert_array_equal(response, f["radar/frequency_response"][0])
        np.testing.assert_array_equal(coords["range_m"], f["radar/range"][()])
    np.testing.assert_array_equal(response, simulated.astype(np.complex64))
    config = radar_sim.RadarConfig.named("xband-v1")
    np.testing.assert_array_equal(coords["aspect_deg"], config.aspect_deg)
    main(["plot", "--data", str(data), "--object", "0", "--out", str(tmp_path / "o0.png")])
    _check_png(tmp_path / "o0.png")
    with h5py.File(data / "shard-00000.h5", "r+") as f:
        del f["radar/response"]  # a damaged label is refused, not simulated in its place
    assert "truncated /radar group, missing response" in one_line_error(
        ["plot", "--data", str(data), "--object", "0", "--out", str(tmp_path / "o2.png")]
    )


def test_label_defaults_to_the_newest_config(tmp_path):
    """Without --config a dataset gets the physics of the current dataset versions: three
    channels with edge diffraction, not xband-v1's VV-only PO."""
    data = write_dataset(tmp_path / "data", n_objects=1)
    main(["label", "--data", str(data), "--workers", "1"])
    with Shard(data / "shard-00000.h5") as s:
        stored = s.radar.config
    assert stored["name"] == "xband-v3" and stored["channels"] == "HH,VV,HV"
    assert stored["edges"] == "mec"


def test_plot_defaults_to_the_labelling_config_in_every_channel(tmp_path):
    """Labels stored without the frequency response are recomputed for the plot with the
    config the dataset was labelled with, not xband-v1: the profiles are the stored label
    (the same bytes, a cylinder under xband-v3's rim rule and portable DFT), VV by default and
    HH on request."""
    import radar_sim

    data = write_dataset(tmp_path / "data", n_objects=3, objects_per_shard=3)
    config = radar_sim.RadarConfig.named("xband-v3").with_grid(n_aspect=5, n_roll=3)
    (tmp_path / "c.json").write_text(config.to_json())
    main(["label", "--data", str(data), "--workers", "1", "--config", str(tmp_path / "c.json")])
    with Shard(data / "shard-00000.h5") as s:
        objects = s.objects()
        k = [s.class_names[c] for c in objects["class"]].index("cylinder")
        stored, oid = s.radar.response(k), int(objects["id"][k])
    _, profiles, _, title = dataset_signature(data, oid, None)
    assert config.name in title and "simulation mesh" in title
    np.testing.assert_array_equal(profiles.astype(np.complex64), stored)
    _, other, _, _ = dataset_signature(data, oid, "xband-v1")  # asked for: another config
    assert other.shape != stored.shape
    with Shard(data / "shard-00000.h5") as s:
        hh = s.radar.polarimetric(k)[list(s.radar.channels).index("HH")]
    _, profiles, _, title = dataset_signature(data, oid, None, channel="HH")
    assert title.endswith(", HH)")
    np.testing.assert_array_equal(profiles.astype(np.complex64), hh)
    assert np.abs(hh - stored).max() > 1e-3 * np.abs(stored).max()  # HH is not VV on a cylinder
    with pytest.raises(SystemExit, match="config xband-v1 has no HH channel"):
        dataset_signature(data, oid, "xband-v1", channel="HH")


def test_millimetre_file_read_as_metres_is_flagged(tmp_path, capsys):
    """A 50 mm cube in a millimetre file read without --units mm is a 50 m cube (about 109
    dBsm broadside at 10 GHz): the extent is printed with the result, and a warning says the
    size is implausible for the band; with --units mm there is no warning."""
    trimesh.creation.box((50.0, 50.0, 50.0)).export(tmp_path / "cube_mm.stl")
    args = ["--freq", "10", "--aspect", "0"]
    main(["rcs", str(tmp_path / "cube_mm.stl"), *args])
    out, err = capsys.readouterr()
    assert "extent 50 x 50 x 50 m" in out
    lam = C / 10e9
    np.testing.assert_allclose(
        table(out)[0, 0], 10 * np.log10(4 * np.pi * 50.0**4 / lam**2), atol=0.01
    )
    assert "50 m across, 1668 wavelengths at 10 GHz" in err and "pass --units mm" in err
    main(["rcs", str(tmp_path / "cube_mm.stl"), "--units", "mm", *args])
    out, err = capsys.readouterr()
    assert "extent 0.05 x 0.05 x 0.05 m" in out and "warning" not in out + err
    main(["rcs", str(tmp_path / "cube_mm.stl"), "--units", "mm", "--freq", "0.5", "--aspect", "0"])
    assert "under half a wavelength at 0.5 GHz" in capsys.readouterr().err


def test_generated_spheres_never_take_the_bounce_path(tmp_path):
    """Spheres from the real generator (Blender decimation folds some facet pairs inward) are
    "convex" or at worst "shadowed": their re-hits stay within a crease, so "auto" does not
    pay 100-1000x for the second bounce. A torus and an L-prism still see themselves."""
    import manifold3d

    from basic_shapes.cli import main as generate
    from basic_shapes.shards import Shard
    from radar_sim import detect_mode
    from radar_sim.scene import prepare

    generate(
        [
            "generate",
            "--data",
            str(tmp_path / "d"),
            "--classes",
            "sphere",
            "--objects-per-class",
            "3",
            "--variants",
            "19",
            "--seed",
            "0",
            "--workers",
            "1",
        ]
    )
    modes, strict = [], []
    with Shard(next((tmp_path / "d").glob("shard-*.h5"))) as s:
        for i in range(s.n_meshes):
            v, f = s.mesh(i)
            modes.append(detect_mode(v, f))
            strict.append(prepare(v, f).convex)
    assert "bounce2" not in modes
    assert "shadowed" in modes  # some meshes are folded, so the test exercises the probe
    torus = trimesh.creation.torus(0.3, 0.1)
    assert detect_mode(torus.vertices, torus.faces) == "bounce2"
    ell = manifold3d.Manifold.cube([0.4, 0.1, 0.3]) + manifold3d.Manifold.cube([0.1, 0.4, 0.3])
    ell = ell.to_mesh()
    ell_vertices = np.asarray(ell.vert_properties)[:, :3]
    assert detect_mode(ell_vertices, np.asarray(ell.tri_verts)) == "bounce2"


def test_float32_noise_is_convex():
    """A sphere whose float32 vertices make a few edges concave by ~1e-6 of the radius is
    still "convex" (the old 1e-6 tolerance sent such meshes to shadow rays)."""
    from radar_sim.scene import CONVEX_TOL, prepare

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    v = np.array(sphere.vertices)
    rng = np.random.default_rng(0)
    v *= 1 + rng.uniform(-5e-6, 5e-6, (len(v), 1))  # radial jitter: dents of ~1e-5 R
    assert 1e-6 < 1e-5 < CONVEX_TOL
    assert prepare(v, sphere.faces).convex
    v[0] *= 1 - 1e-2  # a real dent (the curvature sagitta over one edge is 3e-3 R)
    assert not prepare(v, sphere.faces).convex
