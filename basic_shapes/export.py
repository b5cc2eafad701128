"""`basic-shapes export`: every mesh as a plain file, for tools that do not read HDF5."""

from __future__ import annotations

from pathlib import Path

import trimesh

from basic_shapes.shards import find_object, iter_objects


def export(directory: str | Path, out: str | Path, fmt: str, object_id: int | None = None) -> int:
    """Write ``out/<class>/<object id>/v<variant>.<fmt>`` (metres); return the file count."""
    out = Path(out)
    objects = [find_object(directory, object_id)] if object_id is not None else iter_objects(directory)
    n = 0
    for _, obj, meshes in objects:
        folder = out / obj["class"] / f"{obj['id']:06d}"
        folder.mkdir(parents=True, exist_ok=True)
        for variant, v, f in meshes:
            mesh = trimesh.Trimesh(v, f, process=False)
            mesh.export(folder / f"v{variant:03d}.{fmt}")
            n += 1
    return n
