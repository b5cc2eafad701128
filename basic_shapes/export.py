"""`basic-shapes export`: every mesh as a plain file, for tools that do not read HDF5.

``--format g2s`` instead writes labelled shards as NetCDF for the paper group's loaders
(``basic_shapes.export_g2s``).
"""

from __future__ import annotations

from pathlib import Path

import trimesh
from tqdm import tqdm

from basic_shapes.shards import Shard, dataset_fingerprint, find_object, iter_objects, list_shards


def export(
    directory: str | Path,
    out: str | Path,
    fmt: str,
    object_id: int | None = None,
    progress: bool = False,
) -> int:
    """Write ``out/<class>/<object id>/v<variant>.<fmt>`` (metres); return the file count."""
    if fmt == "g2s":
        if object_id is not None:
            raise ValueError("--object: not supported with --format g2s, which writes whole shards")
        from basic_shapes.export_g2s import export_g2s

        return export_g2s(directory, out, progress)
    out = Path(out)
    total = None
    if object_id is None:
        dataset_fingerprint(directory)  # every shard verified before the first file is written
        total = 0
        for path in list_shards(directory):
            with Shard(path) as shard:
                total += shard.n_meshes
    objects = (
        [find_object(directory, object_id)] if object_id is not None else iter_objects(directory)
    )
    n = 0
    with tqdm(total=total, desc=f"export {fmt}", unit="mesh", disable=not progress) as bar:
        for _, obj, meshes in objects:
            folder = out / obj["class"] / f"{obj['id']:06d}"
            folder.mkdir(parents=True, exist_ok=True)
            for variant, v, f in meshes:
                mesh = trimesh.Trimesh(v, f, process=False)
                mesh.export(folder / f"v{variant:03d}.{fmt}")
                n += 1
                bar.update()
    return n
