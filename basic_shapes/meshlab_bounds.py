"""Bounds on MeshLab's point-to-mesh distance, to find the few samples that can be the maximum.

``verify.Reference`` stores the largest MeshLab distance from a set of samples to a mesh: from
~30,000 surface samples to each variant (``primitive_distance``) and, both ways, between a
variant's and the simple mesh's samples and meshes (``distance``). MeshLab's value for one
sample does not depend on the other samples of the query (checked), so it is enough to ask
MeshLab about every sample that may hold the maximum, against every face that may be closest
to one of them: the stored number stays bit for bit what a query of all samples against the
whole mesh gives, at a fraction of the cost (perf/generate_throughput.py).

MeshLab (vcglib ``face::PointDistanceBase``, double precision) returns for a sample q the
minimum over faces of: the plane distance |d| when q projects inside the face, else the
distance to the first edge (in the order v1v2, v2v0, v0v1) whose signed area b with the
projection is <= 0, or, when every b is positive but the smallest is below 1e-6 times twice
the face area, the distance to that edge. ``face_range`` evaluates those rules in float64 and,
wherever rounding could tip a branch (|b| or b - threshold within ``TAU`` * diagonal^2), takes
every outcome; so [lo - RHO, hi + RHO] (RHO * diagonal) contains MeshLab's value for that face.
Rounding differences are ~1e-16 of the diagonal; RHO and TAU leave a factor of ~1e4.
"""

from __future__ import annotations

import numpy as np
from numba import njit

RHO = 1e-12
"""Slack on a distance, relative to the bbox diagonal."""
TAU = 1e-12
"""Slack on a signed area b (relative to the diagonal squared) before a branch counts as sure."""
EPS = 1e-6
"""vcglib's near-edge threshold, relative to twice the face area."""


@njit(cache=True, inline="always")
def _segment_distance(qx, qy, qz, v, a, b):
    """Distance from q to the segment from vertex a to vertex b of ``v``."""
    ex, ey, ez = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
    rx, ry, rz = qx - v[a, 0], qy - v[a, 1], qz - v[a, 2]
    t = min(max((rx * ex + ry * ey + rz * ez) / (ex * ex + ey * ey + ez * ez), 0.0), 1.0)
    dx, dy, dz = rx - t * ex, ry - t * ey, rz - t * ez
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def _planes(v, faces):
    """Per face: unit normal n and n.v0; per edge (MeshLab's order v1v2, v2v0, v0v1)
    m = n x edge and m.start, so that MeshLab's b is m.q - m.start; the near-edge threshold
    EPS * twice the area (0 for a zero-area face); and the three inverse edge lengths."""
    out = np.empty((len(faces), 20))
    for f in range(len(faces)):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        ux, uy, uz = v[i1, 0] - v[i0, 0], v[i1, 1] - v[i0, 1], v[i1, 2] - v[i0, 2]
        wx, wy, wz = v[i2, 0] - v[i0, 0], v[i2, 1] - v[i0, 1], v[i2, 2] - v[i0, 2]
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        double_area = np.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / double_area, ny / double_area, nz / double_area
        out[f, 0:4] = nx, ny, nz, nx * v[i0, 0] + ny * v[i0, 1] + nz * v[i0, 2]
        for k, (a, c) in enumerate(((i1, i2), (i2, i0), (i0, i1))):
            ex, ey, ez = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
            mx, my, mz = ny * ez - nz * ey, nz * ex - nx * ez, nx * ey - ny * ex
            out[f, 4 + 4 * k : 8 + 4 * k] = mx, my, mz, mx * v[a, 0] + my * v[a, 1] + mz * v[a, 2]
            out[f, 17 + k] = 1.0 / np.sqrt(ex * ex + ey * ey + ez * ez)
        out[f, 16] = EPS * double_area
    return out


@njit(cache=True, inline="always")
def _outcome(qx, qy, qz, v, a, c, b, inv_length, d, cap):
    """MeshLab's distance to edge a -> c, or inf where it is surely >= cap (b < 0: q projects
    outside the edge, at least -b / length from its line)."""
    if b < 0.0 and d * d + (b * inv_length) ** 2 >= cap * cap:
        return np.inf
    return _segment_distance(qx, qy, qz, v, a, c)


