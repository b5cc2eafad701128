"""The monostatic PO field of a mesh for many directions and frequencies.

One geometric pass per direction serves every frequency (``po_kernel``, compiled): each lit
facet becomes three vertex scatterers with frequency-independent weights, summed onto the
mesh's unique vertices, so the frequency sum runs over V scatterers instead of 3F. Facets
where those weights would lose digits (phases nearly coincident) get exact series forms
(polynomials in k) or, rarely, the stable per-frequency evaluation (docs/RADAR.md "Numerics").
The vertex sums Σ_v W_v e^{j2k_n s_v} become binned Taylor moments per direction, contracted
with one direction-independent matrix for all directions at once (``_Moments``).

Shadowing (mode "shadowed") casts one Embree ray per lit facet from its centroid towards the
radar; "bounce2" adds the second and third bounces by shooting and bouncing rays
(``sbr_field``).

Channels (docs/RADAR.md "Polarization"): V = θ̂ and H = φ̂ = r̂ × θ̂ of the line of sight.
Single-bounce PO backscatter is the same for HH and VV and has no HV; the bounces of "bounce2"
and edge diffraction (``radar_sim.edges``) tell the channels apart.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import math
import warnings

import numpy as np

from basic_shapes.portable import complex_parts, matmul, matmul_parts
from radar_sim import facet, po_kernel
from radar_sim.scene import Mesh, RayCaster, UnitsWarning, check_units, mode_of, prepare

C0 = 299_792_458.0
MODES = ("auto", "convex", "shadowed", "bounce2")
CHANNELS = ("HH", "VV", "HV")  # transmit-receive; VH = HV by reciprocity
EDGES = ("none", "mec")  # edge diffraction: none, or Michaeli's equivalent edge currents
DEFAULT_TOL = 1e-10  # bound on each facet's error relative to its specular magnitude P k/√π
GROUP = 64  # directions per kernel call (same in every mode: same bytes)
VERTEX_TERM_COST = 8.0  # one moment update per vertex / one multiply-add of the contraction
DIRECT_COST = 30.0  # one direct phasor and multiply-add / one of the contraction
MOMENT_EPS = facet.EPS / 16  # Taylor remainder of a vertex phasor in the binned sums
MOMENT_BUDGET = 64 << 20  # bytes of moments (or contraction matrix) held at a time
SETUP_CHUNK = 1 << 14  # faces per step of the per-mesh set-up (area vectors)
MIN_PLAUSIBLE_HZ = 1e6  # physical optics on a mesh below 1 MHz: GHz given as Hz


def _cis_of_product(s, s_parts, c) -> np.ndarray:
    """exp(j·s·c) with s·c formed exactly (two-product), so the phase is exact before cis."""
    return facet.cis(*facet.two_product(s, np.asarray(c, dtype=np.float64), s_parts))


def wavenumbers(frequencies_hz) -> np.ndarray:
    f = np.atleast_1d(np.asarray(frequencies_hz, dtype=np.float64))
    if f.ndim != 1 or len(f) == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError(f"frequencies must be a non-empty 1-D array of positive Hz, got {f!r}")
    if f.max() < MIN_PLAUSIBLE_HZ:
        warnings.warn(
            f"frequencies up to {f.max():g} Hz: the simulator takes Hz, so these look "
            f"like GHz (pass {f.max() * 1e9:g} for {f.max():g} GHz)",
            UnitsWarning,
            stacklevel=3,
        )
    return 2.0 * np.pi * f / C0


def unit_directions(directions) -> np.ndarray:
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim == 1:
        d = d[None, :]
    if d.ndim != 2 or d.shape[1] != 3 or len(d) == 0:
        raise ValueError(f"directions must have shape (n, 3), got {np.shape(directions)}")
    norm = np.linalg.norm(d, axis=1)
    if not np.all(np.isfinite(norm)) or np.any(np.abs(norm - 1.0) > 1e-6):
        raise ValueError("directions must be unit vectors (|r| = 1 within 1e-6)")
    return d / norm[:, None]


def resolve_mode(mode: str, mesh: Mesh) -> str:
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    return mode_of(mesh) if mode == "auto" else mode


def monostatic_field(
    vertices, faces, frequencies_hz, directions, mode: str = "auto", *, tol: float = DEFAULT_TOL
) -> np.ndarray:
    """Complex field amplitude A (σ = |A|² in m²), shape (n_directions, n_frequencies).

    ``directions``: unit lines of sight (object towards radar) in the object frame.
    ``mode``: "auto" (``detect_mode``), "convex" (back-face culling only), "shadowed" (Embree
    shadow rays), "bounce2" (shadowed + bounces 2 and 3 by shooting and bouncing rays).
    ``tol``: bound on each facet's numerical error relative to its specular magnitude.
    """
    mesh = prepare(vertices, faces)
    check_units(mesh)
    return mesh_field(
        mesh,
        wavenumbers(frequencies_hz),
        unit_directions(directions),
        resolve_mode(mode, mesh),
        tol,
    )


def polarimetric_field(
    vertices,
    faces,
    frequencies_hz,
    directions,
    mode: str = "auto",
    *,
    edges: str = "none",
    tol: float = DEFAULT_TOL,
) -> np.ndarray:
    """Complex field amplitude per channel, shape (n_directions, 3, n_frequencies), channels
    ``CHANNELS`` = HH, VV, HV (V = θ̂, H = φ̂ of the line of sight); ``edges="mec"`` adds edge
    diffraction. Arguments as ``monostatic_field``, whose result is the VV channel here with
    ``edges="none"``."""
    mesh = prepare(vertices, faces)
    check_units(mesh)
    return channel_field(
        mesh,
        wavenumbers(frequencies_hz),
        unit_directions(directions),
        resolve_mode(mode, mesh),
        tol,
        CHANNELS,
        edges,
    )


@functools.cache
def _keep_heap() -> None:
    """Ask glibc to keep 64 MiB at the top of the heap instead of returning it to the OS on
    every large free: otherwise each batch's numpy temporaries page-fault again (measured 5x
    slower on small VMs). Process-wide and harmless; skipped where there is no glibc."""
    try:
        ctypes.CDLL(ctypes.util.find_library("c")).mallopt(-2, 64 << 20)  # M_TOP_PAD
    except (OSError, AttributeError, TypeError):
        pass


def mesh_field(
    mesh: Mesh, k: np.ndarray, directions: np.ndarray, mode: str, tol: float = DEFAULT_TOL
) -> np.ndarray:
    """``monostatic_field`` on a prepared mesh, wavenumbers and unit directions: the VV
    channel of ``channel_field`` without edge diffraction."""
    return channel_field(mesh, k, directions, mode, tol, ("VV",))[:, 0]


def channel_field(
    mesh: Mesh,
    k: np.ndarray,
    directions: np.ndarray,
    mode: str,
    tol: float = DEFAULT_TOL,
    channels: tuple[str, ...] = CHANNELS,
    edges: str = "none",
) -> np.ndarray:
    """(n_directions, len(channels), n_frequencies) complex: the field per polarization
    channel (``CHANNELS``), with edge diffraction where ``edges`` is "mec"."""
    bad = [c for c in channels if c not in CHANNELS]
    if bad or not channels or edges not in EDGES:
        raise ValueError(f"channels must come from {CHANNELS} and edges from {EDGES}")
    _keep_heap()
    unique, inverse = np.unique(directions, axis=0, return_inverse=True)
    caster = RayCaster(mesh) if mode in ("shadowed", "bounce2") else None
    po = _po_field(mesh, k, unique, caster, tol)
    co = np.array([c != "HV" for c in channels])
    field = po[:, None, :] * co[None, :, None]  # exactly 0 in HV
    if mode == "bounce2":
        field += sbr_field(mesh, k, unique, caster, channels=channels)
    if edges == "mec":
        from radar_sim import edges as edge_diffraction

        wedges = edge_diffraction.sharp_edges(mesh)
        if wedges.count:
            field += edge_diffraction.edge_field(wedges, k, unique)[:, _indices(channels)]
    return field[inverse.reshape(-1)]


def _indices(channels: tuple[str, ...]) -> list[int]:
    return [CHANNELS.index(c) for c in channels]


class _Geometry:
    """Per-mesh arrays of the kernel: facet area vectors (double-double) and corners, with the
    vertices renumbered in the order the faces first use them (``v``, ``f``; ``local[i]`` is
    the new number of the mesh's vertex i). ``prepare`` sorts vertices by x, y, z, which puts
    a face's three corners far apart in memory: once the per-vertex positions and weights
    outgrow the core's L2 cache (about 130k faces), the facet pass waited on memory for every
    corner (perf/kernel_bound.py). Renumbered, neighbouring faces share cache lines. The
    moment sums still run over the mesh's own order (``v_in_order``): no sum changes order."""

    def __init__(self, mesh: Mesh):
        faces = np.asarray(mesh.faces)
        first = np.full(len(mesh.vertices), faces.size, dtype=np.int64)
        np.minimum.at(first, faces.ravel(), np.arange(faces.size))
        order = np.argsort(first, kind="stable")  # vertices by first use (unused: last)
        self.local = np.empty(len(order), dtype=np.int32)
        self.local[order] = np.arange(len(order), dtype=np.int32)
        self.v_in_order = np.ascontiguousarray(mesh.vertices)
        self.v = np.ascontiguousarray(self.v_in_order[order])
        self.f = np.ascontiguousarray(self.local[faces])  # int32: half the traffic
        # by chunks of faces: the double-double arithmetic's temporaries stay in the cache
        # (1.06 against 0.52 µs per face at 500k and 130k faces in one piece); every step is
        # elementwise, so the chunks give the same bytes
        chunks = range(0, max(len(faces), 1), SETUP_CHUNK)
        parts = [
            facet.area_vectors_split(self.v_in_order[faces[i : i + SETUP_CHUNK]]) for i in chunks
        ]
        self.area = np.concatenate([hi for hi, _ in parts])
        self.area_lo = np.concatenate([lo for _, lo in parts])
        self.area_split = np.concatenate(facet.split(self.area), axis=1)  # (F, 6)
        self.two_sided = not mesh.closed
        self._mesh = mesh

    @functools.cached_property
    def centroids(self) -> np.ndarray:  # shadow rays only
        return self._mesh.centroids

    @functools.cached_property
    def normals(self) -> np.ndarray:  # shadow rays only
        return self.area / np.linalg.norm(self.area, axis=1, keepdims=True)


class _Moments:
    """Bins and Taylor terms of ``po_kernel``'s frequency sums, and their contraction.

    Bin width h, a power of two with x = κ_max·h <= 2 (κ = k − k_mid), and M terms, the
    fewest with x^M/M! <= eps/16: the h that minimizes the estimated work per direction,
    M updates per lit vertex (cost VERTEX_TERM_COST each) + n_bins·M·n_k multiply-adds of
    the contraction; or no moments (terms = 0) where direct sums, DIRECT_COST per vertex and
    frequency, cost less (a few vertices). Bins cover |r̂·r| <= R. ``phase_error`` bounds the
    absolute phase error of a vertex phasor so represented: (9 + 1.5x)·e^x ulps of rounding
    (docs/RADAR.md), twice over, and at least that of the direct phasors (16 eps)."""

    def __init__(self, k: np.ndarray, radius: float, n_vertices: int):
        self.k = k
        self.k_mid = 0.5 * (float(k.min()) + float(k.max()))
        kappa = k - self.k_mid
        spread = float(np.abs(kappa).max())
        h = 2.0 ** math.ceil(math.log2(2.0 * radius))  # one bin suffices without spread
        if spread > 0:
            h = min(h, 2.0 ** math.floor(math.log2(2.0 / spread)))
        best = None
        for _ in range(8):  # eight widths, halving from x <= 2
            x = spread * h
            terms, bound = 1, x
            while bound > MOMENT_EPS:
                terms += 1
                bound *= x / terms
            n_bins = 2 * (int(np.ceil(radius / h)) + 1) + 1
            cost = terms * (VERTEX_TERM_COST * 0.5 * n_vertices + n_bins * len(k))
            if best is None or cost < best[0]:
                best = (cost, h, x, terms, n_bins)
            h *= 0.5
        _, self.h, x, self.terms, self.n_bins = best
        if DIRECT_COST * 0.5 * n_vertices * len(k) < best[0]:  # a handful of vertices
            self.terms, x = 0, 0.0
        self.b_min = -(self.n_bins // 2)
        self.width = self.n_bins * self.terms
        self.phase_error = max(16.0, 2.0 * ((9.0 + 1.5 * x) * math.exp(x) + 1.0)) * facet.EPS
        self.two_dk = _uniform_step(k) * 2.0
        step = 1j * kappa * self.h
        taylor = [np.ones_like(step)]
        for m in range(1, self.terms):
            taylor.append(taylor[-1] * step / m)
        self.taylor = np.array(taylor)  # (M, n_k)
        self.chunk = max(1, MOMENT_BUDGET // (max(self.terms, 1) * len(k) * 16))  # bins/block
        small = self.terms and self.n_bins <= self.chunk
        self._parts = complex_parts(self._block(0, self.n_bins)) if small else None

    def _block(self, lo: int, hi: int) -> np.ndarray:
        """Rows (b, m) of e^{j2k_n c_b}(jκ_n h)^m/m! for bins lo <= b - b_min < hi."""
        centres = (np.arange(lo, hi) + self.b_min) * self.h  # exact
        centre = facet.cis(*facet.two_product(centres[:, None], 2.0 * self.k[None, :]))
        return (centre[:, None, :] * self.taylor[None]).reshape(-1, len(self.k))

    def contract(self, mom: np.ndarray) -> np.ndarray:
        """Σ_(b,m) mom[:, (b,m)] · matrix[(b,m), :]: the k⁻¹-weighted frequency sums."""
        if self._parts is not None:
            return matmul_parts(mom, self._parts)  # = matmul(mom, matrix), split once
        out = np.zeros((len(mom), len(self.k)), dtype=np.complex128)
        for lo in range(0, self.n_bins, self.chunk):
            hi = min(lo + self.chunk, self.n_bins)
            out += matmul(mom[:, lo * self.terms : hi * self.terms], self._block(lo, hi))
        return out


def _uniform_step(k: np.ndarray) -> float:
    """Δk of a uniform grid, k_n = k_0 + nΔk to 4 ulp (the phase error that leaves in the
    series facets' phasors is within the 8·eps·2kR term of docs/RADAR.md), else 0."""
    if len(k) < 2:
        return 0.0
    dk = (k[-1] - k[0]) / (len(k) - 1)
    grid = k[0] + dk * np.arange(len(k))
    return float(dk) if dk > 0 and np.all(np.abs(grid - k) <= 4 * facet.EPS * k) else 0.0


def _po_field(
    mesh: Mesh, k: np.ndarray, dirs: np.ndarray, caster: RayCaster | None, tol: float
) -> np.ndarray:
    """First-bounce PO by ``po_kernel`` in groups of directions (memory of the moments and
    shadow masks); the grouping depends only on the mesh and the grid, so the bytes do too
    (within a group the kernel's blocks of directions and its vertex numbering change no sum's
    order either)."""
    geo = _Geometry(mesh)
    plan = _Moments(k, mesh.radius, len(mesh.vertices))
    group = max(1, min(GROUP, MOMENT_BUDGET // (16 * max(plan.width, 1))))
    out = np.zeros((len(dirs), len(k)), dtype=np.complex128)
    no_shadow = np.zeros((0, 0), dtype=np.uint8)
    facets = po_kernel.Facets(
        geo.v,
        geo.f,
        geo.v_in_order,
        geo.local,
        geo.area,
        geo.area_lo,
        geo.area_split,
        geo.two_sided,
    )
    grid = po_kernel.Spectrum(
        k, plan.two_dk, tol, plan.phase_error, po_kernel.CIS_TABLE, po_kernel.CIS_PARAMS
    )
    bins = po_kernel.Bins(1.0 / plan.h, plan.b_min, plan.terms, 2.0 * plan.k_mid)
    for lo in range(0, len(dirs), group):
        r = dirs[lo : lo + group]
        blocked = no_shadow if caster is None else _blocked(r, geo, caster)
        mom = np.zeros((len(r), 2 * plan.width))  # complex moments as (re, im) pairs
        part = out[lo : lo + group]
        idx, val = po_kernel.first_bounce(facets, grid, bins, r, blocked, mom, part)
        if len(idx) > 1:  # listed by blocks of directions, then faces: by direction, face
            order = np.lexsort((idx[:, 0], idx[:, 1]))
            idx, val = idx[order], val[order]
        if plan.terms:
            part += plan.contract(mom.view(np.complex128)) / k
        if len(idx):
            x = 2.0 * val[:, 1:, None] * k
            dd = facet.exp_divided_difference(x[:, 0], x[:, 1], x[:, 2])
            _add_rows(part, idx[:, 1], (2.0 / facet.SQRT_PI) * val[:, :1] * k * dd)
    return out


def _blocked(r: np.ndarray, geo: _Geometry, caster: RayCaster) -> np.ndarray:
    """(n_faces, n_dirs) uint8: 1 where a lit facet's centroid cannot see the radar."""
    signed = matmul(geo.area, r.T)
    lit = signed != 0 if geo.two_sided else signed > 0
    fi, bi = np.nonzero(lit)
    out = np.zeros(signed.shape, dtype=np.uint8)
    if len(fi):
        normals = geo.normals[fi] * np.sign(signed[fi, bi])[:, None]
        hidden = caster.occluded(geo.centroids[fi], r[bi], normals)
        out[fi[hidden], bi[hidden]] = 1
    return out


def _add_rows(out, rows, values) -> None:
    """out[rows] += values, with repeated rows summed."""
    if np.any(rows[1:] < rows[:-1]):
        order = np.argsort(rows, kind="stable")
        rows, values = rows[order], values[order]
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    out[rows[starts]] += np.add.reduceat(values, starts, axis=0)


class _PhaseSums:
    """Σ_v W_v exp(j2k_n s_v) for a batch of (B, V) positions; block method for uniform k."""

    def __init__(self, k: np.ndarray):
        self.k = k
        n = len(k)
        self.q = 16 if n >= 64 else max(1, int(np.ceil(np.sqrt(n))))
        self.p = int(np.ceil(n / self.q))
        self.uniform = False
        if n >= 4:
            dk = (k[-1] - k[0]) / (n - 1)
            grid = k[0] + dk * np.arange(n)
            self.uniform = dk > 0 and bool(np.all(np.abs(grid - k) <= 1e-9 * dk))
            self.dk = dk
        if self.uniform:
            self._steps = np.array([2.0 * k[0], 2.0 * self.dk, 2.0 * self.dk * self.q])[
                :, None, None
            ]

    def phasors(self, s: np.ndarray):
        parts = facet.split(s)
        if not self.uniform:
            return np.stack([_cis_of_product(s, parts, t) for t in 2.0 * self.k], axis=-1)
        nb, nv = s.shape
        q, p = self.q, self.p
        # e^{j2k_0 s}, e^{j2Δk s}, e^{j2qΔk s} in one pass (fewer numpy calls on small arrays)
        base, rho, rho_q = _cis_of_product(s[None], tuple(x[None] for x in parts), self._steps)
        qm = np.empty((nb, q, nv), dtype=np.complex128)  # e^{j2rΔk s}, r < q
        qm[:, 0] = 1.0
        if q > 1:
            qm[:, 1] = rho
        have, step = 2, rho
        while have < q:
            step = step * step
            n = min(have, q - have)
            np.multiply(qm[:, :n], step[:, None, :], out=qm[:, have : have + n])
            have += n
        pm = np.empty((nb, p, nv), dtype=np.complex128)  # e^{j2(k_0 + qPΔk) s}, P < p
        pm[:, 0] = base
        have, step = 1, rho_q
        while have < p:
            n = min(have, p - have)
            np.multiply(pm[:, :n], step[:, None, :], out=pm[:, have : have + n])
            have += n
            step = step * step
        return pm, qm

    def weighted_channels(self, ph, w: np.ndarray) -> np.ndarray:
        """Σ_v w_c,v exp(j2k s_v) for several weight rows c over one batch row of phasors."""
        if not self.uniform:
            return matmul(w, ph[0])
        pm, qm = ph
        x = pm[0][None] * w[:, None, :]  # (c, p, V)
        q_t = qm[0].T
        return np.stack([matmul(xc, q_t) for xc in x]).reshape(len(w), -1)[:, : len(self.k)]


def _powers(x: np.ndarray, n: int) -> np.ndarray:
    """(n, ...) x^0 .. x^(n-1) by repeated products (numpy's ``**`` rounds by CPU model)."""
    out = np.empty((n, *np.shape(x)))
    out[0] = 1.0
    for i in range(1, n):
        out[i] = out[i - 1] * x
    return out


# ---------------------------------------------------------------------------------------------
# Bounces 2 and 3: shooting and bouncing rays (SBR) with physical-optics ray-tube radiation.

MAX_BOUNCES = 3  # the trihedral's return is a triple bounce
RAYS_PER_WAVELENGTH = 8  # tube size λ_min/8: aperture edges resolved to ~1%
SBR_CHUNK = 4096  # ray tubes per frequency-sum chunk (wide footprints)
SINC_TERMS = 8  # sinc(kα)sinc(kβ) to order (kα)¹⁴: remainder < 1e-14 for |kα| <= 1
_SINC = np.array([(-1) ** i / np.prod(np.arange(1.0, 2 * i + 2)) for i in range(SINC_TERMS)])


def polarization(r: np.ndarray) -> np.ndarray:
    """The transmit/receive polarization of "bounce2": θ̂ of the line of sight (vertical, VV),
    x̂·sign(cos θ) at the poles. Single-bounce PO does not depend on it."""
    rho = np.hypot(r[:, 0], r[:, 1])
    safe = np.where(rho > 0, rho, 1.0)
    theta = np.stack([r[:, 2] * r[:, 0] / safe, r[:, 2] * r[:, 1] / safe, -rho], axis=1)
    pole = rho == 0
    theta[pole] = np.stack([np.sign(r[pole, 2]), 0 * r[pole, 2], 0 * r[pole, 2]], axis=1)
    return theta


def sbr_field(
    mesh: Mesh,
    k: np.ndarray,
    dirs: np.ndarray,
    caster: RayCaster,
    spacing: float | None = None,
    max_bounces: int = MAX_BOUNCES,
    channels: tuple[str, ...] = ("VV",),
) -> np.ndarray:
    """(n_dirs, len(channels), n_freq): bounces 2..max_bounces (the first bounce is the exact
    PO of ``_po_field``), per polarization channel.

    Parallel ray tubes of side ``spacing`` (default λ_min/8) are shot along −r̂ over the
    bounding sphere, traced by Embree with PEC reflection of the polarization
    (E' = −E + 2(n·E)n), and from the second hit on, each tube's footprint radiates back by
    physical optics: (k/√π)·ê·(n × (d × E))·Δ²/|d·n|·sinc(kα)sinc(kβ)·e^{jkΦ}, where α, β
    are the footprint's phase slopes and Φ the path phase (docs/RADAR.md, "Bounces"). The
    geometry is traced once; the field E is carried for a V and an H transmission, and ê is
    the receive polarization of each channel.
    A tube whose radiation towards the radar is blocked contributes nothing.
    """
    spacing = spacing or (2.0 * np.pi / float(k.max())) / RAYS_PER_WAVELENGTH
    v = mesh.vertices
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    radius = float(np.sqrt(np.max(np.sum((v - centre) ** 2, axis=1))))
    n_side = int(np.ceil(radius / spacing))
    grid = (np.arange(-n_side, n_side + 1) + 0.0) * spacing
    gu, gv = np.meshgrid(grid, grid, indexing="ij")
    inside = gu**2 + gv**2 <= (radius + spacing) ** 2
    gu, gv = gu[inside], gv[inside]
    area = mesh.area_vectors
    normals = area / np.linalg.norm(area, axis=1, keepdims=True)
    out = np.zeros((len(dirs), len(channels), len(k)), dtype=np.complex128)
    pol = polarization(dirs)
    # (transmit, receive) per channel, 0 = V and 1 = H; only the transmissions needed are traced
    pairs = [{"VV": (0, 0), "HH": (1, 1), "HV": (0, 1)}[c] for c in channels]
    sent = sorted({t for t, _ in pairs})
    for i, r in enumerate(dirs):
        e1 = pol[i]
        e2 = np.cross(r, e1)
        origins = centre + (radius + 2 * spacing) * r + gu[:, None] * e1 + gv[:, None] * e2
        n_rays = len(origins)
        d = np.broadcast_to(-r, (n_rays, 3)).copy()
        fields = {t: np.broadcast_to((e1, e2)[t], (n_rays, 3)).copy() for t in sent}
        tube_a = np.broadcast_to(e1, (n_rays, 3)).copy()
        tube_b = np.broadcast_to(e2, (n_rays, 3)).copy()
        phase = np.zeros(n_rays)  # Φ so far: r̂·p1 − Σ segment lengths
        lift = np.zeros((n_rays, 3))
        point = origins
        for bounce in range(1, max_bounces + 1):
            face, dist = caster.intersect(point, d, lift)
            hit = face >= 0
            if not hit.any():
                break
            face, dist = face[hit], dist[hit]
            d, tube_a, tube_b, phase = d[hit], tube_a[hit], tube_b[hit], phase[hit]
            fields = {t: e[hit] for t, e in fields.items()}
            previous = point[hit]
            point = previous + lift[hit] * caster.offset + dist[:, None] * d
            n = normals[face]
            cos_in = np.einsum("ij,ij->i", n, d)
            n = n * -np.sign(cos_in)[:, None]  # facing the incoming ray
            cos_in = np.abs(cos_in)
            if bounce == 1:
                phase = matmul(point, r)
            else:
                phase = phase - np.einsum("ij,ij->i", point - previous, d)  # path along d
                for c, (t, rx) in enumerate(pairs):
                    _radiate(
                        out[i, c],
                        k,
                        r,
                        (e1, e2)[rx],
                        point,
                        n,
                        d,
                        fields[t],
                        tube_a,
                        tube_b,
                        cos_in,
                        phase + matmul(point, r),
                        spacing,
                        caster,
                    )
            d = d + 2.0 * cos_in[:, None] * n
            fields = {
                t: -e + 2.0 * np.einsum("ij,ij->i", n, e)[:, None] * n for t, e in fields.items()
            }
            tube_a = tube_a - 2.0 * np.einsum("ij,ij->i", tube_a, n)[:, None] * n
            tube_b = tube_b - 2.0 * np.einsum("ij,ij->i", tube_b, n)[:, None] * n
            lift = n
            keep = cos_in > 0
            point, d, tube_a, tube_b, phase, lift = (
                x[keep] for x in (point, d, tube_a, tube_b, phase, lift)
            )
            fields = {t: e[keep] for t, e in fields.items()}
    return out


def _radiate(out, k, r, e, point, n, d, field, tube_a, tube_b, cos_in, phi, spacing, caster):
    """Add the PO radiation of tube footprints at ``point`` (lit side normal ``n``), received
    in polarization ``e``."""
    seen = ~caster.occluded(point, np.broadcast_to(r, point.shape), n)
    if not seen.any():
        return
    point, n, d, field, tube_a, tube_b, cos_in, phi = (
        x[seen] for x in (point, n, d, field, tube_a, tube_b, cos_in, phi)
    )
    current = np.cross(n, np.cross(d, field))
    amp = matmul(current, e) * spacing**2 / cos_in
    q = r - d  # phase slope per unit k
    # tube axes projected along d onto the facet plane: a + d (n·a)/|n·d|
    along_a = tube_a + d * (np.einsum("ij,ij->i", tube_a, n) / cos_in)[:, None]
    along_b = tube_b + d * (np.einsum("ij,ij->i", tube_b, n) / cos_in)[:, None]
    alpha = 0.5 * spacing * np.einsum("ij,ij->i", q, along_a)
    beta = 0.5 * spacing * np.einsum("ij,ij->i", q, along_b)
    # sinc(kα) sinc(kβ) = Σ_m c_m k^{2m} (series in k, |kα|, |kβ| <= 1): the tubes then are
    # point scatterers at Φ/2 with frequency-independent weights, summed like the vertices
    series = np.maximum(np.abs(alpha), np.abs(beta)) * float(k.max()) <= 1.0
    if series.any():
        a2, b2 = alpha[series] ** 2, beta[series] ** 2
        coef = np.zeros((SINC_TERMS, int(series.sum())))
        a_pow, b_pow = _powers(a2, SINC_TERMS), _powers(b2, SINC_TERMS)
        for i in range(SINC_TERMS):
            for j in range(SINC_TERMS - i):
                coef[i + j] += _SINC[i] * _SINC[j] * a_pow[i] * b_pow[j]
        sums = _PhaseSums(k)
        per_power = sums.weighted_channels(
            sums.phasors(0.5 * phi[series][None, :]), coef * (amp[series] / facet.SQRT_PI)
        )
        out += np.sum(per_power * _powers(k, 2 * SINC_TERMS)[1::2], axis=0)
    rest = np.flatnonzero(~series)  # wide footprints: per frequency
    for start in range(0, len(rest), SBR_CHUNK):
        sl = rest[start : start + SBR_CHUNK]
        kk = k[None, :]
        term = (
            np.sinc(kk * alpha[sl, None] / np.pi)
            * np.sinc(kk * beta[sl, None] / np.pi)
            * facet.cis(kk * phi[sl, None])
        )
        out += (k / facet.SQRT_PI) * matmul(amp[sl][None, :], term)[0]
