"""`basic-shapes export --format g2s`: labelled shards as NetCDF in the paper group's layout.

The research group the paper comes from reads one NetCDF file per batch of objects with
``xarray.open_mfdataset(files, combine="nested", concat_dim="sample")``: per object (sample) the
range-time image ``rti`` as (real, imag) float32, every representation mesh padded along a
``mesh_variant`` dimension, and per-sample metadata. Writing that layout here means their
loaders read basic-shapes datasets unchanged (docs/ARCHITECTURE.md, "Formats").

Padding: mesh rows past an object's own count hold ``PAD`` in every column (vertices and
faces alike, so loaders that strip trailing all-``PAD`` rows work), and every mesh is followed
by at least one such row. ``rep_mesh_n_vertices`` / ``rep_mesh_n_faces`` give the counts.
The padded sizes are the dataset's largest mesh + 1, the same in every file, so the files
concatenate along ``sample``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from basic_shapes import __version__
from basic_shapes.infra import atomic_path
from basic_shapes.shards import Shard, ShardError, dataset_fingerprint, list_shards

PAD = -10  # vertex coordinates (m) and face indices alike; the group's loaders' default
NETCDF_GLOB = "shard-*.nc"


@dataclass
class RadarLabels:
    """The per-object labels of one shard and their grid (the only view of /radar used here)."""

    response: np.ndarray  # (n_objects, n_aspect, n_roll, n_range) complex, amplitude in m
    aspect_deg: np.ndarray
    roll_deg: np.ndarray
    range_m: np.ndarray
    frequency_hz: np.ndarray
    config: str  # RadarConfig JSON


def read_labels(shard: Shard) -> RadarLabels:
    """The object labels of every object in ``shard``, through the one /radar reader."""
    radar = shard.radar
    response = np.stack([radar.response(k) for k in range(shard.n_objects)])
    return RadarLabels(
        response,
        radar.aspect_deg,
        radar.roll_deg,
        radar.range_m,
        radar.frequency_hz,
        json.dumps(radar.config, sort_keys=True),
    )


def _mesh_counts(shard: Shard) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per mesh: (variant, vertex count, face count), without reading geometry."""
    table = shard.mesh_table()
    return table["variant"], table["n_vertices"], table["n_faces"]


def padded_sizes(paths: list[Path]) -> tuple[int, int, int]:
    """(mesh variants, vertex rows, face rows) shared by every file of the export."""
    n_var = n_v = n_f = 0
    for p in paths:
        with Shard(p) as s:
            var, nv, nf = _mesh_counts(s)
            n_var = max(n_var, int(var.max()) + 1 if len(var) else 0)
            n_v = max(n_v, int(nv.max(initial=0)))
            n_f = max(n_f, int(nf.max(initial=0)))
    return n_var, n_v + 1, n_f + 1


