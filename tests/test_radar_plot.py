"""`radar-sim plot`: which frequency the RCS panel shows, and ``--variant``."""

import json

import numpy as np
import pytest
import trimesh

import radar_sim
from basic_shapes.shards import Shard
from radar_sim.cli import dataset_signature, main
from radar_sim.plot import band_centre_sample
from test_label import write_dataset


def test_the_title_names_the_frequency_shown():
    """xband-v1 has 128 samples over 8-12 GHz: 10 GHz lies half a step (2/127 GHz) from the two
    middle samples, so the panel shows one of them and says so; an odd grid hits 10 GHz."""
    grid = np.linspace(8e9, 12e9, 128)
    f, text = band_centre_sample(grid)
    assert f in (63, 64)
    assert abs(abs(grid[f] - 10e9) - 2e9 / 127) < 1e-3
    assert text.startswith(f"{grid[f] / 1e9:.4g} GHz") and "10 GHz band centre" in text
    assert grid[f] / 1e9 != pytest.approx(10, abs=1e-3)
    f, text = band_centre_sample(np.linspace(8e9, 12e9, 129))
    assert f == 64 and text == "10 GHz (band centre)"


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """One cube with two complex variants, and a small radar config file."""
    tmp = tmp_path_factory.mktemp("plot")
    config = tmp / "small.json"
    config.write_text(
        json.dumps({"name": "small", "n_aspect": 7, "n_roll": 3, "n_freq": 64, "n_range": 63})
    )
    return write_dataset(tmp / "data", n_objects=1), config


def test_variant_simulates_that_mesh(small, tmp_path):
    data, config = small
    coords, profiles, response, title = dataset_signature(data, 0, str(config), variant=1)
    assert "variant 1" in title and "simulated" in title
    with Shard(data / "shard-00000.h5") as s:
        rows = {int(v): i for i, v in enumerate(s.file["meshes/variant"][()])}
        vertices, faces = s.mesh(rows[1])
    assert len(faces) == 4 * 12  # the subdivided cube, not the 12-face simple mesh
    expected = radar_sim.simulate(vertices, faces, radar_sim.RadarConfig.from_file(config))
    np.testing.assert_array_equal(response, expected.frequency_response)
    np.testing.assert_array_equal(profiles, expected.range_profiles)
    main(
        [
            "plot",
            "--data",
            str(data),
            "--object",
            "0",
            "--variant",
            "2",
            "--config",
            str(config),
            "--out",
            str(tmp_path / "v2.png"),
        ]
    )
    assert (tmp_path / "v2.png").stat().st_size > 10_000


def test_variant_errors(small, tmp_path):
    data, config = small
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "plot",
                "--data",
                str(data),
                "--object",
                "0",
                "--variant",
                "5",
                "--out",
                str(tmp_path / "x.png"),
            ]
        )
    assert "object 0 has no variant 5 (--variant 0..2)" in str(exc.value.code)
    mesh = tmp_path / "box.ply"
    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(mesh)
    with pytest.raises(SystemExit) as exc:
        main(["plot", str(mesh), "--variant", "1", "--out", str(tmp_path / "y.png")])
    assert "--object and --variant need --data DIR" in str(exc.value.code)
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "y.png").exists()
