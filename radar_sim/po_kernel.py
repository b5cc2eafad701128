"""Compiled (numba) first-bounce PO kernel: one pass over the facets per block of directions.

Per direction, every lit facet is classified (docs/RADAR.md, "Numerics") and either scattered
as three frequency-independent k⁻¹ vertex weights onto the mesh's vertices, or, when its
phases nearly coincide, evaluated at once on the frequency grid by an exact series (near-pair
or near-specular forms, below), or handed back for the stable per-frequency integral.

The vertex weights' frequency sums Σ_v w_v e^{j2k_n s_v} are reduced to binned Taylor
moments: with bins of width h (a power of two) centred at c_b = b·h, δ = s − c_b is exact,
and e^{j2k_n s} = e^{j2k_n c_b} · e^{j2k_mid δ} · Σ_m (jκ_n h)^m/m! · u^m with κ_n =
k_n − k_mid and u = 2δ/h in [−1, 1]. Per direction each lit vertex adds M moments
Σ_v w_v e^{j2k_mid δ_v} u_v^m to its bin; ``field`` contracts the moments of all directions
with the direction-independent matrix e^{j2k_n c_b}(jκ_n h)^m/m! in one matrix product. That
is one phasor and M complex updates per lit vertex and direction instead of n_k complex
multiply-adds.

Speed without changing a bit (perf/kernel_bound.py): one pass over the facets serves BLOCK
directions; the facet pass reads the mesh renumbered for locality while the moments are summed
in the mesh's own vertex order; the moments of a lane's lit vertices are formed in stages
(phasors first, then the updates of two vertices interleaved term by term); the special forms
run Horner's scheme across all frequencies at once. Every sum keeps the order of one
direction at a time over the mesh's own numbering.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

from radar_sim import facet

# numba's cache is keyed on this file alone, so what comes from ``facet`` (the e^{jx} table and
# its reduction constants) is passed in as arguments (CIS_TABLE, CIS_PARAMS), never frozen.
CIS_TABLE = np.stack([facet.CIS_TABLE.real, facet.CIS_TABLE.imag])
CIS_PARAMS = np.array([facet.CIS_INV_STEP, facet.CIS_STEP_HI, facet.CIS_STEP_LO, facet.CIS_LIMIT])

# The special forms: a lit facet's field as Σ_v e^{j2k s_v}·(polynomial in k on the vertex).
# Near pair (two phases within g, the third at e from their middle), D = 2P/(√π(4e² − g²)),
# T(y) = tan(y)/y:  A_f = D·{ (e^{j2ks_a} + e^{j2ks_b})/2 · (1/k − j2e T(kg)) − e^{j2ks_c}/k },
# T truncated after y¹⁴; near specular: e^{j2ks_mid} Σ_n (2/√π) P (2jk)^n h_n/(n+2)! · k.
_TWO_OVER_SQRT_PI = 2.0 / np.sqrt(np.pi)
_SQRT_PI = np.sqrt(np.pi)
# tan(y)/y = Σ_m _TAN[m] y^{2m}; the first omitted coefficient is _TAN_NEXT
_TAN = np.array(
    [1.0, 1 / 3, 2 / 15, 17 / 315, 62 / 2835, 1382 / 155925, 21844 / 6081075, 929569 / 638512875]
)
_TAN_NEXT = 6404582 / 10854718875
_SERIES_N = 16  # h_0 … h_15: powers k¹ … k¹⁶
_SERIES_NEXT = 17.0 / 6402373705728000.0  # (n+1)/(n+2)! of the first omitted term, n = 16


@njit(cache=True)
def _split(a):
    t = a * 134217729.0
    hi = t - (t - a)
    return hi, a - hi


@njit(cache=True)
def _two_product(a, b):
    p = a * b
    ah, al = _split(a)
    bh, bl = _split(b)
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


@njit(cache=True)
def _two_sum(a, b):
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


@njit(cache=True)
def _cis(x, x_lo, tab, par):
    """(cos, sin) of x + x_lo: ``facet.cis`` (table and short polynomial), libm beyond."""
    if abs(x) > par[3]:
        c, s = math.cos(x), math.sin(x)
        return c - s * x_lo, s + c * x_lo
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


@njit(cache=True)
def _cis_of_product(s, two_k, tab, par):
    hi, lo = _two_product(s, two_k)
    return _cis(hi, lo, tab, par)


@njit(cache=True)
def _projected(area, area_lo, area_split, f, r0, r1, r2, r_split):
    """r̂·A to relative error <= 42 eps (1e-14): plain when |r̂·A| >= Σ|A_i r_i|/12, else from
    the double-double area vector by exact products (grazing incidence)."""
    a0, a1, a2 = area[f, 0], area[f, 1], area[f, 2]
    p0, p1, p2 = a0 * r0, a1 * r1, a2 * r2
    p = p0 + p1 + p2
    if 12.0 * abs(p) >= abs(p0) + abs(p1) + abs(p2):
        return p
    e0 = (
        (area_split[f, 0] * r_split[0] - p0)
        + area_split[f, 0] * r_split[3]
        + area_split[f, 3] * r_split[0]
    ) + area_split[f, 3] * r_split[3]
    e1 = (
        (area_split[f, 1] * r_split[1] - p1)
        + area_split[f, 1] * r_split[4]
        + area_split[f, 4] * r_split[1]
    ) + area_split[f, 4] * r_split[4]
    e2 = (
        (area_split[f, 2] * r_split[2] - p2)
        + area_split[f, 2] * r_split[5]
        + area_split[f, 5] * r_split[2]
    ) + area_split[f, 5] * r_split[5]
    t, c1 = _two_sum(p0, p1)
    t, c2 = _two_sum(t, p2)
    low = area_lo[f, 0] * r0 + area_lo[f, 1] * r1 + area_lo[f, 2] * r2
    return t + (((c1 + c2) + (e0 + e1 + e2)) + low)


@njit(cache=True)
def _phasors(s, k, two_dk, re, im, tab, par):
    """e^{j2k_n s} into (re, im): accurate (two-product and table, 2 eps) at every 4th
    frequency and multiplied on by e^{j2Δk s} in between on a uniform grid (two_dk > 0):
    at most 3 steps of 4 eps each, so within 16 eps (``field._Moments.phase_error``)."""
    if two_dk > 0.0:
        sr, si = _cis_of_product(s, two_dk, tab, par)
    for n in range(len(k)):
        if two_dk <= 0.0 or n % 4 == 0:
            c, sn = _cis_of_product(s, 2.0 * k[n], tab, par)
        else:
            c, sn = c * sr - sn * si, c * si + sn * sr
        re[n] = c
        im[n] = sn


@njit(cache=True)
def _add_series(row, k, k_hi, two_dk, tol, proj, s0, s1, s2, work, coef, tab, par):
    """Near-specular facet: e^{j2k s_mid} Σ_n (2/√π) P (2jk)^n h_n(σ_lo, σ_hi)/(n+2)! · k,
    truncated where (2k_max d)^N (N+1)/(N+2)! <= tol/2 (at most 16 terms). ``work``: scratch
    rows (``first_bounce``), row 4 holding k²; ``coef``: _SERIES_N scratch numbers. Both, and
    k_hi = max(k), come from the caller: an allocation and a pass over k per facet were a fifth
    of this function's time, and these facets grow as the square of the face count."""
    if s0 > s1:
        s0, s1 = s1, s0
    if s1 > s2:
        s1, s2 = s2, s1
    if s0 > s1:
        s0, s1 = s1, s0
    lo = s0 - s1
    hi = s2 - s1
    x = 2.0 * k_hi * (hi - lo)
    # coef: real parts of (2/√π) P 2^n h_n/(n+2)!, sign of j^n in
    h = 1.0
    lo_pow = 1.0
    fact = 2.0
    scale = _TWO_OVER_SQRT_PI * proj
    bound = 1.0  # x^n (n+1)/(n+2)! of the next term
    terms = _SERIES_N
    for n in range(_SERIES_N):
        if n:
            lo_pow *= lo
            h = hi * h + lo_pow
            fact *= n + 2
            scale *= 2.0
        sign = 1.0 if (n % 4) < 2 else -1.0
        coef[n] = sign * scale * h / fact
        bound *= x * (n + 2) / ((n + 1) * (n + 3)) if n else x / 3.0
        if bound <= 0.5 * tol:
            terms = n + 1
            break
    re, im, k2, pr, pi = work[0], work[1], work[4], work[5], work[6]
    _phasors(s1, k, two_dk, re, im, tab, par)
    top_even = (terms - 1) // 2 * 2
    top_odd = terms - 1 if terms % 2 == 0 else terms - 2
    # Horner in k² term by term over all frequencies (the same operations per frequency as
    # one frequency at a time, in a loop the compiler vectorizes)
    n_k = len(k)
    for i in range(n_k):
        pr[i] = 0.0  # even n: real
        pi[i] = 0.0  # odd n: imaginary, k·(Horner in k²)
    for n in range(top_even, -1, -2):
        cn = coef[n]
        for i in range(n_k):
            pr[i] = pr[i] * k2[i] + cn
    for n in range(top_odd, 0, -2):
        cn = coef[n]
        for i in range(n_k):
            pi[i] = pi[i] * k2[i] + cn
    for i in range(n_k):
        a = pr[i] * k[i]
        b = pi[i] * k2[i]
        row[i] += complex(a * re[i] - b * im[i], a * im[i] + b * re[i])


