"""Edge diffraction: the PTD fringe field of a mesh's sharp edges by equivalent edge currents.

Single-bounce physical optics (PO) already contains the PO part of every edge's diffraction
(the edge terms of the exact facet integrals). What it lacks is the *fringe* field, the
difference between the exact field of the local infinite wedge and its PO approximation,
which is also what makes monostatic returns polarization-dependent (HH ≠ VV, HV ≠ 0).
``edge_field`` adds it with equivalent line currents along each straight edge segment (PTD,
Ufimtsev; Michaeli's equivalent edge currents). Channels HH, VV, HV as ``field.CHANNELS``.

Geometry (``sharp_edges``). A straight edge segment from a to b, unit tangent t̂ = (b−a)/L.
Face 1 is the face whose winding runs a → b, face 2 the other one; n̂_1, n̂_2 are their
outward unit normals and û_1 = n̂_1 × t̂, û_2 = t̂ × n̂_2 the in-face directions leaving the
edge. In the plane perpendicular to t̂, the angle φ is measured from û_1 (φ = 0) towards n̂_1
(φ = π/2), counter-clockwise about t̂; face 2 lies at φ = α = Nπ, the exterior angle
(N = 1 + ψ/π for a convex edge whose normals turn by ψ; N = 2 for the boundary edge of an
open mesh, a half-plane; N = 3/2 for a box edge).

Monostatic wedge coefficients. For a line of sight r̂ (object towards the radar) the incidence
is oblique: cos β = r̂·t̂, sin β = |r̂ − (r̂·t̂)t̂|, and φ_0 is the azimuth of r̂'s projection.
The exact 2-D wedge diffraction coefficients (Sommerfeld; Ufimtsev's normalisation,
u^d = u_0 f e^{-j(kρ+π/4)}/√(2πkρ) for e^{jωt}), for E parallel (f, Dirichlet) and H parallel
(g, Neumann) to the edge, in backscatter φ = φ_0, reduce by the partial fractions
1/(sin a sin b) = (cot b − cot a)/sin(a − b) to

    f = C − S,   g = C + S,   C = −cot(π/2N)/N,   S = [cot(x_1/N) + cot(x_2/N)]/(2N),

with x_1 = φ_0 − π/2 and x_2 = α − π/2 − φ_0 the angles from the two face normals (x_i = 0 is
the specular direction of face i). The PO coefficients of the lit faces (Ufimtsev's f^(0),
g^(0)) are f^(0) = −g^(0) = −Σ_lit cot(x_i)/2, so the fringe coefficients are

    f¹ = C − D_1 − D_2,   g¹ = C + D_1 + D_2,
    D_i = q(x_i/N)/(2N) − q(x_i)/2   (face i lit: |x_i| < π/2),   cot(x_i/N)/(2N)   (unlit),

where q(t) = cot t − 1/t is regular (series for |t| < 1/2): the 1/x_i poles of the exact and
the PO coefficients at the specular directions (the Keller-cone caustics of backscatter) cancel
analytically, so f¹ and g¹ are finite and smooth there, and continuous where a face turns from
lit to unlit (cot(±π/2) = 0); f¹ + g¹ = 2C at every angle. Checks (tests): Ufimtsev's direct
forms for N = 2 (half-plane: f = (sec φ − 1)/2, g = −(sec φ + 1)/2), 3/2 (right angle) and
others; f¹, g¹ → 0 when N → 1 (a flat surface has no fringe).

Equivalent currents. Electric and magnetic line currents along t̂ whose radiation on the
Keller cone reproduces the 2-D fringe field of the oblique-incidence wedge problem (transverse
wavenumber k sin β) are I = 2j E_t f¹/(ηk sin²β), M = 2jη H_t g¹/(k sin²β) (the fringe form of
Michaeli's currents, IEEE TAP 32, 1984, and 34, 1986; Knott, Shaeffer & Tuley, "Radar Cross
Section", 2nd ed., ch. 5-6; Ufimtsev, "Fundamentals of the PTD", 2007, ch. 4 and 7). Radiated
back towards r̂ the sin β factors cancel (E_t = sin β E·ê_∥, |r̂ × (r̂ × t̂)| = sin β). With
ê_∥ = (t̂ − cos β r̂)/sin β and ê_⊥ = r̂ × t̂/sin β, and the amplitude convention of
``field`` (σ = |A|², a broadside plate real positive, e^{+j2k r̂·p}; the PO of a face gives
exactly the f^(0) edge terms below with the same factor, which fixes the phase j):

    A_pq = (j/√π) (f¹ (ê_p·ê_∥)(ê_q·ê_∥) − g¹ (ê_p·ê_⊥)(ê_q·ê_⊥)) ∫_a^b e^{j2k r̂·r} dl,

ê_p, ê_q ∈ {V, H}, V = θ̂ of the line of sight (``field.polarization``), H = r̂ × V = φ̂.
With t_V = V·t̂ and t_H = H·t̂ (t_V² + t_H² = sin²β):

    F_HH = (f¹ t_H² − g¹ t_V²)/sin²β,  F_VV = (f¹ t_V² − g¹ t_H²)/sin²β,
    F_HV = (f¹ + g¹) t_V t_H/sin²β = 2C t_V t_H/sin²β,

all bounded; HV = VH (reciprocity) holds by construction. Off broadside (β ≠ 90°) backscatter
is not on the Keller cone; the coefficients are the 2-D backscatter ones at φ_0 (the usual
choice). Michaeli's full off-cone currents and Mitzner's ILDC differ there by terms in cos β
(one cross-polarized), not modelled. At aspect 90° on an edge along z
(V = −ẑ): VV = f¹ (TM) and HH = −g¹ (TE), the 2-D fringe field scaled to 3-D as
``exact.to_3d``.

Phase integral, closed form. With s = r̂·r at the ends (s_a, s_b), the midpoint s_m and
h = (s_b − s_a)/2 = L cos β/2:

    ∫ e^{j2k r̂·r} dl = L e^{j2k s_m} sinc(2kh) = (e^{j2k s_b} − e^{j2k s_a})/(j2k cos β).

Where |2k_max h| >= ``SERIES_LIMIT`` (1e-3) the second form makes each segment two point
scatterers with frequency-independent weights ±F/(2√π cos β) and a 1/k factor, summed onto
the shared endpoints (collinear sub-segments add up exactly); their cancellation near
broadside costs at most ~ε/|2k_min h| ≈ 2e-11 of the segment's amplitude (ε ≈ 1e-14, the
phasors' error). Below, the sinc is a 9-term series in k at the midpoint (remainder < 1e-17),
so the segment seen broadside (cos β = 0) is exact.

Which edges, and the singular directions.
* An edge contributes where r̂ is outside the body's interior angle, i.e. where a face is lit
  or grazing (convex closed meshes need no shadow rays; other meshes get no shadowing of edges).
* Specular directions (x_i = 0, the caustics) are regular by the cancellation above.
* A face seen edge-on: f¹, g¹ are continuous as a face turns from lit to unlit. Where the last
  visible face turns away (φ_0 → 0 or α on a convex edge) f¹ → 0 but g¹ → −(2/N) cot(π/2N),
  and the edge leaves the view (the double diffraction that continues it physically is not
  modelled). The edge's contribution is therefore tapered to zero (smoothstep) as that face's
  r̂·n̂ goes from ``SHADOW_TAPER`` to 0, so the field is continuous everywhere.
* Grazing along the edge (sin β → 0): the terms are bounded but the limit depends on the
  azimuth of approach, and the canonical 2-D problem (transverse wavenumber k sin β) no longer
  describes a finite edge; the contribution is tapered to zero (smoothstep) for
  sin β < ``GRAZING_TAPER``.

Concave edges (their fringe needs the double reflection between the faces, which first-bounce
PO lacks) and the interior edges of open meshes are not treated; the smooth parts of the
simulation meshes (dihedral angles up to 6° on the convex primitives, 11.5° on eccentric tori)
are not edges.

Numerics. Per direction and edge the coefficients are formed in compiled code (numba, fixed
evaluation order, no fast-math; atan2 from libm, as ``basic_shapes.portable`` uses ``math``;
sin/cos of angles from the e^{jx} table of ``facet.cis``). The frequency sums Σ_p w_p e^{j2k s_p}
over the weighted end points take phasors accurate (exact phase by two-product, table) at every
``PHASOR_BLOCK``-th frequency of a uniform grid and times e^{j2rΔk s} in between, the powers
formed by doubling (relative error ~1e-14), and element-wise updates only (vectorized without
changing the bits), so the bytes do not depend on the CPU (tested under an emulated one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from basic_shapes.geometry import area_normals
from radar_sim import po_kernel
from radar_sim.field import CHANNELS, polarization
from radar_sim.scene import Mesh, prepare

MIN_DIHEDRAL_DEG = 15.0  # normals turning by more than this make a sharp edge
GRAZING_TAPER = 0.1  # sin β below which the contribution fades to 0 (grazing along the edge)
SHADOW_TAPER = 0.02  # r̂·n̂ (≈ elevation, rad) of the last visible face below which it fades
SERIES_LIMIT = 1e-3  # |2 k_max h| below which the segment integral is a series at the midpoint
SINC_TERMS = 9  # Σ_{m<9} (−x²)^m/(2m+1)!: remainder x^18/19! < 1e-17 for |x| <= 1
PHASOR_BLOCK = 32  # frequencies per accurate phasor on a uniform grid (stepped in between)
Q_SERIES_LIMIT = 0.5  # |t| below which cot t − 1/t is its series (12 terms: remainder < 1e-20)
_INV_SQRT_PI = 1.0 / math.sqrt(math.pi)
_CIS = (po_kernel.CIS_TABLE, po_kernel.CIS_PARAMS)  # e^{jx} table of ``facet.cis``
_TWO_PI = 2.0 * math.pi


def _cot_series(terms: int) -> np.ndarray:
    """c_n of cot t − 1/t = Σ_{n>=1} c_n t^{2n−1}: c_n = (−1)^n 2^{2n} B_{2n}/(2n)! (Bernoulli
    numbers, exact rationals rounded once)."""
    from fractions import Fraction

    bern = [Fraction(1)]
    for m in range(1, 2 * terms + 1):
        bern.append(-sum(math.comb(m + 1, j) * bern[j] for j in range(m)) / (m + 1))
    return np.array(
        [
            float((-1) ** n * 2 ** (2 * n) * bern[2 * n] / math.factorial(2 * n))
            for n in range(1, terms + 1)
        ]
    )


_COT_SERIES = _cot_series(12)  # −1/3, −1/45, −2/945, …


@dataclass(frozen=True)
class Wedges:
    """Sharp edge segments of a mesh (metres), in a deterministic order.

    ``points`` (P, 3): the segments' end points (mesh vertices), ``ends`` (E, 2) int64: start
    and end point of each segment (start has the lower vertex index), ``normals`` (E, 2, 3):
    outward unit normals of face 1 (the face whose winding runs start → end) and face 2,
    ``n`` (E,): exterior angle over π (1 < N <= 2; 3/2 for a right angle, 2 for a half-plane).
    """

    points: np.ndarray
    ends: np.ndarray
    normals: np.ndarray
    n: np.ndarray

    @property
    def count(self) -> int:
        return len(self.ends)

    @property
    def start(self) -> np.ndarray:
        """(E, 3) first end point of each segment."""
        return self.points[self.ends[:, 0]]

    @property
    def end(self) -> np.ndarray:
        """(E, 3) second end point of each segment."""
        return self.points[self.ends[:, 1]]

    @property
    def length(self) -> np.ndarray:
        """(E,) segment lengths in metres."""
        d = self.end - self.start
        return np.sqrt(_dot(d, d))

    @property
    def tangent(self) -> np.ndarray:
        """(E, 3) unit tangents from start to end."""
        return (self.end - self.start) / self.length[:, None]


def sharp_edges(mesh, min_dihedral_deg: float = MIN_DIHEDRAL_DEG) -> Wedges:
    """The wedges of a mesh: its convex edges whose face normals turn by more than
    ``min_dihedral_deg`` (closed meshes), and the boundary edges of open meshes (half-planes).

    ``mesh``: a ``radar_sim.scene.Mesh`` (as ``field.mesh_field`` receives it) or a
    ``(vertices, faces)`` pair, which is prepared (welded, oriented) first.

    The default of 15° lies above every angle between neighbouring facets on the smooth parts
    of the simulation meshes (at most 6° on the convex primitives: ``SIMULATION_RULES`` turn by
    <= 0.1 rad; 11.5° on an eccentric torus) and below the sharp rims of the primitives (box
    and cylinder 90°, cone base 93°-169°, frustum top rims down to 12° only for nearly flat
    frusta with a top ratio under 0.1, whose fringe is small: f¹, g¹ vanish like N − 1). The
    rounded box has none: its seams are tangent-continuous and its simulation mesh turns by
    about 0.05 rad at most between facets (tests/test_roundbox.py).
    Collinear consecutive segments stay separate (each is straight); the order is that of
    the (lower, higher) vertex index pairs, so it depends only on the mesh.
    """
    if not isinstance(mesh, Mesh):
        vertices, faces = mesh
        mesh = prepare(vertices, faces)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    normals = _unit(area_normals(v[f]))
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    face = np.tile(np.arange(len(f)), 3)
    lo, hi = directed.min(axis=1), directed.max(axis=1)
    forward = directed[:, 0] == lo  # the face's winding runs lo -> hi
    order = np.lexsort((~forward, hi, lo))  # per edge: the forward face first
    lo, hi, forward, face = lo[order], hi[order], forward[order], face[order]
    first = np.flatnonzero(np.r_[True, (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])])
    count = np.diff(np.r_[first, len(lo)])
    pairs, n1, n2, n_wedge = [], [], [], []
    two = first[count == 2]
    if len(two):
        ok = forward[two] & ~forward[two + 1]  # consistently wound (closed meshes: always)
        if mesh.closed:
            two = two[ok]
            a, b = normals[face[two]], normals[face[two + 1]]
            t = _unit(v[hi[two]] - v[lo[two]])
            cross = _dot(np.cross(a, b), t)  # sin ψ, signed: > 0 convex
            cos = _dot(a, b)
            psi = np.array([math.atan2(float(s), float(c)) for s, c in zip(cross, cos)])
            keep = psi > math.radians(min_dihedral_deg)
            pairs.append(np.stack([lo[two], hi[two]], axis=1)[keep])
            n1.append(a[keep])
            n2.append(b[keep])
            n_wedge.append(1.0 + psi[keep] / math.pi)
    one = first[count == 1]
    if len(one) and not mesh.closed:  # boundary of a sheet: a half-plane, both sides faces
        # face 1 is the side whose winding runs start -> end: the face, or its back
        a = normals[face[one]] * np.where(forward[one], 1.0, -1.0)[:, None]
        pairs.append(np.stack([lo[one], hi[one]], axis=1))
        n1.append(a)
        n2.append(-a)
        n_wedge.append(np.full(len(one), 2.0))
    if not pairs:
        return _empty()
    pairs = np.concatenate(pairs)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    pairs = pairs[order]
    normal_pairs = np.stack([np.concatenate(n1), np.concatenate(n2)], axis=1)[order]
    n_wedge = np.concatenate(n_wedge)[order]
    if not len(pairs):
        return _empty()
    used, ends = np.unique(pairs, return_inverse=True)
    return Wedges(
        points=np.ascontiguousarray(v[used]),
        ends=np.ascontiguousarray(ends.reshape(-1, 2).astype(np.int64)),
        normals=np.ascontiguousarray(normal_pairs),
        n=np.ascontiguousarray(n_wedge),
    )


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (n, 3) arrays, summed in a fixed order (no BLAS, no einsum)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.sqrt(_dot(a, a))[:, None]


def _empty() -> Wedges:
    return Wedges(np.zeros((0, 3)), np.zeros((0, 2), np.int64), np.zeros((0, 2, 3)), np.zeros(0))


def fringe_coefficients(phi0, n) -> tuple[np.ndarray, np.ndarray]:
    """Monostatic fringe coefficients (f¹, g¹) of a wedge of exterior angle Nπ at azimuth
    ``phi0`` (radians from face 1, 0 <= φ_0 <= Nπ), broadcast together; f¹ for E parallel to
    the edge (TM), g¹ for H parallel (TE), Ufimtsev's normalisation (module docstring)."""
    phi0, n = np.broadcast_arrays(np.asarray(phi0, np.float64), np.asarray(n, np.float64))
    f1 = np.empty(phi0.shape)
    g1 = np.empty(phi0.shape)
    for i in np.ndindex(phi0.shape):
        p, m = float(phi0[i]), float(n[i])
        x1, x2 = p - 0.5 * math.pi, m * math.pi - 0.5 * math.pi - p
        cot1 = math.cos(x1) / math.sin(x1) if x1 != 0 else 0.0
        cot2 = math.cos(x2) / math.sin(x2) if x2 != 0 else 0.0
        cos_pn, sin_pn = math.cos(math.pi / m), math.sin(math.pi / m)
        f1[i], g1[i] = _fringe(p, m, _wedge_constant(m), cos_pn, sin_pn, cot1, cot2, *_CIS)
    return f1, g1


