"""HDF5 shards: the contract between the four packages (docs/ARCHITECTURE.md, "Shards").

Ragged meshes are stored flat with offsets. Files are written byte-deterministically
(no HDF5 timestamps) and atomically (``*.tmp``, fsync, rename) so that a killed job never
leaves a file that reads as a valid shard. This module must not import bpy or torch.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from basic_shapes.infra import (
    atomic_path,
    load_json,
    one_line,
    open_hdf5,
    require_dataset,
    require_free_space,
)

SCHEMA_VERSION = 2  # 2: /radar with dimension scales, label fingerprint, mesh_*
SHARD_GLOB = "shard-*.h5"
SPLITS = ("train", "test")
TOOLKIT = "basic-shapes"


class ShardError(ValueError):
    """A shard or dataset directory is unreadable, foreign, truncated or inconsistent."""


def shard_name(index: int) -> str:
    return f"shard-{index:05d}.h5"


def _dataset(group: h5py.Group, name: str, data, **kw) -> h5py.Dataset:
    return group.create_dataset(name, data=data, track_times=False, **kw)


@dataclass
class MeshRecord:
    """One mesh of one object, as produced by the generator."""

    variant: int
    vertices: np.ndarray  # (V, 3) float32, metres
    faces: np.ndarray  # (F, 3) int32, 0-based
    hausdorff: float  # two-sided, relative to the bbox diagonal of the simple mesh
    params: dict
    primitive_distance: float = float("nan")  # two-sided to the analytic primitive, same unit


@dataclass
class ObjectRecord:
    id: int
    class_index: int
    scale: np.ndarray  # (3,) bbox extents, metres
    seed: int
    split: str  # "train", "val" or "test"
    meshes: list[MeshRecord]
    params: dict = field(default_factory=dict)  # hidden shape parameters (analytic.Solid)


def write_shard(
    path: str | os.PathLike,
    objects: list[ObjectRecord],
    class_names: list[str],
    config: dict,
    toolkit_version: str,
) -> None:
    """Write whole objects to one shard, atomically and byte-deterministically."""
    meshes = [m for o in objects for m in o.meshes]
    nv = np.array([len(m.vertices) for m in meshes], dtype=np.int64)
    nf = np.array([len(m.faces) for m in meshes], dtype=np.int64)
    vertices = np.concatenate([np.asarray(m.vertices, np.float32) for m in meshes]).reshape(-1, 3)
    faces = np.concatenate([np.asarray(m.faces, np.int32) for m in meshes]).reshape(-1, 3)
    require_free_space(path, vertices.nbytes + faces.nbytes)
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w", libver="earliest") as f:
            f.attrs["schema_version"] = SCHEMA_VERSION
            f.attrs["toolkit"] = TOOLKIT
            f.attrs["toolkit_version"] = toolkit_version
            f.attrs["generator_config"] = json.dumps(config, sort_keys=True)
            g = f.create_group("objects")
            _dataset(g, "id", np.array([o.id for o in objects], np.int64))
            cls = _dataset(g, "class", np.array([o.class_index for o in objects], np.int16))
            cls.attrs["names"] = json.dumps(class_names)
            _dataset(g, "scale", np.array([o.scale for o in objects], np.float64).reshape(-1, 3))
            _dataset(g, "seed", np.array([o.seed for o in objects], np.uint64))
            _dataset(g, "split", np.array([o.split.encode() for o in objects], "S5"))
            _dataset(
                g,
                "params",
                np.array(
                    [json.dumps(o.params, sort_keys=True).encode() for o in objects],
                    dtype=h5py.string_dtype(),
                ),
            )
            g = f.create_group("meshes")
            obj_index = np.repeat(np.arange(len(objects)), [len(o.meshes) for o in objects])
            _dataset(g, "object_index", obj_index.astype(np.int32))
            _dataset(g, "variant", np.array([m.variant for m in meshes], np.int32))
            _dataset(g, "vertex_offset", np.concatenate([[0], np.cumsum(nv)]).astype(np.int64))
            _dataset(g, "face_offset", np.concatenate([[0], np.cumsum(nf)]).astype(np.int64))
            _dataset(g, "n_faces", nf.astype(np.int32))
            _dataset(g, "hausdorff", np.array([m.hausdorff for m in meshes], np.float64))
            _dataset(
                g,
                "primitive_distance",
                np.array([m.primitive_distance for m in meshes], np.float64),
            )
            _dataset(
                g,
                "params",
                np.array(
                    [json.dumps(m.params, sort_keys=True).encode() for m in meshes],
                    dtype=h5py.string_dtype(),
                ),
            )
            _dataset(g, "vertices", vertices)
            _dataset(g, "faces", faces)
            f.attrs["fingerprint"] = content_fingerprint(f)


def content_fingerprint(f: h5py.File) -> str:
    """sha256 over every dataset under /objects and /meshes (name, dtype, shape, bytes), the
    class names and the generator config: a flipped bit anywhere in an object's definition or
    its meshes changes it. Labels have their own (``radar_fingerprint``)."""
    h = hashlib.sha256()
    h.update(str(f.attrs.get("generator_config", "")).encode())
    h.update(str(f["objects/class"].attrs.get("names", "")).encode())
    for group in ("objects", "meshes"):
        for name in sorted(f[group]):
            d = f[group][name]
            h.update(f"\0{group}/{name}\0{d.dtype.str}\0{d.shape}\0".encode())
            data = d[()]
            if data.dtype.kind == "O":  # variable-length strings (JSON parameters)
                for item in data:
                    raw = item if isinstance(item, bytes) else str(item).encode()
                    h.update(len(raw).to_bytes(8, "little"))
                    h.update(raw)
            else:
                h.update(np.ascontiguousarray(data).tobytes())
    return h.hexdigest()


def _readable(method):
    """h5py's errors on a corrupted file (OSError, KeyError, RuntimeError without the file's
    name) become one ShardError naming the shard."""

    @functools.wraps(method)
    def read(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except ShardError:
            raise
        except (OSError, KeyError, RuntimeError, TypeError, ValueError, IndexError) as exc:
            raise ShardError(
                f"{self.path}: unreadable, corrupted or truncated ({one_line(exc)})"
            ) from None

    return read


class Shard:
    """Read access to one shard. Meshes are read lazily, one slice at a time."""

    REQUIRED = (
        "objects/id",
        "objects/class",
        "objects/scale",
        "objects/split",
        "meshes/object_index",
        "meshes/variant",
        "meshes/vertex_offset",
        "meshes/face_offset",
        "meshes/vertices",
        "meshes/faces",
    )

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.file = open_hdf5(self.path, ShardError, "HDF5 shard")
        try:
            self._validate()
        except Exception:
            self.file.close()
            raise

    def _fail(self, problem: str):
        raise ShardError(f"{self.path}: {problem}")

    @_readable
    def _validate(self) -> None:
        """Structure and indices, all checked before any mesh is handed out.

        The opener bounded every declared size by the file's bytes; here the offsets are
        checked completely (start 0, non-decreasing, ending at the array lengths), object
        and class indices are checked in range, and the JSON attributes must parse. Face
        indices are checked per mesh as meshes are read (``mesh``), and for the whole shard,
        with the fingerprint, by ``verify``.
        """
        f = self.file
        if _text_attr(f, "toolkit") != TOOLKIT:
            self._fail("not a basic-shapes shard (no toolkit attribute)")
        if _text_attr(f, "schema_version") != str(SCHEMA_VERSION):
            self._fail(
                f"schema version {_text_attr(f, 'schema_version')} is not the supported "
                f"{SCHEMA_VERSION}"
            )
        missing = [n for n in self.REQUIRED if n not in f]
        if missing:
            self._fail(f"truncated shard, missing {', '.join(missing)}")
        for name in ("generator_config", "fingerprint"):
            if _text_attr(f, name) is None:
                self._fail(f"missing the {name} attribute")
        self._config = load_json(
            _text_attr(f, "generator_config"),
            error=ShardError,
            what=f"{self.path}: generator_config",
        )
        if not isinstance(self._config, dict):
            self._fail("generator_config is not a JSON object")
        self._class_names = load_json(
            _text_attr(f["objects/class"], "names") or "null",
            error=ShardError,
            what=f"{self.path}: /objects/class names",
        )
        if not (
            isinstance(self._class_names, list)
            and self._class_names
            and all(isinstance(c, str) for c in self._class_names)
        ):
            self._fail("/objects/class names is not a non-empty JSON list of strings")
        self._validate_tables()

    def _validate_tables(self) -> None:
        f, err, path = self.file, ShardError, self.path
        n_obj = len(require_dataset(f, "objects/id", "iu", 1, err, path))
        for name, kinds, ndim, tail in (
            ("objects/class", "iu", 1, ()),
            ("objects/scale", "f", 2, (3,)),
            ("objects/split", "SO", 1, ()),
        ):
            if len(require_dataset(f, name, kinds, ndim, err, path, tail)) != n_obj:
                self._fail(f"/{name} has not one row per object ({n_obj})")
        n = len(require_dataset(f, "meshes/variant", "iu", 1, err, path))
        if len(require_dataset(f, "meshes/object_index", "iu", 1, err, path)) != n:
            self._fail(f"/meshes/object_index has not one row per mesh ({n})")
        n_v = len(require_dataset(f, "meshes/vertices", "f", 2, err, path, (3,)))
        n_f = len(require_dataset(f, "meshes/faces", "iu", 2, err, path, (3,)))
        for name, total in (("vertex_offset", n_v), ("face_offset", n_f)):
            off = require_dataset(f, f"meshes/{name}", "i", 1, err, path)[()]
            if len(off) != n + 1 or off[0] != 0 or off[-1] != total or np.any(np.diff(off) < 0):
                self._fail(
                    f"/meshes/{name} is not a valid offset table (n+1 = {n + 1} entries "
                    f"from 0, non-decreasing, ending at {total})"
                )
        cls = f["objects/class"][()]
        if len(cls) and (cls.min() < 0 or cls.max() >= len(self._class_names)):
            self._fail(f"/objects/class holds an index outside 0..{len(self._class_names) - 1}")
        oi = f["meshes/object_index"][()]
        if len(oi) and (oi.min() < 0 or oi.max() >= n_obj):
            self._fail(f"/meshes/object_index holds an index outside 0..{n_obj - 1}")
        var = f["meshes/variant"][()]
        if len(var) and (var.min() < 0 or var.max() >= MAX_VARIANTS):
            self._fail(f"/meshes/variant holds a value outside 0..{MAX_VARIANTS - 1}")

    @_readable
    def verify(self, chunk: int = 1 << 20) -> None:
        """Check every face index against its mesh's vertex count (in chunks of ``chunk``
        faces, so memory stays bounded) and the stored fingerprint against the content.

        Run wherever a job trusts a shard it did not just write (resume, scoring): a shard
        edited with its fingerprint kept must not pass as "already done".
        """
        g = self.file["meshes"]
        vo, fo = g["vertex_offset"][()], g["face_offset"][()]
        n_vertices = np.diff(vo)
        faces = g["faces"]
        for start in range(0, len(faces), chunk):
            block = faces[start : start + chunk]
            mesh = np.searchsorted(fo, np.arange(start, start + len(block)), side="right") - 1
            bad = ((block < 0) | (block >= n_vertices[mesh][:, None])).any(axis=1)
            if bad.any():
                row = start + int(np.flatnonzero(bad)[0])
                self._fail(f"face row {row} indexes a vertex outside its mesh")
        if self.computed_fingerprint() != self.fingerprint:
            self._fail("content does not match its stored fingerprint (edited or corrupted)")

    @_readable
    def verify_labels(self) -> None:
        """The labels (/radar) against their stored fingerprint, where there are labels."""
        if self.has_labels and self.radar.computed_fingerprint() != self.radar.fingerprint:
            self._fail(
                "labels (/radar) do not match their stored fingerprint (edited or "
                "corrupted); relabel with radar-sim label"
            )

    def close(self) -> None:
        self.file.close()

    def __enter__(self) -> Shard:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- metadata ---------------------------------------------------------------------
    @property
    def config(self) -> dict:
        return dict(self._config)

    @property
    def fingerprint(self) -> str:
        return _text_attr(self.file, "fingerprint")

    @property
    def class_names(self) -> list[str]:
        return list(self._class_names)

    @property
    def n_objects(self) -> int:
        return len(self.file["objects/id"])

    @property
    def n_meshes(self) -> int:
        return len(self.file["meshes/variant"])

    @_readable
    def objects(self) -> dict[str, np.ndarray]:
        g = self.file["objects"]
        out = {k: g[k][()] for k in ("id", "class", "scale", "seed")}
        out["split"] = np.array([s.decode() for s in g["split"][()]])
        return out

    @_readable
    def object_params(self) -> list[dict]:
        """Hidden shape parameters per object (``/objects/params``; {} where the shard has none)."""
        raw = self.object_params_text()
        if raw is None:
            return [{} for _ in range(self.n_objects)]
        return [
            load_json(p, what=f"{self.path}: /objects/params[{k}]", error=ShardError)
            for k, p in enumerate(raw)
        ]

    @_readable
    def object_params_text(self) -> np.ndarray | None:
        """``/objects/params`` as stored (JSON bytes per object), None where absent."""
        return self.file["objects/params"][()] if "objects/params" in self.file else None

    @_readable
    def mesh_table(self) -> dict[str, np.ndarray]:
        """Per-mesh metadata (no geometry): object_index, variant, n_vertices, n_faces,
        hausdorff."""
        g = self.file["meshes"]
        out = {k: g[k][()] for k in ("object_index", "variant", "n_faces", "hausdorff")}
        out["n_vertices"] = np.diff(g["vertex_offset"][()])
        return out

    @_readable
    def mesh_measures(self) -> list[np.ndarray]:
        """The generator's per-mesh records as stored: hausdorff, primitive_distance and
        params (JSON bytes), those present, in that order (what a manifest hashes)."""
        g = self.file["meshes"]
        return [g[n][()] for n in ("hausdorff", "primitive_distance", "params") if n in g]

    @_readable
    def computed_fingerprint(self) -> str:
        """``content_fingerprint`` recomputed from the stored content."""
        return content_fingerprint(self.file)

    # --- geometry ---------------------------------------------------------------------
    @_readable
    def mesh(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(vertices float32 (V,3), faces int32 (F,3)) of mesh ``i`` of this shard."""
        g = self.file["meshes"]
        v0, v1 = g["vertex_offset"][i : i + 2]
        f0, f1 = g["face_offset"][i : i + 2]
        vertices, faces = g["vertices"][v0:v1], g["faces"][f0:f1]
        if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
            self._fail(f"mesh {i} has a face index outside its {len(vertices)} vertices")
        return vertices, faces

    def mesh_params(self, i: int) -> dict:
        return load_json(
            self.file["meshes/params"][i], error=ShardError, what=f"{self.path}: mesh {i} params"
        )

    def iter_meshes(self) -> Iterator[tuple[int, int, np.ndarray, np.ndarray]]:
        """Yield (object_index, variant, vertices, faces) for every mesh, in order."""
        oi = self.file["meshes/object_index"][()]
        var = self.file["meshes/variant"][()]
        for i in range(self.n_meshes):
            v, f = self.mesh(i)
            yield int(oi[i]), int(var[i]), v, f

    def simple_mesh_index(self) -> np.ndarray:
        """Index of the variant-0 (simple) mesh of each object."""
        var = self.file["meshes/variant"][()]
        oi = self.file["meshes/object_index"][()]
        idx = np.full(self.n_objects, -1, np.int64)
        sel = np.flatnonzero(var == 0)
        idx[oi[sel]] = sel
        return idx

    # --- radar labels -----------------------------------------------------------------
    @property
    def has_labels(self) -> bool:
        return "radar/response" in self.file

    @property
    def has_radar(self) -> bool:
        """A /radar group, complete or not (``radar`` says what is missing)."""
        return "radar" in self.file

    @functools.cached_property
    @_readable
    def radar(self) -> RadarGroup:
        """The ``/radar`` group (labels), validated once; ``ShardError`` if absent or malformed."""
        return RadarGroup(self)