@njit(cache=True, inline="always")
def face_range(qx, qy, qz, v, faces, planes, f, tau, cap):
    """(lo, hi): the least and largest value MeshLab's rules can give for sample q and face f,
    no slack; (inf, inf) where every one of them is surely >= cap. (Scalars and indices, no
    array views: a view passed per call costs reference counting, 80 ns a call.)"""
    i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
    if planes[f, 16] == 0.0:  # zero area: MeshLab measures to a segment in the face's bbox
        return 0.0, np.inf
    d = planes[f, 0] * qx + planes[f, 1] * qy + planes[f, 2] * qz - planes[f, 3]
    if abs(d) >= cap:  # every outcome is at least the plane distance
        return np.inf, np.inf
    lo, hi = np.inf, -np.inf
    b0 = planes[f, 4] * qx + planes[f, 5] * qy + planes[f, 6] * qz - planes[f, 7]  # edge v1v2
    if b0 <= tau:  # MeshLab may return this edge's distance ...
        lo = hi = _outcome(qx, qy, qz, v, i1, i2, b0, planes[f, 17], d, cap)
        if b0 < -tau:  # ... and surely does, looking no further
            return lo, hi
    b1 = planes[f, 8] * qx + planes[f, 9] * qy + planes[f, 10] * qz - planes[f, 11]  # edge v2v0
    if b1 <= tau:
        e = _outcome(qx, qy, qz, v, i2, i0, b1, planes[f, 18], d, cap)
        lo, hi = min(lo, e), max(hi, e)
        if b1 < -tau:
            return lo, hi
    b2 = planes[f, 12] * qx + planes[f, 13] * qy + planes[f, 14] * qz - planes[f, 15]  # edge v0v1
    if b2 <= tau:
        e = _outcome(qx, qy, qz, v, i0, i1, b2, planes[f, 19], d, cap)
        lo, hi = min(lo, e), max(hi, e)
        if b2 < -tau:
            return lo, hi
    smallest = min(b0, min(b1, b2))
    if smallest < planes[f, 16] + tau:  # all inside but near an edge: that edge's distance
        near = smallest + 2 * tau
        if b0 <= near:
            e = _outcome(qx, qy, qz, v, i1, i2, b0, planes[f, 17], d, cap)
            lo, hi = min(lo, e), max(hi, e)
        if b1 <= near:
            e = _outcome(qx, qy, qz, v, i2, i0, b1, planes[f, 18], d, cap)
            lo, hi = min(lo, e), max(hi, e)
        if b2 <= near:
            e = _outcome(qx, qy, qz, v, i0, i1, b2, planes[f, 19], d, cap)
            lo, hi = min(lo, e), max(hi, e)
    if smallest >= planes[f, 16] - tau:
        lo, hi = min(lo, abs(d)), max(hi, abs(d))
    return lo, hi


@njit(cache=True)
def _face_cells(vertices, faces, origin, cell, dims):
    """Compressed lists of the faces whose bbox meets each grid cell (start, faces)."""
    n_cells = dims[0] * dims[1] * dims[2]
    box = np.empty((len(faces), 6), np.int64)
    count = np.zeros(n_cells + 1, np.int64)
    for f in range(len(faces)):
        for k in range(3):
            lo = min(
                vertices[faces[f, 0], k], min(vertices[faces[f, 1], k], vertices[faces[f, 2], k])
            )
            hi = max(
                vertices[faces[f, 0], k], max(vertices[faces[f, 1], k], vertices[faces[f, 2], k])
            )
            box[f, k] = min(max(int((lo - origin[k]) / cell), 0), dims[k] - 1)
            box[f, 3 + k] = min(max(int((hi - origin[k]) / cell), 0), dims[k] - 1)
        for i in range(box[f, 0], box[f, 3] + 1):
            for j in range(box[f, 1], box[f, 4] + 1):
                for k in range(box[f, 2], box[f, 5] + 1):
                    count[(i * dims[1] + j) * dims[2] + k + 1] += 1
    for c in range(n_cells):
        count[c + 1] += count[c]
    fill = count[:-1].copy()
    items = np.empty(count[-1], np.int64)
    for f in range(len(faces)):
        for i in range(box[f, 0], box[f, 3] + 1):
            for j in range(box[f, 1], box[f, 4] + 1):
                for k in range(box[f, 2], box[f, 5] + 1):
                    c = (i * dims[1] + j) * dims[2] + k
                    items[fill[c]] = f
                    fill[c] += 1
    return count, items


