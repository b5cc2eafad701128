"""`radar-sim label` on real shards, a real Dask LocalCluster and the real simulator.

The shards are real data in the real format, written with ``basic_shapes.shards.write_shard``
from trimesh meshes (boxes, cylinders, icospheres; variants are the same polyhedra with more
triangles or another vertex order), so these tests do not need Blender.
"""

import hashlib
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
from basic_shapes.shards import MeshRecord, ObjectRecord, Shard, shard_name, write_shard
from radar_sim.cli import main
from radar_sim.label import LabelRequest, label_directory, select_variants

CLASSES = ["cube", "cylinder", "sphere"]
OPTIONS = ["--variants", "sample:1", "--frequency-response"]


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
        write_shard(directory / shard_name(i // objects_per_shard), objects[i:i + objects_per_shard],
                    CLASSES, {"test": True}, "0.1.0")
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
    np.testing.assert_allclose(stored, computed, rtol=0, atol=2 ** -22 * peak)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("raw") / "data")


@pytest.fixture(scope="module")
def labelled(dataset, tmp_path_factory):
    """The dataset labelled through the CLI on a 2-worker LocalCluster."""
    out = tmp_path_factory.mktemp("two") / "data"
    shutil.copytree(dataset, out)
    main(["label", str(out), "--workers", "2", *OPTIONS])
    return out


def test_labels_agree_with_simulate(dataset, labelled):
    config = radar_sim.RadarConfig.named("xband-v1")
    n_variant_labels = 0
    for path in sorted(labelled.glob("shard-*.h5")):
        with Shard(path) as s, Shard(dataset / path.name) as raw:
            assert s.fingerprint == raw.fingerprint
            for name in ("meshes/vertices", "meshes/faces", "objects/id"):
                np.testing.assert_array_equal(s.file[name][()], raw.file[name][()])
            g = s.file["radar"]
            assert g.attrs["config"] == config.to_json()
            for name in ("aspect_deg", "roll_deg", "frequency_hz", "range_m"):
                np.testing.assert_array_equal(g[name][()], getattr(config, name))
            assert g["response"].dtype == np.complex64
            assert g["response"].shape == (s.n_objects, 61, 21, 107)
            assert g["frequency_response"].shape == (s.n_objects, 61, 21, 128)
            for k, row in enumerate(s.simple_mesh_index()):
                v, f = s.mesh(int(row))
                r = radar_sim.simulate(v, f, config)
                same_label(g["response"][k], r.range_profiles)
                same_label(g["frequency_response"][k], r.frequency_response)
                assert g["mode"][k].decode() == r.mode == radar_sim.detect_mode(v, f)
            rows = g["variant_mesh_index"][()]
            assert list(s.file["meshes/object_index"][()][rows]) == list(range(s.n_objects))
            assert (s.file["meshes/variant"][()][rows] > 0).all()
            for j, row in enumerate(rows):
                v, f = s.mesh(int(row))
                r = radar_sim.simulate(v, f, config)
                same_label(g["variant_response"][j], r.range_profiles)
                assert g["variant_mode"][j].decode() == r.mode
                n_variant_labels += 1
    assert n_variant_labels == 6


def test_bytes_do_not_depend_on_worker_count(dataset, labelled, tmp_path):
    one = tmp_path / "one"
    shutil.copytree(dataset, one)
    main(["label", str(one), "--workers", "1", *OPTIONS])
    assert digests(one) == digests(labelled)
    assert digests(one) != digests(dataset)


def test_existing_scheduler(dataset, labelled, tmp_path):
    from distributed import LocalCluster

    work = tmp_path / "data"
    shutil.copytree(dataset, work)
    with LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None) as cluster:
        main(["label", str(work), "--scheduler", cluster.scheduler_address, *OPTIONS])
    assert digests(work) == digests(labelled)


def test_rerun_skips_labelled_shards(labelled, capsys):
    before = {p: p.stat().st_mtime_ns for p in labelled.glob("shard-*.h5")}
    main(["label", str(labelled), *OPTIONS])
    assert "skipped 6 shard(s)" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in labelled.glob("shard-*.h5")} == before


def test_variant_sample_is_drawn_from_the_object_seed(dataset):
    with Shard(dataset / shard_name(0)) as s:
        first, again = select_variants(s, "sample:1"), select_variants(s, "sample:1")
        assert [list(r) for r in first] == [list(r) for r in again]
        assert [len(r) for r in select_variants(s, "all")] == [2]
        assert [len(r) for r in select_variants(s, "sample:5")] == [2]
        assert [len(r) for r in select_variants(s, "none")] == [0]