def edge_field(edges: Wedges, k, directions) -> np.ndarray:
    """Fringe field of the equivalent edge currents, to be added to the PO field.

    ``edges``: ``sharp_edges(mesh)``; ``k`` (n_freq,) wavenumbers 2πf/c in rad/m;
    ``directions`` (n_dir, 3) unit lines of sight (object towards radar, object frame).
    Returns complex (n_dir, 3, n_freq): channels ``CHANNELS`` = (HH, VV, HV), amplitude A with
    σ = |A|² (m²), phase referenced to the origin as ``field.mesh_field``; V = θ̂ of the line
    of sight (x̂·sign(cos θ) at the poles, ``field.polarization``), H = r̂ × V = φ̂.
    """
    k = np.ascontiguousarray(np.atleast_1d(np.asarray(k, dtype=np.float64)))
    if k.ndim != 1 or not len(k) or not np.all(np.isfinite(k)) or np.any(k <= 0):
        raise ValueError("k must be a non-empty 1-D array of positive wavenumbers (rad/m)")
    r = np.asarray(directions, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 3:
        raise ValueError(f"directions must have shape (n, 3), got {np.shape(directions)}")
    norm = np.sqrt(_dot(r, r))
    if not np.all(np.isfinite(norm)) or np.any(np.abs(norm - 1.0) > 1e-6):
        raise ValueError("directions must be unit vectors (|r| = 1 within 1e-6)")
    out_re = np.zeros((len(r), len(CHANNELS), len(k)))
    out_im = np.zeros_like(out_re)
    if edges.count and len(r):
        r = np.ascontiguousarray(r)
        v = np.ascontiguousarray(polarization(r))
        h = np.ascontiguousarray(np.cross(r, v))
        t = np.ascontiguousarray(edges.tangent)
        n1 = np.ascontiguousarray(edges.normals[:, 0])
        n2 = np.ascontiguousarray(edges.normals[:, 1])
        u1 = np.ascontiguousarray(np.cross(n1, t))
        u2 = np.ascontiguousarray(np.cross(t, n2))
        nw = np.ascontiguousarray(edges.n, dtype=np.float64)
        const = np.array([_wedge_constant(float(x)) for x in nw])
        cos_pn = np.array([math.cos(math.pi / float(x)) for x in nw])
        sin_pn = np.array([math.sin(math.pi / float(x)) for x in nw])
        _edge_kernel(
            r,
            v,
            h,
            np.ascontiguousarray(edges.points),
            np.ascontiguousarray(edges.ends),
            t,
            edges.length,
            u1,
            n1,
            u2,
            n2,
            nw,
            const,
            cos_pn,
            sin_pn,
            k,
            _uniform_step(k) * 2.0,
            po_kernel.CIS_TABLE,
            po_kernel.CIS_PARAMS,
            np.array([GRAZING_TAPER, SHADOW_TAPER, SERIES_LIMIT]),
            out_re,
            out_im,
        )
    return out_re + 1j * out_im


def _wedge_constant(n: float) -> float:
    """C = −cot(π/2N)/N (libm, the same bits everywhere)."""
    a = math.pi / (2.0 * n)
    return -math.cos(a) / (math.sin(a) * n)


def _uniform_step(k: np.ndarray) -> float:
    """Δk of a uniform grid (k_n = k_0 + nΔk to 4 ulp), else 0: phasors are then stepped."""
    if len(k) < 2:
        return 0.0
    dk = (k[-1] - k[0]) / (len(k) - 1)
    grid = k[0] + dk * np.arange(len(k))
    eps = np.finfo(np.float64).eps
    return float(dk) if dk > 0 and np.all(np.abs(grid - k) <= 4 * eps * k) else 0.0


# ---------------------------------------------------------------------------------------------
# compiled part


@njit(cache=True, inline="always")
def _q(t):
    """cot t − 1/t, regular at 0: its Taylor series below Q_SERIES_LIMIT (the direct form would
    cancel), the direct form above it (cancellation at most a factor 12 at t = 1/2)."""
    if abs(t) >= Q_SERIES_LIMIT:
        return math.cos(t) / math.sin(t) - 1.0 / t
    u = t * t
    acc = _COT_SERIES[len(_COT_SERIES) - 1]
    for i in range(len(_COT_SERIES) - 2, -1, -1):
        acc = acc * u + _COT_SERIES[i]
    return t * acc


@njit(cache=True, inline="always")
def _fringe(phi0, n, c, cos_pn, sin_pn, cot1, cot2, tab, par):
    """(f¹, g¹) at azimuth φ_0 of a wedge with exterior angle Nπ: C = ``_wedge_constant``,
    (cos, sin)(π/N), and cot x_1, cot x_2 of the face-normal angles (used where a face is lit
    and |x_i| >= 1/2; the caller has them from vector components). One cis (table), no libm."""
    alpha = n * math.pi
    x1 = phi0 - 0.5 * math.pi
    x2 = alpha - 0.5 * math.pi - phi0
    t1 = x1 / n  # t1 + t2 = π − π/N
    c1, s1 = _cis(t1, 0.0, tab, par)
    c2 = -(cos_pn * c1 - sin_pn * s1)  # cos(π − π/N − t1)
    s2 = sin_pn * c1 + cos_pn * s1
    d = 0.0
    for x, t, ct, st, cot_x in ((x1, t1, c1, s1, cot1), (x2, x2 / n, c2, s2, cot2)):
        if abs(x) < 0.5 * math.pi:  # face lit: the specular poles cancel analytically
            q_t = _q(t) if abs(t) < Q_SERIES_LIMIT else ct / st - 1.0 / t
            q_x = _q(x) if abs(x) < Q_SERIES_LIMIT else cot_x - 1.0 / x
            d += 0.5 * (q_t / n - q_x)
        else:
            d += 0.5 * ct / (st * n)
    return c - d, c + d


@njit(cache=True, inline="always")
def _smoothstep(x):
    if x >= 1.0:
        return 1.0
    if x <= 0.0:
        return 0.0
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, inline="always")
def _split(a):
    t = a * 134217729.0
    hi = t - (t - a)
    return hi, a - hi


