"""`basic-shapes export --format g2s` on a real generated (Blender) and labelled (Dask) dataset.

The exported files are opened exactly as the paper group's loader opens them:
``xarray.open_mfdataset(sorted(glob(...)), engine="h5netcdf", combine="nested",
concat_dim="sample")``, and with a plain ``xarray.open_mfdataset(glob, engine="h5netcdf")``
(``combine="by_coords"``); every value is compared with the shards read directly with h5py.
The dataset has meshes of 8 to ~1,900 vertices and out-of-distribution variants (900, 925,
950) on its test objects: the sizes the padding must not blow up.
"""

import hashlib
import json
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
# every polarization channel, as "xband-v2" stores them, on the same small grid
POLARIMETRIC = radar_sim.RadarConfig(
    name="g2s-pol", n_aspect=7, n_roll=4, n_freq=64, n_range=63, channels="HH,VV,HV"
)


@pytest.fixture(scope="module")
def raw(tmp_path_factory):
    """6 objects (2 cubes, cylinders, spheres; 3 in the test split with one OOD mesh per
    remesher), simple mesh + 2 variants, 4 objects per shard: 2 shards of unequal size."""
    out = tmp_path_factory.mktemp("g2s") / "raw"
    cfg = GenerateConfig(
        classes=("cube", "cylinder", "sphere"),
        objects_per_class=2,
        variants=2,
        seed=3,
        objects_per_shard=4,
        test_fraction=0.5,
        val_fraction=0.0,
        ood_variants_per_remesher=1,
    )
    generate(out, cfg, workers=0, progress=False)
    return out


def _labelled(raw, tmp_path_factory, config):
    out = tmp_path_factory.mktemp("g2s") / "labelled"
    shutil.copytree(raw, out)
    label_directory(out, LabelRequest(config), workers=1, progress=False)
    return out


def _exported(labelled, tmp_path_factory):
    out = tmp_path_factory.mktemp("g2s") / "nc"
    assert cli.main(["export", "--data", str(labelled), "--format", "g2s", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def labelled(raw, tmp_path_factory):
    return _labelled(raw, tmp_path_factory, CONFIG)


@pytest.fixture(scope="module")
def exported(labelled, tmp_path_factory):
    return _exported(labelled, tmp_path_factory)


@pytest.fixture(scope="module")
def labelled_pol(raw, tmp_path_factory):
    return _labelled(raw, tmp_path_factory, POLARIMETRIC)


@pytest.fixture(scope="module")
def exported_pol(labelled_pol, tmp_path_factory):
    return _exported(labelled_pol, tmp_path_factory)


def open_like_the_group(directory):
    return xr.open_mfdataset(
        sorted(glob(f"{directory}/*.nc")), engine="h5netcdf", combine="nested", concat_dim="sample"
    )


def open_plainly(directory):
    """The one call a newcomer tries first: a glob, every default (``combine="by_coords"``)."""
    return xr.open_mfdataset(f"{directory}/*.nc", engine="h5netcdf")


def digests(directory):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.iterdir())}


