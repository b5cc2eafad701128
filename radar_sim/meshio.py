"""Read one mesh file (OBJ, STL, PLY) for the command line, in metres.

Mesh files carry no units, so the caller states them (``--units``) and we scale to metres,
the simulator's unit. OBJ goes through the toolkit's own reader (``basic_shapes.geometry``:
relative indices resolved where they appear), STL and PLY through trimesh. STL stores a
triangle soup: coincident vertices are merged so that
closure and convexity can be detected. Anything unreadable is a one-line ``MeshFileError``;
implausible units are the simulator's warning (``radar_sim.UnitsWarning``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from basic_shapes.geometry import read_obj
from basic_shapes.meshcheck import MeshError, check_coordinates

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
FORMATS = (".obj", ".stl", ".ply")


class MeshFileError(ValueError):
    """A mesh file cannot be read as a triangle mesh."""


def load_mesh(path: str | os.PathLike, units: str = "m") -> tuple[np.ndarray, np.ndarray]:
    """(vertices float64 (V,3) in metres, faces int32 (F,3)) of a mesh file in ``units``."""
    import trimesh

    path = Path(path)
    if units not in UNITS:
        raise MeshFileError(f"{path}: unknown units {units!r}; expected one of {', '.join(UNITS)}")
    if path.suffix.lower() not in FORMATS:
        raise MeshFileError(
            f"{path}: unsupported mesh format {path.suffix or '(none)'!r}; "
            f"expected {', '.join(FORMATS)}"
        )
    if not path.is_file():
        raise MeshFileError(f"{path}: no such file")
    try:
        if path.suffix.lower() == ".obj":
            vertices, faces = read_obj(path)
        else:
            mesh = trimesh.load(path, force="mesh", process=False)
            faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
            vertices = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), np.float64)
    except Exception as exc:  # trimesh raises many types for malformed files
        detail = str(exc).splitlines()[0] if str(exc) else ""
        raise MeshFileError(
            f"{path}: not a readable {path.suffix[1:].upper()} mesh "
            f"({exc.__class__.__name__}: {detail.removeprefix(f'{path}: ')})"
        ) from None
    if len(faces) == 0:
        raise MeshFileError(
            f"{path}: holds no triangles (empty, or not a {path.suffix[1:].upper()} mesh)"
        )
    if not np.isfinite(vertices).all():
        raise MeshFileError(f"{path}: vertices contain NaN or inf")
    try:  # before merging: trimesh rounds coordinates to integers there (numpy warnings)
        check_coordinates(vertices)
    except MeshError as exc:
        raise MeshFileError(f"{path}: {exc}") from None
    merged = trimesh.Trimesh(vertices, faces, process=False)
    merged.merge_vertices()
    return np.asarray(merged.vertices) * UNITS[units], np.asarray(merged.faces, np.int32)
