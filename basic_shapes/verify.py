"""Shape checks for generated meshes: two-sided Hausdorff (pymeshlab) and tolerances.

Topology and manifold checks (``defect``, ``topology_key``) live in basic_shapes/meshcheck.py.

Every mesh is compared with two things: the object's simple mesh (Hausdorff, ``tolerance``)
and the object itself, the analytic primitive (``Reference.primitive_distance``,
``primitive_tolerance``): mesh samples -> surface by basic_shapes.analytic.surface_distance,
surface samples -> mesh by pymeshlab.

Hausdorff distances are measured by pymeshlab from an explicit, deterministic point sample
of each surface to the other mesh. MeshLab's own face sampling (Montecarlo) draws from a
process-wide random generator that is never reseeded, so it would make the stored distance
depend on what was measured before in the process; our samples are every vertex plus the
centroids of a k x k subdivision of every face (k grows with the face area). For a convex
polytope such as the cube this is exact, not just an estimate: a triangle whose vertices
and centroid lie on the polytope's surface lies in one of its faces (docs/GENERATOR.md).
"""

from __future__ import annotations

import ctypes
import functools
import importlib.util
from pathlib import Path

import numpy as np

from basic_shapes import analytic, meshlab_bounds, portable, primitives
from basic_shapes.geometry import twice_area_squared
from basic_shapes.meshcheck import bbox_diagonal

PLANAR_TOLERANCE = 1e-6
"""Bound for planar-faced shapes: float32 vertex rounding is ~6e-8 of the diagonal."""

SAMPLE_SPACING = 1.0 / 8
"""Target distance between face samples, as a fraction of the bbox diagonal."""

SURFACE_SPACING = 1.0 / 128
"""Spacing of the analytic surface's samples (fraction of the diagonal): the surface -> mesh
distance peaks mid-facet (a sagitta) and is flat there, so it is found to second order."""

TOP_FREQUENCY_HZ = 12e9
"""Top of the default band: distances are also stated in its wavelength (25 mm)."""

MAX_FACE_SUBDIVISION = 8
"""Cap on k: at most k*k samples per face."""

SEARCH_RADIUS = 0.5
"""MeshLab's maxdist, relative to the reference diagonal. MeshLab silently drops samples
farther than maxdist, so when any is dropped the measurement is redone without a limit."""
UNLIMITED = 1e30


@functools.cache
def _pymeshlab():
    """Import pymeshlab, first loading Blender's Embree when bpy is installed.

    Both ship a ``libembree4.so.4``; whichever loads first serves the process, and
    pymeshlab's older copy lacks symbols bpy needs, so bpy would then fail to import.
    Blender's copy serves pymeshlab fine. This loads the library only, not bpy.
    """
    spec = importlib.util.find_spec("bpy")
    if spec is not None and spec.origin:
        embree = Path(spec.origin).parent / "lib" / "libembree4.so.4"
        if embree.exists():
            ctypes.CDLL(str(embree))
    import pymeshlab

    return pymeshlab


def _stratified_weights(k: int) -> np.ndarray:
    """Barycentric centroids of the k*k sub-triangles of a k-subdivided triangle, (k*k, 3)."""
    up = [(i + 1 / 3, j + 1 / 3) for i in range(k) for j in range(k - i)]
    down = [(i + 2 / 3, j + 2 / 3) for i in range(k - 1) for j in range(k - 1 - i)]
    ij = np.array(up + down, np.float64) / k
    return np.column_stack([ij, 1.0 - ij.sum(axis=1)])


_WEIGHTS = [None] + [_stratified_weights(k) for k in range(1, MAX_FACE_SUBDIVISION + 1)]