def test_killed_run_resumes_to_identical_bytes(dataset, labelled, tmp_path):
    """SIGKILL a labelling process after its first shard; the rerun matches an uninterrupted run."""
    work = tmp_path / "data"
    shutil.copytree(dataset, work)
    raw, done = digests(dataset), digests(labelled)
    proc = subprocess.Popen([sys.executable, "-m", "radar_sim.cli", "label", str(work),
                             "--workers", "1", *OPTIONS], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    sizes = {p: p.stat().st_size for p in work.glob("shard-*.h5")}
    deadline = time.time() + 60
    while time.time() < deadline and proc.poll() is None:
        if any(p.stat().st_size != n for p, n in sizes.items()):
            break
        time.sleep(0.002)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    mid = digests(work)
    assert all(mid[n] in (raw[n], done[n]) for n in raw), "a shard is neither raw nor labelled"
    n_done = sum(mid[n] == done[n] for n in raw)
    assert 1 <= n_done < len(raw), f"kill was not mid-run ({n_done} of {len(raw)} labelled)"
    main(["label", str(work), "--workers", "2", *OPTIONS])
    assert digests(work) == done
    assert not list(work.glob("*.tmp"))


def test_other_config_is_an_error_unless_overwrite(labelled, tmp_path):
    work = tmp_path / "data"
    shutil.copytree(labelled, work)
    before = digests(work)
    with pytest.raises(SystemExit) as exc:
        main(["label", str(work)])  # same config, other options (no variants)
    message = str(exc.value.code)
    assert "already labelled, with different radar options" in message
    assert str(work / shard_name(0)) in message and "\n" not in message
    other = tmp_path / "other.json"
    other.write_text('{"name": "coarse", "n_freq": 64, "n_range": 63}')
    message = _one_line_error(["label", str(work), "--config", str(other), *OPTIONS])
    assert "already labelled, with different radar config (" in message
    assert digests(work) == before
    # relabel with the physics forced: on these convex meshes shadow rays hide nothing
    request = LabelRequest(radar_sim.RadarConfig.named("xband-v1"), mode="shadowed")
    summary = label_directory(work, request, workers=2, overwrite=True, progress=False)
    assert len(summary.labelled) == 6
    for path in sorted(work.glob("shard-*.h5")):
        with h5py.File(path) as f, h5py.File(labelled / path.name) as ref:
            assert "variant_response" not in f["radar"] and "frequency_response" not in f["radar"]
            assert [m.decode() for m in f["radar/mode"][()]] == ["shadowed"]
            assert [m.decode() for m in ref["radar/mode"][()]] == ["convex"]
            same_label(f["radar/response"][0], ref["radar/response"][0])


def _one_line_error(argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    message = str(exc.value.code)
    assert message.startswith("radar-sim: ") and "\n" not in message
    return message


def test_bad_datasets_fail_fast_and_change_nothing(dataset, tmp_path):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    with h5py.File(foreign / shard_name(0), "w") as f:
        f["x"] = 1
    assert "not a basic-shapes shard" in _one_line_error(["label", str(foreign)])

    truncated = tmp_path / "truncated"
    shutil.copytree(dataset, truncated)
    data = (truncated / shard_name(3)).read_bytes()
    (truncated / shard_name(3)).write_bytes(data[:len(data) // 2])
    before = digests(truncated)
    message = _one_line_error(["label", str(truncated)])
    assert str(truncated / shard_name(3)) in message and "not a readable HDF5 shard" in message
    assert digests(truncated) == before  # validated before any work: nothing labelled

    assert "no such dataset directory" in _one_line_error(["label", str(tmp_path / "missing")])
    assert "holds no shards" in _one_line_error(["label", str(tmp_path)])
    assert "xband-v9" in _one_line_error(["label", str(truncated), "--config", "xband-v9"])


def test_unreachable_scheduler(dataset, tmp_path):
    import dask

    work = tmp_path / "data"
    shutil.copytree(dataset, work)
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        message = _one_line_error(["label", str(work), "--scheduler", "tcp://127.0.0.1:1"])
    assert "cannot use the Dask cluster tcp://127.0.0.1:1" in message
    assert digests(work) == digests(dataset)


def test_bad_mesh_names_shard_and_object(tmp_path):
    data = write_dataset(tmp_path / "nan", n_objects=2, objects_per_shard=2, corrupt=1)
    before = digests(data)
    message = _one_line_error(["label", str(data), "--workers", "1"])
    assert str(data / shard_name(0)) in message and "object 1" in message
    assert digests(data) == before


def test_cli_exit_status_and_stderr(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "radar_sim.cli", "label", str(tmp_path / "nope")],
                          capture_output=True, text=True)
    assert proc.returncode != 0
    assert proc.stderr.strip().splitlines() == [f"radar-sim: error: {tmp_path / 'nope'}: no such "
                                                f"dataset directory"]
