"""The monostatic PO field of a mesh for many directions and frequencies.

One geometric pass per direction serves every frequency: each lit facet becomes three vertex
scatterers with frequency-independent weights (``facet.regular_weights``), summed onto the
mesh's unique vertices, so the frequency sum runs over V scatterers instead of 3F. Facets
where those weights would lose digits (phases nearly coincident) get exact series forms that
are polynomials in k on their vertices, or, rarely, the stable per-frequency evaluation
(``facet.classify``, docs/RADAR.md "Numerics").

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
from radar_sim.geometry import Mesh, RayCaster, check_units, mode_of, prepare

C0 = 299_792_458.0
MODES = ("auto", "convex", "shadowed", "bounce2")
DEFAULT_TOL = 1e-10     # bound on each facet's error relative to its specular magnitude P k/√π
BATCH = 16              # directions per geometric batch (keeps the working set in L2)
SPECIAL_CHUNK = 1024    # special-facet scatterers per frequency-sum chunk
PHASOR_ULPS = 64.0      # absolute phase error of a fast-path phasor, in units of eps (bound)


def _cis_of_product(s, s_parts, c) -> np.ndarray:
    """exp(j·s·c) with s·c formed exactly (two-product), so the phase is exact before cis."""
    return facet.cis(*facet.two_product(s, np.asarray(c, dtype=np.float64), s_parts))


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
    unique, inverse = np.unique(directions, axis=0, return_inverse=True)
    caster = RayCaster(mesh) if mode in ("shadowed", "bounce2") else None
    field = _po_field(mesh, k, unique, caster, tol)
    if mode == "bounce2":
        field += sbr_field(mesh, k, unique, caster)
    return field[inverse.reshape(-1)]


def _batches(d: np.ndarray, size: int) -> list[np.ndarray]:
    """Groups of at most ``size`` nearby directions (recursive bisection along the widest
    coordinate): the directions of a group light nearly the same vertices, so the union of
    their lit vertices, over which the group's frequency sums run, stays small."""
    out = []
    stack = [np.arange(len(d))]
    while stack:
        idx = stack.pop()
        if len(idx) <= size:
            out.append(idx)
            continue
        pts = d[idx]
        axis = int(np.argmax(pts.max(axis=0) - pts.min(axis=0)))
        idx = idx[np.argsort(pts[:, axis], kind="stable")]
        cut = int(np.ceil(len(idx) / size / 2)) * size
        stack += [idx[cut:], idx[:cut]]
    return out


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
    """First-bounce PO: regular facets through batched vertex sums, the rest afterwards."""
    geo = _Scatter(mesh)
    sums = _PhaseSums(k)
    k_lo = float(k.min())
    quick = geo.longest[:, None] * sums.phase_error
    scale = tol * k_lo * k_lo
    out = np.zeros((len(dirs), len(k)), dtype=np.complex128)
    n_f = len(geo.f)
    f0, f1, f2 = geo.f[:, 0], geo.f[:, 1], geo.f[:, 2]
    stacked = np.empty((3 * n_f, BATCH))
    special_faces, special_dirs, special_proj = [], [], []
    for batch in _batches(dirs, BATCH):
        r = dirs[batch]
        nb = len(r)
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
        regular = np.abs(abc) * scale >= quick            # Σ|weights|·phasor error small
        special = lit & ~regular
        regular &= lit
        q = np.zeros_like(abc)
        np.divide(proj, (2.0 * facet.SQRT_PI) * abc, out=q, where=regular)
        x = stacked[:, :nb]
        np.multiply(q, b, out=x[:n_f])
        np.multiply(q, c, out=x[n_f:2 * n_f])
        np.multiply(q, a, out=x[2 * n_f:])
        w = geo.incidence @ x                             # (V, B) k⁻¹ vertex weights
        if special.any():
            fi, bi = np.nonzero(special)
            special_faces.append(fi)
            special_dirs.append(batch[bi])
            special_proj.append(proj[fi, bi])
        active = np.flatnonzero(np.any(w != 0, axis=1))
        if len(active):
            st = np.ascontiguousarray(s[active].T)
            wt = np.ascontiguousarray(w[active].T)
            out[batch] = sums.weighted(sums.phasors(st), wt) / k
    if special_faces:
        _special_field(out, np.concatenate(special_faces), np.concatenate(special_dirs),
                       np.concatenate(special_proj), geo, dirs, sums, tol)
    return out