def face_samples(vertices: np.ndarray, faces: np.ndarray, spacing: float) -> np.ndarray:
    """k*k stratified points per face, k = ceil(sqrt(2 * area) / spacing) capped (k = 1: the
    centroid). Area, not edge length, sets k: collapsed flat regions are full of long slivers."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    limit = (spacing**2) ** 2  # k = 1 exactly when 2 * area <= spacing^2
    large = np.flatnonzero(twice_area_squared(a, b, c) > limit)
    parts = [(a + b + c) / 3.0]
    if len(large):
        parts[0] = np.delete(parts[0], large, axis=0)
        a, b, c = a[large], b[large], c[large]
        twice_area = np.sqrt(twice_area_squared(a, b, c))
        k = np.minimum(np.ceil(np.sqrt(twice_area) / spacing), MAX_FACE_SUBDIVISION).astype(int)
        for level in np.unique(k):
            sel = k == level
            w = _WEIGHTS[level]
            parts.append(
                (
                    w[:, 0, None, None] * a[sel]
                    + w[:, 1, None, None] * b[sel]
                    + w[:, 2, None, None] * c[sel]
                ).reshape(-1, 3)
            )
    return np.concatenate(parts)


def _samples(vertices: np.ndarray, faces: np.ndarray, spacing: float, diagonal: float):
    """A mesh's Hausdorff samples: every vertex and its face samples."""
    v = np.asarray(vertices, np.float64)
    return meshlab_bounds.SampleBounds(
        np.concatenate([v, face_samples(v, faces, spacing)]), diagonal
    )


class Reference:
    """A mesh that many others are compared with (the simple mesh of one object).

    Its samples (and the analytic surface's) are set up once for all its variants. MeshLab
    measures only the samples that may hold a direction's maximum, against the faces that may
    be closest to them (``meshlab_bounds``): the same numbers as measuring all of them, at a
    fraction of the cost.
    """

    def __init__(
        self, vertices: np.ndarray, faces: np.ndarray, solid: analytic.Solid | None = None
    ):
        self.diagonal = bbox_diagonal(vertices)
        if not self.diagonal > 0:
            raise ValueError("reference mesh has an empty bounding box")
        self.spacing = self.diagonal * SAMPLE_SPACING
        self._mesh = (np.asarray(vertices, np.float64), np.asarray(faces))
        self._samples = _samples(*self._mesh, self.spacing, self.diagonal)
        self.solid = solid
        if solid is not None:
            samples = analytic.surface_samples(solid, solid.diagonal * SURFACE_SPACING)
            self._surface = meshlab_bounds.SampleBounds(samples, solid.diagonal)

    def distance(self, vertices: np.ndarray, faces: np.ndarray) -> float:
        """Two-sided Hausdorff distance to the reference, relative to its bbox diagonal."""
        v = np.asarray(vertices, np.float64)
        radius = SEARCH_RADIUS * self.diagonal
        to_ref = _one_sided_subset(
            _samples(v, faces, self.spacing, self.diagonal), self._mesh, radius
        )
        from_ref = _one_sided_subset(self._samples, (v, faces), radius)
        return max(to_ref, from_ref) / self.diagonal

    def primitive_distance(self, vertices: np.ndarray, faces: np.ndarray) -> float:
        """Two-sided distance from a mesh to the object's analytic surface, relative to the
        object's bbox diagonal (NaN for a Reference built without the Solid)."""
        solid = self.solid
        if solid is None:
            return float("nan")
        v = np.asarray(vertices, np.float64)
        spacing = solid.diagonal * SURFACE_SPACING * 4
        points = np.concatenate([v, face_samples(v, faces, spacing)])
        to_surface = float(analytic.surface_distance(solid, points).max())
        from_surface = _one_sided_subset(self._surface, (v, faces), SEARCH_RADIUS * solid.diagonal)
        return max(to_surface, from_surface) / solid.diagonal


def _one_sided_subset(samples: meshlab_bounds.SampleBounds, mesh, radius: float) -> float:
    """``_one_sided`` from every sample to ``mesh`` (vertices, faces), asking MeshLab about the
    samples that may hold the maximum only, against the faces that may be closest to them (a
    MeshSet of its own: cheaper than adding and deleting meshes in a kept one)."""
    picked, near = samples.candidates(*mesh)
    ms = _pymeshlab().MeshSet()
    ms.add_mesh(
        _pymeshlab().Mesh(vertex_matrix=mesh[0], face_matrix=np.asarray(mesh[1], np.int32)[near])
    )
    ms.add_mesh(_pymeshlab().Mesh(vertex_matrix=samples.samples[picked]))
    return _one_sided(ms, sampled=1, target=0, radius=radius)


