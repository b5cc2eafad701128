"""Basic Shapes: one object, many meshes of exactly the same shape (Blender-generated).

Importing this package does not import bpy; only ``basic_shapes.blender`` does.
"""

__version__ = "0.1.0"

from basic_shapes.shards import (
    Shard,
    ShardError,
    dataset_fingerprint,
    iter_objects,
    list_shards,
    mesh_uid,
)

__all__ = [
    "Shard",
    "ShardError",
    "dataset_fingerprint",
    "iter_objects",
    "list_shards",
    "mesh_uid",
    "__version__",
]