@njit(cache=True, inline="always")
def _cis_of_product(s, two_k, tab, par):
    """(cos, sin) of s·two_k, the product formed exactly (two-product), then ``facet.cis``."""
    x = s * two_k
    ah, al = _split(s)
    bh, bl = _split(two_k)
    return _cis(x, ((ah * bh - x) + ah * bl + al * bh) + al * bl, tab, par)


@njit(cache=True, inline="always")
def _cis(x, x_lo, tab, par):
    """(cos, sin) of x + x_lo: ``facet.cis`` (4096-entry table and a short polynomial, a few
    ulp), libm beyond 6.6e6 rad. The same as ``po_kernel._cis`` on purpose: numba's on-disk
    cache is keyed on the caller's file only, so a compiled helper imported from another
    module would go stale in it when that module changes; each kernel file keeps its own."""
    if abs(x) > par[3]:
        c, sn = math.cos(x), math.sin(x)
        return c - sn * x_lo, sn + c * x_lo
    m = math.floor(x * par[0] + 0.5)
    r = x - m * par[1]
    r -= m * par[2]
    r += x_lo
    r2 = r * r
    cm1 = r2 * (-0.5 + r2 * (1.0 / 24.0))
    sn = r * (1.0 + r2 * (-1.0 / 6.0 + r2 * (1.0 / 120.0)))
    i = int(m) & (tab.shape[1] - 1)
    tr = tab[0, i]
    ti = tab[1, i]
    return tr + (tr * cm1 - ti * sn), ti + (tr * sn + ti * cm1)