def _text_attr(obj, name: str) -> str | None:
    value = obj.attrs.get(name)
    if isinstance(value, bytes):
        value = value.decode(errors="replace")
    return None if value is None else str(value)


def list_shards(directory: str | os.PathLike) -> list[Path]:
    d = Path(directory)
    if not d.is_dir():
        raise ShardError(f"{d}: no such dataset directory")
    paths = sorted(d.glob(SHARD_GLOB))
    if not paths:
        raise ShardError(f"{d}: holds no shards ({SHARD_GLOB})")
    return paths


def dataset_fingerprint(directory: str | os.PathLike) -> str:
    """sha256 over the shards' own fingerprints, in shard order, each verified (``Shard.verify``)
    against its shard's content: scoring and submission rely on this identity."""
    h = hashlib.sha256()
    for p in list_shards(directory):
        with Shard(p) as s:
            s.verify()
            h.update(s.fingerprint.encode())
    return h.hexdigest()


def label_fingerprint(directory: str | os.PathLike) -> str:
    """sha256 over the shards' label fingerprints, in shard order, each recomputed from the
    stored labels and compared with the one stored (``ShardError`` if unlabelled or edited):
    scoring, training, resuming and submission all come through here."""
    h = hashlib.sha256()
    for p in list_shards(directory):
        with Shard(p) as s:
            labels = s.radar  # ShardError if unlabelled
            s.verify_labels()
            h.update(labels.fingerprint.encode())
    return h.hexdigest()