@njit(cache=True)
def _add_pair_tan(row, k, k_lo, k_hi, two_dk, tol, d, e, g, si, sj, work, tab, par):
    """The k⁰⁺ part of a near pair: −j e D T(kg) (e^{j2ks_i} + e^{j2ks_j}), T = tan(y)/y
    truncated where TAN_m (k_hi g)^{2m}/(k_lo e) <= tol/2 (at most 8 terms). ``work``:
    scratch rows (``first_bounce``)."""
    n_tan = len(_TAN)
    y2_max = (k_hi * g) ** 2
    bound = 1.0 / abs(k_lo * e)
    terms = n_tan
    for m in range(1, n_tan):
        bound *= y2_max
        if _TAN[m] * bound <= 0.5 * tol:
            terms = m
            break
    re, im, re2, im2, t_k, y2 = work[0], work[1], work[2], work[3], work[5], work[6]
    _phasors(si, k, two_dk, re, im, tab, par)
    _phasors(sj, k, two_dk, re2, im2, tab, par)
    n_k = len(k)
    for i in range(n_k):
        y2[i] = (k[i] * g) * (k[i] * g)
        t_k[i] = _TAN[terms - 1]
    for m in range(terms - 2, -1, -1):  # Horner term by term over all frequencies
        cm = _TAN[m]
        for i in range(n_k):
            t_k[i] = t_k[i] * y2[i] + cm
    for i in range(n_k):
        amp = -e * d * t_k[i]  # times j
        row[i] += complex(-amp * (im[i] + im2[i]), amp * (re[i] + re2[i]))


