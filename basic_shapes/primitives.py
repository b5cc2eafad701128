"""Registry of the primitives the generator can build (no bpy here: verify.py reads it too).

A primitive is one of Blender's ``bpy.ops.mesh.primitive_*_add`` operators at its default
size (centred at the origin). Curved primitives name the operator keywords that set their
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

    operator:   name in ``bpy.ops.mesh`` (called once per process and resolution).
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
    shape:      operator keywords set by an object's hidden shape parameters
                (``analytic.HIDDEN``); None for a primitive without any.
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
    shape: Callable[[dict], dict] | None = None

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
        shape=lambda params: {"radius2": params["top_ratio"]},
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