def _object(s: Shard, objs: dict, k: int, oi: np.ndarray, var: np.ndarray):
    rows = np.flatnonzero(oi == k)
    meshes = [(int(var[i]), *s.mesh(i)) for i in rows]
    obj = {
        "id": int(objs["id"][k]),
        "class": s.class_names[objs["class"][k]],
        "scale": objs["scale"][k],
        "split": str(objs["split"][k]),
        "shard_object_index": k,
        "hausdorff": s.file["meshes/hausdorff"][rows[0] : rows[-1] + 1],
    }
    return obj, meshes


def iter_objects(directory: str | os.PathLike, split: str | None = None):
    """Yield (shard path, object dict, list of (variant, vertices, faces)) per object.

    Only one object's meshes are in memory at a time. ``split`` must be one of ``SPLITS``.
    """
    if split is not None and split not in SPLITS:
        raise ValueError(f"split must be one of {', '.join(SPLITS)} (or None), got {split!r}")
    for p in list_shards(directory):
        with Shard(p) as s:
            s.verify()  # readers never hand out a mesh whose bytes were changed
            objs = s.objects()
            oi = s.file["meshes/object_index"][()]
            var = s.file["meshes/variant"][()]
            for k in range(s.n_objects):
                if split is None or objs["split"][k] == split:
                    yield (p, *_object(s, objs, k, oi, var))


