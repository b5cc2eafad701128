"""HDF5 shards: the contract between the four packages (docs/ARCHITECTURE.md, "Shards").

Ragged meshes are stored flat with offsets. Files are written byte-deterministically
(no HDF5 timestamps) and atomically (``*.tmp``, fsync, rename) so that a killed job never
leaves a file that reads as a valid shard. This module must not import bpy or torch.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import h5py
import numpy as np

SCHEMA_VERSION = 1
SHARD_GLOB = "shard-*.h5"
TOOLKIT = "basic-shapes"


class ShardError(ValueError):
    """A shard or dataset directory is unreadable, foreign, truncated or inconsistent."""


def shard_name(index: int) -> str:
    return f"shard-{index:05d}.h5"


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path; on success fsync it and rename it onto ``path``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    finally:
        tmp.unlink(missing_ok=True)


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
    split: str  # "train" or "test"
    meshes: list[MeshRecord]
    params: dict = field(default_factory=dict)  # hidden shape parameters (analytic.Solid)


def write_shard(path: str | os.PathLike, objects: list[ObjectRecord], class_names: list[str],
                config: dict, toolkit_version: str) -> None:
    """Write whole objects to one shard, atomically and byte-deterministically."""
    meshes = [m for o in objects for m in o.meshes]
    nv = np.array([len(m.vertices) for m in meshes], dtype=np.int64)
    nf = np.array([len(m.faces) for m in meshes], dtype=np.int64)
    vertices = np.concatenate([np.asarray(m.vertices, np.float32) for m in meshes]).reshape(-1, 3)
    faces = np.concatenate([np.asarray(m.faces, np.int32) for m in meshes]).reshape(-1, 3)
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
            _dataset(g, "params", np.array([json.dumps(o.params, sort_keys=True).encode()
                                            for o in objects], dtype=h5py.string_dtype()))
            g = f.create_group("meshes")
            obj_index = np.repeat(np.arange(len(objects)), [len(o.meshes) for o in objects])
            _dataset(g, "object_index", obj_index.astype(np.int32))
            _dataset(g, "variant", np.array([m.variant for m in meshes], np.int32))
            _dataset(g, "vertex_offset", np.concatenate([[0], np.cumsum(nv)]).astype(np.int64))
            _dataset(g, "face_offset", np.concatenate([[0], np.cumsum(nf)]).astype(np.int64))
            _dataset(g, "n_faces", nf.astype(np.int32))
            _dataset(g, "hausdorff", np.array([m.hausdorff for m in meshes], np.float64))
            _dataset(g, "primitive_distance",
                     np.array([m.primitive_distance for m in meshes], np.float64))
            _dataset(g, "params", np.array([json.dumps(m.params, sort_keys=True).encode()
                                            for m in meshes], dtype=h5py.string_dtype()))
            _dataset(g, "vertices", vertices)
            _dataset(g, "faces", faces)
            f.attrs["fingerprint"] = _fingerprint(f)


def _fingerprint(f: h5py.File) -> str:
    """sha256 over the mesh and object content (not over labels), stable across writes."""
    h = hashlib.sha256()
    for name in ("objects/id", "objects/class", "objects/scale", "objects/split",
                 "meshes/variant", "meshes/vertex_offset", "meshes/face_offset",
                 "meshes/vertices", "meshes/faces"):
        h.update(name.encode())
        h.update(np.ascontiguousarray(f[name][()]).tobytes())
    return h.hexdigest()


class Shard:
    """Read access to one shard. Meshes are read lazily, one slice at a time."""

    REQUIRED = ("objects/id", "objects/class", "objects/scale", "objects/split",
                "meshes/object_index", "meshes/variant", "meshes/vertex_offset",
                "meshes/face_offset", "meshes/vertices", "meshes/faces")

    def __init__(self, path: str | os.PathLike, mode: str = "r"):
        self.path = Path(path)
        try:
            self.file = h5py.File(self.path, mode)
        except OSError as exc:
            raise ShardError(f"{self.path}: not a readable HDF5 shard ({exc.__class__.__name__}: "
                             f"{str(exc).splitlines()[0]})") from None
        try:
            self._validate()
        except Exception:
            self.file.close()
            raise

    def _validate(self) -> None:
        f = self.file
        if f.attrs.get("toolkit") != TOOLKIT:
            raise ShardError(f"{self.path}: not a basic-shapes shard (no toolkit attribute)")
        if int(f.attrs.get("schema_version", -1)) != SCHEMA_VERSION:
            raise ShardError(f"{self.path}: schema version {f.attrs.get('schema_version')} "
                             f"is not the supported {SCHEMA_VERSION}")
        missing = [n for n in self.REQUIRED if n not in f]
        if missing:
            raise ShardError(f"{self.path}: truncated shard, missing {', '.join(missing)}")
        vo, fo = f["meshes/vertex_offset"], f["meshes/face_offset"]
        n = len(f["meshes/variant"])
        if len(vo) != n + 1 or len(fo) != n + 1 or vo[-1] != len(f["meshes/vertices"]) \
                or fo[-1] != len(f["meshes/faces"]):
            raise ShardError(f"{self.path}: mesh offsets do not match the vertex/face arrays")

    def close(self) -> None:
        self.file.close()

    def __enter__(self) -> "Shard":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- metadata ---------------------------------------------------------------------
    @property
    def config(self) -> dict:
        return json.loads(self.file.attrs["generator_config"])

    @property
    def fingerprint(self) -> str:
        return str(self.file.attrs["fingerprint"])

    @property
    def class_names(self) -> list[str]:
        return json.loads(self.file["objects/class"].attrs["names"])

    @property
    def n_objects(self) -> int:
        return len(self.file["objects/id"])

    @property
    def n_meshes(self) -> int:
        return len(self.file["meshes/variant"])

    def objects(self) -> dict[str, np.ndarray]:
        g = self.file["objects"]
        out = {k: g[k][()] for k in ("id", "class", "scale", "seed")}
        out["split"] = np.array([s.decode() for s in g["split"][()]])
        return out

    def mesh_table(self) -> dict[str, np.ndarray]:
        """Per-mesh metadata (no geometry): object_index, variant, n_faces, hausdorff."""
        g = self.file["meshes"]
        return {k: g[k][()] for k in ("object_index", "variant", "n_faces", "hausdorff")}

    # --- geometry ---------------------------------------------------------------------
    def mesh(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(vertices float32 (V,3), faces int32 (F,3)) of mesh ``i`` of this shard."""
        g = self.file["meshes"]
        v0, v1 = g["vertex_offset"][i:i + 2]
        f0, f1 = g["face_offset"][i:i + 2]
        return g["vertices"][v0:v1], g["faces"][f0:f1]

    def mesh_params(self, i: int) -> dict:
        return json.loads(self.file["meshes/params"][i])

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


