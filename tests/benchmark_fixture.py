"""A tiny labelled Basic Shapes dataset for the benchmark tests, written without Blender.

Stand-in until the real ``basic-shapes generate`` + ``radar-sim label`` pipeline is fast
enough for tests: shards are written with ``basic_shapes.shards.write_shard`` from trimesh
meshes, several variants per object that keep the shape (a box, the same box subdivided once
and twice; a 16- and a 24-sided cylinder; an icosphere at two subdivision levels), and a
``/radar`` group whose label is a deterministic analytic function of the object (NOT physics):
each of the 8 bounding-box corners p_k is a point scatterer of class-dependent strength g, so
for line of sight u and range bin r, A(r) = sum_k g exp(-((r - u.p_k) / 0.1 m)^2)
exp(2j pi u.p_k / 0.03 m). Labels are per object, as in real shards.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import trimesh

from basic_shapes.shards import (
    MeshRecord,
    ObjectRecord,
    rewrite_atomically,
    shard_name,
    write_radar,
    write_shard,
)

CLASSES = ["cube", "cylinder", "sphere"]
STRENGTH = {"cube": 1.0, "cylinder": 0.5, "sphere": 0.2}


def variants(cls: str, scale: np.ndarray) -> list[trimesh.Trimesh]:
    """Meshes of one object, simple first; all of the same shape up to curved-part sampling."""
    if cls == "cube":
        simple = trimesh.creation.box(extents=scale)
        once = simple.subdivide()
        return [simple, once, once.subdivide()]
    if cls == "cylinder":
        meshes = [trimesh.creation.cylinder(radius=0.5, height=1.0, sections=n) for n in (16, 24)]
        meshes.append(meshes[0].subdivide())
    else:
        meshes = [trimesh.creation.icosphere(subdivisions=n, radius=0.5) for n in (1, 2)]
        meshes.append(meshes[0].subdivide())
    for m in meshes:
        m.apply_scale(scale)
    return meshes


def analytic_label(cls: str, scale: np.ndarray, aspect_deg, roll_deg, range_m) -> np.ndarray:
    """(n_aspect, n_roll, n_range) complex64 stand-in label (see module docstring)."""
    th, ph = np.meshgrid(np.radians(aspect_deg), np.radians(roll_deg), indexing="ij")
    los = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * scale / 2
    proj = los @ corners.T  # (a, r, 8)
    r = np.asarray(range_m)[None, None, None, :]
    amp = np.exp(-(((r - proj[..., None]) / 0.1) ** 2)) * np.exp(
        2j * np.pi * proj[..., None] / 0.03
    )
    return (STRENGTH[cls] * amp.sum(axis=2)).astype(np.complex64)


def make_dataset(
    directory: str | Path,
    objects_per_class: int = 4,
    n_test_per_class: int = 2,
    n_shards: int = 2,
    grid: tuple[int, int, int] = (7, 5, 16),
    seed: int = 0,
    n_val_per_class: int = 0,
    ood: tuple[int, ...] = (),
) -> Path:
    """Write ``n_shards`` labelled shards into ``directory``; return it. Per class, the first
    ``n_test_per_class`` objects are test, the next ``n_val_per_class`` val, the rest train.
    ``ood``: variant numbers appended to every object (copies of its last variant), as OOD
    meshes would be."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    aspect = np.linspace(0.0, 180.0, grid[0])
    roll = np.arange(grid[1]) * 360.0 / grid[1]
    rng_m = np.linspace(-1.5, 1.5, grid[2])
    objects = []
    for c, cls in enumerate(CLASSES):
        for j in range(objects_per_class):
            scale = np.round(rng.uniform(0.3, 1.5, 3), 3)
            meshes = [
                MeshRecord(
                    variant=v,
                    vertices=m.vertices.astype(np.float32),
                    faces=m.faces.astype(np.int32),
                    hausdorff=0.0,
                    params={"fixture": cls, "n_faces": len(m.faces)},
                )
                for v, m in enumerate(variants(cls, scale))
            ]
            meshes += [
                MeshRecord(v, meshes[-1].vertices, meshes[-1].faces, 0.0, {"remesher": "fixture"})
                for v in ood
            ]
            objects.append(
                ObjectRecord(
                    id=len(objects),
                    class_index=c,
                    scale=scale,
                    seed=seed * 1000 + len(objects),
                    split="test"
                    if j < n_test_per_class
                    else "val"
                    if j < n_test_per_class + n_val_per_class
                    else "train",
                    meshes=meshes,
                )
            )
    for k in range(n_shards):
        part = objects[k::n_shards]
        path = directory / shard_name(k)
        write_shard(path, part, CLASSES, {"fixture": True, "seed": seed}, "0.1.0")
        labels = np.stack(
            [analytic_label(CLASSES[o.class_index], o.scale, aspect, roll, rng_m) for o in part]
        )

        def add_radar(f: h5py.File, labels=labels):
            write_radar(
                f,
                attrs={
                    "config": json.dumps({"fixture": "analytic corners"}),
                    "simulation_rule": json.dumps({"fixture": True}),
                    "options": json.dumps({"fixture": True}),
                },
                coordinates={
                    "aspect_deg": aspect,
                    "roll_deg": roll,
                    "range_m": rng_m,
                    "frequency_hz": np.linspace(8e9, 12e9, grid[2]),
                },
                object_ids=f["objects/id"][()],
                modes=["convex"] * len(labels),
                responses=labels,
            )

        rewrite_atomically(path, add_radar)
    return directory