def find_object(directory: str | os.PathLike, object_id: int):
    """(shard path, object dict, meshes) of one object, reading only the shard that holds it."""
    for p in list_shards(directory):
        with Shard(p) as s:
            ids = s.file["objects/id"][()]
            hit = np.flatnonzero(ids == object_id)
            if len(hit):
                s.verify()
                s.verify_labels()
                oi = s.file["meshes/object_index"][()]
                var = s.file["meshes/variant"][()]
                return (p, *_object(s, s.objects(), int(hit[0]), oi, var))
    raise ShardError(f"{directory}: no object with id {object_id}")


def rewrite_atomically(path: str | os.PathLike, edit) -> None:
    """Copy a shard, let ``edit(h5py.File)`` change the copy, then swap it in atomically."""
    path = Path(path)
    require_free_space(path, path.stat().st_size)
    with atomic_path(path) as tmp:
        shutil.copyfile(path, tmp)
        with h5py.File(tmp, "r+") as f:
            edit(f)


MAX_VARIANTS = 1000


def mesh_uid(object_id: int, variant: int) -> int:
    """Global mesh id used to key predictions files: object_id * 1000 + variant."""
    if not 0 <= variant < MAX_VARIANTS:
        raise ValueError(f"variant {variant} outside 0..{MAX_VARIANTS - 1}")
    if object_id < 0:
        raise ValueError(f"object id {object_id} is negative")
    return int(object_id) * MAX_VARIANTS + int(variant)