def stored(directory, name):
    """``/radar/<name>`` of every shard, concatenated (read directly, as a check)."""
    rows = []
    for path in sorted(directory.glob("shard-*.h5")):
        with h5py.File(path, "r") as f:
            rows.append(f[f"radar/{name}"][()])
    return np.concatenate(rows)


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
    assert ds.sizes["sample"] == 6 and ds["sample"].values.tolist() == list(range(6))
    assert ds["rti"].dims == ("sample", "aspect", "roll", "range", "complex")
    assert ds["rti"].dtype == np.float32
    response = stored(labelled, "response")
    assert response.shape == (6, 7, 4, 63)
    np.testing.assert_array_equal(ds["rti"].values[..., 0], response.real)
    np.testing.assert_array_equal(ds["rti"].values[..., 1], response.imag)
    assert "rti_polarimetric" not in ds and "polarization" not in ds.dims  # VV labels only

    np.testing.assert_allclose(ds["aspect_rad"].values, np.linspace(0, np.pi, 7), rtol=1e-15)
    np.testing.assert_allclose(ds["roll_rad"].values, np.arange(4) * np.pi / 2, rtol=1e-15)
    np.testing.assert_allclose(ds["aspect"].values, np.linspace(0, 180, 7), rtol=1e-15)
    np.testing.assert_allclose(ds["roll"].values, [0, 90, 180, 270], rtol=1e-15)
    bin_m = C0 / (2 * 64 * 4e9 / 63)  # c / (2 N df), df = 4 GHz / 63 intervals
    np.testing.assert_allclose(ds["range"].values, np.arange(-31, 32) * bin_m, rtol=1e-12)
    assert (ds["frequency"].values == 10e9).all() and (ds["bandwidth"].values == 4e9).all()
    units = {
        "rti": "m",
        "aspect": "degree",
        "roll": "degree",
        "aspect_rad": "rad",
        "roll_rad": "rad",
        "range": "m",
        "scale": "m",
        "frequency": "Hz",
        "bandwidth": "Hz",
        "rep_mesh_vertices": "m",
        "rep_mesh_faces": "1",
        "rep_mesh_n_vertices": "1",
    }
    assert {name: ds[name].attrs.get("units") for name in units} == units


def test_every_variable_has_cf_names_and_every_dimension_an_index(exported):
    """CF: ``long_name`` on every variable and coordinate, ``units`` on every one holding
    numbers (texts such as ``label`` have none); an index coordinate on every dimension."""
    with xr.open_dataset(exported / "shard-00000.nc", engine="h5netcdf") as ds:
        assert ds.attrs["Conventions"] == "CF-1.8"
        for name, var in ds.variables.items():
            assert var.attrs.get("long_name"), name
            if var.dtype.kind in "iuf":
                assert var.attrs.get("units"), name
        assert set(ds.dims) == set(ds.indexes)
        assert ds["complex"].values.tolist() == ["real", "imag"]
        assert ds["xyz"].values.tolist() == ["x", "y", "z"]


def test_the_radar_config_round_trips(exported):
    with xr.open_dataset(exported / "shard-00001.nc", engine="h5netcdf") as ds:
        attrs = dict(ds.attrs)
    assert attrs["radar_config_name"] == "g2s-test"
    assert attrs["radar_config"] == CONFIG.to_json()
    assert radar_sim.RadarConfig(**json.loads(attrs["radar_config"])) == CONFIG
    assert radar_sim.RadarConfig.named("xband-v1").name == "xband-v1"  # what a named one loads


def test_a_plain_open_mfdataset_opens_the_export_in_one_call(exported):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plain = open_plainly(exported).load()
    assert plain.identical(open_like_the_group(exported).load())
    # index coordinates: select by value, not by position
    assert plain["rti"].sel(aspect=90.0, roll=180.0).shape == (6, 63, 2)
    assert plain["rti"].sel(complex="imag").shape == (6, 7, 4, 63)
    ood = plain["rep_mesh_n_vertices"].sel(mesh_variant=925)
    assert ((ood > 0) == (plain["split"] == "test")).all()  # test objects only


