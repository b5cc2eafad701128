"""Per-face features of a normalized mesh, its ray probes, surface points and normal
descriptor, in numpy: what the baselines read.

The board computes them too: an ONNX model under the contract of ``benchmark.scoring.onnx_model``
may ask for them as inputs (``face_direct``, ``face_tokens``, ``face_edges``, ``ray_probes``,
``surface_points``, ``surface_neighbours``, ``normal_descriptor``), so they are part of the
benchmark's definition, not of any model, and are computed by this one torch-free code for
training (``benchmark.training.models.features.featurize``), for the board and for a third party
alike. Meshes arrive scale-normalized (``benchmark.scoring.data.normalize_mesh``: the longest
axis spans [-0.5, 0.5]); discretization covers ``[-COORD_RANGE, COORD_RANGE]`` and clips
anything outside.

Ray probes: ``N_RAYS`` fixed directions (``basic_shapes.geometry.fibonacci_directions``) are cast
from the bounding-box centre against the mesh; each ray reports its nearest and farthest hit
(distance and the surface normal there, oriented along the ray). These are properties of the
surface alone, so any two meshings of one surface give the same probes up to round-off (the
invariant model's input). Surface points (``surface_points``): a fixed-seed sample uniform by
area, the same only in distribution for two meshings; with their nearest neighbours
(``point_neighbours``), the point-cloud model's input. The normal descriptor
(``normal_descriptor``): area-weighted statistics of the face normals that name the primitive
(the ``class-scale-nn`` reference's classifier and the regressor's input).
"""

from __future__ import annotations

import numpy as np

from basic_shapes.geometry import area_normals, fibonacci_directions, unit_normals
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
    normal, norm = unit_normals(tri)
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

    d = fibonacci_directions(n_rays)
    near = np.full(n_rays, np.inf)
    far = np.full(n_rays, -np.inf)
    near_n = np.zeros((n_rays, 3))
    far_n = np.zeros((n_rays, 3))
    eps = 1e-9
    for s in range(0, len(tri), chunk):
        t3 = tri[s : s + chunk]
        e1, e2 = t3[:, 1] - t3[:, 0], t3[:, 2] - t3[:, 0]
        normal = unit_normals(t3)[0]
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


# --- surface points (the point-cloud model's input) -----------------------------------------
N_POINTS = 512
POINT_DIM = 6  # position (3) + the unit normal of the face it lies on (3)
POINT_SEED = 0
K_NEIGHBOURS = 16  # the point-cloud model's neighbourhood


def surface_points(
    vertices: np.ndarray, faces: np.ndarray, n_points: int = N_POINTS, seed: int = POINT_SEED
) -> np.ndarray:
    """(n_points, POINT_DIM) float32: points drawn uniformly by area on the mesh's surface, each
    with its face's unit normal (``face_geometry``'s, the winding's orientation).

    Deterministic (a fixed seed: one mesh, one sample, so it can be cached and the board
    computes the same). Faces are drawn by inverting the cumulative area at stratified
    uniforms, one in each [k, k + 1) / n_points, so a face of area a out of A receives
    n_points a / A points within 2 (a plain draw is off by its binomial spread); a point is
    uniform on its face. Two meshings of one surface give two samples of one distribution,
    not the same points.
    """
    g = face_geometry(vertices, faces)
    cumulative = np.cumsum(g["area"])
    if not len(cumulative) or not cumulative[-1] > 0:
        raise ValueError("mesh has no face of non-zero area")
    rng = np.random.default_rng(seed)
    u = (np.arange(n_points) + rng.random(n_points)) / n_points * cumulative[-1]
    face = np.minimum(np.searchsorted(cumulative, u, side="right"), len(cumulative) - 1)
    r1, r2 = rng.random((2, n_points))
    s = np.sqrt(r1)
    weights = np.stack([1 - s, s * (1 - r2), s * r2], 1)  # uniform on a triangle
    points = np.einsum("pk,pkj->pj", weights, g["triangles"][face])
    return np.concatenate([points, g["normal"][face]], 1).astype(np.float32)