# --- the /radar group (labels): its only reader and writer -------------------------------------
RADAR_DIMS = {
    "object": ("object id (/objects/id)", None),
    "aspect": ("aspect angle", "degree"),
    "roll": ("roll angle", "degree"),
    "range": ("down-range distance", "m"),
    "frequency": ("frequency", "Hz"),
    "mesh": ("mesh row (/meshes)", None),
    "polarization": ("polarization channel, transmit then receive (H = phi, V = theta)", None),
}
"""Dimension scales of /radar: name -> (long_name, units). Coordinates of every label array."""
RADAR_ARRAYS = {
    "response": ("object", "aspect", "roll", "range"),
    "frequency_response": ("object", "aspect", "roll", "frequency"),
    "mode": ("object",),
    "mesh_response": ("mesh", "aspect", "roll", "range"),
    "mesh_mode": ("mesh",),
    "polarimetric": ("object", "polarization", "aspect", "roll", "range"),
}
_PROFILE = "complex range profile, VV: the square of its modulus is the RCS in each range bin"
RADAR_VARIABLES = {
    "response": (f"{_PROFILE} (the object's label)", "m"),
    "frequency_response": ("complex scattering amplitude per frequency, VV (sqrt of RCS)", "m"),
    "mode": ("simulation mode of the object's label (radar_sim.label.MODES)", None),
    "mesh_response": (f"{_PROFILE} (of one stored mesh, /radar/mesh)", "m"),
    "mesh_mode": ("simulation mode of the mesh's label", None),
    "polarimetric": (_PROFILE.replace("VV", "per polarization channel"), "m"),
}
"""Label arrays of /radar: name -> (long_name, units), CF attributes from SHARD_FORMAT 2 on."""
SHARD_FORMAT = 2
"""How /radar is written. 1: the label arrays carry no long_name or units (every version
recorded up to hidden-cpu-v3 keeps it, so it rebuilds to its recorded file sha256);
2: they carry RADAR_VARIABLES' CF attributes. Only the bytes differ, never a fingerprint."""


