"""`radar-sim label` on real shards, a real Dask LocalCluster and the real simulator.

The shards are real data in the real format, written with ``basic_shapes.shards.write_shard``
from trimesh meshes (boxes, cylinders, icospheres; variants are the same polyhedra with more
triangles or another vertex order), so these tests do not need Blender.
"""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest
import trimesh

import radar_sim
from basic_shapes.analytic import simulation_mesh, solid_for
from basic_shapes.shards import (
    RADAR_VARIABLES,
    SHARD_FORMAT,
    MeshRecord,
    ObjectRecord,
    Shard,
    ShardError,
    dataset_fingerprint,
    label_fingerprint,
    shard_name,
    write_shard,
)
from radar_sim.cli import main
from radar_sim.label import SIDECAR, LabelRequest, label_directory, select_mesh_rows

CLASSES = ["cube", "cylinder", "sphere"]
# An L-band grid keeps the simulation meshes (refined for the top frequency) small in tests.
LBAND = {
    "name": "test-lband",
    "n_aspect": 7,
    "n_roll": 3,
    "f_start_hz": 1e9,
    "f_stop_hz": 2e9,
    "n_freq": 32,
    "n_range": 31,
}


@pytest.fixture(scope="module")
def lband(tmp_path_factory):
    path = tmp_path_factory.mktemp("config") / "lband.json"
    path.write_text(json.dumps(LBAND))
    return str(path)


def options(lband):
    return ["--config", lband, "--mesh-labels", "sample:1", "--frequency-response"]


def object_meshes(cls: str, scale) -> list[trimesh.Trimesh]:
    """Simple mesh first, then two complex meshes of exactly the same polyhedron."""
    if cls == "cube":
        simple = trimesh.creation.box(extents=scale)
    elif cls == "cylinder":
        simple = trimesh.creation.cylinder(radius=0.5, height=1.0, sections=24)
        simple.apply_scale(scale)
    else:
        simple = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
        simple.apply_scale(scale)
    finer = simple.subdivide()
    order = np.random.default_rng(len(simple.faces)).permutation(len(simple.faces))
    return [simple, finer, trimesh.Trimesh(simple.vertices, simple.faces[order], process=False)]


def write_dataset(directory, n_objects=6, objects_per_shard=1, corrupt=None):
    """Shards of ``objects_per_shard`` objects, classes in turn, scales 0.3-0.9 m.

    ``corrupt`` (object id) gets a NaN vertex in its simple mesh.
    """
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    objects = []
    for oid in range(n_objects):
        cls = oid % len(CLASSES)
        scale = rng.uniform(0.3, 0.9, 3)
        meshes = []
        for variant, m in enumerate(object_meshes(CLASSES[cls], scale)):
            v = np.array(m.vertices, np.float32)
            if oid == corrupt and variant == 0:
                v[0, 0] = np.nan
            meshes.append(MeshRecord(variant, v, np.array(m.faces, np.int32), 0.0, {"n": variant}))
        objects.append(ObjectRecord(oid, cls, scale, 1000 + oid, "train", meshes))
    for i in range(0, n_objects, objects_per_shard):
        write_shard(
            directory / shard_name(i // objects_per_shard),
            objects[i : i + objects_per_shard],
            CLASSES,
            {"seed": 0, "variants": 2},
            "0.1.0",
        )
    return directory


def digests(d):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(d.glob("shard-*"))}


def same_label(stored, computed):
    """complex64 labels equal to a direct ``simulate`` in this process, up to complex64 rounding.

    Not bit-equal: the workers run single-threaded BLAS (Dask sets OMP_NUM_THREADS=1) while this
    process may not, and the core's matrix products round differently with the thread count.
    """
    assert stored.dtype == np.complex64
    peak = np.abs(computed).max()
    np.testing.assert_allclose(stored, computed, rtol=0, atol=2**-22 * peak)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("raw") / "data")


@pytest.fixture(scope="module")
def labelled(dataset, lband, tmp_path_factory):
    """The dataset labelled through the CLI on a 2-worker LocalCluster."""
    out = tmp_path_factory.mktemp("two") / "data"
    shutil.copytree(dataset, out)
    main(["label", "--data", str(out), "--workers", "2", *options(lband)])
    return out