_STAGE = 256  # vertices whose phasors are formed before their moments are added
BLOCK = 8  # directions per pass over the facets (any number gives the same bytes)


@njit(cache=True)
def _add_moments(m_f, lit_s, lit_w, n_lit, inv_h, h, b_min, n_terms, two_k_mid, tab, par):
    """Add the moments of the first ``n_lit`` weighted vertices (positions ``lit_s``, weights
    ``lit_w``, in the mesh's vertex order) to ``m_f``, the float64 view (re, im interleaved)
    of one direction's (n_bins·n_terms) complex moments.

    In stages of _STAGE vertices: first every vertex's bin, u and w·e^{j2k_mid δ}, then the
    moment updates two vertices at a time, interleaved term by term. A moment receives its
    additions in the vertices' order either way (vertex t's term m before vertex t+1's), so
    the sums are those of one vertex at a time, bit for bit; indices are unsigned (no
    negative-index wrap-around)."""
    two_over_h = 2.0 * inv_h
    u_buf = np.empty(_STAGE)
    re_buf = np.empty(_STAGE)
    im_buf = np.empty(_STAGE)
    at_buf = np.empty(_STAGE, dtype=np.uint64)
    two = np.uint64(2)
    one = np.uint64(1)
    for t0 in range(0, n_lit, _STAGE):
        n = min(_STAGE, n_lit - t0)
        for t in range(n):
            si = lit_s[t0 + t]
            wi = lit_w[t0 + t]
            bf = math.floor(si * inv_h + 0.5)
            delta = si - bf * h  # exact: h is a power of two
            u_buf[t] = delta * two_over_h
            c, sn = _cis_of_product(delta, two_k_mid, tab, par)
            re_buf[t] = wi * c
            im_buf[t] = wi * sn
            at_buf[t] = np.uint64(2 * (int(bf) - b_min) * n_terms)
        t = 0
        while t + 1 < n:
            a, b = at_buf[t], at_buf[t + 1]
            ra, ia, ua = re_buf[t], im_buf[t], u_buf[t]
            rb, ib, ub = re_buf[t + 1], im_buf[t + 1], u_buf[t + 1]
            pa = 1.0
            pb = 1.0
            for m in range(n_terms):
                j = two * np.uint64(m)
                m_f[a + j] += ra * pa
                m_f[a + j + one] += ia * pa
                m_f[b + j] += rb * pb
                m_f[b + j + one] += ib * pb
                pa *= ua
                pb *= ub
            t += 2
        if t < n:
            a, ra, ia, ua = at_buf[t], re_buf[t], im_buf[t], u_buf[t]
            pa = 1.0
            for m in range(n_terms):
                j = two * np.uint64(m)
                m_f[a + j] += ra * pa
                m_f[a + j + one] += ia * pa
                pa *= ua


