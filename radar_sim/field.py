"""The monostatic PO field of a mesh for many directions and frequencies.

One geometric pass per direction serves every frequency: each lit facet becomes three vertex
scatterers with frequency-independent weights (``facet.regular_weights``), summed onto the
mesh's unique vertices, so the frequency sum runs over V scatterers instead of 3F. Facets
where those weights would lose digits get exact confluent forms (coincident pair, exact
specular) or, rarely, the stable per-frequency evaluation (``facet.classify``).

The frequency sum Σ_v W_v e^{j2k_n s_v} for uniformly spaced k_n = k_0 + nΔk is a batched
complex matrix product: with n = qP + r, e^{j2k_n s} = [e^{j2k_0 s} e^{j2qPΔk s}]·e^{j2rΔk s},
so per direction a (P × V) by (V × q) product, and only 1 + q + P phasors per vertex built by
multiplication from three accurate ones. Those three are computed from the exact product
2k·s (Dekker's two-product), so every vertex phasor is accurate to a few ulp in absolute phase:
that keeps near-degenerate weights usable (their error is the phasor error times Σ|W|).

Shadowing (mode "shadowed") casts one Embree ray per lit facet from its centroid towards the
radar; "bounce2" adds the second and third bounces by shooting and bouncing rays
(``sbr_field``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

import numpy as np
import scipy.sparse as sp

from radar_sim import facet
from radar_sim.geometry import Mesh, MeshError, RayCaster, check_units, mode_of, prepare

C0 = 299_792_458.0
MODES = ("auto", "convex", "shadowed", "bounce2")
DEFAULT_TOL = 1e-10     # bound on each facet's error relative to its specular magnitude P k/√π
BATCH = 16              # directions per geometric batch (keeps the working set in L2)
PHASOR_ULPS = 64.0      # absolute phase error of a fast-path phasor, in units of eps (bound)

def _cis_of_product(s, s_parts, c: float) -> np.ndarray:
    """exp(j·s·c) with s·c formed exactly (two-product), so the phase is exact before cis."""
    return facet.cis(*facet.two_product(s, np.float64(c), s_parts))


def wavenumbers(frequencies_hz) -> np.ndarray:
    f = np.atleast_1d(np.asarray(frequencies_hz, dtype=np.float64))
    if f.ndim != 1 or len(f) == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError(f"frequencies must be a non-empty 1-D array of positive Hz, got {f!r}")
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


def monostatic_field(vertices, faces, frequencies_hz, directions, mode: str = "auto", *,
                     tol: float = DEFAULT_TOL) -> np.ndarray:
    """Complex field amplitude A (σ = |A|² in m²), shape (n_directions, n_frequencies).

    ``directions``: unit lines of sight (object towards radar) in the object frame.
    ``mode``: "auto" (``detect_mode``), "convex" (back-face culling only), "shadowed" (Embree
    shadow rays), "bounce2" (shadowed + bounces 2 and 3 by shooting and bouncing rays).
    ``tol``: bound on each facet's numerical error relative to its specular magnitude.
    """
    mesh = prepare(vertices, faces)
    check_units(mesh)
    return mesh_field(mesh, wavenumbers(frequencies_hz), unit_directions(directions),
                      resolve_mode(mode, mesh), tol)


@functools.cache
def _keep_heap() -> None:
    """Ask glibc to keep 64 MiB at the top of the heap instead of returning it to the OS on
    every large free: otherwise each batch's numpy temporaries page-fault again (measured 5x
    slower on small VMs). Process-wide and harmless; skipped where there is no glibc."""
    try:
        ctypes.CDLL(ctypes.util.find_library("c")).mallopt(-2, 64 << 20)   # M_TOP_PAD
    except (OSError, AttributeError, TypeError):
        pass


def mesh_field(mesh: Mesh, k: np.ndarray, directions: np.ndarray, mode: str,
               tol: float = DEFAULT_TOL) -> np.ndarray:
    """``monostatic_field`` on a prepared mesh, wavenumbers and unit directions."""
    _keep_heap()
    unique, first, inverse = np.unique(directions, axis=0, return_index=True,
                                       return_inverse=True)
    order = _locality_order(unique)
    caster = RayCaster(mesh) if mode in ("shadowed", "bounce2") else None
    field = _po_field(mesh, k, unique[order], caster, tol)
    if mode == "bounce2":
        field += sbr_field(mesh, k, unique[order], caster)
    out = np.empty_like(field)
    out[order] = field
    return out[inverse.reshape(-1)]


def _locality_order(d: np.ndarray) -> np.ndarray:
    """Directions sorted into 15° longitude strips, by colatitude within each: neighbours in a
    batch light nearly the same vertices."""
    theta = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    strip = np.floor((np.arctan2(d[:, 1], d[:, 0]) % (2 * np.pi)) / np.radians(15.0))
    return np.lexsort((theta, strip))


class _Scatter:
    """Geometry shared by every batch: facet corners and the corner -> vertex incidence."""

    def __init__(self, mesh: Mesh):
        v, f = mesh.vertices, mesh.faces
        self.v = v
        self.f = f
        self.area = mesh.area_vectors
        self.two_sided = not mesh.closed
        edges = np.stack([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 1]],
                          v[f[:, 0]] - v[f[:, 2]]])
        self.longest = np.sqrt(np.max(np.einsum("eij,eij->ei", edges, edges), axis=0))
        n_f = len(f)
        self.incidence = sp.csr_matrix(
            (np.ones(3 * n_f), (f.T.reshape(-1), np.arange(3 * n_f))), shape=(len(v), 3 * n_f))
        self.centroids = mesh.centroids
        self.normals = self.area / np.linalg.norm(self.area, axis=1, keepdims=True)


def _po_field(mesh: Mesh, k: np.ndarray, dirs: np.ndarray, caster: RayCaster | None,
              tol: float) -> np.ndarray:
    geo = _Scatter(mesh)
    sums = _PhaseSums(k)
    k_lo, k_hi = float(k.min()), float(k.max())
    phase_error = sums.phase_error
    quick = geo.longest[:, None] * phase_error
    scale = tol * k_lo * k_lo
    out = np.zeros((len(dirs), len(k)), dtype=np.complex128)
    f0, f1, f2 = geo.f[:, 0], geo.f[:, 1], geo.f[:, 2]
    for start in range(0, len(dirs), BATCH):
        r = dirs[start:start + BATCH]
        s = geo.v @ r.T                                   # (V, B) phase positions r̂·r_v
        signed = geo.area @ r.T                           # (F, B) projected areas
        proj = np.abs(signed) if geo.two_sided else np.maximum(signed, 0.0)
        if caster is not None:
            _shadow(proj, signed, r, geo, caster)
        s0, s1, s2 = s[f0], s[f1], s[f2]
        a = s0 - s1
        b = s1 - s2
        c = s2 - s0
        abc = a * b * c
        lit = proj > 0
        regular = np.abs(abc) * scale >= quick
        special = lit & ~regular
        regular &= lit
        q = np.zeros_like(abc)
        np.divide(proj, (2.0 * facet.SQRT_PI) * abc, out=q, where=regular)
        w = geo.incidence @ np.concatenate([q * b, q * c, q * a])     # (V, B) k⁻¹ weights
        fi, bi = np.nonzero(special)
        extra = _special(fi, bi, a, b, c, proj, s, geo, w, k_lo, k_hi, phase_error, tol)
        out[start:start + len(r)] = _batch_sum(s, w, extra, sums, k)
    return out


def _shadow(proj, signed, r, geo: _Scatter, caster: RayCaster) -> None:
    """Zero the projected area of lit facets whose centroid cannot see the radar."""
    fi, bi = np.nonzero(proj > 0)
    if not len(fi):
        return
    normals = geo.normals[fi] * np.sign(signed[fi, bi])[:, None]
    blocked = caster.occluded(geo.centroids[fi], r[bi], normals)
    proj[fi[blocked], bi[blocked]] = 0.0


class _Extra:
    """Special facets of one batch: polynomial-in-k vertex scatterers and stable facets."""

    def __init__(self):
        self.rows, self.verts, self.coefs = [], [], []
        self.stable = None

    def add(self, rows, verts, coefs):
        self.rows.append(rows)
        self.verts.append(verts)
        self.coefs.append(coefs)


def _special(fi, bi, a, b, c, proj, s, geo, w, k_lo, k_hi, phase_error, tol) -> _Extra:
    """Facets the quick test did not pass: exact classification, then their forms."""
    extra = _Extra()
    if not len(fi):
        return extra
    aa, bb, cc, p = a[fi, bi], b[fi, bi], c[fi, bi], proj[fi, bi]
    kind = facet.classify(aa, bb, cc, k_lo, k_hi, phase_error, tol)
    corners = geo.f[fi]                                              # (n, 3)
    sel = kind == facet.REGULAR
    if sel.any():
        wr = facet.regular_weights(p[sel], aa[sel], bb[sel], cc[sel])
        for corner in range(3):
            np.add.at(w, (corners[sel, corner], bi[sel]), wr[corner])
    sel = np.flatnonzero(kind == facet.SERIES)
    if len(sel):
        sv = s[corners[sel], bi[sel, None]]                          # (n, 3) phases
        order = np.argsort(sv, axis=1)
        rows = np.arange(len(sel))[:, None]
        ordered = sv[rows, order]
        mid = order[:, 1]
        coefs = facet.series_coefficients(p[sel], ordered[:, 0] - ordered[:, 1],
                                          ordered[:, 2] - ordered[:, 1])
        extra.add(bi[sel], corners[sel, mid], coefs)
    sel = np.flatnonzero(kind == facet.PAIR)
    if len(sel):
        gaps = np.abs(np.stack([aa[sel], bb[sel], cc[sel]], axis=1))
        pair = np.argmin(gaps, axis=1)           # 0: (0,1) | 1: (1,2) | 2: (2,0); third = +2
        i = corners[sel, pair]
        j = corners[sel, (pair + 1) % 3]
        m = corners[sel, (pair + 2) % 3]
        col = bi[sel]
        g = s[i, col] - s[j, col]
        e = 0.5 * (s[i, col] + s[j, col]) - s[m, col]
        pair_coef, third_coef = facet.pair_coefficients(p[sel], e, g)
        extra.add(np.concatenate([col, col, col]), np.concatenate([i, j, m]),
                  np.concatenate([pair_coef, pair_coef, third_coef]))
    sel = kind == facet.STABLE
    if sel.any():
        extra.stable = (corners[sel], bi[sel], p[sel])
    return extra


def _batch_sum(s, w, extra: _Extra, sums: "_PhaseSums", k) -> np.ndarray:
    """Σ_v e^{j2ks_v}(w_v/k + special polynomials) + stable facets, for one batch."""
    active = np.any(w != 0, axis=1)
    if extra.verts:
        verts = np.concatenate(extra.verts)
        active[verts] = True
    idx = np.flatnonzero(active)
    st = np.ascontiguousarray(s[idx].T)                              # (B, Va)
    ph = sums.phasors(st)
    out = sums.weighted(ph, np.ascontiguousarray(w[idx].T)) / k
    if extra.verts:
        rows = np.concatenate(extra.rows)
        local = np.searchsorted(idx, verts)
        key = rows * len(idx) + local
        keys, inverse = np.unique(key, return_inverse=True)
        merge = sp.csr_matrix((np.ones(len(key)), (inverse, np.arange(len(key)))),
                              shape=(len(keys), len(key)))
        coefs = merge @ np.concatenate(extra.coefs)
        urows, ulocal = keys // len(idx), keys % len(idx)
        terms = (coefs @ sums.powers) * sums.select(ph, urows, ulocal)
        starts = np.flatnonzero(np.r_[True, urows[1:] != urows[:-1]])
        out[urows[starts]] += np.add.reduceat(terms, starts, axis=0)
    if extra.stable is not None:
        corners, sb, p = extra.stable
        x = 2.0 * s[corners, sb[:, None]][:, :, None] * k
        dd = facet.exp_divided_difference(x[:, 0], x[:, 1], x[:, 2])
        np.add.at(out, sb, (2.0 / facet.SQRT_PI) * p[:, None] * k * dd)
    return out


class _PhaseSums:
    """Σ_v W_v exp(j2k_n s_v) for a batch of (B, V) positions; block method for uniform k."""

    def __init__(self, k: np.ndarray):
        self.k = k
        n = len(k)
        self.powers = k[None, :] ** facet.CHANNELS[:, None]          # (channels, n_k)
        self.q = 16 if n >= 64 else max(1, int(np.ceil(np.sqrt(n))))
        self.p = int(np.ceil(n / self.q))
        self.uniform = False
        if n >= 4:
            dk = (k[-1] - k[0]) / (n - 1)
            grid = k[0] + dk * np.arange(n)
            self.uniform = dk > 0 and bool(np.all(np.abs(grid - k) <= 1e-9 * dk))
            self.dk = dk
        extra = self.p + self.q if self.uniform else 0
        # absolute phase error of each computed phasor (radians): cis and the recurrences
        self.phase_error = facet.EPS * (PHASOR_ULPS + 2.0 * extra)

    def phasors(self, s: np.ndarray):
        parts = facet.split(s)
        two_k = 2.0 * self.k
        if not self.uniform:
            return np.stack([_cis_of_product(s, parts, t) for t in two_k], axis=-1)
        nb, nv = s.shape
        q, p = self.q, self.p
        base = _cis_of_product(s, parts, two_k[0])
        rho = _cis_of_product(s, parts, 2.0 * self.dk)
        rho_q = _cis_of_product(s, parts, 2.0 * self.dk * q)
        qm = np.empty((nb, q, nv), dtype=np.complex128)   # e^{j2rΔk s}, r < q
        qm[:, 0] = 1.0
        if q > 1:
            qm[:, 1] = rho
        have, step = 2, rho
        while have < q:
            step = step * step
            n = min(have, q - have)
            np.multiply(qm[:, :n], step[:, None, :], out=qm[:, have:have + n])
            have += n
        pm = np.empty((nb, p, nv), dtype=np.complex128)   # e^{j2(k_0 + qPΔk) s}, P < p
        pm[:, 0] = base
        have, step = 1, rho_q
        while have < p:
            n = min(have, p - have)
            np.multiply(pm[:, :n], step[:, None, :], out=pm[:, have:have + n])
            have += n
            step = step * step
        return pm, qm

    def weighted(self, ph, w: np.ndarray) -> np.ndarray:
        if not self.uniform:
            return np.einsum("bv,bvn->bn", w, ph)
        pm, qm = ph
        nb = len(w)
        x = pm * w[:, None, :]
        return np.matmul(x, qm.transpose(0, 2, 1)).reshape(nb, -1)[:, :len(self.k)]

    def select(self, ph, rows, cols) -> np.ndarray:
        """Full phasor rows (n, n_k) of chosen (batch row, vertex) pairs."""
        if not self.uniform:
            return ph[rows, cols]
        pm, qm = ph
        full = pm[rows, :, cols][:, :, None] * qm[rows, :, cols][:, None, :]
        return full.reshape(len(rows), -1)[:, :len(self.k)]


# ---------------------------------------------------------------------------------------------
# Bounces 2 and 3: shooting and bouncing rays (SBR) with physical-optics ray-tube radiation.

MAX_BOUNCES = 3          # the trihedral's return is a triple bounce
RAYS_PER_WAVELENGTH = 8  # tube size λ_min/8: aperture edges resolved to ~1%
SBR_CHUNK = 4096         # ray tubes per frequency-sum chunk


def polarization(r: np.ndarray) -> np.ndarray:
    """The transmit/receive polarization of "bounce2": θ̂ of the line of sight (vertical, VV),
    x̂·sign(cos θ) at the poles. Single-bounce PO does not depend on it."""
    rho = np.hypot(r[:, 0], r[:, 1])
    safe = np.where(rho > 0, rho, 1.0)
    theta = np.stack([r[:, 2] * r[:, 0] / safe, r[:, 2] * r[:, 1] / safe, -rho], axis=1)
    pole = rho == 0
    theta[pole] = np.stack([np.sign(r[pole, 2]), 0 * r[pole, 2], 0 * r[pole, 2]], axis=1)
    return theta


def sbr_field(mesh: Mesh, k: np.ndarray, dirs: np.ndarray, caster: RayCaster,
              spacing: float | None = None, max_bounces: int = MAX_BOUNCES) -> np.ndarray:
    """Field of bounces 2..max_bounces (the first bounce is the exact PO of ``_po_field``).

    Parallel ray tubes of side ``spacing`` (default λ_min/8) are shot along −r̂ over the
    bounding sphere, traced by Embree with PEC reflection of the polarization
    (E' = −E + 2(n·E)n), and from the second hit on, each tube's footprint radiates back by
    physical optics: (k/√π)·ê·(n × (d × E))·Δ²/|d·n|·sinc(kα)sinc(kβ)·e^{jkΦ}, where α, β
    are the footprint's phase slopes and Φ the path phase (docs/RADAR.md, "Bounces").
    A tube whose radiation towards the radar is blocked contributes nothing.
    """
    spacing = spacing or (2.0 * np.pi / float(k.max())) / RAYS_PER_WAVELENGTH
    v = mesh.vertices
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    radius = float(np.sqrt(np.max(np.sum((v - centre) ** 2, axis=1))))
    n_side = int(np.ceil(radius / spacing))
    grid = (np.arange(-n_side, n_side + 1) + 0.0) * spacing
    gu, gv = np.meshgrid(grid, grid, indexing="ij")
    inside = gu ** 2 + gv ** 2 <= (radius + spacing) ** 2
    gu, gv = gu[inside], gv[inside]
    area = mesh.area_vectors
    normals = area / np.linalg.norm(area, axis=1, keepdims=True)
    out = np.zeros((len(dirs), len(k)), dtype=np.complex128)
    pol = polarization(dirs)
    for i, r in enumerate(dirs):
        e1 = pol[i]
        e2 = np.cross(r, e1)
        origins = centre + (radius + 2 * spacing) * r + gu[:, None] * e1 + gv[:, None] * e2
        n_rays = len(origins)
        d = np.broadcast_to(-r, (n_rays, 3)).copy()
        field = np.broadcast_to(e1, (n_rays, 3)).copy()
        tube_a = np.broadcast_to(e1, (n_rays, 3)).copy()
        tube_b = np.broadcast_to(e2, (n_rays, 3)).copy()
        phase = np.zeros(n_rays)               # Φ so far: r̂·p1 − Σ segment lengths
        lift = np.zeros((n_rays, 3))
        point = origins
        for bounce in range(1, max_bounces + 1):
            face, dist = caster.intersect(point, d, lift)
            hit = face >= 0
            if not hit.any():
                break
            face, dist = face[hit], dist[hit]
            d, field, tube_a, tube_b, phase = d[hit], field[hit], tube_a[hit], tube_b[hit], phase[hit]
            previous = point[hit]
            point = previous + lift[hit] * caster.offset + dist[:, None] * d
            n = normals[face]
            cos_in = np.einsum("ij,ij->i", n, d)
            n = n * -np.sign(cos_in)[:, None]            # facing the incoming ray
            cos_in = np.abs(cos_in)
            if bounce == 1:
                phase = point @ r
            else:
                phase = phase - np.einsum("ij,ij->i", point - previous, d)   # path along d
                _radiate(out[i], k, r, point, n, d, field, tube_a, tube_b, cos_in,
                         phase + point @ r, spacing, caster)
            d = d + 2.0 * cos_in[:, None] * n
            field = -field + 2.0 * np.einsum("ij,ij->i", n, field)[:, None] * n
            tube_a = tube_a - 2.0 * np.einsum("ij,ij->i", tube_a, n)[:, None] * n
            tube_b = tube_b - 2.0 * np.einsum("ij,ij->i", tube_b, n)[:, None] * n
            lift = n
            keep = cos_in > 0
            point, d, field, tube_a, tube_b, phase, lift = (
                x[keep] for x in (point, d, field, tube_a, tube_b, phase, lift))
    return out


def _radiate(out, k, r, point, n, d, field, tube_a, tube_b, cos_in, phi, spacing, caster):
    """Add the PO radiation of tube footprints at ``point`` (lit side normal ``n``)."""
    seen = ~caster.occluded(point, np.broadcast_to(r, point.shape), n)
    if not seen.any():
        return
    point, n, d, field, tube_a, tube_b, cos_in, phi = (
        x[seen] for x in (point, n, d, field, tube_a, tube_b, cos_in, phi))
    e = polarization(r[None, :])[0]
    current = np.cross(n, np.cross(d, field))
    amp = (current @ e) * spacing ** 2 / cos_in
    q = r - d                                            # phase slope per unit k
    # tube axes projected along d onto the facet plane: a + d (n·a)/|n·d|
    along_a = tube_a + d * (np.einsum("ij,ij->i", tube_a, n) / cos_in)[:, None]
    along_b = tube_b + d * (np.einsum("ij,ij->i", tube_b, n) / cos_in)[:, None]
    alpha = 0.5 * spacing * np.einsum("ij,ij->i", q, along_a)
    beta = 0.5 * spacing * np.einsum("ij,ij->i", q, along_b)
    for start in range(0, len(phi), SBR_CHUNK):
        sl = slice(start, start + SBR_CHUNK)
        kk = k[None, :]
        term = (np.sinc(kk * alpha[sl, None] / np.pi) * np.sinc(kk * beta[sl, None] / np.pi)
                * facet.cis(kk * phi[sl, None]))
        out += (k / facet.SQRT_PI) * (amp[sl] @ term)