def test_labels_are_the_primitives_physics(dataset, labelled):
    """/radar/response is the primitive on its simulation mesh; /radar/mesh_response the
    physics on the stored meshes drawn (one per object here, the simple one may be drawn)."""
    config = radar_sim.RadarConfig(**LBAND)
    n_mesh_labels = 0
    for path in sorted(labelled.glob("shard-*.h5")):
        with Shard(path) as s, Shard(dataset / path.name) as raw:
            assert s.fingerprint == raw.fingerprint
            for name in ("meshes/vertices", "meshes/faces", "objects/id"):
                np.testing.assert_array_equal(s.file[name][()], raw.file[name][()])
            radar = s.radar
            assert radar.config == config.to_dict()
            for name, value in radar.coordinates.items():
                np.testing.assert_array_equal(value, getattr(config, name))
            assert s.file["radar/response"].dtype == np.complex64
            assert s.file["radar/response"].shape == (s.n_objects, 7, 3, 31)
            assert radar.fingerprint == radar.computed_fingerprint()
            objs = s.objects()
            for k in range(s.n_objects):
                solid = solid_for(CLASSES[objs["class"][k]], objs["scale"][k])
                r = radar_sim.simulate(
                    *simulation_mesh(solid, config.f_stop_hz), config, mode="convex"
                )
                same_label(radar.response(k), r.range_profiles)
                same_label(radar.frequency_response(k), r.frequency_response)
                assert radar.modes[k] == "convex"
            rows = radar.mesh_index
            assert list(s.file["meshes/object_index"][()][rows]) == list(range(s.n_objects))
            for j, row in enumerate(rows):
                r = radar_sim.simulate(*s.mesh(int(row)), config)
                same_label(radar.mesh_response(j), r.range_profiles)
                assert radar.mesh_modes[j] == r.mode
                n_mesh_labels += 1
    assert n_mesh_labels == 6
    assert not (labelled / SIDECAR).exists()


def test_sphere_label_matches_an_independent_fine_mesh(tmp_path):
    """A sphere object's stored label (X band, 7 x 3 directions) is within 1 dB² (benchmark
    metric) of the smooth ellipsoid simulated on a 260,096-face trimesh UV sphere, a mesh built
    independently of the simulation-mesh rule: measured 0.41 dB², where the physics of the
    object's 1,280-face icosphere (the label before labels were the primitive's) is 39 dB² away."""
    from benchmark.scoring.data import db_target

    xband = {"name": "test-xband-coarse", "n_aspect": 7, "n_roll": 3}
    (tmp_path / "x.json").write_text(json.dumps(xband))
    data = write_dataset(tmp_path / "data", n_objects=3, objects_per_shard=3)
    main(["label", "--data", str(data), "--config", str(tmp_path / "x.json"), "--workers", "1"])
    with Shard(data / shard_name(0)) as s:
        scale = s.objects()["scale"][2]
        assert s.class_names[s.objects()["class"][2]] == "sphere"
        stored = db_target(s.radar.response(2))
    fine = trimesh.creation.uv_sphere(radius=0.5, count=[256, 256])
    fine.apply_scale(scale)
    reference = db_target(
        radar_sim.simulate(
            fine.vertices, fine.faces, radar_sim.RadarConfig(**xband), mode="convex"
        ).range_profiles
    )
    mse = float(np.mean((stored.astype(np.float64) - reference) ** 2))
    assert mse < 1.0, mse


def test_xarray_reads_named_dimensions(labelled):
    import warnings

    import xarray as xr

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with xr.open_dataset(labelled / shard_name(0), engine="h5netcdf", group="radar") as ds:
            assert ds["response"].dims == ("object", "aspect", "roll", "range")
            assert ds["frequency_response"].dims == ("object", "aspect", "roll", "frequency")
            assert ds["mesh_response"].dims == ("mesh", "aspect", "roll", "range")
            assert ds["aspect"].attrs["units"] == "degree" and ds["range"].attrs["units"] == "m"
            assert ds["frequency"].attrs["units"] == "Hz"
            np.testing.assert_array_equal(
                ds["frequency"].values, radar_sim.RadarConfig(**LBAND).frequency_hz
            )
            assert ds["object"].values.tolist() == [0]
            with Shard(labelled / shard_name(0)) as s:
                np.testing.assert_array_equal(ds["response"].values[0], s.radar.response(0))
            for name, (long_name, units) in RADAR_VARIABLES.items():  # CF names, format 2
                if name in ds:
                    assert ds[name].attrs["long_name"] == long_name
                    assert ds[name].attrs.get("units") == units