@njit(cache=True, inline="always")
def _inside(qx, qy, qz, planes, f, tau):
    """|d| if q surely projects inside face f, away from its edges (MeshLab then returns the
    plane distance), else inf."""
    d = planes[f, 0] * qx + planes[f, 1] * qy + planes[f, 2] * qz - planes[f, 3]
    for k in range(4, 16, 4):
        b = planes[f, k] * qx + planes[f, k + 1] * qy + planes[f, k + 2] * qz - planes[f, k + 3]
        if not b > planes[f, 16] + tau:
            return np.inf
    return abs(d)


@njit(cache=True)
def _first_inside(samples, cells, planes, start, items, tau):
    """Per sample, |d| of the first face of its cell it surely projects inside (inf if none):
    a bound that costs a few dot products (outside a convex mesh, one face at most)."""
    out = np.full(len(samples), np.inf)
    for s in range(len(samples)):
        c = cells[s]
        for t in range(start[c], start[c + 1]):
            out[s] = _inside(samples[s, 0], samples[s, 1], samples[s, 2], planes, items[t], tau)
            if out[s] < np.inf:
                break
    return out


@njit(cache=True)
def _upper(samples, cells, picked, first, vertices, faces, planes, start, items, tau):
    """For the picked samples, the smallest ``hi`` over the faces of their cell."""
    out = np.empty(len(picked))
    for i in range(len(picked)):
        s = picked[i]
        qx, qy, qz = samples[s, 0], samples[s, 1], samples[s, 2]
        best = first[s]
        for t in range(start[cells[s]], start[cells[s] + 1]):
            best = min(
                best, face_range(qx, qy, qz, vertices, faces, planes, items[t], tau, best)[1]
            )
        out[i] = best
    return out


@njit(cache=True)
def _lower(samples, vertices, faces, planes, tau, slack):
    """Per sample, the smallest ``lo`` over all faces: at most MeshLab's value. A face whose
    bbox is farther than the best so far (+ slack) cannot go below it and is skipped."""
    box = np.empty((len(faces), 6))
    for f in range(len(faces)):
        for k in range(3):
            box[f, k] = min(
                vertices[faces[f, 0], k], min(vertices[faces[f, 1], k], vertices[faces[f, 2], k])
            )
            box[f, 3 + k] = max(
                vertices[faces[f, 0], k], max(vertices[faces[f, 1], k], vertices[faces[f, 2], k])
            )
    out = np.full(len(samples), np.inf)
    for s in range(len(samples)):
        qx, qy, qz = samples[s, 0], samples[s, 1], samples[s, 2]
        for f in range(len(faces)):
            gap = 0.0
            for k in range(3):
                g = max(box[f, k] - samples[s, k], samples[s, k] - box[f, 3 + k], 0.0)
                gap += g * g
            if np.sqrt(gap) > out[s] + slack:
                continue
            cap = out[s] + slack
            out[s] = min(out[s], face_range(qx, qy, qz, vertices, faces, planes, f, tau, cap)[0])
    return out