def _shadow(proj, signed, r, geo: _Scatter, caster: RayCaster) -> None:
    """Zero the projected area of lit facets whose centroid cannot see the radar."""
    fi, bi = np.nonzero(proj > 0)
    if not len(fi):
        return
    normals = geo.normals[fi] * np.sign(signed[fi, bi])[:, None]
    blocked = caster.occluded(geo.centroids[fi], r[bi], normals)
    proj[fi[blocked], bi[blocked]] = 0.0


def _special_field(out, fi, di, proj, geo: _Scatter, dirs, sums: "_PhaseSums", tol) -> None:
    """Facets that failed the quick test, all directions at once: exact classification, then
    regular weights, the near-pair or near-specular series (polynomials in k on vertices), or
    the stable per-frequency integral. Positions are recomputed here so that each facet's
    weights and phasors use the very same r̂·r values."""
    k = sums.k
    corners = geo.f[fi]                                              # (n, 3)
    s = np.einsum("nij,nj->ni", geo.v[corners], dirs[di])            # (n, 3)
    a, b, c = s[:, 0] - s[:, 1], s[:, 1] - s[:, 2], s[:, 2] - s[:, 0]
    kind = facet.classify(a, b, c, float(k.min()), float(k.max()), sums.phase_error, tol)
    entries = []                       # (facets, which corner, coefficients per channel)
    sel = np.flatnonzero(kind == facet.REGULAR)
    if len(sel):
        for corner, wv in enumerate(facet.regular_weights(proj[sel], a[sel], b[sel], c[sel])):
            coef = np.zeros((len(sel), len(facet.CHANNELS)), dtype=np.complex128)
            coef[:, 0] = wv                                          # channel k⁻¹
            entries.append((sel, corner, coef))
    sel = np.flatnonzero(kind == facet.SERIES)
    if len(sel):
        order = np.argsort(s[sel], axis=1)
        ordered = np.take_along_axis(s[sel], order, axis=1)
        coef = facet.series_coefficients(proj[sel], ordered[:, 0] - ordered[:, 1],
                                         ordered[:, 2] - ordered[:, 1])
        entries.append((sel, order[:, 1], coef))
    sel = np.flatnonzero(kind == facet.PAIR)
    if len(sel):
        gaps = np.abs(np.stack([a[sel], b[sel], c[sel]], axis=1))
        i = np.argmin(gaps, axis=1)              # pair (i, i+1), third i+2 (mod 3)
        j, m = (i + 1) % 3, (i + 2) % 3
        si, sj, sm = s[sel, i], s[sel, j], s[sel, m]
        pair_coef, third_coef = facet.pair_coefficients(proj[sel], 0.5 * (si + sj) - sm, si - sj)
        entries += [(sel, i, pair_coef), (sel, j, pair_coef), (sel, m, third_coef)]
    if entries:
        rows = np.concatenate([di[sel] for sel, _, _ in entries])
        verts = np.concatenate([corners[sel, x] for sel, x, _ in entries])
        pos = np.concatenate([s[sel, x] for sel, x, _ in entries])
        key = rows * len(geo.v) + verts
        keys, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        merge = sp.csr_matrix((np.ones(len(key)), (inverse, np.arange(len(key)))),
                              shape=(len(keys), len(key)))
        merged = merge @ np.concatenate([coef for _, _, coef in entries])   # (entries, channels)
        used = np.flatnonzero(np.any(merged != 0, axis=0))
        merged, powers = merged[:, used], sums.powers[used]
        ph = sums.phasors(pos[first][None, :])
        rows = rows[first]                                           # sorted (keys are)
        for lo in range(0, len(keys), SPECIAL_CHUNK):               # (chunk, n_k) in cache
            sl = slice(lo, lo + SPECIAL_CHUNK)
            cols = np.arange(lo, min(lo + SPECIAL_CHUNK, len(keys)))
            terms = (merged[sl] @ powers) * sums.select(ph, np.zeros(len(cols), dtype=int), cols)
            _add_rows(out, rows[sl], terms)
    sel = np.flatnonzero(kind == facet.STABLE)
    if len(sel):
        x = 2.0 * s[sel][:, :, None] * k
        dd = facet.exp_divided_difference(x[:, 0], x[:, 1], x[:, 2])
        _add_rows(out, di[sel], (2.0 / facet.SQRT_PI) * proj[sel, None] * k * dd)


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
        self.powers = k[None, :] ** facet.CHANNELS[:, None]          # (channels, n_k)
        self.q = 16 if n >= 64 else max(1, int(np.ceil(np.sqrt(n))))
        self.p = int(np.ceil(n / self.q))
        self.uniform = False
        if n >= 4:
            dk = (k[-1] - k[0]) / (n - 1)
            grid = k[0] + dk * np.arange(n)
            self.uniform = dk > 0 and bool(np.all(np.abs(grid - k) <= 1e-9 * dk))
            self.dk = dk
        if self.uniform:
            self._steps = np.array([2.0 * k[0], 2.0 * self.dk, 2.0 * self.dk * self.q])[:, None, None]
        extra = self.p + self.q if self.uniform else 0
        # absolute phase error of each computed phasor (radians): cis and the recurrences
        self.phase_error = facet.EPS * (PHASOR_ULPS + 2.0 * extra)

    def phasors(self, s: np.ndarray):
        parts = facet.split(s)
        if not self.uniform:
            return np.stack([_cis_of_product(s, parts, t) for t in 2.0 * self.k], axis=-1)
        nb, nv = s.shape
        q, p = self.q, self.p
        # e^{j2k_0 s}, e^{j2Δk s}, e^{j2qΔk s} in one pass (fewer numpy calls on small arrays)
        base, rho, rho_q = _cis_of_product(s[None], tuple(x[None] for x in parts), self._steps)
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

    def weighted_channels(self, ph, w: np.ndarray) -> np.ndarray:
        """Σ_v w_c,v exp(j2k s_v) for several weight rows c over one batch row of phasors."""
        if not self.uniform:
            return w @ ph[0]
        pm, qm = ph
        x = pm[0][None] * w[:, None, :]                               # (c, p, V)
        return np.matmul(x, qm[0].T[None]).reshape(len(w), -1)[:, :len(self.k)]

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
SBR_CHUNK = 4096         # ray tubes per frequency-sum chunk (wide footprints)
SINC_TERMS = 8           # sinc(kα)sinc(kβ) to order (kα)¹⁴: remainder < 1e-14 for |kα| <= 1
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
    # sinc(kα) sinc(kβ) = Σ_m c_m k^{2m} (series in k, |kα|, |kβ| <= 1): the tubes then are
    # point scatterers at Φ/2 with frequency-independent weights, summed like the vertices
    series = np.maximum(np.abs(alpha), np.abs(beta)) * float(k.max()) <= 1.0
    if series.any():
        a2, b2 = alpha[series] ** 2, beta[series] ** 2
        coef = np.zeros((SINC_TERMS, int(series.sum())))
        for i in range(SINC_TERMS):
            for j in range(SINC_TERMS - i):
                coef[i + j] += _SINC[i] * _SINC[j] * a2 ** i * b2 ** j
        sums = _PhaseSums(k)
        per_power = sums.weighted_channels(sums.phasors(0.5 * phi[series][None, :]),
                                           coef * (amp[series] / facet.SQRT_PI))
        out += np.sum(per_power * k ** (1 + 2 * np.arange(SINC_TERMS))[:, None], axis=0)
    rest = np.flatnonzero(~series)                       # wide footprints: per frequency
    for start in range(0, len(rest), SBR_CHUNK):
        sl = rest[start:start + SBR_CHUNK]
        kk = k[None, :]
        term = (np.sinc(kk * alpha[sl, None] / np.pi) * np.sinc(kk * beta[sl, None] / np.pi)
                * facet.cis(kk * phi[sl, None]))
        out += (k / facet.SQRT_PI) * (amp[sl] @ term)
