"""`radar-sim rcs` and `radar-sim plot` on real mesh files and real shards."""

import subprocess
import sys

import h5py
import numpy as np
import pytest
import trimesh
from matplotlib.image import imread

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
    rows = [line.split() for line in out.splitlines()
            if line and not line.startswith(("#", "aspect_deg"))]
    return np.array(rows, float)[:, 1:]


def one_line_error(argv) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    message = str(exc.value.code)
    assert message.startswith("radar-sim: ") and "\n" not in message
    return message


def test_rcs_of_plate_matches_broadside_formula(tmp_path):
    path = tmp_path / "plate.obj"
    plate().export(path)
    freqs = np.array([8.0, 10.0, 12.0])
    proc = subprocess.run([sys.executable, "-m", "radar_sim.cli", "rcs", str(path), "--freq",
                           "8,10,12", "--aspect", "0"], capture_output=True, text=True, check=True)
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
    assert "no such file" in one_line_error(["rcs", str(tmp_path / "x.obj"), "--freq", "10",
                                             "--aspect", "0"])
    (tmp_path / "junk.stl").write_bytes(b"\x00\x01 not an stl at all")
    message = one_line_error(["rcs", str(tmp_path / "junk.stl"), "--freq", "10", "--aspect", "0"])
    assert str(tmp_path / "junk.stl") in message
    (tmp_path / "m.dae").write_text("<xml/>")
    assert "unsupported mesh format" in one_line_error(["rcs", str(tmp_path / "m.dae"), "--freq",
                                                        "10", "--aspect", "0"])
    (tmp_path / "nan.obj").write_text("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert "NaN" in one_line_error(["rcs", str(tmp_path / "nan.obj"), "--freq", "10",
                                    "--aspect", "0"])


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
    main(["plot", str(data), "--object", "1", "--roll", "30", "--out", str(tmp_path / "o1.png")])
    _check_png(tmp_path / "o1.png")
    assert "no object with id 7" in one_line_error(["plot", str(data), "--object", "7",
                                                    "--out", str(tmp_path / "o7.png")])
    assert "--object" in one_line_error(["plot", str(data), "--out", str(tmp_path / "o.png")])
    assert "no such file or directory" in one_line_error(["plot", str(tmp_path / "nope"),
                                                          "--out", str(tmp_path / "n.png")])


def test_plot_uses_stored_labels(tmp_path):
    import radar_sim

    data = write_dataset(tmp_path / "data", n_objects=1)
    _, _, simulated, title = dataset_signature(data, 0, "xband-v1")
    assert "simulated" in title
    main(["label", str(data), "--workers", "1", "--frequency-response"])
    coords, profiles, response, title = dataset_signature(data, 0, "xband-v1")
    assert "stored labels" in title
    with h5py.File(data / "shard-00000.h5") as f:
        np.testing.assert_array_equal(profiles, f["radar/response"][0])
        np.testing.assert_array_equal(response, f["radar/frequency_response"][0])
        np.testing.assert_array_equal(coords["range_m"], f["radar/range_m"][()])
    np.testing.assert_array_equal(response, simulated.astype(np.complex64))
    config = radar_sim.RadarConfig.named("xband-v1")
    np.testing.assert_array_equal(coords["aspect_deg"], config.aspect_deg)
    main(["plot", str(data), "--object", "0", "--out", str(tmp_path / "o0.png")])
    _check_png(tmp_path / "o0.png")