@njit(cache=True, inline="always")  # array arguments of a call cost reference counts
def _phasors(s, k, two_dk, z_re, z_im, ph_re, ph_im, tab, par):
    """e^{j2k_n s} into (ph_re, ph_im). On a uniform grid: accurate (exact phase, table) at
    every PHASOR_BLOCK-th frequency, times e^{j2rΔk s} (r < PHASOR_BLOCK) in between, the
    powers by doubling (z^{m+r} = z^m z^r): relative error <= ~2·log2(PHASOR_BLOCK) ulp + 2 ulp.
    Otherwise accurate at every frequency."""
    n_k = len(k)
    if two_dk > 0.0:
        block = z_re.shape[0]
        zr, zi = _cis_of_product(s, two_dk, tab, par)
        z_re[0], z_im[0], z_re[1], z_im[1] = 1.0, 0.0, zr, zi
        have = 2
        while have < block:
            zr, zi = zr * zr - zi * zi, 2.0 * zr * zi  # z^have
            for r in range(have):
                z_re[have + r] = z_re[r] * zr - z_im[r] * zi
                z_im[have + r] = z_re[r] * zi + z_im[r] * zr
            have *= 2
        for lo in range(0, n_k, block):
            ar, ai = _cis_of_product(s, 2.0 * k[lo], tab, par)
            for r in range(min(block, n_k - lo)):
                ph_re[lo + r] = ar * z_re[r] - ai * z_im[r]
                ph_im[lo + r] = ar * z_im[r] + ai * z_re[r]
    else:
        for i in range(n_k):
            ph_re[i], ph_im[i] = _cis_of_product(s, 2.0 * k[i], tab, par)


