"""The toolkit's geometry, one implementation each (all four packages use it), numpy only:
face normals and areas (``area_normals``, the one face-normal formula; ``unit_normals``;
``twice_area_squared``), the aspect/roll convention (``line_of_sight``), the one direction
set (``fibonacci_directions``) and the one OBJ reader (``read_obj``).

Arrays: triangles (F, 3, 3) of corners, or corners a, b, c (F, 3) each; directions (n, 3)
unit vectors; vertices (V, 3) float64 and faces (F, 3) int32, 0-based, as ``read_obj``
returns them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def area_normals(triangles: np.ndarray) -> np.ndarray:
    """(F, 3) (b - a) x (c - a) of (F, 3, 3) triangles: the normal by the right-hand rule,
    of length twice the area. The toolkit's one face-normal formula (generator, simulator
    and benchmark features all orient and weigh faces by it)."""
    t = np.asarray(triangles)
    return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])


def unit_normals(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals (F, 3), twice the areas (F,)) of (F, 3, 3) triangles by ``area_normals``;
    a degenerate face gets the zero normal rather than NaN (features must stay finite)."""
    cross = area_normals(triangles)
    twice = np.linalg.norm(cross, axis=1)
    normal = np.divide(cross, twice[:, None], out=np.zeros_like(cross), where=twice[:, None] > 0)
    return normal, twice


def twice_area_squared(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """|(b - a) x (c - a)|^2 per triangle, from corners a, b, c (F, 3) each: (F,).

    Squared, so no square root is taken where only a comparison is needed (np.cross is
    several times slower than these products).
    """
    u, w = b - a, c - a
    return (
        (u[:, 1] * w[:, 2] - u[:, 2] * w[:, 1]) ** 2
        + (u[:, 2] * w[:, 0] - u[:, 0] * w[:, 2]) ** 2
        + (u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]) ** 2
    )


def _sind(deg):
    """sin of degrees, exact at multiples of 90° (so axis-aligned views are exactly aligned)."""
    deg = np.asarray(deg, dtype=np.float64)
    r = np.sin(np.radians(deg))
    quarter = np.mod(deg, 90.0) == 0
    return np.where(quarter, np.round(r), r)


def _cosd(deg):
    deg = np.asarray(deg, dtype=np.float64)
    r = np.cos(np.radians(deg))
    quarter = np.mod(deg, 90.0) == 0
    return np.where(quarter, np.round(r), r)


def line_of_sight(aspect_deg, roll_deg=0.0) -> np.ndarray:
    """(n, 3) unit lines of sight for aspects θ (degrees) at roll φ (scalar or one per aspect)."""
    theta = np.atleast_1d(np.asarray(aspect_deg, dtype=np.float64))
    if theta.ndim != 1 or len(theta) == 0 or not np.isfinite(theta).all():
        raise ValueError(
            f"aspect_deg must be a non-empty 1-D array of finite degrees, "
            f"got shape {np.shape(aspect_deg)}"
        )
    phi = np.asarray(roll_deg, dtype=np.float64)
    if phi.ndim > 1 or phi.size not in (1, len(theta)) or not np.isfinite(phi).all():
        raise ValueError(
            f"roll_deg must be one finite angle or one per aspect, "
            f"got shape {np.shape(roll_deg)} for {len(theta)} aspects"
        )
    phi = np.broadcast_to(phi.reshape(-1), theta.shape)
    st = _sind(theta)
    return np.stack([st * _cosd(phi), st * _sind(phi), _cosd(theta)], axis=-1)


def fibonacci_directions(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def read_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and fan-triangulated faces of an OBJ file (positions only; materials ignored).

    Our own small reader: trimesh resolves negative (relative) indices against the final vertex
    count instead of the count at the face, which is wrong when ``v`` and ``f`` lines interleave.
    """
    verts: list[list[str]] = []
    faces: list[tuple[int, int, int]] = []
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                parts = line.split()
                if not parts:
                    continue
                if parts[0] == "v":
                    verts.append(parts[1:4])
                elif parts[0] == "f":
                    n = len(verts)
                    idx = [
                        i - 1 if i > 0 else n + i
                        for i in (int(p.split("/", 1)[0]) for p in parts[1:])
                    ]
                    faces.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))
        v = np.array(verts, dtype=np.float64).reshape(-1, 3)
    except ValueError as exc:  # non-numeric or missing fields
        raise ValueError(f"{path}: unreadable OBJ ({exc})") from None
    f = np.array(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        raise ValueError(f"{path}: holds no faces")
    if not np.isfinite(v).all():
        raise ValueError(f"{path}: vertices contain NaN or inf")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"{path}: a face index lies outside the {len(v)} vertices")
    return v, f.astype(np.int32)