def radar_fingerprint(
    config_json: str,
    rule_json: str,
    responses,
    mesh_index=(),
    mesh_responses=(),
    channels=(),
    channel_responses=(),
) -> str:
    """sha256 over the radar config, the simulation-mesh rule and the stored label bytes: the
    /radar/response rows in object order, then the per-mesh physics (its mesh rows and
    /radar/mesh_response rows) where stored, then every polarization channel (their names
    and /radar/polarimetric rows) where stored; complex64, C order. Rows are iterables, so a
    writer hashes while streaming and a reader recomputes it from the stored datasets."""
    h = hashlib.sha256()
    for part in (config_json, rule_json):
        h.update(part.encode())
        h.update(b"\0")
    for row in responses:
        h.update(np.ascontiguousarray(row, np.complex64).tobytes())
    mesh_index = np.asarray(mesh_index, np.int64)
    if len(mesh_index):
        h.update(b"\0mesh\0" + mesh_index.tobytes())
        for row in mesh_responses:
            h.update(np.ascontiguousarray(row, np.complex64).tobytes())
    if len(channels):
        h.update(b"\0polarimetric\0" + ",".join(channels).encode())
        for row in channel_responses:
            h.update(np.ascontiguousarray(row, np.complex64).tobytes())
    return h.hexdigest()


