"""The toolkit's one OBJ reader (the simulator's command line and the ShapeNet corpus use it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


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
