"""`basic-shapes export --format g2s` on a real generated (Blender) and labelled (Dask) dataset.

The exported files are opened exactly as the paper group's loader opens them:
``xarray.open_mfdataset(sorted(glob(...)), engine="h5netcdf", combine="nested",
concat_dim="sample")``, and every value is compared with the shards read directly with h5py.
"""

import hashlib
import shutil
import warnings
from glob import glob

import h5py
import numpy as np
import pytest
import xarray as xr

import radar_sim
from basic_shapes import cli
from basic_shapes.export_g2s import PAD
from basic_shapes.generate import GenerateConfig, generate
from basic_shapes.shards import iter_objects
from radar_sim.label import LabelRequest, label_directory

C0 = 299_792_458.0
CONFIG = radar_sim.RadarConfig(name="g2s-test", n_aspect=7, n_roll=4, n_freq=64, n_range=63)


@pytest.fixture(scope="module")
def raw(tmp_path_factory):
    """3 objects (cube, cylinder, sphere), simple mesh + 2 variants, 2 objects per shard."""
    out = tmp_path_factory.mktemp("g2s") / "raw"
    cfg = GenerateConfig(
        classes=("cube", "cylinder", "sphere"),
        objects_per_class=1,
        variants=2,
        seed=3,
        objects_per_shard=2,
    )
    generate(out, cfg, workers=0, progress=False)
    return out


@pytest.fixture(scope="module")
def labelled(raw, tmp_path_factory):
    out = tmp_path_factory.mktemp("g2s") / "labelled"
    shutil.copytree(raw, out)
    label_directory(out, LabelRequest(CONFIG), workers=1, progress=False)
    return out


@pytest.fixture(scope="module")
def exported(labelled, tmp_path_factory):
    out = tmp_path_factory.mktemp("g2s") / "nc"
    assert cli.main(["export", "--data", str(labelled), "--format", "g2s", "--out", str(out)]) == 0
    return out


def open_like_the_group(directory):
    return xr.open_mfdataset(
        sorted(glob(f"{directory}/*.nc")), engine="h5netcdf", combine="nested", concat_dim="sample"
    )


def digests(directory):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.iterdir())}


def obj_seed(directory, object_id):
    for path in sorted(directory.glob("shard-*.h5")):
        with h5py.File(path, "r") as f:
            hit = np.flatnonzero(f["objects/id"][()] == object_id)
            if len(hit):
                return f["objects/seed"][hit[0]]
    raise KeyError(object_id)


def test_the_groups_loader_reads_labels_and_coordinates(labelled, exported):
    assert sorted(p.name for p in exported.iterdir()) == ["shard-00000.nc", "shard-00001.nc"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = open_like_the_group(exported).load()
    assert ds.sizes["sample"] == 3
    assert ds["rti"].dims == ("sample", "aspect", "roll", "range", "complex")
    assert ds["rti"].dtype == np.float32
    stored = []
    for path in sorted(labelled.glob("shard-*.h5")):
        with h5py.File(path, "r") as f:
            stored.append(f["radar/response"][()])
    stored = np.concatenate(stored)
    assert stored.shape == (3, 7, 4, 63)
    np.testing.assert_array_equal(ds["rti"].values[..., 0], stored.real)
    np.testing.assert_array_equal(ds["rti"].values[..., 1], stored.imag)

    np.testing.assert_allclose(ds["aspect_rad"].values, np.linspace(0, np.pi, 7), rtol=1e-15)
    np.testing.assert_allclose(ds["roll_rad"].values, np.arange(4) * np.pi / 2, rtol=1e-15)
    bin_m = C0 / (2 * 64 * 4e9 / 63)  # c / (2 N df), df = 4 GHz / 63 intervals
    np.testing.assert_allclose(ds["range"].values, np.arange(-31, 32) * bin_m, rtol=1e-12)
    assert (ds["frequency"].values == 10e9).all() and (ds["bandwidth"].values == 4e9).all()
    units = {
        "rti": "m",
        "aspect_rad": "rad",
        "roll_rad": "rad",
        "range": "m",
        "scale": "m",
        "frequency": "Hz",
        "bandwidth": "Hz",
        "rep_mesh_vertices": "m",
    }
    assert {name: ds[name].attrs.get("units") for name in units} == units


def test_meshes_are_padded_and_match_the_shards(exported, labelled):
    ds = open_like_the_group(exported).load()
    objects = list(iter_objects(labelled))
    assert ds["object_id"].values.tolist() == [obj["id"] for _, obj, _ in objects]
    assert ds["label"].values.tolist() == ["cube", "cylinder", "sphere"]
    assert list(ds["mesh_variant"].values) == [0, 1, 2]
    n_v, n_f = ds.sizes["vertex"], ds.sizes["face"]
    largest = 0
    for i, (_, obj, meshes) in enumerate(objects):
        sample = ds.isel(sample=i)
        assert sample["seed"].item() == int(obj_seed(labelled, obj["id"]))
        np.testing.assert_array_equal(sample["scale"].values, obj["scale"])
        for variant, v, f in meshes:
            vert = sample["rep_mesh_vertices"].values[variant]
            face = sample["rep_mesh_faces"].values[variant]
            assert sample["rep_mesh_n_vertices"].values[variant] == len(v)
            assert sample["rep_mesh_n_faces"].values[variant] == len(f)
            np.testing.assert_array_equal(vert[: len(v)], v)
            np.testing.assert_array_equal(face[: len(f)], f)
            assert (vert[len(v) :] == PAD).all() and (face[len(f) :] == PAD).all()
            # what a loader that strips trailing all-PAD rows gets back: exactly the mesh
            assert not (vert[: len(v)] == PAD).all(axis=1).any()
            largest = max(largest, len(v))
    assert n_v == largest + 1 and n_f > 1
    assert ds["rep_mesh_vertices"].attrs["pad_value"] == PAD == ds.attrs["pad_value"]


def test_same_dataset_same_bytes(labelled, exported, tmp_path):
    again = tmp_path / "again"
    assert (
        cli.main(["export", "--data", str(labelled), "--format", "g2s", "--out", str(again)]) == 0
    )
    assert digests(again) == digests(exported)
    assert (
        cli.main(["export", "--data", str(labelled), "--format", "g2s", "--out", str(again)]) == 0
    )
    assert digests(again) == digests(exported)  # re-export in place: same files, no *.tmp


def test_unlabelled_dataset_is_refused(raw, tmp_path):
    out = tmp_path / "nc"
    with pytest.raises(SystemExit) as exc:
        cli.main(["export", "--data", str(raw), "--format", "g2s", "--out", str(out)])
    err = str(exc.value.code)
    assert err.startswith("basic-shapes export: error:") and "\n" not in err
    assert "shard-00000.h5: has no radar labels" in err
    assert not out.exists()


def test_foreign_files_in_out_are_kept(labelled, tmp_path):
    out = tmp_path / "nc"
    out.mkdir()
    (out / "shard-00009.nc").write_bytes(b"someone else's")
    with pytest.raises(SystemExit) as exc:
        cli.main(["export", "--data", str(labelled), "--format", "g2s", "--out", str(out)])
    assert "shard-00009.nc, not part of this export" in str(exc.value.code)
    assert [p.name for p in out.iterdir()] == ["shard-00009.nc"]
    assert (out / "shard-00009.nc").read_bytes() == b"someone else's"
