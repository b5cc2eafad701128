"""Per-face features of a normalized mesh and its ray probes, in numpy: what the baselines read.

The board computes them too: an ONNX model under the contract of ``benchmark.scoring.onnx_model``
may ask for them as inputs (``face_direct``, ``face_tokens``, ``face_edges``, ``ray_probes``),
so they are part of the benchmark's definition, not of any model, and are computed by this one
torch-free code for training (``benchmark.training.models.features.featurize``), for the
board and for a third party alike. Meshes arrive scale-normalized
(``benchmark.scoring.data.normalize_mesh``: the longest axis spans [-0.5, 0.5]);
discretization covers ``[-COORD_RANGE, COORD_RANGE]`` and clips anything outside.

Ray probes: ``N_RAYS`` fixed directions (``radar_sim.geometry.fibonacci_directions``) are cast
from the bounding-box centre against the mesh; each ray reports its nearest and farthest hit
(distance and the surface normal there, oriented along the ray). These are properties of the
surface alone, so any two meshings of one surface give the same probes up to round-off (the
invariant model's input).
"""

from __future__ import annotations

import numpy as np

from basic_shapes.meshcheck import directed_edges

N_BINS = 128  # discretization levels per quantity, as in MeshGPT
COORD_RANGE = 0.5
DIRECT_DIM = 15  # centre (3) + corner vectors (9) + unit normal (3)
N_TOKENS = 16  # discretized: coordinates (9) + interior angles (3) + area (1) + normal (3)
TOKEN_GROUPS = (("coord", 9), ("angle", 3), ("area", 1), ("normal", 3))
MAX_LOG_AREA, MIN_LOG_AREA = 0.0, -14.0  # natural log of a face area in normalized units


def face_adjacency(faces: np.ndarray) -> np.ndarray:
    """(2, E) int64 directed edges between faces that share a mesh edge (both directions).

    Faces around a non-manifold edge are all connected pairwise. Sorted, without duplicates.
    """
    faces = np.asarray(faces, np.int64)
    n_faces = len(faces)
    if n_faces == 0:
        return np.zeros((2, 0), np.int64)
    edges = np.sort(directed_edges(faces), axis=1)  # undirected: either winding meets
    keys = edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1]
    owner = np.tile(np.arange(n_faces), 3)  # row k * F + i of directed_edges is face i's
    order = np.argsort(keys, kind="stable")
    keys, owner = keys[order], owner[order]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    lengths = np.diff(np.r_[starts, len(keys)])
    pairs = [np.stack([owner[starts[lengths == 2]], owner[starts[lengths == 2] + 1]], 1)]
    for s, n in zip(starts[lengths > 2], lengths[lengths > 2]):
        group = owner[s : s + n]
        i, j = np.triu_indices(n, 1)
        pairs.append(np.stack([group[i], group[j]], 1))
    pairs = np.concatenate(pairs)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]  # a face repeating an edge is not its own neighbour
    both = np.concatenate([pairs, pairs[:, ::-1]])
    both = np.unique(both, axis=0)
    return np.ascontiguousarray(both.T)


