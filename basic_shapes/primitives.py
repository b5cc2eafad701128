"""Registry of the primitives the generator can build (no bpy here: verify.py reads it too).

A primitive is one of Blender's ``bpy.ops.mesh.primitive_*_add`` operators at its default
size (centred at the origin), or a unit-space mesh built per object (``construct``: the
rounded box, whose radius is in metres). Curved primitives name the operator keywords that set their
tessellation, the values a complex variant may use, and an analytic bound on how far a
tessellation lies from the smooth surface; verify.tolerance turns that into the Hausdorff
bound a variant must meet (derivation in docs/GENERATOR.md, "Mesh generation").

Adding a primitive is one entry in PRIMITIVES, for example a hexagonal prism (planar, so no
tessellation to vary; Blender puts a vertex on the y axis)::

    PRIMITIVES["hex_prism"] = Primitive(operator="primitive_cylinder_add", planar=True,
                                        extents=(3 ** 0.5, 2.0, 2.0), options={"vertices": 6})
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Resolution:
    """One tessellation keyword of a curved primitive and the values a variant may use.

    Allowed values are ``lo, lo + step, ..., hi``; the steps are chosen so that every
    allowed tessellation keeps a vertex at each bounding-box extreme (multiples of 4 around
    an axis, an even ring count), so all variants share the simple mesh's bounding box.
    """

    default: int
    lo: int
    hi: int
    step: int

    def values(self) -> range:
        return range(self.lo, self.hi + 1, self.step)

    def allows(self, value: int) -> bool:
        return self.lo <= value <= self.hi and (value - self.lo) % self.step == 0


COLLAPSE_OR_NONE = {"collapse": 0.8, "none": 0.2}
"""Un-subdivide removes cube corners and halves circle resolutions (GENERATOR.md)."""


@dataclass(frozen=True)
class Primitive:
    """How to build one primitive and how far its complex variants may depart from it.

    operator:   name in ``bpy.ops.mesh`` (called once per process and resolution), or "" for a
                primitive that ``construct`` builds.
    planar:     the shape is a polytope (every face flat): variants must match to ~1e-6.
    extents:    bounding-box extents of the operator's default mesh; ``scale`` divides
                by these per axis, so a mesh's bbox extents equal the requested scale.
    resolution: tessellation keywords of the operator (curved primitives only).
    gap:        unit-space bound g(res) such that the tessellation at ``res`` and the smooth
                surface are within g of each other (Hausdorff).
    convex:     the solid is convex and every tessellation is inscribed in the smooth surface
                (all vertices on it), so two tessellations are within max(g_a, g_b) of each
                other; otherwise the triangle inequality gives g_a + g_b.
    euler:      V - E + F of the closed surface (2 for a sphere-like shape, 0 for a torus).
    decimation: relative frequency of each Decimate mode applied after the loop cuts
                ("collapse", "unsubdiv", or "none"), only those that keep this shape.
    shape:      f(hidden shape parameters (``analytic.HIDDEN``), scale) -> the operator's (or
                ``construct``'s) keywords for one object; None for a primitive without any.
    construct:  f(**tessellation and shape keywords) -> (unit-space vertices, polygons): the
                mesh built here rather than by a Blender operator.
    metric:     the tessellation is built in metres, not a unit shape scaled per axis: ``gap``
                is already its bound relative to the bbox diagonal, worst case over scales and
                hidden parameters.
    """

    operator: str
    planar: bool
    extents: tuple[float, float, float]
    resolution: dict[str, Resolution] = field(default_factory=dict)
    gap: Callable[[dict[str, int]], float] | None = None
    convex: bool = True
    euler: int = 2
    decimation: dict[str, float] = field(default_factory=lambda: dict(COLLAPSE_OR_NONE))
    options: dict = field(default_factory=dict)
    shape: Callable[[dict, tuple], dict] | None = None
    construct: Callable[..., tuple] | None = None
    metric: bool = False

    def default_resolution(self) -> dict[str, int]:
        return {k: r.default for k, r in self.resolution.items()}

    def resolutions(self) -> list[dict[str, int]]:
        """Every allowed tessellation (one empty dict for a primitive without any)."""
        keys = list(self.resolution)
        return [
            dict(zip(keys, values))
            for values in itertools.product(*(self.resolution[k].values() for k in keys))
        ]

    def coarsest_resolution(self) -> dict[str, int]:
        """The allowed tessellation farthest from the smooth surface (smallest counts)."""
        return {k: min(r.lo, r.default) for k, r in self.resolution.items()}


def _polygon_gap(n: int) -> float:
    """Sagitta of a regular n-gon inscribed in the unit circle: 1 - cos(pi/n)."""
    return 1.0 - math.cos(math.pi / n)


def _uv_sphere_gap(res: dict[str, int]) -> float:
    """Every point of a UV sphere mesh lies at radius >= cos(pi/segments) cos(pi/(2 rings))."""
    return 1.0 - math.cos(math.pi / res["segments"]) * math.cos(math.pi / (2 * res["ring_count"]))


def _torus_gap(res: dict[str, int], major: float = 1.0, minor: float = 0.25) -> float:
    """Minor-circle sagitta plus the major-circle sagitta at the outer radius."""
    return minor * _polygon_gap(res["minor_segments"]) + (major + minor) * _polygon_gap(
        res["major_segments"]
    )


ROUND_RATIO_MAX = 0.45
"""The largest rounded-box radius over its smallest extent (``analytic.HIDDEN``)."""


def _unit_radii(round_ratio: float, scale) -> tuple[float, float, float]:
    """The rounded box's radius (round_ratio x the smallest extent, metres) along each axis of
    the unit box (extents 2), which the object's scale stretches back to a sphere."""
    radius = round_ratio * min(scale)
    return tuple(radius / (s / 2) for s in scale)


