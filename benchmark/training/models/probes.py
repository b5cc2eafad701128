"""Ray probes: the surface seen along fixed rays from the bounding-box centre (numpy only).

``N_RAYS`` fixed directions (``radar_sim.geometry.fibonacci_directions``) are cast against the
mesh; each ray reports its nearest and farthest hit (distance and the surface normal there,
oriented along the ray). These are properties of the surface alone, so any two meshings of
one surface give the same probes up to round-off. The features of the invariant model
(``benchmark.training.models.invariant``); kept apart so that ``features`` needs no model code.
"""

from __future__ import annotations

import numpy as np

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