class RadarGroup:
    """Read access to ``/radar``: coordinates, request attributes, labels read per object.

    ``response(k)`` is the object's label: the physics of its analytic primitive on the
    simulation mesh (the VV channel). ``polarimetric(k)`` holds every channel of a
    polarimetric config (``channels``). ``mesh_response(j)`` is the physics of one stored
    representation mesh (row ``mesh_index[j]``), stored when labelling with ``--mesh-labels``.
    """

    def __init__(self, shard: Shard):
        f, self.path = shard.file, shard.path
        if "radar" not in f:
            raise ShardError(f"{self.path}: no radar labels (/radar); run `radar-sim label` first")
        self.group = g = f["radar"]
        required = ["object", "aspect", "roll", "range", "frequency", "response", "mode"]
        if "mesh_response" in g or "mesh" in g:
            required += ["mesh", "mesh_response", "mesh_mode"]
        if "polarimetric" in g or "polarization" in g:
            required += ["polarization", "polarimetric"]
        missing = [n for n in required if n not in g]
        if missing:
            raise ShardError(f"{self.path}: truncated /radar group, missing {', '.join(missing)}")
        coords = {n: g[n][()] for n in RADAR_DIMS if n in g}
        self.object_ids = coords["object"]
        self.aspect_deg, self.roll_deg = coords["aspect"], coords["roll"]
        self.range_m, self.frequency_hz = coords["range"], coords["frequency"]
        self.mesh_index = coords.get("mesh", np.zeros(0, np.int64))
        self.channels = tuple(c.decode() for c in coords.get("polarization", [b"VV"]))
        if not np.array_equal(self.object_ids, f["objects/id"][()]):
            raise ShardError(f"{self.path}: /radar/object does not list the shard's objects")
        for name, dims in RADAR_ARRAYS.items():
            if name in g:
                expected = tuple(len(coords[d]) for d in dims)
                d, complex_ = g[name], name.endswith("response")
                if d.shape != expected or complex_ and d.dtype.kind != "c":
                    raise ShardError(
                        f"{self.path}: /radar/{name} is {d.dtype}{d.shape}, expected "
                        f"{'complex' if complex_ else ''}{expected}"
                    )
        n_meshes = len(f["meshes/variant"])
        rows = self.mesh_index
        if len(rows) and (rows.min() < 0 or rows.max() >= n_meshes):
            raise ShardError(f"{self.path}: /radar/mesh holds rows outside 0..{n_meshes - 1}")

    # attributes -----------------------------------------------------------------------------
    def _json(self, name: str) -> dict:
        value = _text_attr(self.group, name)
        if value is None:
            raise ShardError(f"{self.path}: /radar attribute {name!r} missing")
        return load_json(value, error=ShardError, what=f"{self.path}: /radar attribute {name!r}")

    @property
    def config(self) -> dict:
        """The radar config (``RadarConfig`` fields) the labels were computed with."""
        return self._json("config")

    @property
    def options(self) -> dict:
        return self._json("options")

    @property
    def simulation_rule(self) -> dict:
        return self._json("simulation_rule")

    @property
    def fingerprint(self) -> str:
        """``radar_fingerprint`` of these labels, as stored when they were written."""
        value = self.group.attrs.get("label_fingerprint")
        if not isinstance(value, str):
            raise ShardError(f"{self.path}: /radar has no label_fingerprint attribute")
        return value

    def computed_fingerprint(self) -> str:
        """The fingerprint recomputed from the stored content (reads every label once)."""
        rows = (self.group["response"][k] for k in range(len(self.object_ids)))
        mesh_rows = (self.group["mesh_response"][j] for j in range(len(self.mesh_index)))
        polarimetric = "polarimetric" in self.group
        return radar_fingerprint(
            _text_attr(self.group, "config") or "",
            _text_attr(self.group, "simulation_rule") or "",
            rows,
            self.mesh_index,
            mesh_rows,
            self.channels if polarimetric else (),
            (self.polarimetric(k) for k in range(len(self.object_ids))) if polarimetric else (),
        )

    # labels -----------------------------------------------------------------------------------
    @property
    def coordinates(self) -> dict[str, np.ndarray]:
        return {
            "aspect_deg": self.aspect_deg,
            "roll_deg": self.roll_deg,
            "range_m": self.range_m,
            "frequency_hz": self.frequency_hz,
        }

    @property
    def modes(self) -> list[str]:
        return [m.decode() for m in self.group["mode"][()]]

    def response(self, k: int) -> np.ndarray:
        """Range profiles (aspect, roll, range) complex64 of the shard's object ``k``."""
        return self.group["response"][k]

    @property
    def has_frequency_response(self) -> bool:
        return "frequency_response" in self.group

    def frequency_response(self, k: int) -> np.ndarray:
        """(aspect, roll, frequency) complex64 of object ``k`` (``--frequency-response``)."""
        if not self.has_frequency_response:
            raise ShardError(f"{self.path}: labelled without --frequency-response")
        return self.group["frequency_response"][k]

    @property
    def mesh_modes(self) -> list[str]:
        return [m.decode() for m in self.group["mesh_mode"][()]] if len(self.mesh_index) else []

    def mesh_response(self, j: int) -> np.ndarray:
        """Range profiles of the representation mesh in row ``mesh_index[j]`` of /meshes."""
        return self.group["mesh_response"][j]

    @property
    def has_polarimetric(self) -> bool:
        """Whether every channel of a polarimetric config is stored (``polarimetric``)."""
        return "polarimetric" in self.group

    def polarimetric(self, k: int) -> np.ndarray:
        """(polarization, aspect, roll, range) complex64 of object ``k``, channels ``channels``."""
        if not self.has_polarimetric:
            raise ShardError(
                f"{self.path}: labelled with the VV channel only (no /radar/polarimetric)"
            )
        return self.group["polarimetric"][k]


