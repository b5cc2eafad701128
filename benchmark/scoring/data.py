"""Torch-free readers over labelled shards: splits, dB targets, normalized meshes, scale bins.

What a model sees (docs/BENCHMARK.md, "Inputs"):

* the mesh scale-normalized: ``(v - c) / s`` with ``c`` the centre of the mesh's own bounding
  box and ``s`` the largest extent of the object's scale (``/objects/scale``, the same for
  every variant of an object), so the longest axis spans [-0.5, 0.5];
* the scale itself, in metres and discretized per axis into ``ScaleBins`` (32 log-spaced
  bins over the dataset's generator scale range);
* the target: the object's range profiles in dB, ``T = 20 log10(max(|profile|, 1e-4))``.

Only small per-mesh metadata is held in memory; meshes and labels are read on demand, so
the readers work on datasets of any size. ``BasicShapes`` is the torch dataset (the one path
training reads through), with an optional PyTorch Geometric view; torch is imported only
inside it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from basic_shapes.scales import SCALE_RANGE
from basic_shapes.shards import (
    Shard,
    ShardError,
    dataset_fingerprint,
    is_ood_variant,
    label_fingerprint,
    list_shards,
    mesh_uid,
    ood_remesher,
)

FLOOR_AMPLITUDE = 1e-4
FLOOR_DB = -80.0
SPLITS = ("train", "val", "test")
VARIANTS = ("simple", "all")
GRID_NAMES = ("aspect_deg", "roll_deg", "range_m")


def db_target(response: np.ndarray) -> np.ndarray:
    """The benchmark target: 20 log10 of the field amplitude, floored at -80 dB (float32)."""
    amplitude = np.abs(np.asarray(response, np.complex128))
    return (20.0 * np.log10(np.maximum(amplitude, FLOOR_AMPLITUDE))).astype(np.float32)


def normalize_mesh(vertices: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
    """Centre on the mesh's bbox centre and divide by the largest object extent (float32).

    ``scale`` is the object's bbox extents in metres; by default the mesh's own extents.
    Using the object's scale (identical for all variants) keeps the divisor independent of
    how the object happens to be meshed.
    """
    v = np.asarray(vertices, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ValueError(f"vertices must be a non-empty (V, 3) array, got shape {v.shape}")
    lo, hi = v.min(axis=0), v.max(axis=0)
    extent = float(np.max(hi - lo if scale is None else np.asarray(scale, np.float64)))
    if not np.isfinite(extent) or extent <= 0 or not np.all(np.isfinite(v)):
        raise ValueError("cannot normalize a mesh with non-finite vertices or zero extent")
    return ((v - (lo + hi) / 2) / extent).astype(np.float32)


@dataclass(frozen=True)
class ScaleBins:
    """Per-axis scale discretization: ``n`` bins with log-spaced edges from ``lo`` to ``hi`` m.

    Bin ``i`` holds scales in [edges[i], edges[i+1]); scales below ``lo`` fall in bin 0 and
    scales at or above ``hi`` in bin ``n-1``. The default spans the generator's scale range
    (``basic_shapes.scales.SCALE_RANGE``, 0.2-2 m: each of the 32 bins is about 7.5% wide);
    ``for_config`` follows the range a dataset was generated with.
    """

    lo: float = SCALE_RANGE[0]
    hi: float = SCALE_RANGE[1]
    n: int = 32

    @classmethod
    def for_config(cls, generator_config: dict, n: int = 32) -> ScaleBins:
        lo, hi = generator_config.get("scale_range", SCALE_RANGE)
        return cls(float(lo), float(hi), n)

    def __post_init__(self):
        if not (0 < self.lo < self.hi) or self.n < 1:
            raise ValueError(f"bad scale bins: lo={self.lo}, hi={self.hi}, n={self.n}")

    @property
    def edges(self) -> np.ndarray:
        return np.geomspace(self.lo, self.hi, self.n + 1)

    def index(self, scale: np.ndarray) -> np.ndarray:
        """Bin index (int64) of every element of ``scale`` (metres)."""
        idx = np.searchsorted(self.edges, np.asarray(scale, np.float64), side="right") - 1
        return np.clip(idx, 0, self.n - 1).astype(np.int64)

    def centre(self, index: np.ndarray) -> np.ndarray:
        """Geometric centre (metres) of bin ``index``."""
        e = self.edges
        i = np.asarray(index)
        return np.sqrt(e[i] * e[i + 1])


class BenchmarkData:
    """An index over a directory of labelled shards.

    ``objects`` and ``meshes`` are dicts of equal-length arrays (global rows across shards):
    objects: shard, row, id, class_index, scale (n,3), split;
    meshes: shard, row, object (row into objects), variant, n_faces, uid, ood.
    Shard files are opened lazily, once per process (safe with DataLoader workers).
    """

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        self.paths = list_shards(self.directory)
        objects, meshes, grid, names, config = [], [], None, None, None
        n_obj = 0
        for k, path in enumerate(self.paths):
            with Shard(path) as s:
                g = self._read_grid(s)
                if grid is None:
                    grid, names, config = g, s.class_names, s.config
                elif not all(np.array_equal(grid[n], g[n]) for n in GRID_NAMES):
                    raise ShardError(f"{path}: radar grid differs from {self.paths[0].name}")
                elif s.class_names != names:
                    raise ShardError(f"{path}: class names {s.class_names} differ from {names}")
                o, m = s.objects(), s.mesh_table()
                objects.append(
                    {
                        "shard": np.full(len(o["id"]), k, np.int32),
                        "row": np.arange(len(o["id"]), dtype=np.int64),
                        "id": o["id"],
                        "class_index": o["class"].astype(np.int64),
                        "scale": o["scale"],
                        "split": o["split"],
                    }
                )
                meshes.append(
                    {
                        "shard": np.full(len(m["variant"]), k, np.int32),
                        "row": np.arange(len(m["variant"]), dtype=np.int64),
                        "object": m["object_index"].astype(np.int64) + n_obj,
                        "variant": m["variant"].astype(np.int64),
                        "n_faces": m["n_faces"].astype(np.int64),
                    }
                )
                n_obj += len(o["id"])
        self.objects = {key: np.concatenate([o[key] for o in objects]) for key in objects[0]}
        self.meshes = {key: np.concatenate([m[key] for m in meshes]) for key in meshes[0]}
        self.grid, self.class_names, self.config = grid, names, config
        self.target_shape = tuple(len(grid[n]) for n in GRID_NAMES)
        self.scale_bins = ScaleBins.for_config(config)
        self._check_index()
        self.meshes["uid"] = np.array(
            [
                mesh_uid(i, v)
                for i, v in zip(self.objects["id"][self.meshes["object"]], self.meshes["variant"])
            ],
            np.int64,
        )
        order = np.lexsort((self.meshes["variant"], self.meshes["object"]))
        self.meshes["ood"] = is_ood_variant(self.meshes["variant"])
        self._by_object, self._ood_by_object = (  # OOD meshes never reach meshes_of/mesh_rows
            np.split(
                rows, np.cumsum(np.bincount(self.meshes["object"][rows], minlength=n_obj))[:-1]
            )
            for rows in (order[~self.meshes["ood"][order]], order[self.meshes["ood"][order]])
        )
        self._handles: dict[int, Shard] = {}
        self._pid = os.getpid()

    @staticmethod
    def _read_grid(s: Shard) -> dict[str, np.ndarray]:
        if not s.has_labels:
            raise ShardError(
                f"{s.path}: no radar labels (/radar/response); "
                f"run `radar-sim label` on the dataset first"
            )
        coords = s.radar.coordinates  # validates the group's shapes
        return {n: coords[n] for n in GRID_NAMES}

    def _check_index(self) -> None:
        ids = self.objects["id"]
        if len(np.unique(ids)) != len(ids):
            raise ShardError(f"{self.directory}: object ids are not unique across shards")
        bad = sorted(set(self.objects["split"]) - set(SPLITS))
        if bad:
            raise ShardError(f"{self.directory}: unknown split names {bad}")
        simple = np.zeros(len(ids), bool)
        simple[self.meshes["object"][self.meshes["variant"] == 0]] = True
        if not simple.all():
            oid = int(ids[np.flatnonzero(~simple)[0]])
            raise ShardError(f"{self.directory}: object {oid} has no simple mesh (variant 0)")

    # --- metadata -------------------------------------------------------------------------
    @cached_property
    def fingerprint(self) -> str:
        """sha256 of the shards' mesh content (``basic_shapes.shards.dataset_fingerprint``)."""
        return dataset_fingerprint(self.directory)

    @cached_property
    def label_fingerprint(self) -> str:
        """sha256 of the labels: radar config, simulation-mesh rule, stored label bytes
        (``basic_shapes.shards.label_fingerprint``)."""
        return label_fingerprint(self.directory)

    def object_rows(self, split: str | None = None) -> np.ndarray:
        """Global object rows of a split (all objects if ``split`` is None)."""
        if split is None:
            return np.arange(len(self.objects["id"]))
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        return np.flatnonzero(self.objects["split"] == split)

    def test_objects(self) -> np.ndarray:
        """Global object rows of the test split; ``ShardError`` if there are none to score."""
        rows = self.object_rows("test")
        if not len(rows):
            raise ShardError(f"{self.directory}: the dataset has no test-split objects")
        return rows

    def mesh_rows(self, split: str | None = None, variants: str = "all") -> np.ndarray:
        """Global mesh rows of a split, object by object, simple mesh first."""
        if variants not in VARIANTS:
            raise ValueError(f"variants must be one of {VARIANTS}, got {variants!r}")
        rows = [self.meshes_of(o) for o in self.object_rows(split)]
        if variants == "simple":
            rows = [r[:1] for r in rows]
        return np.concatenate(rows) if rows else np.zeros(0, np.int64)

    def meshes_of(self, obj: int) -> np.ndarray:
        """Global mesh rows of object row ``obj``, sorted by variant (simple first), without its
        out-of-distribution meshes (``ood_meshes_of``), which no training reader may see."""
        return self._by_object[obj]

    def ood_meshes_of(self, obj: int) -> np.ndarray:
        """Global rows of object row ``obj``'s OOD test meshes (variants 900-999), by variant;
        the remesher of each is ``basic_shapes.shards.ood_remesher(variant)``."""
        return self._ood_by_object[obj]

    # --- content --------------------------------------------------------------------------
    def _shard(self, k: int) -> Shard:
        if self._pid != os.getpid():  # forked DataLoader worker: never share HDF5 handles
            self._handles, self._pid = {}, os.getpid()
        if k not in self._handles:
            self._handles[k] = Shard(self.paths[k])
        return self._handles[k]

    def mesh(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        """Raw (vertices float32 metres, faces int32) of global mesh row ``row``."""
        return self._shard(int(self.meshes["shard"][row])).mesh(int(self.meshes["row"][row]))

    def object_params(self) -> list[dict]:
        """Hidden shape parameters of every object row ({} on Basic Shapes), shard by shard."""
        per_shard = {}
        out = []
        for s, r in zip(self.objects["shard"], self.objects["row"]):
            if int(s) not in per_shard:
                per_shard[int(s)] = self._shard(int(s)).object_params()
            out.append(per_shard[int(s)][int(r)])
        return out

    def target(self, obj: int) -> np.ndarray:
        """dB target (n_aspect, n_roll, n_range) float32 of global object row ``obj``."""
        shard = self._shard(int(self.objects["shard"][obj]))
        t = db_target(shard.radar.response(int(self.objects["row"][obj])))
        if not np.all(np.isfinite(t)):
            raise ShardError(
                f"{shard.path}: non-finite radar label for object {int(self.objects['id'][obj])}"
            )
        return t

    def batch(self, rows: np.ndarray, scale_bins: ScaleBins | None = None) -> dict:
        """The protocol batch (docs/BENCHMARK.md) for global mesh rows ``rows``.

        Scale bins default to the dataset's own (``self.scale_bins``).
        """
        scale_bins = scale_bins or self.scale_bins
        verts, faces = [], []
        scale = self.objects["scale"][self.meshes["object"][rows]].astype(np.float64)
        for r, s in zip(rows, scale):
            v, f = self.mesh(int(r))
            try:
                verts.append(normalize_mesh(v, s))
            except ValueError as exc:
                raise ShardError(
                    f"{self.paths[self.meshes['shard'][r]]}: mesh_uid "
                    f"{self.meshes['uid'][r]}: {exc}"
                ) from None
            faces.append(np.asarray(f, np.int64))
        return {
            "vertices": verts,
            "faces": faces,
            "scale_bins": scale_bins.index(scale).reshape(-1, 3),
            "scale_m": scale,
        }

    def close(self) -> None:
        for s in self._handles.values():
            s.close()
        self._handles = {}

    def __enter__(self) -> BenchmarkData:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_handles": {}}

    def describe(self) -> str:
        n_val, n_test = (len(self.object_rows(s)) for s in ("val", "test"))
        return (
            f"{self.directory}: {len(self.paths)} shards, {len(self.objects['id'])} objects "
            f"({n_val} val, {n_test} test), {len(self.meshes['uid'])} meshes, classes "
            f"{json.dumps(self.class_names)}, target grid {self.target_shape}"
        )


class BasicShapes:
    """Map-style PyTorch dataset of one split: ``BasicShapes(root, split="train",
    variants="simple")`` (what Basic trains on) or ``variants="all"`` (Ideal; every mesh, and
    on the test split the out-of-distribution meshes too: every mesh that is scored).

    ``root`` is a directory of labelled shards (or an open ``BenchmarkData``); ``split`` is
    "train", "val" or "test" (by object; see docs/BENCHMARK.md). Item: dict of tensors
    ``vertices`` (V,3) float32 normalized, ``faces`` (F,3) int64, ``scale_bins`` (3,) int64,
    ``scale_m`` (3,) float32, ``target`` (n_aspect, n_roll, n_range) float32 dB,
    ``class_index``, ``object_id``, ``mesh_uid`` and ``variant`` int64 scalars, ``remesher``
    (the OOD remesher's name, "" for the generator's own meshes); ``transform`` (e.g.
    ``BasicShapes.to_pyg``) is applied to it. Meshes are ragged: batch with
    ``collate_meshes`` (or PyG's ``DataLoader`` on the ``to_pyg`` view).
    """

    def __init__(
        self,
        root: BenchmarkData | str | os.PathLike,
        split: str = "train",
        variants: str = "simple",
        scale_bins: ScaleBins | None = None,
        transform=None,
    ):
        self.data = root if isinstance(root, BenchmarkData) else BenchmarkData(root)
        self.split, self.variants = split, variants
        self.rows = self.data.mesh_rows(split, variants)
        if variants == "all" and split == "test":  # scored, never trained on
            self.rows = np.concatenate(
                [self.rows, *(self.data.ood_meshes_of(o) for o in self.data.object_rows(split))]
            )
            self.rows = self.rows[
                np.lexsort(
                    (self.data.meshes["variant"][self.rows], self.data.meshes["object"][self.rows])
                )
            ]
        self.scale_bins = scale_bins or self.data.scale_bins
        self.transform = transform
        self._last: tuple[int, np.ndarray] | None = None  # consecutive meshes share a target

    def __len__(self) -> int:
        return len(self.rows)

    def __repr__(self) -> str:
        return (
            f"BasicShapes({self.data.directory}, split={self.split!r}, "
            f"variants={self.variants!r}, n={len(self)})"
        )

    def object_of(self, i: int) -> int:
        """Global object row of item ``i`` (items of one object are consecutive)."""
        return int(self.data.meshes["object"][self.rows[i]])

    def target(self, obj: int) -> np.ndarray:
        if self._last is None or self._last[0] != obj:
            self._last = (obj, self.data.target(obj))
        return self._last[1]

    def __getitem__(self, i: int) -> dict:
        import torch

        row = int(self.rows[i])
        obj = self.object_of(i)
        variant = int(self.data.meshes["variant"][row])
        b = self.data.batch(np.array([row]), self.scale_bins)
        item = {
            "vertices": torch.from_numpy(b["vertices"][0]),
            "faces": torch.from_numpy(b["faces"][0]),
            "scale_bins": torch.from_numpy(b["scale_bins"][0]),
            "scale_m": torch.from_numpy(b["scale_m"][0].astype(np.float32)),
            "target": torch.from_numpy(self.target(obj)),
            "class_index": torch.tensor(int(self.data.objects["class_index"][obj])),
            "object_id": torch.tensor(int(self.data.objects["id"][obj])),
            "mesh_uid": torch.tensor(int(self.data.meshes["uid"][row])),
            "variant": torch.tensor(variant),
            "remesher": ood_remesher(variant) or "",
        }
        return self.transform(item) if self.transform else item

    @staticmethod
    def to_pyg(item: dict):
        """A ``torch_geometric.data.Data`` view of an item: ``pos`` (vertices), ``face``
        (3, F), ``y`` (1, n_aspect, n_roll, n_range) so PyG batches stack targets, and the
        scalars as (1,)-shaped attributes."""
        from torch_geometric.data import Data

        return Data(
            pos=item["vertices"],
            face=item["faces"].t().contiguous(),
            y=item["target"].unsqueeze(0),
            scale_bins=item["scale_bins"].unsqueeze(0),
            scale_m=item["scale_m"].unsqueeze(0),
            class_index=item["class_index"].view(1),
            object_id=item["object_id"].view(1),
            mesh_uid=item["mesh_uid"].view(1),
            variant=item["variant"].view(1),
            remesher=item["remesher"],
        )


def collate_meshes(items: list[dict]) -> dict:
    """Batch ``BasicShapes`` items: ragged meshes as lists, everything else stacked."""
    import torch

    out = {k: [it[k] for it in items] for k in ("vertices", "faces")}
    for k in items[0]:
        if k not in out:
            values = [it[k] for it in items]
            out[k] = torch.stack(values) if torch.is_tensor(values[0]) else values
    return out