def _discretize(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    q = np.floor((np.asarray(x, np.float64) - lo) / (hi - lo) * N_BINS)
    return np.clip(q, 0, N_BINS - 1).astype(np.int64)


def face_geometry(vertices: np.ndarray, faces: np.ndarray) -> dict[str, np.ndarray]:
    """Triangles, centres, areas, unit normals and interior angles of every face."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]  # (F, 3, 3)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normal = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
    angles = np.empty((len(tri), 3))
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        cos = np.einsum("ij,ij->i", a, b) / np.maximum(na * nb, 1e-30)
        angles[:, k] = np.arccos(np.clip(cos, -1.0, 1.0))
    return {
        "triangles": tri,
        "centre": tri.mean(1),
        "area": 0.5 * norm,
        "normal": normal,
        "angles": angles,
    }


def face_features(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(direct (F, 15) float32, tokens (F, 16) int64 in [0, N_BINS), area (F,) float32) of one
    normalized mesh: the direct (Kohler et al.) and the discretized MeshGPT-style features."""
    g = face_geometry(vertices, faces)
    # Corners in a canonical order, sorted by (z, y, x) as MeshGPT does, so that neither
    # embedding depends on which corner a file lists first (the normal keeps the winding).
    tri = g["triangles"]
    order = np.lexsort((tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]), axis=1)
    canon = np.take_along_axis(tri, order[:, :, None], 1)
    corners = canon - g["centre"][:, None]
    direct = np.concatenate([g["centre"], corners.reshape(-1, 9), g["normal"]], 1)
    log_area = np.log(np.maximum(g["area"], np.exp(MIN_LOG_AREA)))
    tokens = np.concatenate(
        [
            _discretize(canon.reshape(-1, 9), -COORD_RANGE, COORD_RANGE),
            _discretize(np.take_along_axis(g["angles"], order, 1), 0.0, np.pi),
            _discretize(log_area[:, None], MIN_LOG_AREA, MAX_LOG_AREA),
            _discretize(g["normal"], -1.0, 1.0),
        ],
        1,
    )
    return direct.astype(np.float32), tokens, g["area"].astype(np.float32)


N_RAYS = 256
PROBE_DIM = 12  # direction (3), hit flag, near distance + normal (4), far distance + normal (4)


def ray_probes(
    vertices: np.ndarray, faces: np.ndarray, n_rays: int = N_RAYS, chunk: int = 4096
) -> np.ndarray:
    """(n_rays, PROBE_DIM) float32 probe features of one mesh (float64 Moller-Trumbore).

    Hits exactly on a shared edge count for both faces (a small barycentric tolerance), which
    does not matter: both report the same distance, and the normals of a flat region agree.
    """
    v = np.asarray(vertices, np.float64)
    origin = (v.min(0) + v.max(0)) / 2
    tri = v[np.asarray(faces, np.int64)] - origin
    from radar_sim.geometry import fibonacci_directions  # the toolkit's one direction set

    d = fibonacci_directions(n_rays)
    near = np.full(n_rays, np.inf)
    far = np.full(n_rays, -np.inf)
    near_n = np.zeros((n_rays, 3))
    far_n = np.zeros((n_rays, 3))
    eps = 1e-9
    for s in range(0, len(tri), chunk):
        t3 = tri[s : s + chunk]
        e1, e2 = t3[:, 1] - t3[:, 0], t3[:, 2] - t3[:, 0]
        normal = np.cross(e1, e2)
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
        p = np.cross(d[:, None], e2[None])  # (R, T, 3)
        det = np.einsum("tk,rtk->rt", e1, p)
        ok = np.abs(det) > 1e-15
        inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
        s_vec = -t3[:, 0]  # ray origin (0) minus first vertex
        u = np.einsum("tk,rtk->rt", s_vec, p) * inv
        q = np.cross(s_vec, e1)  # (T, 3)
        w = np.einsum("rk,tk->rt", d, q) * inv
        dist = np.einsum("tk,tk->t", e2, q)[None] * inv
        hit = ok & (u >= -eps) & (w >= -eps) & (u + w <= 1 + eps) & (dist > 0)
        dist_near = np.where(hit, dist, np.inf)
        dist_far = np.where(hit, dist, -np.inf)
        i_near, i_far = dist_near.argmin(1), dist_far.argmax(1)
        rows = np.arange(n_rays)
        better = dist_near[rows, i_near] < near
        near[better] = dist_near[rows, i_near][better]
        near_n[better] = normal[i_near[better]]
        better = dist_far[rows, i_far] > far
        far[better] = dist_far[rows, i_far][better]
        far_n[better] = normal[i_far[better]]
    hit = np.isfinite(near)
    flip = lambda n: n * np.where(np.einsum("rk,rk->r", n, d) < 0, -1.0, 1.0)[:, None]  # noqa: E731
    out = np.concatenate(
        [
            d,
            hit[:, None],
            np.where(hit, near, 0)[:, None],
            flip(near_n),
            np.where(hit, far, 0)[:, None],
            flip(far_n),
        ],
        1,
    )
    return out.astype(np.float32)