def list_shards(directory: str | os.PathLike) -> list[Path]:
    d = Path(directory)
    if not d.is_dir():
        raise ShardError(f"{d}: no such dataset directory")
    paths = sorted(d.glob(SHARD_GLOB))
    if not paths:
        raise ShardError(f"{d}: holds no shards ({SHARD_GLOB})")
    return paths


def dataset_fingerprint(directory: str | os.PathLike) -> str:
    """sha256 over the shards' own fingerprints, in shard order."""
    h = hashlib.sha256()
    for p in list_shards(directory):
        with Shard(p) as s:
            h.update(s.fingerprint.encode())
    return h.hexdigest()


def _object(s: Shard, objs: dict, k: int, oi: np.ndarray, var: np.ndarray):
    rows = np.flatnonzero(oi == k)
    meshes = [(int(var[i]), *s.mesh(i)) for i in rows]
    obj = {"id": int(objs["id"][k]), "class": s.class_names[objs["class"][k]],
           "scale": objs["scale"][k], "split": str(objs["split"][k]), "shard_object_index": k,
           "hausdorff": s.file["meshes/hausdorff"][rows[0]:rows[-1] + 1]}
    return obj, meshes


def iter_objects(directory: str | os.PathLike, split: str | None = None):
    """Yield (shard path, object dict, list of (variant, vertices, faces)) per object.

    Only one object's meshes are in memory at a time.
    """
    for p in list_shards(directory):
        with Shard(p) as s:
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
                oi = s.file["meshes/object_index"][()]
                var = s.file["meshes/variant"][()]
                return (p, *_object(s, s.objects(), int(hit[0]), oi, var))
    raise ShardError(f"{directory}: no object with id {object_id}")


def rewrite_atomically(path: str | os.PathLike, edit) -> None:
    """Copy a shard, let ``edit(h5py.File)`` change the copy, then swap it in atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        shutil.copyfile(path, tmp)
        with h5py.File(tmp, "r+") as f:
            edit(f)


MAX_VARIANTS = 1000


def mesh_uid(object_id: int, variant: int) -> int:
    """Global mesh id used to key predictions files: object_id * 1000 + variant."""
    if not 0 <= variant < MAX_VARIANTS:
        raise ValueError(f"variant {variant} outside 0..{MAX_VARIANTS - 1}")
    return int(object_id) * MAX_VARIANTS + int(variant)


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