@njit(cache=True)
def _near_faces(samples, picked, reach, origin, cell, dims, start, items, n_faces):
    """Faces listed in any cell within ``reach`` of a picked sample (its box of cells): every
    face whose bbox comes that close, so every face that can give MeshLab's minimum."""
    mark = np.zeros(n_faces, np.bool_)
    lo, hi = np.empty(3, np.int64), np.empty(3, np.int64)
    for i in range(len(picked)):
        for k in range(3):
            x = samples[picked[i], k] - origin[k]
            lo[k] = min(max(int(np.floor((x - reach[i]) / cell)), 0), dims[k] - 1)
            hi[k] = min(max(int(np.floor((x + reach[i]) / cell)), 0), dims[k] - 1)
        for a in range(lo[0], hi[0] + 1):
            for b in range(lo[1], hi[1] + 1):
                for c in range(lo[2], hi[2] + 1):
                    cell_id = (a * dims[1] + b) * dims[2] + c
                    for t in range(start[cell_id], start[cell_id + 1]):
                        mark[items[t]] = True
    return np.flatnonzero(mark)


PROBES = 16
"""Samples of largest upper bound whose lower bound is computed against every face, per round."""

CELLS_PER_DIAGONAL = 48
"""Grid cell size: faces of the finest variants (4000 triangles) are about one cell wide."""


class SampleBounds:
    """Fixed samples (an object's surface samples) and the grid their cells index, set up once
    for the many meshes measured against them."""

    def __init__(self, samples: np.ndarray, diagonal: float):
        self.samples = np.ascontiguousarray(samples, np.float64)
        self.diagonal = float(diagonal)
        self.cell = self.diagonal / CELLS_PER_DIAGONAL
        self.origin = self.samples.min(axis=0)
        index = np.floor((self.samples - self.origin) / self.cell).astype(np.int64)
        self.dims = index.max(axis=0) + 1
        self.cells = np.ravel_multi_index(index.T, self.dims)

    def candidates(self, vertices: np.ndarray, faces: np.ndarray) -> tuple:
        """Indices of the samples whose MeshLab distance to the mesh may be the largest, and of
        the faces that can be closest to them.

        Every sample left out has an upper bound below a lower bound of some kept sample's
        distance, so the maximum over the kept ones is the maximum over all; every face left
        out is farther from each kept sample than that sample's upper bound, so MeshLab's
        minimum over the kept faces is its minimum over all.
        """
        v = np.ascontiguousarray(vertices, np.float64)
        f = np.ascontiguousarray(faces, np.int64)
        tau, rho = TAU * self.diagonal**2, RHO * self.diagonal
        planes = _planes(v, f)
        start, items = _face_cells(v, f, self.origin, self.cell, self.dims)
        first = _first_inside(self.samples, self.cells, planes, start, items, tau)
        finite = np.flatnonzero(first < np.inf)
        bound = self._raise(-np.inf, finite, first[finite], v, f, planes)
        picked = np.flatnonzero(first + rho >= bound)
        upper = _upper(self.samples, self.cells, picked, first, v, f, planes, start, items, tau)
        bound = self._raise(bound, picked, upper, v, f, planes)
        keep = upper + rho >= bound
        reach = np.minimum(upper[keep] + 4 * rho, self.cell * self.dims.sum())  # inf: all
        near = _near_faces(
            self.samples,
            picked[keep],
            reach,
            self.origin,
            self.cell,
            self.dims,
            start,
            items,
            len(f),
        )
        return picked[keep], near

    def _raise(self, bound, picked, upper, v, f, planes) -> float:
        """``bound`` raised to the largest lower bound of the picked samples of largest upper
        bound, PROBES at a time, while one could still beat it (at most 4 rounds)."""
        tau, rho = TAU * self.diagonal**2, RHO * self.diagonal
        top = (
            np.argpartition(-upper, min(4 * PROBES, len(upper)) - 1)[: 4 * PROBES]
            if len(upper)
            else np.zeros(0, np.int64)
        )
        top = top[np.argsort(-upper[top])]
        for first in range(0, len(top), PROBES):
            probes = top[first : first + PROBES]
            if upper[probes[0]] + rho <= bound + 2 * rho:  # nothing left to gain
                break
            lower = _lower(self.samples[picked[probes]], v, f, planes, tau, rho)
            bound = max(bound, float(lower.max()) - rho)
        return bound