def test_shard_format_1_writes_the_same_labels_without_variable_attributes(dataset, tmp_path):
    """The versions recorded before CF names were added rebuild to their recorded bytes."""
    fingerprints, attrs = {}, {}
    for fmt in (1, SHARD_FORMAT):
        out = tmp_path / str(fmt)
        shutil.copytree(dataset, out)
        request = LabelRequest(radar_sim.RadarConfig(**LBAND), shard_format=fmt)
        label_directory(out, request, workers=0, progress=False)
        with Shard(out / shard_name(0)) as s:
            fingerprints[fmt] = s.radar.fingerprint
            attrs[fmt] = dict(s.file["radar/response"].attrs)
    assert fingerprints[1] == fingerprints[SHARD_FORMAT]
    assert "units" not in attrs[1] and attrs[SHARD_FORMAT]["units"] == "m"


def test_bytes_do_not_depend_on_worker_count(dataset, labelled, lband, tmp_path):
    one = tmp_path / "one"
    shutil.copytree(dataset, one)
    main(["label", "--data", str(one), "--workers", "1", *options(lband)])
    assert digests(one) == digests(labelled)
    assert digests(one) != digests(dataset)


def test_existing_scheduler(dataset, labelled, lband, tmp_path):
    from distributed import LocalCluster

    work = tmp_path / "data"
    shutil.copytree(dataset, work)
    with LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None) as cluster:
        main(
            [
                "label",
                "--data",
                str(work),
                "--scheduler",
                cluster.scheduler_address,
                *options(lband),
            ]
        )
    assert digests(work) == digests(labelled)


def test_rerun_skips_labelled_shards(labelled, lband, capsys):
    before = {p: p.stat().st_mtime_ns for p in labelled.glob("shard-*.h5")}
    main(["label", "--data", str(labelled), *options(lband)])
    assert "skipped 6 shard(s)" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in labelled.glob("shard-*.h5")} == before


def test_mesh_sample_is_drawn_from_the_object_seed(dataset):
    with Shard(dataset / shard_name(0)) as s:
        first, again = select_mesh_rows(s, "sample:2"), select_mesh_rows(s, "sample:2")
        assert [list(r) for r in first] == [list(r) for r in again] and len(first[0]) == 2
        assert [list(r) for r in select_mesh_rows(s, "all")] == [[0, 1, 2]]  # simple included
        assert [len(r) for r in select_mesh_rows(s, "sample:5")] == [3]
        assert [len(r) for r in select_mesh_rows(s, "none")] == [0]


def test_killed_run_resumes_per_object_to_identical_bytes(lband, tmp_path):
    """SIGKILL a labelling process once some objects of a shard are finished: the shard is
    untouched, the finished objects wait on disk, and the rerun reuses them and ends with the
    bytes of an uninterrupted run."""
    raw = write_dataset(tmp_path / "raw", n_objects=12, objects_per_shard=12)
    done = tmp_path / "done"
    shutil.copytree(raw, done)
    args = ["--config", lband, "--mesh-labels", "all"]
    main(["label", "--data", str(done), "--workers", "1", *args])
    work = tmp_path / "work"
    shutil.copytree(raw, work)
    sidecar = work / SIDECAR / "shard-00000"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "radar_sim.cli",
            "label",
            "--data",
            str(work),
            "--workers",
            "1",
            *args,
        ],
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if sidecar.is_dir() and len(list(sidecar.glob("object-*.h5"))) >= 2:
            break
        time.sleep(0.002)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = len(list(sidecar.glob("object-*.h5")))
    assert 2 <= finished < 12, f"kill was not mid-shard ({finished} of 12 objects finished)"
    assert digests(work) == digests(raw)  # the shard itself is untouched until complete
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "radar_sim.cli",
            "label",
            "--data",
            str(work),
            "--workers",
            "2",
            *args,
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    assert f"{finished} finished before an interruption" in proc.stdout
    assert f"{12 - finished}/{12 - finished} objects, last shard-00000.h5" in proc.stderr
    assert digests(work) == digests(done)
    assert not (work / SIDECAR).exists() and not list(work.rglob("*.tmp"))