def point_neighbours(points: np.ndarray, k: int = K_NEIGHBOURS) -> np.ndarray:
    """(n, k) int64: each point's ``k`` nearest points of ``points`` (n, >= 3; the first three
    columns are the position), itself first, by float64 distance, ties by index."""
    p = np.asarray(points, np.float64)[:, :3]
    d = ((p[:, None] - p[None]) ** 2).sum(-1)
    return np.ascontiguousarray(np.argsort(d, axis=1, kind="stable")[:, :k], np.int64)


# --- normal descriptor (the class-scale-nn reference's and the regressor's input) ---------
HIST_BINS = 6
AZIMUTH_BINS = 24
AXIS_TOL = 1e-3  # |n_k| > 1 - tol: facing along axis k; |n_k| < tol: across it


def _conditional_spread(n: np.ndarray, w: np.ndarray, k: int) -> float:
    """Area-weighted std of n_k within bins of the azimuth around axis k: 0 when n_k is a
    function of the azimuth (the side of a cylinder or of an elliptic cone), large when
    the normals cover an area of the sphere (ellipsoid, torus)."""
    u, v = n[:, (k + 1) % 3], n[:, (k + 2) % 3]
    b = np.minimum(
        ((np.arctan2(v, u) + np.pi) / (2 * np.pi) * AZIMUTH_BINS).astype(int), AZIMUTH_BINS - 1
    )
    wsum = np.bincount(b, w, AZIMUTH_BINS)
    m1 = np.bincount(b, w * n[:, k], AZIMUTH_BINS)
    m2 = np.bincount(b, w * n[:, k] ** 2, AZIMUTH_BINS)
    ok = wsum > 0
    return float(np.sqrt(max((m2[ok] - m1[ok] ** 2 / wsum[ok]).sum() / wsum.sum(), 0.0)))


def normal_descriptor(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted statistics of face normals in the object's axes (primitives are scaled
    per axis, never rotated) that tell the primitive's *kind* apart whatever its proportions
    and however its surface is meshed:

    * the area facing exactly along an axis (all of a box; a cylinder's or cone's caps);
    * the area facing exactly across an axis but not along one (a cylinder's side);
    * the normals' spread around a curve (``_conditional_spread``, least over the axes,
      saturated at 0.5): ~0 for ruled sides (cylinder, cone), large for ellipsoid and torus;
    * the area whose normal points towards the bounding-box centre, x3 (zero for any convex
      body; the torus's inner side);
    * per axis, a histogram of |n_k| at weight 0.1 (proportions: breaks ties only).

    On real generated meshes (5 primitives, every variant) a 1-NN on this descriptor names
    the class of held-out objects without error (tests/test_references.py).
    """
    v = np.asarray(vertices, np.float64)
    tri = v[np.asarray(faces, np.int64)]
    n = area_normals(tri)
    area = np.linalg.norm(n, axis=1)
    ok = area > 0
    if not ok.any():
        raise ValueError("mesh has no face of non-zero area")
    n, w, tri = n[ok] / area[ok, None], area[ok] / area[ok].sum(), tri[ok]
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    inward = w[np.einsum("ij,ij->i", n, tri.mean(axis=1) - centre) < 0].sum()
    an = np.abs(n)
    along = an.max(axis=1) > 1 - AXIS_TOL
    across = ~along & (an.min(axis=1) < AXIS_TOL)
    rest = ~along
    spread = min(_conditional_spread(n[rest], w[rest], k) for k in range(3)) if rest.any() else 0.0
    hist = [
        np.histogram(an[:, k], bins=HIST_BINS, range=(0, 1 + 1e-9), weights=w)[0] for k in range(3)
    ]
    return np.concatenate(
        [
            [w[along].sum(), w[across].sum(), min(4 * spread, 0.5), 3 * inward],
            0.1 * np.concatenate(hist),
        ]
    )


DESCRIPTOR_DIM = 4 + 3 * HIST_BINS