def in_wavelengths(relative: float, scale) -> float:
    """A distance relative to the bbox diagonal of extents ``scale``, in wavelengths at the
    top frequency of the default band."""
    return relative * portable.norm(scale) * TOP_FREQUENCY_HZ / analytic.C0


def _one_sided(ms, sampled: int, target: int, radius: float) -> float:
    """Largest distance from the vertices of mesh ``sampled`` to the faces of ``target``."""
    n = ms.mesh(sampled).vertex_number()
    r = ms.get_hausdorff_distance(
        sampledmesh=sampled,
        targetmesh=target,
        samplevert=True,
        sampleedge=False,
        sampleface=False,
        samplenum=n,
        maxdist=_pymeshlab().PureValue(radius),
    )
    if r["n_samples"] < n:
        return _one_sided(ms, sampled, target, radius=UNLIMITED)
    return float(r["max"])


def hausdorff(v_a: np.ndarray, f_a: np.ndarray, v_b: np.ndarray, f_b: np.ndarray) -> float:
    """Two-sided Hausdorff distance between meshes a and b, relative to a's bbox diagonal."""
    return Reference(v_a, f_a).distance(v_b, f_b)


def tolerance(class_name: str, params: dict) -> float:
    """The Hausdorff bound (relative to the bbox diagonal) a variant of ``class_name`` must meet.

    Planar-faced shapes: PLANAR_TOLERANCE. Curved ones: the distance between the coarsest
    allowed tessellation and the default one, worst case over all scales (GENERATOR.md).
    ``params["resolution"]``, when given, must be an allowed tessellation, since the bound
    only covers those.
    """
    spec = primitives.get(class_name)
    resolution = params.get("resolution", {}) if params else {}
    unknown = set(resolution) - set(spec.resolution)
    if unknown:
        raise ValueError(f"{class_name}: no tessellation parameter {sorted(unknown)}")
    for key, value in resolution.items():
        if not spec.resolution[key].allows(value):
            raise ValueError(f"{class_name}: {key}={value} is outside the allowed tessellations")
    if spec.planar:
        return PLANAR_TOLERANCE
    coarse = spec.gap(spec.coarsest_resolution())
    default = spec.gap(spec.default_resolution())
    unit_bound = max(coarse, default) if spec.convex else coarse + default
    return _relative(spec, unit_bound) + PLANAR_TOLERANCE


def _relative(spec: primitives.Primitive, gap: float) -> float:
    """A gap relative to the bbox diagonal, worst case over all scales.

    A per-axis scale s maps unit-space displacements d to |diag(s / e0) d| <= max(s / e0)|d|;
    relative to the diagonal |s| that is at most |d| / min(e0), reached as s approaches an axis.
    A primitive built in metres states its relative gap itself (``Primitive.metric``)."""
    return gap if spec.metric else gap / min(spec.extents)


def primitive_tolerance(class_name: str, params: dict) -> float:
    """The bound (relative to the bbox diagonal) on a mesh's distance to the analytic primitive.

    Planar-faced shapes: PLANAR_TOLERANCE. A curved tessellation at resolution r, loop-cut or
    not, is inscribed in the smooth surface (every face is a planar polygon with its vertices on
    it): gap(r) / min(e0). A decimated variant has no such structure; it passed ``tolerance``
    against the simple mesh, itself within gap(default) / min(e0) of the surface, so the
    triangle inequality bounds it by the sum (GENERATOR.md, "Distance to the primitive").
    """
    bound = tolerance(class_name, params)
    spec = primitives.get(class_name)
    if spec.planar:
        return bound
    resolution = (params or {}).get("resolution") or spec.default_resolution()
    if (params or {}).get("decimate", {}).get("kind", "none") == "none":
        return _relative(spec, spec.gap(resolution)) + PLANAR_TOLERANCE
    return bound + _relative(spec, spec.gap(spec.default_resolution()))