def write_radar(
    f: h5py.File,
    *,
    attrs: dict[str, str],
    coordinates: dict[str, np.ndarray],
    object_ids: np.ndarray,
    modes: list[str],
    responses,
    frequency_responses=None,
    mesh_index=None,
    mesh_modes=None,
    mesh_responses=None,
    channels=None,
    channel_responses=None,
    shard_format: int = SHARD_FORMAT,
) -> str:
    """Write ``/radar`` into an open shard (replacing any); return its label fingerprint.

    ``attrs`` must hold ``config`` and ``simulation_rule`` (JSON); ``coordinates`` the keys
    of ``RadarGroup.coordinates``. The per-object and per-mesh label arguments are iterables
    consumed one row at a time, so a shard's labels never need to be in memory at once.
    ``channels`` (names) and ``channel_responses`` store every polarization channel.
    Every array gets HDF5 dimension scales with units (and, from ``shard_format`` 2, its own
    long_name and units), which makes the group a NetCDF-4 group:
    ``xarray.open_dataset(shard, engine="h5netcdf", group="radar")`` names its dimensions
    (object, aspect, roll, range, frequency, mesh).
    """
    if "radar" in f:
        del f["radar"]
    g = f.create_group("radar")
    for key, value in attrs.items():
        g.attrs[key] = value
    coords = {
        "object": np.asarray(object_ids, np.int64),
        "aspect": coordinates["aspect_deg"],
        "roll": coordinates["roll_deg"],
        "range": coordinates["range_m"],
        "frequency": coordinates["frequency_hz"],
    }
    if mesh_index is not None:
        coords["mesh"] = np.asarray(mesh_index, np.int64)
    if channels is not None:
        coords["polarization"] = [c.encode() for c in channels]
    strings = h5py.string_dtype()
    for name, data in coords.items():
        dtype = {"object": np.int64, "mesh": np.int64, "polarization": strings}.get(name)
        d = _dataset(g, name, np.asarray(data, dtype or np.float64), dtype=dtype or np.float64)
        d.make_scale(name)
        long_name, units = RADAR_DIMS[name]
        d.attrs["long_name"] = long_name
        if units:
            d.attrs["units"] = units

    def array(name: str, rows, dtype):
        dims = RADAR_ARRAYS[name]
        d = g.create_dataset(
            name,
            (len(coords[dims[0]]), *(len(coords[x]) for x in dims[1:])),
            dtype,
            track_times=False,
        )
        for axis, dim in enumerate(dims):
            d.dims[axis].attach_scale(g[dim])
        if shard_format >= 2:
            long_name, units = RADAR_VARIABLES[name]
            d.attrs["long_name"] = long_name
            if units:
                d.attrs["units"] = units
        for i, row in enumerate(rows):
            d[i] = row if dtype is strings else np.asarray(row, dtype)
        return d

    response = array("response", responses, np.complex64)
    array("mode", [m.encode() for m in modes], strings)
    if frequency_responses is not None:
        array("frequency_response", frequency_responses, np.complex64)
    if mesh_index is not None:
        array("mesh_response", mesh_responses, np.complex64)
        array("mesh_mode", [m.encode() for m in mesh_modes], strings)
    if channels is not None:
        array("polarimetric", channel_responses, np.complex64)
    mesh_rows = g["mesh_response"] if mesh_index is not None else ()
    channel_rows = g["polarimetric"] if channels is not None else ()
    fingerprint = radar_fingerprint(
        attrs["config"],
        attrs["simulation_rule"],
        (response[k] for k in range(len(response))),
        coords.get("mesh", ()),
        (mesh_rows[j] for j in range(len(mesh_rows))),
        channels or (),
        (channel_rows[k] for k in range(len(channel_rows))),
    )
    g.attrs["label_fingerprint"] = fingerprint
    return fingerprint


OOD_REMESHERS = ("isotropic", "qem", "delaunay")
"""Remeshers of the out-of-distribution test meshes (basic_shapes/remesh.py), in slot order."""
OOD_FIRST = 900
"""Variants OOD_FIRST..MAX_VARIANTS-1 are reserved for OOD meshes, never training variants."""
OOD_SLOT = 25
"""Variant numbers per remesher: remesher r owns OOD_FIRST + r * OOD_SLOT + (0..OOD_SLOT-1)."""


def is_ood_variant(variant) -> bool | np.ndarray:
    """Whether a variant number (or array of them) is an out-of-distribution test mesh."""
    v = np.asarray(variant)
    out = (v >= OOD_FIRST) & (v < MAX_VARIANTS)
    return bool(out) if out.ndim == 0 else out


def ood_remesher(variant: int) -> str | None:
    """The remesher that made an OOD variant (None for the simple mesh and training variants)."""
    if not is_ood_variant(variant):
        return None
    return OOD_REMESHERS[(int(variant) - OOD_FIRST) // OOD_SLOT]


def ood_variant(remesher: str, k: int) -> int:
    """Variant number of the k-th OOD mesh of ``remesher`` (0 <= k < OOD_SLOT)."""
    if remesher not in OOD_REMESHERS:
        raise ValueError(f"unknown remesher {remesher!r}; known: {', '.join(OOD_REMESHERS)}")
    if not 0 <= k < OOD_SLOT:
        raise ValueError(f"OOD mesh index {k} outside 0..{OOD_SLOT - 1}")
    return OOD_FIRST + OOD_REMESHERS.index(remesher) * OOD_SLOT + k
