"""Blender mesh core: the simple mesh of an object and its verified complex variants.

The only module that imports bpy (lazily, on first use; one Blender state per process).
Each primitive is built once per process and tessellation with its own operator and kept as
a BMesh in unit space; a variant copies it, scales it, adds random loop cuts with bmesh and
runs it through one reusable object carrying a Decimate and a Triangulate modifier,
evaluated through the depsgraph. Nothing a variant does survives into the next one, so the
same (class, scale, seed, n_variants) gives bit-identical arrays in any process, whatever
was generated before.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from collections import defaultdict

import numpy as np

from basic_shapes import analytic, meshcheck, primitives, verify
from basic_shapes.shards import MeshRecord

MAX_ATTEMPTS = 64
"""Tries per variant before giving up (a rejected try is regenerated with a new stream)."""

MAX_TRIANGLES = 4000
"""Largest triangle count of a variant (and of a mesh before decimation)."""

MAX_CUT_STEPS = 4
"""At most this many edge rings are cut per variant. A bmesh subdivision costs time in
proportion to the whole mesh, so the cuts reach their target in a few large steps."""

MAX_CUTS_PER_RING = 32
"""More cuts in one ring would slice a face into slivers and fan the triangles at its ends."""

COLLAPSE_OVERSHOOT = 3.0
"""A collapsed variant is cut to up to this many times its final triangle count first."""

QUAD_METHODS = ("BEAUTY", "FIXED", "FIXED_ALTERNATE", "SHORTEST_DIAGONAL", "LONGEST_DIAGONAL")
NGON_METHODS = ("BEAUTY", "CLIP")

STAGE_SECONDS: dict[str, float] = defaultdict(float)
"""CPU seconds (all threads) spent per stage in this process, rejected attempts included,
read by perf/mesh_core.py: simple, primitive, loop_cuts, decimate, extract, checks,
hausdorff, analytic (the distance to the analytic primitive)."""
ATTEMPTS: dict[str, int] = defaultdict(int)
"""Built meshes per outcome in this process: accepted or the rejection reason."""


def _lap(stage: str, start: float) -> float:
    """Charge the CPU time since ``start`` to ``stage``; returns now (the next start)."""
    now = time.process_time()
    STAGE_SECONDS[stage] += now - start
    return now


def object_meshes(
    class_name: str, scale: np.ndarray, seed: int, n_variants: int, shape: dict | None = None
) -> list[MeshRecord]:
    """The simple mesh (variant 0) and ``n_variants`` verified complex variants of one object.

    ``scale`` holds the bbox extents in metres (x, y, z); ``shape`` the object's hidden shape
    parameters (``analytic.HIDDEN``; default: drawn from ``seed`` as the generator does), which
    every mesh and the primitive check use. Every
    variant is a closed manifold within ``verify.tolerance`` of the simple mesh (two-sided
    Hausdorff relative to the simple mesh's bbox diagonal) and differs in topology from every
    other mesh of the object.
    """
    spec = primitives.get(class_name)
    scale = np.asarray(scale, np.float64)
    if scale.shape != (3,) or not np.all(np.isfinite(scale)) or not np.all(scale > 0):
        raise ValueError(f"scale must be 3 positive finite extents in metres, got {scale!r}")
    if not 0 <= n_variants < 1000:
        raise ValueError(f"n_variants must be in 0..999, got {n_variants}")
    if not 0 <= int(seed) < 2**64:
        raise ValueError(f"seed must be in 0..2**64-1, got {seed}")
    known = class_name in analytic.ALL_KINDS  # a registry-only primitive has no analytic shape
    if shape is None:
        shape = analytic.hidden_params(class_name, int(seed))
    solid = analytic.solid_for(class_name, scale, shape) if known else None
    with _LOCK:  # bpy is not thread-safe: threads of one process take turns
        return _object_meshes(spec, class_name, scale, int(seed), n_variants, solid)


def _object_meshes(spec, class_name, scale, seed, n_variants, solid) -> list[MeshRecord]:
    """object_meshes after validation, under the lock (``solid``: None for a registry-only
    primitive, which has no analytic shape yet)."""
    blender = _state()
    has_shape = solid is not None and spec.shape is not None
    blender.shape = spec.shape(solid.params, solid.scale) if has_shape else {}
    start = time.process_time()
    simple_params = {
        "resolution": spec.default_resolution(),
        "loop_cuts": [],
        "decimate": {"kind": "none"},
        "triangulate": {"quad": "BEAUTY", "ngon": "BEAUTY"},
    }
    v0, f0 = blender.build(class_name, scale, simple_params, rng=None)
    error = meshcheck.defect(v0, f0, spec.euler)
    if error:
        raise RuntimeError(f"{class_name}: simple mesh is broken: {error}")
    reference = verify.Reference(v0, f0, solid)
    gap = reference.primitive_distance(v0, f0)
    if solid is not None and not gap <= verify.primitive_tolerance(class_name, simple_params):
        raise RuntimeError(f"{class_name}: simple mesh is {gap:.3g} diagonals from the primitive")
    _lap("simple", start)
    records = [MeshRecord(0, v0, f0, 0.0, simple_params, gap)]
    seen = {meshcheck.topology_key(f0, len(v0))}
    for variant in range(1, n_variants + 1):
        records.append(_variant(blender, class_name, scale, seed, variant, reference, seen))
    return records


def warm_up(class_names) -> float:
    """Build every allowed tessellation of these classes now; returns the CPU seconds spent.

    Otherwise each one is built on first use (a few ms each, once per process). Classes with
    hidden shape parameters are built per object instead.
    """
    start = time.process_time()
    with _LOCK:
        for name in (n for n in class_names if primitives.get(n).shape is None):
            for resolution in primitives.get(name).resolutions():
                _state().primitive(name, resolution)
    return time.process_time() - start


def _variant(blender, class_name, scale, seed, variant, reference, seen) -> MeshRecord:
    """The first try of this variant that passes every check (``seen`` gets its topology)."""
    spec = primitives.PRIMITIVES[class_name]
    rejected = {}
    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng([seed, variant, attempt])
        params = _sample_params(spec, rng)
        v, f = blender.build(class_name, scale, params, rng)
        start = time.process_time()
        key = meshcheck.topology_key(f, len(v))
        reason = "duplicate topology" if key in seen else meshcheck.defect(v, f, spec.euler)
        start = _lap("checks", start)
        if reason is None:
            params["tolerance"] = verify.tolerance(class_name, params)
            distance = reference.distance(v, f)
            start = _lap("hausdorff", start)
            params["primitive_tolerance"] = verify.primitive_tolerance(class_name, params)
            gap = reference.primitive_distance(v, f) if distance <= params["tolerance"] else None
            _lap("analytic", start)
            if gap is not None and not gap > params["primitive_tolerance"]:
                seen.add(key)
                params["attempt"] = attempt
                ATTEMPTS["accepted"] += 1
                return MeshRecord(variant, v, f, distance, params, gap)
            reason = (
                "Hausdorff above tolerance" if gap is None else "primitive distance above tolerance"
            )
        ATTEMPTS[reason.split(" (")[0]] += 1
        rejected[reason] = rejected.get(reason, 0) + 1
    raise RuntimeError(
        f"{class_name} seed {seed}: variant {variant} failed {MAX_ATTEMPTS} attempts ({rejected})"
    )


def _sample_params(spec: primitives.Primitive, rng: np.random.Generator) -> dict:
    """Random choices of one try; the rings to cut are drawn while cutting (see build)."""
    resolution = {k: int(rng.choice(r.values())) for k, r in spec.resolution.items()}
    kinds = list(spec.decimation)
    weights = np.array([spec.decimation[k] for k in kinds])
    decimate: dict = {"kind": kinds[rng.choice(len(kinds), p=weights / weights.sum())]}
    if decimate["kind"] == "collapse":
        overshoot = math.exp(rng.uniform(0, math.log(COLLAPSE_OVERSHOOT)))
        decimate["overshoot"] = round(float(overshoot), 4)
        decimate["triangulate"] = bool(rng.integers(2))
    elif decimate["kind"] == "unsubdiv":
        decimate["iterations"] = 1  # two un-subdivide a UV sphere beyond its tolerance (88 %)
    return {
        "resolution": resolution,
        "size": round(float(rng.uniform()), 6),
        "cut_steps": int(rng.integers(1, MAX_CUT_STEPS + 1)),
        "decimate": decimate,
        "triangulate": {
            "quad": QUAD_METHODS[rng.integers(len(QUAD_METHODS))],
            "ngon": NGON_METHODS[rng.integers(len(NGON_METHODS))],
        },
    }


_STATE = None
_LOCK = threading.RLock()


def _state() -> _Blender:
    global _STATE
    if _STATE is None:
        _STATE = _Blender()
    return _STATE


def _drop_inherited_blender_paths() -> None:
    """Forget Blender's script folders inherited from a parent process's sys.path.

    Importing bpy appends ``.../bpy/<version>/scripts/modules`` (and siblings) to sys.path;
    a process spawned by a parent that had bpy loaded (Dask and multiprocessing workers copy
    sys.path) would then import the pure-Python ``bpy`` package from there instead of Blender
    itself and fail on ``_bpy``. bpy adds these folders back when it loads.
    """
    if "bpy" not in sys.modules:
        marker = f"{os.sep}bpy{os.sep}"
        sys.path[:] = [p for p in sys.path if not (marker in p and f"{os.sep}scripts" in p)]


class _Blender:
    """The process's Blender session: cached primitives and one reusable modifier object."""

    def __init__(self):
        _drop_inherited_blender_paths()
        try:
            import bpy  # first: bmesh and mathutils are only importable once bpy is loaded
        except ImportError as exc:
            raise ImportError(
                f"cannot load Blender (bpy): {exc}. If pymeshlab was imported "
                "before bpy, its older Embree shadows Blender's; import pymeshlab "
                "through basic_shapes.verify, which loads Blender's first"
            ) from exc
        import bmesh
        import mathutils

        self.bpy, self.bmesh, self.mathutils = bpy, bmesh, mathutils
        bpy.ops.wm.read_factory_settings(use_empty=True)
        self.mesh = bpy.data.meshes.new("variant")
        self.obj = bpy.data.objects.new("variant", self.mesh)
        bpy.context.scene.collection.objects.link(self.obj)
        self.decimate = self.obj.modifiers.new("decimate", "DECIMATE")
        self.triangulate = self.obj.modifiers.new("triangulate", "TRIANGULATE")
        self.triangulate.min_vertices = 4
        self._primitives: dict[tuple, tuple[object, list[int]]] = {}
        self.shape: dict = {}  # keywords set by the hidden shape of the object being built
        self._frames: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    # --- primitives ---------------------------------------------------------------------
    def primitive(self, class_name: str, resolution: dict[str, int]):
        """Unit-space BMesh of a primitive at a tessellation (built once, never modified)."""
        return self._cached(class_name, resolution)[0]

    def _cached(self, class_name: str, resolution: dict[str, int]) -> tuple[object, list[int]]:
        """(BMesh, indices of its n-gons), built on first use."""
        spec = primitives.PRIMITIVES[class_name]
        options = self.shape if spec.shape else {}
        key = (class_name, tuple(sorted(resolution.items())), tuple(sorted(options.items())))
        if key not in self._primitives:
            if options:  # one object's shape at a time: drop the previous object's
                for old in [k for k in self._primitives if k[2] and k[2] != key[2]]:
                    self._primitives.pop(old)[0].free()
            bm = self._build_primitive(spec, {**resolution, **options})
            self._primitives[key] = bm, [i for i, f in enumerate(bm.faces) if len(f.verts) > 4]
        return self._primitives[key]

    def frame(self, class_name: str) -> tuple[np.ndarray, np.ndarray]:
        """(bbox centre, bbox extents) of the default tessellation as built by Blender.

        Every mesh of an object is mapped by the same affine map, centre -> origin and
        extents -> scale, so the simple mesh's bbox is exactly the requested one (to float32
        rounding; a UV sphere's is 0.9999990 rather than 1) and the variants keep their shape
        relative to it.
        """
        if class_name not in self._frames:
            bm = self.primitive(class_name, primitives.PRIMITIVES[class_name].default_resolution())
            co = np.array([v.co[:] for v in bm.verts], np.float64)
            lo, hi = co.min(axis=0), co.max(axis=0)
            self._frames[class_name] = ((lo + hi) / 2, hi - lo)
        return self._frames[class_name]

    def _build_primitive(self, spec: primitives.Primitive, resolution: dict[str, int]):
        if spec.construct is not None:
            co, rings = spec.construct(**resolution)
            co = np.asarray(co, np.float32)
        else:
            co, rings = self._operator_mesh(spec, resolution)
        extents = co.max(axis=0) - co.min(axis=0)
        if not np.allclose(extents, spec.extents, rtol=1e-5) or not np.allclose(
            co.max(axis=0) + co.min(axis=0), 0, atol=1e-5
        ):
            raise RuntimeError(
                f"{spec.operator or 'construct'}{resolution}: bbox extents {extents} are not "
                f"the registered {spec.extents} around the origin"
            )
        # The UV sphere operator merges duplicate vertices in a way that leaves its faces in a
        # different order (and rotation) in every process: put them in a canonical order.
        polygons = []
        for ring in rings:
            first = ring.index(min(ring))
            polygons.append(ring[first:] + ring[:first])
        polygons.sort()
        bm = self.bmesh.new()  # geometry only: UVs, seams and sharp flags would steer decimation
        verts = [bm.verts.new(p) for p in co.tolist()]
        for ring in polygons:
            bm.faces.new([verts[i] for i in ring])
        return bm

    def _operator_mesh(self, spec: primitives.Primitive, resolution: dict[str, int]):
        """(vertices float32 (V, 3), polygons as vertex lists) of Blender's operator."""
        bpy = self.bpy
        getattr(bpy.ops.mesh, spec.operator)(**spec.options, **resolution)
        obj = bpy.context.active_object
        mesh = obj.data
        bpy.data.objects.remove(obj)
        co = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", co)
        rings = [list(poly.vertices) for poly in mesh.polygons]
        bpy.data.meshes.remove(mesh)
        return co.reshape(-1, 3), rings

    # --- one mesh -------------------------------------------------------------------------
    def build(
        self, class_name: str, scale: np.ndarray, params: dict, rng: np.random.Generator | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (V, 3) float32 and triangles (F, 3) int32 of one mesh.

        With ``rng`` (a complex variant) the mesh gets loop cuts and decimation as drawn by
        _sample_params; what was done is added to ``params``.
        """
        spec = primitives.PRIMITIVES[class_name]
        start = time.process_time()
        cached, ngon_indices = self._cached(class_name, params["resolution"])
        bm = cached.copy()  # same element order as the cache
        try:
            centre, extents = self.frame(class_name)
            matrix = self.mathutils.Matrix
            to_scale = matrix.Diagonal((scale / extents).tolist() + [1.0]) @ matrix.Translation(
                (-centre).tolist()
            )
            self.bmesh.ops.transform(bm, matrix=to_scale, verts=bm.verts)
            start = _lap("primitive", start)
            if rng is not None and ngon_indices:
                # n-gons (caps) first, so that every cut ring ends in triangles
                bm.faces.ensure_lookup_table()
                method = {"CLIP": "EAR_CLIP"}.get(params["triangulate"]["ngon"], "BEAUTY")
                self.bmesh.ops.triangulate(
                    bm, faces=[bm.faces[i] for i in ngon_indices], ngon_method=method
                )
            if rng is not None:
                self._cut(bm, spec.euler, params, rng)
            start = _lap("loop_cuts", start)
            bm.to_mesh(self.mesh)
        finally:
            bm.free()
        self._set_modifiers(params)
        evaluated = self.obj.evaluated_get(self.bpy.context.evaluated_depsgraph_get()).data
        start = _lap("decimate", start)
        arrays = _arrays(evaluated)
        _lap("extract", start)
        return arrays

    def _cut(self, bm, euler: int, params: dict, rng: np.random.Generator) -> None:
        """Loop cuts towards a final triangle count drawn log-uniformly above the primitive's.

        The final count is base * (MAX_TRIANGLES / base) ** size. Collapse cuts past it by its
        overshoot and decimates back to it (ratio recorded), un-subdivide cuts past it by 2 per
        iteration, no decimation cuts to it. Records [[ring length, cuts], ...] in order.
        """
        base = 2 * (len(bm.verts) - euler)  # triangles of a closed mesh: 2 (V - chi)
        final = base * (MAX_TRIANGLES / base) ** params["size"]
        decimate = params["decimate"]
        growth = {
            "collapse": decimate.get("overshoot"),
            "unsubdiv": 2.0 ** decimate.get("iterations", 0),
            "none": 1.0,
        }[decimate["kind"]]
        target = min(final * growth, MAX_TRIANGLES)
        params["target_triangles"] = int(round(final))
        params["loop_cuts"] = cuts_done = []
        steps = params["cut_steps"]
        for step in range(steps):
            triangles = 2 * (len(bm.verts) - euler)
            ring = _random_ring(bm, rng)
            if ring is None:
                break
            per_cut = 2 * len(ring)  # each cut adds one vertex per ring edge
            room = (MAX_TRIANGLES - triangles) // per_cut
            if room < 1:
                break
            wanted = (target - triangles) / (steps - step) / per_cut
            cuts = int(
                np.clip(round(wanted * rng.uniform(0.5, 1.5)), 1, min(room, MAX_CUTS_PER_RING))
            )
            # use_single_edge fans out the triangles where a ring ends (no 180-degree corners)
            self.bmesh.ops.subdivide_edges(
                bm,
                edges=ring,
                cuts=cuts,
                use_grid_fill=False,
                use_single_edge=True,
                use_only_quads=False,
            )
            cuts_done.append([len(ring), cuts])
        if decimate["kind"] == "collapse":
            decimate["ratio"] = round(min(1.0, final / (2 * (len(bm.verts) - euler))), 6)

    def _set_modifiers(self, params: dict) -> None:
        """Configure both modifiers; every field is set, so no state leaks between meshes."""
        mod, decimate = self.decimate, params["decimate"]
        # a collapse whose cuts fell short of its target has nothing to do (ratio 1)
        mod.show_viewport = decimate["kind"] != "none" and decimate.get("ratio", 0.0) < 1.0
        mod.decimate_type = "UNSUBDIV" if decimate["kind"] == "unsubdiv" else "COLLAPSE"
        mod.ratio = decimate.get("ratio", 1.0)
        mod.iterations = decimate.get("iterations", 0)
        mod.use_collapse_triangulate = decimate.get("triangulate", False)
        mod.use_symmetry = False
        mod.vertex_group = ""
        # a collapse that triangulates leaves nothing for the Triangulate modifier to do
        self.triangulate.show_viewport = not (
            mod.show_viewport and mod.use_collapse_triangulate and decimate["kind"] == "collapse"
        )
        self.triangulate.quad_method = params["triangulate"]["quad"]
        self.triangulate.ngon_method = params["triangulate"]["ngon"]


def _random_ring(bm, rng: np.random.Generator, tries: int = 16):
    """The edges of the edge ring through a random edge, or None if none is found.

    A ring is the chain of opposite edges across quads (what a Blender loop cut subdivides),
    ending where it closes or meets a triangle, or the edges around a vertex whose faces are
    all triangles: a pole or a cone's apex (the only rings a cone has).
    """
    bm.edges.ensure_lookup_table()
    for _ in range(tries):
        edge = bm.edges[int(rng.integers(len(bm.edges)))]
        if any(len(f.verts) == 4 for f in edge.link_faces):
            return _quad_ring(edge)
        for vert in edge.verts:
            if all(len(f.verts) == 3 for f in vert.link_faces):
                return list(vert.link_edges)
    return None


def _quad_ring(edge) -> list:
    """The edge ring through ``edge``: opposite edges across quads, both ways, until a non-quad."""
    ring, seen = [edge], {edge}
    for loop in edge.link_loops:
        while len(loop.face.verts) == 4:
            loop = loop.link_loop_next.link_loop_next
            if loop.edge in seen:
                break
            seen.add(loop.edge)
            ring.append(loop.edge)
            if loop.link_loop_radial_next is loop:
                break
            loop = loop.link_loop_radial_next
    return ring


def _arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float32 (V, 3), faces int32 (F, 3)) of a triangulated Blender mesh.

    Reads the attribute arrays directly: ``loops.foreach_get`` is 200x slower."""
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.attributes["position"].data.foreach_get("vector", co)
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
    if len(corners) != 3 * len(mesh.polygons):
        raise RuntimeError("the Triangulate modifier left non-triangular faces")
    return co.reshape(-1, 3), corners.reshape(-1, 3)