def shard_dataset(shard: Shard, sizes: tuple[int, int, int], fingerprint: str):
    """The xarray Dataset of one shard in the g2s layout (one shard in memory at a time)."""
    import xarray as xr

    labels = read_labels(shard)
    objs = shard.objects()
    n = shard.n_objects
    if labels.response.shape[0] != n:
        raise ShardError(f"{shard.path}: {labels.response.shape[0]} radar labels for {n} objects")
    n_var, n_v, n_f = sizes
    vertices = np.full((n, n_var, n_v, 3), PAD, np.float32)
    faces = np.full((n, n_var, n_f, 3), PAD, np.int32)
    counts_v = np.zeros((n, n_var), np.int32)
    counts_f = np.zeros((n, n_var), np.int32)
    for k, variant, v, f in shard.iter_meshes():
        vertices[k, variant, : len(v)] = v
        faces[k, variant, : len(f)] = f
        counts_v[k, variant], counts_f[k, variant] = len(v), len(f)
    rti = np.stack([labels.response.real, labels.response.imag], axis=-1).astype(np.float32)
    f_hz = labels.frequency_hz
    names = shard.class_names
    data = {
        "rti": (
            ("sample", "aspect", "roll", "range", "complex"),
            rti,
            {
                "long_name": "range profile, the object's label (/radar/response), (real, imag)",
                "units": "m",
                "description": "complex amplitude A with sigma = |A|^2 in m^2; "
                "a point scatterer of 1 m^2 peaks at 1; last dimension (real, imag)",
            },
        ),
        "rep_mesh_vertices": (
            ("sample", "mesh_variant", "vertex", "xyz"),
            vertices,
            {"long_name": "representation mesh vertices", "units": "m", "pad_value": PAD},
        ),
        "rep_mesh_faces": (
            ("sample", "mesh_variant", "face", "corner"),
            faces,
            {"long_name": "representation mesh faces (0-based vertex indices)", "pad_value": PAD},
        ),
        "rep_mesh_n_vertices": (
            ("sample", "mesh_variant"),
            counts_v,
            {"long_name": "vertex rows before padding"},
        ),
        "rep_mesh_n_faces": (
            ("sample", "mesh_variant"),
            counts_f,
            {"long_name": "face rows before padding"},
        ),
        "label": (
            ("sample",),
            np.array([names[c] for c in objs["class"]], dtype=object),
            {"long_name": "class of the primitive"},
        ),
        "seed": (("sample",), objs["seed"].astype(np.uint64), {"long_name": "object seed"}),
        "scale": (
            ("sample", "xyz"),
            objs["scale"].astype(np.float64),
            {"long_name": "bounding-box extents per axis (x, y, z)", "units": "m"},
        ),
        "frequency": (
            ("sample",),
            np.full(n, (f_hz[0] + f_hz[-1]) / 2),
            {"long_name": "centre frequency of the swept band", "units": "Hz"},
        ),
        "bandwidth": (
            ("sample",),
            np.full(n, f_hz[-1] - f_hz[0]),
            {"long_name": "swept band, last minus first frequency sample", "units": "Hz"},
        ),
        "object_id": (
            ("sample",),
            objs["id"].astype(np.int64),
            {"long_name": "basic-shapes object id"},
        ),
        "split": (
            ("sample",),
            np.array(objs["split"], dtype=object),
            {"long_name": "basic-shapes split (train/test)"},
        ),
    }
    coords = {
        "aspect_rad": (
            ("aspect",),
            np.radians(labels.aspect_deg),
            {
                "long_name": "aspect theta; line of sight (sin theta cos roll, "
                "sin theta sin roll, cos theta)",
                "units": "rad",
            },
        ),
        "roll_rad": (
            ("roll",),
            np.radians(labels.roll_deg),
            {"long_name": "roll about the z axis", "units": "rad"},
        ),
        "range": (
            ("range",),
            labels.range_m,
            {"long_name": "relative range, positive away from the radar", "units": "m"},
        ),
        "mesh_variant": (
            ("mesh_variant",),
            np.arange(n_var, dtype=np.int32),
            {"long_name": "0 = simple mesh, 1.. = complex variants of the same shape"},
        ),
    }
    attrs = {
        "source": f"basic-shapes {__version__}",
        "format": "g2s",
        "dataset_fingerprint": fingerprint,
        "radar_config": labels.config,
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
    for name in ("rti", "rep_mesh_vertices", "rep_mesh_faces"):
        shape = ds[name].shape
        encoding[name].update(zlib=True, complevel=4, chunksizes=(1, *shape[1:]))
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf", encoding=encoding)


def export_g2s(directory: str | Path, out: str | Path) -> int:
    """Write ``out/shard-NNNNN.nc`` for every ``shard-NNNNN.h5``; return the file count.

    Every shard is checked (labels present) before anything is written; files of an earlier
    export with the same names are replaced, any other ``shard-*.nc`` in ``out`` is an error.
    """
    paths = list_shards(directory)
    for p in paths:
        with Shard(p) as s:
            if not s.has_labels:
                raise ShardError(f"{p}: has no radar labels; run `radar-sim label` first")
            s.radar  # noqa: B018 - reading it refuses a malformed /radar before any write
            s.verify()
            s.verify_labels()
    out = Path(out)
    targets = [out / (p.stem + ".nc") for p in paths]
    if out.is_dir():
        others = sorted(set(out.glob(NETCDF_GLOB)) - set(targets))
        if others:
            raise ShardError(
                f"{out}: holds {others[0].name}, not part of this export; choose an empty directory"
            )
    out.mkdir(parents=True, exist_ok=True)
    sizes = padded_sizes(paths)
    fingerprint = dataset_fingerprint(directory)
    for p, target in zip(paths, targets, strict=True):
        with Shard(p) as s:
            ds = shard_dataset(s, sizes, fingerprint)
        _write(ds, target)
    return len(targets)