def test_relabelling_with_another_band_changes_the_label_fingerprint(labelled, lband, tmp_path):
    """Same meshes, other band: the mesh fingerprint stays, the label fingerprint changes, and
    predictions bound to the old labels are refused by the scorer."""
    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.protocol import Predictions, PredictionsError, write_predictions

    work = tmp_path / "data"
    shutil.copytree(labelled, work)
    before, labels_before = dataset_fingerprint(work), label_fingerprint(work)
    with BenchmarkData(work) as data:
        shape = data.target_shape
    predictions = tmp_path / "p.h5"
    write_predictions(
        predictions,
        before,
        np.arange(1),
        np.zeros((1, *shape), np.float32),
        label_fingerprint=labels_before,
    )
    other = tmp_path / "sband.json"
    other.write_text(
        json.dumps({**LBAND, "name": "test-sband", "f_start_hz": 2e9, "f_stop_hz": 3e9})
    )
    main(["label", "--data", str(work), "--config", str(other), "--overwrite"])
    assert dataset_fingerprint(work) == before
    assert label_fingerprint(work) != labels_before
    with BenchmarkData(work) as data, pytest.raises(PredictionsError, match="made for labels"):
        Predictions(predictions, data)


def test_other_config_is_an_error_unless_overwrite(labelled, lband, tmp_path):
    work = tmp_path / "data"
    shutil.copytree(labelled, work)
    before = digests(work)
    message = _one_line_error(["label", "--data", str(work), "--config", lband])  # no mesh labels
    assert "already labelled, with different radar options" in message
    assert str(work / shard_name(0)) in message
    other = tmp_path / "other.json"
    other.write_text('{"name": "coarse", "n_freq": 64, "n_range": 63}')
    message = _one_line_error(
        ["label", "--data", str(work), "--config", str(other), *options(lband)[2:]]
    )
    assert "already labelled, with different radar config (" in message
    assert digests(work) == before
    # relabel with the physics forced: on convex primitives shadow rays hide nothing
    request = LabelRequest(radar_sim.RadarConfig(**LBAND), mode="shadowed")
    summary = label_directory(work, request, workers=2, overwrite=True, progress=False)
    assert len(summary.labelled) == 6
    for path in sorted(work.glob("shard-*.h5")):
        with Shard(path) as s, Shard(labelled / path.name) as ref:
            assert "mesh_response" not in s.radar.group
            assert not s.radar.has_frequency_response
            assert s.radar.modes == ["shadowed"] and ref.radar.modes == ["convex"]
            same_label(s.radar.response(0), ref.radar.response(0))


def test_objects_outside_the_range_window_are_refused(tmp_path):
    data = write_dataset(tmp_path / "data", n_objects=2, objects_per_shard=2)
    small = tmp_path / "small.json"
    small.write_text(json.dumps({**LBAND, "name": "tiny-window", "n_range": 3}))
    before = digests(data)
    message = _one_line_error(["label", "--data", str(data), "--config", str(small)])
    assert str(data / shard_name(0)) in message and "object 0 (cube," in message
    assert "range window of radar config 'tiny-window'" in message
    assert digests(data) == before and not (data / SIDECAR).exists()