@njit(cache=True)
def _frequency_sums(s, w, k, two_dk, tab, par, out_re, out_im):
    """out[c] += Σ_p w[c, p] e^{j2k s_p}/k for the three channels c (one direction)."""
    n_k = len(k)
    z_re = np.empty(PHASOR_BLOCK)
    z_im = np.empty(PHASOR_BLOCK)
    ph_re = np.empty(n_k)
    ph_im = np.empty(n_k)
    a0r, a0i, a1r, a1i = np.zeros(n_k), np.zeros(n_k), np.zeros(n_k), np.zeros(n_k)
    a2r, a2i = np.zeros(n_k), np.zeros(n_k)
    for p in range(len(s)):
        w0, w1, w2 = w[0, p], w[1, p], w[2, p]
        _phasors(s[p], k, two_dk, z_re, z_im, ph_re, ph_im, tab, par)
        for i in range(n_k):  # element-wise: vectorized, the same bits at any width
            a0r[i] += w0 * ph_re[i]
        for i in range(n_k):
            a0i[i] += w0 * ph_im[i]
        for i in range(n_k):
            a1r[i] += w1 * ph_re[i]
        for i in range(n_k):
            a1i[i] += w1 * ph_im[i]
        for i in range(n_k):
            a2r[i] += w2 * ph_re[i]
        for i in range(n_k):
            a2i[i] += w2 * ph_im[i]
    for i in range(n_k):
        out_re[0, i] += a0r[i] / k[i]
        out_im[0, i] += a0i[i] / k[i]
        out_re[1, i] += a1r[i] / k[i]
        out_im[1, i] += a1i[i] / k[i]
        out_re[2, i] += a2r[i] / k[i]
        out_im[2, i] += a2i[i] / k[i]


