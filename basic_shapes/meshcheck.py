"""Triangle-mesh checks shared by the generator, the radar simulator and the benchmark.

One implementation of each check, numpy only (radar_sim and benchmark import it without bpy,
torch or pymeshlab): array validation (``as_arrays``), welding (``weld``), repeated-vertex and
duplicate faces, dropping unreferenced vertices, directed edges and their partners (closed,
consistently oriented surfaces), signed volume, and the generator's acceptance test
(``defect``, ``topology_key``). The callers choose the policy: radar_sim repairs what it can
and raises ``MeshError``, the generator rejects a variant with ``defect``'s reason, the corpus
compacts and re-checks after decimation.

Arrays: vertices (V, 3) real, faces (F, 3) integer vertex indices, 0-based. A directed edge
(a, b) is an ordered pair of a face's consecutive corners; a closed, consistently oriented
surface uses each directed edge once and also its reverse (b, a), in the neighbouring face.
"""

from __future__ import annotations

import numpy as np

from basic_shapes import portable
from basic_shapes.geometry import twice_area_squared

MAX_COORDINATE = 1e9
"""Largest vertex coordinate accepted (metres for the simulator): a million kilometres. Far
beyond it products of coordinates overflow and phases lose every digit (a mesh scaled by 1e30
printed numpy's overflow warnings and a meaningless RCS)."""


class MeshError(ValueError):
    """The vertices/faces cannot be used as a triangle mesh (one-line message says why)."""


def as_arrays(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Validated copies: vertices float64 (V, 3) finite and within ``MAX_COORDINATE``, faces
    int64 (F, 3) in range.

    Raises ``MeshError`` naming the first bad vertex or face, so a user can find it in a file.
    """
    try:
        v = np.asarray(vertices)
        f = np.asarray(faces)
    except (ValueError, TypeError) as exc:
        raise MeshError(f"vertices/faces are not arrays: {exc}") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"faces must have shape (F, 3) (triangles), got {f.shape}")
    if v.dtype.kind not in "iuf":
        raise MeshError(f"vertices must be real numbers, got dtype {v.dtype}")
    if f.dtype.kind not in "iu":
        raise MeshError(f"faces must be integer vertex indices, got dtype {f.dtype}")
    if len(v) == 0 or len(f) == 0:
        raise MeshError(f"mesh is empty ({len(v)} vertices, {len(f)} faces)")
    v = v.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(v).all(axis=1))
    if len(bad):
        raise MeshError(
            f"vertex {bad[0]} is not finite: {v[bad[0]].tolist()} ({len(bad)} non-finite vertices)"
        )
    check_coordinates(v)
    f = f.astype(np.int64)
    out = np.flatnonzero((f < 0).any(axis=1) | (f >= len(v)).any(axis=1))
    if len(out):
        raise MeshError(
            f"face {out[0]} refers to vertex {f[out[0]].tolist()}, but the mesh has "
            f"{len(v)} vertices (indices are 0-based)"
        )
    return v, f


def check_coordinates(v: np.ndarray) -> None:
    """Refuse (``MeshError``) coordinates beyond ``MAX_COORDINATE`` in absolute value."""
    largest = float(np.abs(v).max(initial=0.0))
    if largest > MAX_COORDINATE:
        raise MeshError(
            f"coordinates too large (up to {largest:.3g} in absolute value, at most "
            f"{MAX_COORDINATE:g} allowed): check the units"
        )


def bbox_diagonal(vertices: np.ndarray) -> float:
    """Length of the axis-aligned bounding box's diagonal of (V, 3) vertices: the unit of
    relative distances and areas."""
    v = np.asarray(vertices, np.float64)
    return portable.norm(v.max(axis=0) - v.min(axis=0))


def repeated_vertex(faces: np.ndarray) -> np.ndarray:
    """(F,) bool: the face names one vertex twice (a degenerate face whatever the coordinates;
    its edges would otherwise pass the edge-partner test)."""
    f = np.asarray(faces)
    return (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])


def face_repeats(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first (F,) bool, count (F,) int64) for faces (F, 3): whether a face is the first one on
    its three vertices (either winding), and how many faces share those vertices.

    Keeping ``first`` keeps double-sided geometry once; keeping ``count == 1`` removes both
    faces of the back-to-back fin an edge collapse leaves on a closed surface.
    """
    rows = np.sort(np.asarray(faces), axis=1)
    first = np.zeros(len(rows), dtype=bool)
    count = np.zeros(len(rows), dtype=np.int64)
    if len(rows) == 0:
        return first, count
    order = np.lexsort(rows.T[::-1])
    sr = rows[order]
    new = np.r_[True, np.any(sr[1:] != sr[:-1], axis=1)]
    first[order[new]] = True  # lexsort is stable: the first of each group comes first
    group = np.cumsum(new) - 1
    count[order] = np.bincount(group)[group]
    return first, count


def drop_unreferenced(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V', 3) that some face uses, in their original order, and the faces (F, 3)
    int64 renumbered onto them (after faces were removed, their vertices would dangle)."""
    used, inverse = np.unique(faces, return_inverse=True)
    return vertices[used], inverse.reshape(-1, 3)


def weld(
    vertices: np.ndarray, faces: np.ndarray, decimals: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with identical coordinates (after rounding to ``decimals``, if given).

    Returns the merged vertices (V', 3), sorted by (x, y, z) of their key, each the first
    original vertex of its group, and faces (F, 3) int64 renumbered onto them. Files duplicate
    vertices along seams (normals, UVs); unwelded, every seam would read as an open boundary.
    """
    v = np.asarray(vertices)
    key = v if decimals is None else np.round(v, decimals)
    order = np.lexsort(key.T[::-1])
    sk = key[order]
    new = np.r_[True, np.any(sk[1:] != sk[:-1], axis=1)]
    remap = np.empty(len(v), dtype=np.int64)
    remap[order] = np.cumsum(new) - 1
    return v[order[new]], remap[np.asarray(faces)]


def directed_edges(faces: np.ndarray) -> np.ndarray:
    """(3F, 2) directed edges of faces (F, 3): row k*F + i is face i's edge from corner k to
    corner k+1 (mod 3), so the row index gives back the face and the corner."""
    f = np.asarray(faces)
    return np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])