def _one_line_error(argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    message = str(exc.value.code)
    assert message.startswith(f"radar-sim {argv[0]}: error: ") and "\n" not in message
    return message


def test_bad_datasets_fail_fast_and_change_nothing(dataset, tmp_path):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    with h5py.File(foreign / shard_name(0), "w") as f:
        f["x"] = 1
    assert "not a basic-shapes shard" in _one_line_error(["label", "--data", str(foreign)])

    truncated = tmp_path / "truncated"
    shutil.copytree(dataset, truncated)
    data = (truncated / shard_name(3)).read_bytes()
    (truncated / shard_name(3)).write_bytes(data[: len(data) // 2])
    before = digests(truncated)
    message = _one_line_error(["label", "--data", str(truncated)])
    assert str(truncated / shard_name(3)) in message and "not a readable HDF5 shard" in message
    assert digests(truncated) == before  # validated before any work: nothing labelled

    assert "no such dataset directory" in _one_line_error(
        ["label", "--data", str(tmp_path / "missing")]
    )
    assert "holds no shards" in _one_line_error(["label", "--data", str(tmp_path)])
    assert "xband-v9" in _one_line_error(
        ["label", "--data", str(truncated), "--config", "xband-v9"]
    )


def test_unreachable_scheduler(dataset, tmp_path):
    import dask

    work = tmp_path / "data"
    shutil.copytree(dataset, work)
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        message = _one_line_error(
            ["label", "--data", str(work), "--scheduler", "tcp://127.0.0.1:1"]
        )
    assert "cannot use the Dask cluster tcp://127.0.0.1:1" in message
    assert digests(work) == digests(dataset)


def test_bad_mesh_names_shard_and_object(lband, tmp_path):
    data = write_dataset(tmp_path / "nan", n_objects=2, objects_per_shard=2, corrupt=1)
    before = digests(data)
    message = _one_line_error(
        ["label", "--data", str(data), "--workers", "1", "--config", lband, "--mesh-labels", "all"]
    )
    assert str(data / shard_name(0)) in message and "object 1" in message
    assert digests(data) == before


def test_cli_exit_status_and_stderr(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "radar_sim.cli", "label", "--data", str(tmp_path / "nope")],
        capture_output=True,
        text=True,
    )
    assert proc.returncode != 0
    assert proc.stderr.strip().splitlines() == [
        f"radar-sim label: error: {tmp_path / 'nope'}: no such dataset directory"
    ]


def test_info_prints_both_fingerprints(dataset, labelled, capsys):
    from basic_shapes.info import summary

    text = summary(labelled)
    assert f"mesh fingerprint  {dataset_fingerprint(labelled)}" in text
    assert f"label fingerprint {label_fingerprint(labelled)} (radar config 'test-lband')" in text
    assert dataset_fingerprint(labelled) == dataset_fingerprint(dataset)
    assert "label fingerprint (not every shard is labelled" in summary(dataset)


def test_sidecars_of_another_request_are_dropped_only_once_all_shards_are_valid(
    dataset, labelled, lband, tmp_path, capsys
):
    work = tmp_path / "data"
    shutil.copytree(dataset, work)
    stale = work / SIDECAR / "shard-00000" / "object-00000.h5"
    stale.parent.mkdir(parents=True)
    with h5py.File(stale, "w") as f:
        f.attrs["request"] = "labels of another config"
    good = (work / shard_name(3)).read_bytes()
    (work / shard_name(3)).write_bytes(good[: len(good) // 2])
    assert "not a readable HDF5 shard" in _one_line_error(
        ["label", "--data", str(work), *options(lband)]
    )
    assert stale.is_file()  # validation failed: nothing touched
    (work / shard_name(3)).write_bytes(good)
    main(["label", "--data", str(work), "--workers", "1", *options(lband)])
    assert "finished before an interruption" not in capsys.readouterr().out
    assert digests(work) == digests(labelled) and not (work / SIDECAR).exists()


def test_objects_are_computed_largest_first(dataset):
    """The first object calibrates the time estimate, so the most work goes first (a cube
    first made a 2-hour job read 74 h); ties keep the shards' order."""
    from radar_sim.label import _tasks, plan_shard

    request = LabelRequest(radar_sim.RadarConfig(**LBAND))
    plans = [plan_shard(p, request, overwrite=True) for p in sorted(dataset.glob("shard-*.h5"))]
    order = [(obj.object_id, obj.work) for _plan, obj, _meshes in _tasks(plans)]
    works = [w for _oid, w in order]
    assert len(order) == 6 and len(set(works)) > 1
    assert works == sorted(works, reverse=True)
    assert order[0][0] != 0  # object 0 is a cube, the least work


def test_polarimetric_labels_are_stored_as_a_named_dimension(dataset, tmp_path):
    """A config with channels HH,VV,HV stores /radar/polarimetric over a named polarization
    dimension: VV is /radar/response bit for bit, single-bounce PO without edges gives HH = VV
    and HV = 0 on these convex objects, and the label fingerprint covers every channel."""
    import xarray as xr

    config = tmp_path / "pol.json"
    config.write_text(json.dumps({**LBAND, "name": "lband-pol", "channels": "HH,VV,HV"}))
    data = tmp_path / "data"
    shutil.copytree(dataset, data)
    for p in sorted(data.glob("shard-*"))[1:]:
        p.unlink()
    main(["label", "--data", str(data), "--workers", "1", "--config", str(config)])
    path = data / shard_name(0)
    with Shard(path) as s:
        assert s.radar.channels == ("HH", "VV", "HV")
        hh, vv, hv = s.radar.polarimetric(0)
        np.testing.assert_array_equal(vv, s.radar.response(0))
        np.testing.assert_array_equal(hh, vv)
        assert not np.any(hv)
        s.verify_labels()
    with xr.open_dataset(path, engine="h5netcdf", group="radar") as ds:
        assert ds["polarimetric"].dims == ("object", "polarization", "aspect", "roll", "range")
        assert [c.decode() if isinstance(c, bytes) else c for c in ds["polarization"].values] == [
            "HH",
            "VV",
            "HV",
        ]
    with h5py.File(path, "r+") as f:
        f["radar/polarimetric"][0, 2, 0, 0, 0] = 1.0  # a cross-polar echo that was never there
    with Shard(path) as s, pytest.raises(ShardError, match="do not match their stored fingerprint"):
        s.verify_labels()