Facets = namedtuple("Facets", "v faces v_in_order local area area_lo area_split two_sided")
"""The mesh as the facet pass reads it (``field._Geometry.facets``): ``v``, ``faces`` renumbered
for locality; ``v_in_order`` the mesh's own vertices, whose order is the order of the moment
sums, and ``local[i]`` the renumbered index of its vertex i; ``area`` (n_faces, 3) area vectors
with their low parts ``area_lo`` and Veltkamp halves ``area_split`` (hi parts, then lo parts);
``two_sided``: an open mesh, lit from both sides."""

Spectrum = namedtuple("Spectrum", "k two_dk tol phase_error tab par")
"""The frequency grid as the sums need it: wavenumbers ``k``, ``two_dk`` = 2Δk of a uniform
grid (0: not uniform), the accuracy ``tol`` and the vertices' ``phase_error`` bound, and the
e^{jx} table ``tab`` and its constants ``par`` (CIS_TABLE, CIS_PARAMS)."""

Bins = namedtuple("Bins", "inv_h b_min n_terms two_k_mid")
"""The Taylor moments' bins (``field._Moments``): 1/h, the first bin's index, the terms per
bin (0: direct sums instead of moments) and 2·k_mid."""


# C901: a numba kernel, its loop nest over the facets kept in one piece; a split would first
# have to show no loss of speed (perf/radar_kernel.py)
@njit(cache=True)
def first_bounce(mesh, grid, bins, dirs, blocked, mom, out):  # noqa: C901
    """Moments ``mom`` (n_dirs, 2·n_bins·n_terms: the float64 view of complex moments) of the
    k⁻¹ vertex weights (n_terms = 0: their frequency sums added to ``out`` directly), special
    facets added to ``out`` (n_dirs, n_k); returns the facets left for the stable integral as
    (face, direction) index pairs, their projected areas and their three positions r̂·r_i,
    by blocks of BLOCK directions and within a block by face. ``mesh``: Facets; ``grid``:
    Spectrum; ``bins``: Bins; ``blocked`` (n_faces, n_dirs) uint8 marks shadowed facets (size
    0: none).

    One pass over the facets serves BLOCK directions (their positions and weights side by
    side per vertex). Every sum is formed in the same order as one direction at a time over
    the mesh's own numbering: a vertex weight and a row of ``out`` over the faces in face
    order, a moment over the vertices in the mesh's order; the blocks and the renumbering
    only change where the numbers are kept."""
    v, faces, v_in_order, local = mesh.v, mesh.faces, mesh.v_in_order, mesh.local
    area, area_lo, area_split, two_sided = mesh.area, mesh.area_lo, mesh.area_split, mesh.two_sided
    k, two_dk, tol, phase_error, tab, par = grid
    inv_h, b_min, n_terms, two_k_mid = bins
    n_v = len(v)
    n_f = len(faces)
    n_dirs = len(dirs)
    k_lo = k.min()
    k_hi = k.max()
    k_lo2 = k_lo * k_lo
    h = 1.0 / inv_h
    shadowed = blocked.size > 0
    s = np.empty((n_v, BLOCK))
    w = np.empty((n_v, BLOCK))
    lit_s = np.empty(n_v)
    lit_w = np.empty(n_v)
    r = np.empty((BLOCK, 3))
    r_split = np.empty((BLOCK, 6))
    scratch = np.empty((7, len(k)))  # phasors (4 rows), k², Horner sums (2 rows)
    coef = np.empty(_SERIES_N)
    touched = np.empty(n_v, dtype=np.uint8)  # a vertex given a weight in this block
    for n in range(len(k)):
        scratch[4, n] = k[n] * k[n]
    cap = 64
    st_idx = np.empty((cap, 2), dtype=np.int64)
    st_val = np.empty((cap, 4))
    n_st = 0
    for d0 in range(0, n_dirs, BLOCK):
        nd = min(BLOCK, n_dirs - d0)
        for e in range(BLOCK):  # lanes past the last direction repeat it (never read)
            for c in range(3):
                r[e, c] = dirs[min(d0 + e, n_dirs - 1), c]
                r_split[e, c], r_split[e, 3 + c] = _split(r[e, c])
        for i in range(n_v):
            x0, x1, x2 = v[i, 0], v[i, 1], v[i, 2]
            for e in range(BLOCK):
                s[i, e] = x0 * r[e, 0] + x1 * r[e, 1] + x2 * r[e, 2]
                w[i, e] = 0.0
            touched[i] = 0
        for f in range(n_f):
            i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
            for e in range(nd):
                p = _projected(area, area_lo, area_split, f, r[e, 0], r[e, 1], r[e, 2], r_split[e])
                if two_sided:
                    p = abs(p)
                if not p > 0.0 or (shadowed and blocked[f, d0 + e]):
                    continue
                s0, s1, s2 = s[i0, e], s[i1, e], s[i2, e]
                a = s0 - s1
                b = s1 - s2
                c = s2 - s0
                abc = a * b * c
                aa, bb, cc = abs(a), abs(b), abs(c)
                d_max = max(aa, bb, cc)
                # Hermite-Genocchi: the facet integral is a second divided difference of the
                # exponential, so A_f(k) = (1/k) sum_i W_i exp(j 2k s_i) with frequency-free
                # (W0, W1, W2) = P / (2 sqrt(pi) abc) * (b, c, a). Near-coincident phases make
                # the W large and cancelling: their relative error d_max * eps / (k_lo^2 |abc|)
                # must stay within tol, else a series form below (docs/RADAR.md, "Exact facet
                # integral" and the table of forms).
                if abc != 0.0 and d_max * phase_error <= tol * k_lo2 * abs(abc):
                    q = p / ((2.0 * _SQRT_PI) * abc)
                    w[i0, e] += q * b
                    w[i1, e] += q * c
                    w[i2, e] += q * a
                    touched[i0] = touched[i1] = touched[i2] = 1
                    continue
                row = out[d0 + e]
                if (2.0 * k_hi * d_max) ** 16 * _SERIES_NEXT <= tol:
                    _add_series(row, k, k_hi, two_dk, tol, p, s0, s1, s2, scratch, coef, tab, par)
                    continue
                d_min = min(aa, bb, cc)
                ke = k_lo * d_max
                if (
                    ke > 0.0
                    and (
                        _TAN_NEXT * (k_hi * d_min) ** 16 / ke
                        + phase_error * (1.0 / ke + 1.0 / (ke * ke))
                    )
                    <= tol
                ):
                    if aa == d_min:  # pair (0, 1), third 2
                        pi_, pj, pm = i0, i1, i2
                        si, sj, sm = s0, s1, s2
                    elif bb == d_min:  # pair (1, 2), third 0
                        pi_, pj, pm = i1, i2, i0
                        si, sj, sm = s1, s2, s0
                    else:  # pair (2, 0), third 1
                        pi_, pj, pm = i2, i0, i1
                        si, sj, sm = s2, s0, s1
                    gap = 0.5 * (si + sj) - sm
                    g = si - sj
                    dd = _TWO_OVER_SQRT_PI * p / (4.0 * gap * gap - g * g)
                    w[pi_, e] += 0.5 * dd
                    w[pj, e] += 0.5 * dd
                    w[pm, e] -= dd
                    touched[pi_] = touched[pj] = touched[pm] = 1
                    _add_pair_tan(
                        row, k, k_lo, k_hi, two_dk, tol, dd, gap, g, si, sj, scratch, tab, par
                    )
                    continue
                if n_st == cap:
                    cap *= 2
                    grown_idx = np.empty((cap, 2), dtype=np.int64)
                    grown_val = np.empty((cap, 4))
                    grown_idx[:n_st] = st_idx
                    grown_val[:n_st] = st_val
                    st_idx, st_val = grown_idx, grown_val
                st_idx[n_st, 0] = f
                st_idx[n_st, 1] = d0 + e
                st_val[n_st, 0] = p
                st_val[n_st, 1] = s0
                st_val[n_st, 2] = s1
                st_val[n_st, 3] = s2
                n_st += 1
        # each lane's weights in the mesh's own vertex order (one cache line per vertex, read
        # only for a vertex that got a weight: the others' are still 0.0; kept in the
        # positions' memory, which is not read again in this block), then per lane its
        # weighted vertices in that order, without a branch per vertex, and their moments
        w_in_order = s.reshape(BLOCK, n_v)
        for i in range(n_v):
            j = local[i]
            if touched[j]:
                for e in range(BLOCK):
                    w_in_order[e, i] = w[j, e]
            else:
                for e in range(BLOCK):
                    w_in_order[e, i] = 0.0
        for e in range(nd):
            r0, r1, r2 = r[e, 0], r[e, 1], r[e, 2]
            w_e = w_in_order[e]
            n_lit = 0
            for i in range(n_v):
                wi = w_e[i]
                lit_s[n_lit] = v_in_order[i, 0] * r0 + v_in_order[i, 1] * r1 + v_in_order[i, 2] * r2
                lit_w[n_lit] = wi
                n_lit += wi != 0.0
            if n_terms == 0:  # few vertices: direct sums
                row = out[d0 + e]
                for t in range(n_lit):
                    wi = lit_w[t]
                    _phasors(lit_s[t], k, two_dk, scratch[0], scratch[1], tab, par)
                    for n in range(len(k)):
                        wk = wi / k[n]
                        row[n] += complex(wk * scratch[0, n], wk * scratch[1, n])
            else:
                _add_moments(
                    mom[d0 + e], lit_s, lit_w, n_lit, inv_h, h, b_min, n_terms, two_k_mid, tab, par
                )
    return st_idx[:n_st], st_val[:n_st]