def _match(f: np.ndarray) -> tuple[str | None, np.ndarray | None]:
    """(problem or None, partner or None) of the directed edges of int64 faces (F, 3), F > 0."""
    directed = directed_edges(f)
    n = int(f.max()) + 1
    key = directed[:, 0] * n + directed[:, 1]
    order = np.argsort(key, kind="stable")
    sk = key[order]
    if np.any(sk[1:] == sk[:-1]):
        return "edge used twice in the same direction (non-manifold or flipped face)", None
    reverse = directed[:, 1] * n + directed[:, 0]
    pos = np.minimum(np.searchsorted(sk, reverse), len(sk) - 1)
    if np.any(sk[pos] != reverse):
        return "open boundary edge", None
    return None, order[pos]


def _nonempty_int64(faces: np.ndarray) -> np.ndarray:
    f = np.asarray(faces, np.int64)  # int64: the edge keys a * n + b overflow int32
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"faces must be a non-empty (F, 3) array, got shape {f.shape}")
    return f


def edge_partner(faces: np.ndarray) -> np.ndarray | None:
    """(3F,) int64: for each row (a, b) of ``directed_edges(faces)`` the row of (b, a).

    None unless every directed edge occurs once and has its reverse: the surface is closed
    (watertight), 2-manifold at every edge and consistently wound.
    """
    return _match(_nonempty_int64(faces))[1]


def is_closed(faces: np.ndarray) -> bool:
    """True when every edge is shared by exactly two faces with opposite orientation and no face
    repeats a vertex (such a face would pair its own edges)."""
    f = np.asarray(faces, np.int64)
    if len(f) == 0 or repeated_vertex(f).any():
        return False
    return edge_partner(f) is not None


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Volume enclosed by a closed surface, vertices (V, 3), faces (F, 3): positive when the
    faces wind counter-clockwise seen from outside (outward normals)."""
    v = np.asarray(vertices)
    f = np.asarray(faces)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def topology_key(faces: np.ndarray, n_vertices: int) -> tuple:
    """Vertex count and vertex-degree histogram: meshes with different keys are not isomorphic."""
    degree = np.bincount(np.asarray(faces).ravel(), minlength=n_vertices)
    return (int(n_vertices), len(faces), tuple(np.bincount(degree).tolist()))


MIN_RELATIVE_AREA = 1e-12
"""Triangles smaller than this times the squared bbox diagonal count as degenerate."""


def defect(vertices: np.ndarray, faces: np.ndarray, euler: int) -> str | None:
    """Why a triangle mesh is not a closed, consistently oriented manifold of Euler
    characteristic ``euler`` without degenerate triangles (None when it is).

    A reason, not an exception: the generator counts rejected tries by reason and retries.
    """
    v = np.asarray(vertices, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        return "vertices are not a finite (V, 3) array"
    f = np.asarray(faces, np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        return "not a non-empty (F, 3) triangle array"
    n_vertices = len(v)
    if f.min() < 0 or f.max() >= n_vertices:
        return "face index out of range"
    if np.any(repeated_vertex(f)):
        return "degenerate face (repeated vertex)"
    if np.bincount(f.ravel(), minlength=n_vertices).min() == 0:
        return "unreferenced vertex"
    problem = _match(f)[0]
    if problem is not None:
        return problem
    chi = n_vertices - len(f) * 3 // 2 + len(f)
    if chi != euler:
        return f"Euler characteristic {chi}, expected {euler}"
    twice_area_sq = twice_area_squared(v[f[:, 0]], v[f[:, 1]], v[f[:, 2]])
    if twice_area_sq.min() <= (2 * MIN_RELATIVE_AREA * bbox_diagonal(v) ** 2) ** 2:
        return "degenerate (zero-area) triangle"
    return None