def test_meshes_are_padded_and_match_the_shards(exported, labelled):
    ds = open_like_the_group(exported).load()
    objects = list(iter_objects(labelled))
    assert ds["object_id"].values.tolist() == [obj["id"] for _, obj, _ in objects]
    assert ds["label"].values.tolist() == [obj["class"] for _, obj, _ in objects]
    variants = sorted({int(v) for _, _, meshes in objects for v, _, _ in meshes})
    assert variants == [0, 1, 2, 900, 925, 950]
    # only the variant numbers present: not 951 slots, most of them empty
    assert ds["mesh_variant"].values.tolist() == variants
    n_v, n_f = ds.sizes["vertex"], ds.sizes["face"]
    largest_v = largest_f = 0
    for i, (_, obj, meshes) in enumerate(objects):
        sample = ds.isel(sample=i)
        assert sample["seed"].item() == int(obj_seed(labelled, obj["id"]))
        np.testing.assert_array_equal(sample["scale"].values, obj["scale"])
        assert sample["split"].item() == obj["split"]
        present = set()
        for variant, v, f in meshes:
            at = sample.sel(mesh_variant=variant)
            vert, face = at["rep_mesh_vertices"].values, at["rep_mesh_faces"].values
            assert at["rep_mesh_n_vertices"].item() == len(v)
            assert at["rep_mesh_n_faces"].item() == len(f)
            np.testing.assert_array_equal(vert[: len(v)], v)
            np.testing.assert_array_equal(face[: len(f)], f)
            assert (vert[len(v) :] == PAD).all() and (face[len(f) :] == PAD).all()
            # what a loader that strips trailing all-PAD rows gets back: exactly the mesh
            assert not (vert[: len(v)] == PAD).all(axis=1).any()
            largest_v, largest_f = max(largest_v, len(v)), max(largest_f, len(f))
            present.add(variant)
        absent = sample.sel(mesh_variant=[v for v in variants if v not in present])
        assert (absent["rep_mesh_n_vertices"] == 0).all() and (
            absent["rep_mesh_n_faces"] == 0
        ).all()
        assert (absent["rep_mesh_vertices"] == PAD).all() and (
            absent["rep_mesh_faces"] == PAD
        ).all()
    assert n_v == largest_v + 1 and n_f == largest_f + 1  # the export's largest mesh + 1
    assert ds["rep_mesh_vertices"].attrs["pad_value"] == PAD == ds.attrs["pad_value"]
    assert ds["rep_mesh_faces"].dtype == np.int32 and ds["rep_mesh_vertices"].dtype == np.float32


def test_polarimetric_labels_are_exported_over_a_polarization_dimension(
    labelled_pol, exported_pol, tmp_path
):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = open_plainly(exported_pol).load()
    assert ds.identical(open_like_the_group(exported_pol).load())
    pol = ds["rti_polarimetric"]
    assert pol.dims == ("sample", "polarization", "aspect", "roll", "range", "complex")
    assert pol.dtype == np.float32 and pol.attrs["units"] == "m" and pol.attrs["long_name"]
    assert ds["polarization"].values.tolist() == ["HH", "VV", "HV"]
    assert ds["polarization"].attrs["long_name"]
    channels = stored(labelled_pol, "polarimetric")
    assert channels.shape == (6, 3, 7, 4, 63)
    np.testing.assert_array_equal(pol.values[..., 0], channels.real)
    np.testing.assert_array_equal(pol.values[..., 1], channels.imag)
    np.testing.assert_array_equal(pol.sel(polarization="VV").values, ds["rti"].values)
    assert ds.attrs["radar_config_name"] == "g2s-pol"
    assert radar_sim.RadarConfig(**json.loads(ds.attrs["radar_config"])) == POLARIMETRIC
    again = tmp_path / "again"
    cli.main(["export", "--data", str(labelled_pol), "--format", "g2s", "--out", str(again)])
    assert digests(again) == digests(exported_pol)


def test_shards_labelled_with_two_configs_are_refused(labelled, labelled_pol, tmp_path):
    data = tmp_path / "mixed"
    shutil.copytree(labelled, data)
    shutil.copy(labelled_pol / "shard-00001.h5", data / "shard-00001.h5")
    out = tmp_path / "nc"
    with pytest.raises(SystemExit) as exc:
        cli.main(["export", "--data", str(data), "--format", "g2s", "--out", str(out)])
    err = str(exc.value.code)
    assert "shard-00001.h5: labelled with radar config 'g2s-pol'" in err and "\n" not in err
    assert not out.exists()


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


def test_export_shows_progress_on_stderr_unless_quiet(labelled, tmp_path, capsys):
    args = ["export", "--data", str(labelled), "--format", "g2s", "--out"]
    assert cli.main([*args, str(tmp_path / "a")]) == 0
    out = capsys.readouterr()
    assert "g2s check" in out.err and "g2s write" in out.err and "2/2" in out.err
    assert out.out.startswith("wrote 2 NetCDF (g2s) files")
    assert cli.main([*args, str(tmp_path / "b"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    assert cli.main(["export", "--data", str(labelled), "--out", str(tmp_path / "obj")]) == 0
    assert "export obj" in capsys.readouterr().err


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