# C901: a numba kernel, its loop nest over the edges kept in one piece; a split would first
# have to be timed against it (no loss of speed, as for po_kernel.first_bounce)
@njit(cache=True)
def _edge_kernel(  # noqa: C901
    r,
    pol_v,
    pol_h,
    points,
    ends,
    t,
    length,
    u1,
    n1,
    u2,
    n2,
    nw,
    const,
    cos_pn,
    sin_pn,
    k,
    two_dk,
    tab,
    par,
    limits,
    out_re,
    out_im,
):
    """Per direction: the channel weights of every visible segment, as endpoint weights (1/k)
    or, near broadside, a series at the midpoint; then the frequency sums."""
    grazing, shadow, series_limit = limits[0], limits[1], limits[2]
    n_pts = points.shape[0]
    n_k = len(k)
    k_max = 0.0
    for i in range(n_k):
        k_max = max(k_max, k[i])
    weight = np.zeros((n_pts, 3))
    touched = np.zeros(n_pts, dtype=np.bool_)
    stack = np.empty(n_pts, dtype=np.int64)
    s = np.empty(n_pts)
    ts = np.empty(n_pts)  # the end points with weights, of one direction
    tw = np.empty((3, n_pts))
    fact = np.empty(SINC_TERMS)
    fact[0] = 1.0
    for m in range(1, SINC_TERMS):
        fact[m] = -fact[m - 1] / ((2.0 * m) * (2.0 * m + 1.0))  # (−1)^m/(2m+1)!
    for d in range(r.shape[0]):
        rx, ry, rz = r[d, 0], r[d, 1], r[d, 2]
        for p in range(n_pts):
            s[p] = rx * points[p, 0] + ry * points[p, 1] + rz * points[p, 2]
        n_touched = 0
        for e in range(ends.shape[0]):
            y1 = rx * n1[e, 0] + ry * n1[e, 1] + rz * n1[e, 2]
            y2 = rx * n2[e, 0] + ry * n2[e, 1] + rz * n2[e, 2]
            if y1 < 0.0 and y2 < 0.0:
                continue  # inside the body's interior angle: the edge is not seen
            x = rx * u1[e, 0] + ry * u1[e, 1] + rz * u1[e, 2]
            sin_b = math.sqrt(x * x + y1 * y1)
            taper = _smoothstep(sin_b / grazing)
            if taper == 0.0:
                continue
            if nw[e] < 2.0:  # the last visible face's elevation, when the other one is dark
                if y2 < 0.0:
                    taper *= _smoothstep(y1 / shadow)
                elif y1 < 0.0:
                    taper *= _smoothstep(y2 / shadow)
                if taper == 0.0:
                    continue
            phi0 = math.atan2(y1, x)
            if phi0 < 0.0:
                phi0 += _TWO_PI
            phi0 = min(phi0, nw[e] * math.pi)
            xu2 = rx * u2[e, 0] + ry * u2[e, 1] + rz * u2[e, 2]
            # cot x_1 = −tan φ_0, cot x_2 = −tan(α − φ_0), from the components (lit faces only)
            cot1 = -y1 / x if x != 0.0 else 0.0
            cot2 = -y2 / xu2 if xu2 != 0.0 else 0.0
            f1, g1 = _fringe(phi0, nw[e], const[e], cos_pn[e], sin_pn[e], cot1, cot2, tab, par)
            tv = pol_v[d, 0] * t[e, 0] + pol_v[d, 1] * t[e, 1] + pol_v[d, 2] * t[e, 2]
            th = pol_h[d, 0] * t[e, 0] + pol_h[d, 1] * t[e, 1] + pol_h[d, 2] * t[e, 2]
            scale = taper * _INV_SQRT_PI / (tv * tv + th * th)
            w_hh = (f1 * th * th - g1 * tv * tv) * scale
            w_vv = (f1 * tv * tv - g1 * th * th) * scale
            w_hv = (f1 + g1) * tv * th * scale
            a, b = ends[e, 0], ends[e, 1]
            half = 0.5 * (s[b] - s[a])
            if abs(2.0 * k_max * half) >= series_limit:
                # (j/√π) F (e^{j2ks_b} − e^{j2ks_a})/(j2k cos β) = F/(2√π cos β)·(…)/k
                c = 0.5 * length[e] / (2.0 * half)  # 1/(2 cos β)
                if not touched[b]:
                    touched[b] = True
                    stack[n_touched] = b
                    n_touched += 1
                if not touched[a]:
                    touched[a] = True
                    stack[n_touched] = a
                    n_touched += 1
                weight[b, 0] += c * w_hh
                weight[b, 1] += c * w_vv
                weight[b, 2] += c * w_hv
                weight[a, 0] -= c * w_hh
                weight[a, 1] -= c * w_vv
                weight[a, 2] -= c * w_hv
            else:
                # (j/√π) F L e^{j2ks_m} sinc(2kh), the sinc as a series in (2kh)²
                mid = 0.5 * (s[a] + s[b])
                h2 = 4.0 * half * half
                for i in range(n_k):
                    pr, pi = _cis_of_product(mid, 2.0 * k[i], tab, par)
                    x2 = h2 * k[i] * k[i]
                    series = fact[SINC_TERMS - 1]
                    for m in range(SINC_TERMS - 2, -1, -1):
                        series = series * x2 + fact[m]
                    amp = length[e] * series
                    # j·(pr + j pi) = −pi + j pr
                    out_re[d, 0, i] -= w_hh * amp * pi
                    out_im[d, 0, i] += w_hh * amp * pr
                    out_re[d, 1, i] -= w_vv * amp * pi
                    out_im[d, 1, i] += w_vv * amp * pr
                    out_re[d, 2, i] -= w_hv * amp * pi
                    out_im[d, 2, i] += w_hv * amp * pr
        if n_touched == 0:
            continue
        m = 0
        for j in range(n_touched):
            p = stack[j]
            touched[p] = False
            if weight[p, 0] != 0.0 or weight[p, 1] != 0.0 or weight[p, 2] != 0.0:
                ts[m] = s[p]
                tw[0, m], tw[1, m], tw[2, m] = weight[p, 0], weight[p, 1], weight[p, 2]
                m += 1
            weight[p, 0] = 0.0
            weight[p, 1] = 0.0
            weight[p, 2] = 0.0
        _frequency_sums(ts[:m], tw[:, :m], k, two_dk, tab, par, out_re[d], out_im[d])