def _roundbox(segments: int, radii) -> tuple:
    """Unit-space vertices and polygons (quads, then the corners' pole fans)."""
    from basic_shapes.analytic import roundbox_polygons  # numba: only where meshes are built

    v, quads, tris = roundbox_polygons((1.0, 1.0, 1.0), radii, segments)
    return v, quads.tolist() + tris.tolist()


PRIMITIVES: dict[str, Primitive] = {
    "cube": Primitive(operator="primitive_cube_add", planar=True, extents=(2.0, 2.0, 2.0)),
    "cylinder": Primitive(
        operator="primitive_cylinder_add",
        planar=False,
        extents=(2.0, 2.0, 2.0),
        resolution={"vertices": Resolution(default=32, lo=24, hi=48, step=4)},
        gap=lambda r: _polygon_gap(r["vertices"]),
    ),
    "sphere": Primitive(
        operator="primitive_uv_sphere_add",
        planar=False,
        extents=(2.0, 2.0, 2.0),
        resolution={
            "segments": Resolution(default=32, lo=24, hi=48, step=4),
            "ring_count": Resolution(default=16, lo=12, hi=24, step=2),
        },
        gap=_uv_sphere_gap,
        decimation={"collapse": 0.7, "unsubdiv": 0.1, "none": 0.2},
    ),
    "cone": Primitive(
        operator="primitive_cone_add",
        planar=False,
        extents=(2.0, 2.0, 2.0),
        resolution={"vertices": Resolution(default=32, lo=24, hi=48, step=4)},
        gap=lambda r: _polygon_gap(r["vertices"]),
    ),
    "torus": Primitive(
        operator="primitive_torus_add",
        planar=False,
        extents=(2.5, 2.5, 0.5),
        convex=False,
        euler=0,
        resolution={
            "major_segments": Resolution(default=48, lo=48, hi=72, step=4),
            "minor_segments": Resolution(default=12, lo=12, hi=20, step=4),
        },
        gap=_torus_gap,
        decimation={"collapse": 0.6, "unsubdiv": 0.2, "none": 0.2},
    ),
    # The hidden-parameter track: a cone whose top radius is top_ratio times its base radius.
    # Every side quad is a planar trapezoid whose sagitta shrinks from the base rim's to
    # top_ratio times it, so the cone's gap bounds it for any ratio.
    "frustum": Primitive(
        operator="primitive_cone_add",
        planar=False,
        extents=(2.0, 2.0, 2.0),
        resolution={"vertices": Resolution(default=32, lo=24, hi=48, step=4)},
        gap=lambda r: _polygon_gap(r["vertices"]),
        shape=lambda params, scale: {"radius2": params["top_ratio"]},
    ),
    # The hidden-parameter track: a box whose edges and corners are rounded with the radius
    # round_ratio x its smallest extent, in metres (a sphere stays a sphere whatever the scale),
    # so the mesh is built for each object (``construct``), in unit space, by the same function
    # as its simulation mesh. Corners are UV-sphere octants (planar trapezoids) and edges
    # rectangles, so the gap is the UV sphere's at 4 x segments around, times the radius, at
    # most ROUND_RATIO_MAX / sqrt(3) of the diagonal (the radius is at most that ratio times
    # the smallest extent, and the diagonal at least sqrt(3) times it).
    "roundbox": Primitive(
        operator="",
        planar=False,
        extents=(2.0, 2.0, 2.0),
        # the default turns by 11.25 degrees per segment, as the cylinder's and UV sphere's do
        resolution={"segments": Resolution(default=8, lo=4, hi=12, step=1)},
        gap=lambda r: (
            ROUND_RATIO_MAX
            / math.sqrt(3)
            * _uv_sphere_gap({"segments": 4 * r["segments"], "ring_count": 2 * r["segments"]})
        ),
        shape=lambda params, scale: {"radii": _unit_radii(params["round_ratio"], scale)},
        construct=_roundbox,
        metric=True,
    ),
}

DEFAULT_CLASSES = ("cube", "cylinder", "sphere")


def get(class_name: str) -> Primitive:
    """The registry entry, or a clear error naming the known classes."""
    try:
        return PRIMITIVES[class_name]
    except KeyError:
        raise ValueError(
            f"unknown primitive class {class_name!r}; known: {', '.join(sorted(PRIMITIVES))}"
        ) from None
