"""`basic-shapes export --format g2s`: labelled shards as NetCDF in the paper group's layout.

The research group the paper comes from reads one NetCDF file per batch of objects with
``xarray.open_mfdataset(files, combine="nested", concat_dim="sample")``: per object (sample) the
range-time image ``rti`` as (real, imag) float32, every representation mesh padded along a
``mesh_variant`` dimension, and per-sample metadata. Writing that layout here means their
loaders read basic-shapes datasets unchanged (docs/ARCHITECTURE.md, "Formats").

Every dimension has an index coordinate, and every file of one export has the same ones except
``sample`` (numbered through the whole export), so a plain ``xarray.open_mfdataset(glob)``
(``combine="by_coords"``) opens the export as well as the group's nested call. Every variable
carries ``long_name``, and ``units`` where it holds numbers (CF conventions).

Padding: ``mesh_variant`` lists only the variant numbers present somewhere in the export
(0 = simple mesh, 1.. complex variants, 900.. out-of-distribution meshes), not every number up
to the largest, so OOD meshes no longer multiply the file by ~50. Mesh rows past an object's own
count hold ``PAD`` in every column (vertices and faces alike, so loaders that strip trailing
all-``PAD`` rows work), and every mesh is followed by at least one such row.
``rep_mesh_n_vertices`` / ``rep_mesh_n_faces`` give the counts. The row counts are the
export's largest mesh + 1 in every file: files with different sizes along a dimension would not
concatenate (an outer join would turn the pad into NaN and the int32 faces into float64).

A config with several polarization channels (``/radar/polarimetric``, e.g. "xband-v2") adds
``rti_polarimetric`` over a ``polarization`` dimension; ``rti`` stays the VV label.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from basic_shapes import __version__
from basic_shapes.infra import atomic_path
from basic_shapes.shards import Shard, ShardError, dataset_fingerprint, list_shards

PAD = -10  # vertex coordinates (m) and face indices alike; the group's loaders' default
NETCDF_GLOB = "shard-*.nc"
CONVENTIONS = "CF-1.8"
COMPRESSED = ("rti", "rti_polarimetric", "rep_mesh_vertices", "rep_mesh_faces")


@dataclass
class RadarLabels:
    """The per-object labels of one shard and their grid (the only view of /radar used here)."""

    response: np.ndarray  # (n_objects, n_aspect, n_roll, n_range) complex, amplitude in m
    aspect_deg: np.ndarray
    roll_deg: np.ndarray
    range_m: np.ndarray
    frequency_hz: np.ndarray
    config: dict  # RadarConfig fields
    channels: tuple[str, ...] = ("VV",)
    # (n_objects, n_channel, n_aspect, n_roll, n_range) complex where every channel is stored
    polarimetric: np.ndarray | None = None


def read_labels(shard: Shard) -> RadarLabels:
    """The object labels of every object in ``shard``, through the one /radar reader."""
    radar = shard.radar
    n = shard.n_objects
    response = np.stack([radar.response(k) for k in range(n)])
    pol = np.stack([radar.polarimetric(k) for k in range(n)]) if radar.has_polarimetric else None
    return RadarLabels(
        response,
        radar.aspect_deg,
        radar.roll_deg,
        radar.range_m,
        radar.frequency_hz,
        radar.config,
        radar.channels if pol is not None else ("VV",),
        pol,
    )


@dataclass(frozen=True)
class Layout:
    """What every file of one export shares, so that the files concatenate along ``sample``."""

    variants: tuple[int, ...]  # the mesh_variant coordinate: variant numbers present anywhere
    vertex_rows: int  # the largest mesh + 1
    face_rows: int
    config: dict  # the radar config every shard was labelled with


def plan(paths: list[Path], progress: bool = False) -> tuple[Layout, list[int]]:
    """The export's shared layout and each file's first sample number. Checks every shard
    (labels present, content matching its fingerprints, one radar config) before anything is
    written; reads the mesh table, not the geometry."""
    variants: set[int] = set()
    n_v = n_f = 0
    config = None
    first, total = [], 0
    for p in tqdm(paths, desc="g2s check", unit="shard", disable=not progress):
        with Shard(p) as s:
            if not s.has_labels:
                raise ShardError(f"{p}: has no radar labels; run `radar-sim label` first")
            radar = s.radar  # reading it refuses a malformed /radar
            s.verify()
            s.verify_labels()
            if config is None:
                config = radar.config
            elif radar.config != config:
                raise ShardError(
                    f"{p}: labelled with radar config {radar.config.get('name')!r}, "
                    f"{paths[0].name} with {config.get('name')!r}; one export needs one config"
                )
            table = s.mesh_table()
            variants.update(int(v) for v in table["variant"])
            n_v = max(n_v, int(table["n_vertices"].max(initial=0)))
            n_f = max(n_f, int(table["n_faces"].max(initial=0)))
            first.append(total)
            total += s.n_objects
    return Layout(tuple(sorted(variants)), n_v + 1, n_f + 1, config or {}), first


def _var(dims, values, long_name: str, units: str | None = None, **attrs):
    """A variable with CF ``long_name`` and, for numbers, ``units`` ("1": dimensionless)."""
    meta = {"long_name": long_name, **({"units": units} if units is not None else {}), **attrs}
    return (dims, values, meta)


def _strings(values) -> np.ndarray:
    return np.array(list(values), dtype=object)


def shard_dataset(shard: Shard, layout: Layout, first_sample: int, fingerprint: str):
    """The xarray Dataset of one shard in the g2s layout (one shard in memory at a time)."""
    import xarray as xr

    labels = read_labels(shard)
    objs = shard.objects()
    n = shard.n_objects
    if labels.response.shape[0] != n:
        raise ShardError(f"{shard.path}: {labels.response.shape[0]} radar labels for {n} objects")
    slot = {v: i for i, v in enumerate(layout.variants)}
    n_var, n_v, n_f = len(slot), layout.vertex_rows, layout.face_rows
    vertices = np.full((n, n_var, n_v, 3), PAD, np.float32)
    faces = np.full((n, n_var, n_f, 3), PAD, np.int32)
    counts_v = np.zeros((n, n_var), np.int32)
    counts_f = np.zeros((n, n_var), np.int32)
    for k, variant, v, f in shard.iter_meshes():
        j = slot[int(variant)]
        vertices[k, j, : len(v)] = v
        faces[k, j, : len(f)] = f
        counts_v[k, j], counts_f[k, j] = len(v), len(f)
    f_hz = labels.frequency_hz
    names = shard.class_names
    image = ("sample", "aspect", "roll", "range", "complex")
    data = {
        "rti": _var(
            image,
            np.stack([labels.response.real, labels.response.imag], axis=-1).astype(np.float32),
            "range profile, the object's label (/radar/response, the VV channel), (real, imag)",
            "m",
            description="complex amplitude A with sigma = |A|^2 in m^2; "
            "a point scatterer of 1 m^2 peaks at 1; last dimension (real, imag)",
        ),
    }
    if labels.polarimetric is not None:
        pol = labels.polarimetric
        data["rti_polarimetric"] = _var(
            ("sample", "polarization", *image[1:]),
            np.stack([pol.real, pol.imag], axis=-1).astype(np.float32),
            "range profiles in every polarization channel (/radar/polarimetric), (real, imag)",
            "m",
            description="as rti, one image per channel; the VV channel equals rti",
        )
    data |= {
        "rep_mesh_vertices": _var(
            ("sample", "mesh_variant", "vertex", "xyz"),
            vertices,
            "representation mesh vertices",
            "m",
            pad_value=PAD,
        ),
        "rep_mesh_faces": _var(
            ("sample", "mesh_variant", "face", "corner"),
            faces,
            "representation mesh faces (0-based vertex indices)",
            "1",
            pad_value=PAD,
        ),
        "rep_mesh_n_vertices": _var(
            ("sample", "mesh_variant"), counts_v, "vertex rows before padding", "1"
        ),
        "rep_mesh_n_faces": _var(
            ("sample", "mesh_variant"), counts_f, "face rows before padding", "1"
        ),
        "label": _var(
            ("sample",), _strings(names[c] for c in objs["class"]), "class of the primitive"
        ),
        "seed": _var(("sample",), objs["seed"].astype(np.uint64), "object seed", "1"),
        "scale": _var(
            ("sample", "xyz"),
            objs["scale"].astype(np.float64),
            "bounding-box extents per axis (x, y, z)",
            "m",
        ),
        "frequency": _var(
            ("sample",),
            np.full(n, (f_hz[0] + f_hz[-1]) / 2),
            "centre frequency of the swept band",
            "Hz",
        ),
        "bandwidth": _var(
            ("sample",),
            np.full(n, f_hz[-1] - f_hz[0]),
            "swept band, last minus first frequency sample",
            "Hz",
        ),
        "object_id": _var(("sample",), objs["id"].astype(np.int64), "basic-shapes object id", "1"),
        "split": _var(("sample",), _strings(objs["split"]), "basic-shapes split (train/test)"),
    }
    coords = {
        "sample": _var(
            ("sample",),
            np.arange(first_sample, first_sample + n, dtype=np.int64),
            "sample number in the export (files in shard order)",
            "1",
        ),
        "aspect": _var(("aspect",), labels.aspect_deg, "aspect angle theta", "degree"),
        "aspect_rad": _var(
            ("aspect",),
            np.radians(labels.aspect_deg),
            "aspect theta; line of sight (sin theta cos roll, sin theta sin roll, cos theta)",
            "rad",
        ),
        "roll": _var(("roll",), labels.roll_deg, "roll angle about the z axis", "degree"),
        "roll_rad": _var(("roll",), np.radians(labels.roll_deg), "roll about the z axis", "rad"),
        "range": _var(
            ("range",), labels.range_m, "relative range, positive away from the radar", "m"
        ),
        "complex": _var(("complex",), _strings(("real", "imag")), "part of a complex amplitude"),
        "mesh_variant": _var(
            ("mesh_variant",),
            np.array(layout.variants, np.int32),
            "mesh variant number: 0 = simple mesh, 1.. = complex variants of the same shape, "
            "900.. = out-of-distribution test meshes (by remesher)",
            "1",
        ),
        "vertex": _var(("vertex",), np.arange(n_v, dtype=np.int32), "vertex row", "1"),
        "xyz": _var(("xyz",), _strings("xyz"), "Cartesian axis"),
        "face": _var(("face",), np.arange(n_f, dtype=np.int32), "face row", "1"),
        "corner": _var(("corner",), np.arange(3, dtype=np.int32), "corner of a triangle", "1"),
    }
    if labels.polarimetric is not None:
        coords["polarization"] = _var(
            ("polarization",),
            _strings(labels.channels),
            "polarization channel, transmit then receive (H = phi, V = theta)",
        )
    attrs = {
        "Conventions": CONVENTIONS,
        "source": f"basic-shapes {__version__}",
        "format": "g2s",
        "dataset_fingerprint": fingerprint,
        "radar_config_name": str(labels.config.get("name", "")),
        "radar_config": json.dumps(labels.config, sort_keys=True),
        "pad_value": PAD,
    }
    return xr.Dataset(data, coords=coords, attrs=attrs)


def _write(ds, path: Path) -> None:
    """Write atomically, one compressed chunk per sample; no _FillValue anywhere, so readers
    see the pad value rather than NaN."""
    encoding = {
        name: {"_FillValue": None}
        for name in (*ds.data_vars, *ds.coords)
        if ds[name].dtype != object
    }
    for name in COMPRESSED:
        if name in ds:
            shape = ds[name].shape
            encoding[name].update(zlib=True, complevel=4, chunksizes=(1, *shape[1:]))
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf", encoding=encoding)


def export_g2s(directory: str | Path, out: str | Path, progress: bool = False) -> int:
    """Write ``out/shard-NNNNN.nc`` for every ``shard-NNNNN.h5``; return the file count.

    Every shard is checked (labels present, one radar config) before anything is written;
    files of an earlier export with the same names are replaced, any other ``shard-*.nc`` in
    ``out`` is an error.
    """
    paths = list_shards(directory)
    layout, first = plan(paths, progress)
    out = Path(out)
    targets = [out / (p.stem + ".nc") for p in paths]
    if out.is_dir():
        others = sorted(set(out.glob(NETCDF_GLOB)) - set(targets))
        if others:
            raise ShardError(
                f"{out}: holds {others[0].name}, not part of this export; choose an empty directory"
            )
    out.mkdir(parents=True, exist_ok=True)
    fingerprint = dataset_fingerprint(directory)
    jobs = zip(paths, targets, first, strict=True)
    for p, target, start in tqdm(
        jobs, desc="g2s write", unit="shard", total=len(paths), disable=not progress
    ):
        with Shard(p) as s:
            ds = shard_dataset(s, layout, start, fingerprint)
        _write(ds, target)
    return len(targets)
