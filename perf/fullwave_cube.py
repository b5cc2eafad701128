"""A full-wave 3-D reference for the labels' physics: perfectly conducting (PEC) cubes solved by
the boundary element method (bempp-cl), against physical optics (PO) and PO + edge diffraction
(Michaeli's equivalent edge currents, MEC) of the simulator, in the benchmark's metric.

    python perf/fullwave_cube.py [--sizes 0.5 1] [--epw 10] [--refine-epw 20]
                                 [--refine-sizes 0.5] [--rolls 0 45] [--cut-step 1]
                                 [--freq-ghz 10] [--sphere-radius 0.5] [--out NAME.json]

Needs the optional extra: pip install -c constraints.txt '.[fullwave]' (bempp-cl, numba backend;
no OpenCL). Sizes are in wavelengths at ``--freq-ghz``; every figure scales with a/λ only.

Reference. The electric field integral equation (EFIE) of the cube's surface current, RWG
(Rao-Wilton-Glisson) basis and Galerkin testing: bempp-cl's ``maxwell.electric_field(RWG, RWG,
SNC)``, dense, one LU per cube with every angle and polarization as a right-hand side. Mesh: each
face split into n x n squares of side a/n <= λ/``--epw`` (two triangles each). The EFIE, not a
combined-field (CFIE) or Calderón form: bempp-cl 0.4.2's magnetic operator takes only SNC test
functions, with which the MFIE's identity term is the ill-conditioned twisted RWG pairing; its
well-conditioned forms need Buffa-Christiansen functions on the barycentric refinement (6x the
elements, ~36x the assembly), too costly on this machine. The EFIE is wrong only near interior
(cavity) resonances, ka = π√(l²+m²+n²) with at most one index zero: each size reports its
distance to the nearest (0.5 λ: 41%, 1 λ: 12%, 2 λ: 3%; 1.5 λ sits on one). The reference's
own error: the sizes of ``--refine-sizes`` (default the first) solved again at
``--refine-epw`` (self-convergence, in the same metric), and the sphere against Mie at the same
density. The mirror symmetry of the roll-0 cut (θ ↔ 90° - θ swaps two faces) is only a
consistency check of the assembly, quadrature and right-hand sides: the structured mesh has that
symmetry too, so it cannot see the mesh's error.
Cost: dense assembly grows as (elements)², 6(a/λ · epw)² elements; a 1 λ cube at λ/10 (1,200
triangles, 1,800 unknowns) is about a minute on an idle 2-core machine, 2 λ (4,800 triangles)
16 times that and 0.8 GB of matrix, so the default sizes stop at 1 λ.

Conventions (docs/RADAR.md). bempp's e^{-iωt}: incident E = p̂ e^{-ik r̂·x} (from the radar at
r̂), right-hand side b_m = ∫ p̂·f_m e^{-ik r̂·x} (= -bempp's projection of E×n̂ on SNC), current
coefficients x = Z⁻¹b and co-polarized far-field amplitude F = (jk/4π) bᵀx, E^s ~ F e^{ikr}/r
(bempp's far-field operator, checked against it on the sphere). The toolkit's amplitude (e^{jωt},
σ = |A|² m², a broadside plate real and positive) is A = 2√π j conj(F). V = θ̂ and H = φ̂ of the
line of sight as ``radar_sim.field.polarization``. The sphere check compares that pipeline
(icosphere, same mesh density) with ``exact.mie_backscatter`` in magnitude and phase first.

Cuts: aspect θ 0..90° at each roll φ of ``--rolls``; φ = 0 is the principal plane through the
+z and +x face normals (broadside, the y-directed edge seen edge-on at 45°, broadside again);
φ = 45° runs from the +z face over the corner direction (54.7°) to the z-directed edge.

Models: ``radar_sim.polarimetric_field`` of the cube's 12-triangle mesh (vertices ±a/2),
``edges="none"`` (PO) and ``edges="mec"`` (PO + MEC fringe), channels HH and VV. Metric as the
benchmark (20 log10 max(|A|, 1e-4), a -80 dB floor): median |Δ| (dB) and MSE (dB²) over all
angles of a cut, and over the angles within 30 dB of the reference's peak on that cut; also the
complex error ‖A - A_ref‖/‖A_ref‖ over the cut.

Writes perf/results/fullwave_cube.json (hardware, times, meshes, the reference amplitudes and
all figures) and prints tables.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy import linalg, sparse, special

try:
    import bempp_cl.api as bempp
    from bempp_cl.api.integration.triangle_gauss import rule
except ImportError:
    sys.exit("perf/fullwave_cube.py: needs bempp-cl: pip install -c constraints.txt '.[fullwave]'")

import radar_sim
from basic_shapes.geometry import area_normals, line_of_sight
from basic_shapes.infra import hardware, write_json
from radar_sim import exact
from radar_sim.field import C0, CHANNELS, polarization

RESULTS = Path(__file__).parent / "results"
FLOOR = 1e-4  # benchmark.scoring.data.FLOOR_AMPLITUDE: -80 dB
PEAK_WINDOW_DB = 30.0
POLS = ("HH", "VV")
QUADRATURE_ORDER = 4  # right-hand sides and far fields (bempp's default regular order)
SPHERE_TOLERANCE = 0.1  # complex relative error vs Mie above which the conventions are wrong
RESONANCE_WARN = 0.02  # relative distance to a cavity resonance below which the EFIE is suspect
DIRECTION_CHUNK = 32


# --- meshes ---------------------------------------------------------------------------------


def merge(points: np.ndarray, tris: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Weld coincident vertices (integer keys at ``scale``), keeping the triangles' winding."""
    key = np.round(points / scale).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return points[first], inv.ravel()[tris]


def cube_mesh(a: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed cube [-a/2, a/2]³, each face n x n squares split in two, outward winding."""
    g = np.linspace(-a / 2, a / 2, n + 1)
    points, tris = [], []
    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3
        for sign in (-1.0, 1.0):
            base = sum(len(p) for p in points)
            p = np.zeros(((n + 1) ** 2, 3))
            p[:, axis] = sign * a / 2
            p[:, u] = np.repeat(g, n + 1)
            p[:, w] = np.tile(g, n + 1)
            points.append(p)
            i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
            q00 = (base + i * (n + 1) + j).ravel()
            q10, q01 = q00 + n + 1, q00 + 1
            t = np.concatenate([np.c_[q00, q10, q10 + 1], np.c_[q00, q10 + 1, q01]])
            tris.append(t if sign > 0 else t[:, [0, 2, 1]])
    return merge(np.concatenate(points), np.concatenate(tris), a / n / 2)


def icosphere(radius: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Sphere: each icosahedron face split into n² triangles, vertices pushed onto the sphere."""
    t = (1 + 5**0.5) / 2
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t]]
        + [[0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=float,
    )
    faces = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4]]
    faces += [[11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8]]
    faces += [[3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    points, tris = [], []
    for a, b, c in faces:
        index = {}
        for i in range(n + 1):
            for j in range(n + 1 - i):
                index[i, j] = len(points)
                points.append(v[a] + (v[b] - v[a]) * i / n + (v[c] - v[a]) * j / n)
        for i in range(n):
            for j in range(n - i):
                tris.append((index[i, j], index[i + 1, j], index[i, j + 1]))
                if i + j < n - 1:
                    tris.append((index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]))
    p = np.array(points)
    p *= radius / np.linalg.norm(p, axis=1)[:, None]
    return merge(p, np.array(tris), radius * 1e-6)


def max_edge(v: np.ndarray, f: np.ndarray) -> float:
    return float(
        max(np.linalg.norm(v[f[:, i]] - v[f[:, (i + 1) % 3]], axis=1).max() for i in range(3))
    )


# --- interior resonances (where the EFIE fails) ---------------------------------------------


def cube_resonance(a_over_lambda: float) -> dict:
    """Nearest cavity resonance of the cube: a/λ = √(l²+m²+n²)/2, at most one index zero."""
    top = int(2 * a_over_lambda) + 3
    r = np.arange(top + 1)
    i0, i1, i2 = np.meshgrid(r, r, r, indexing="ij")
    ok = (i0 <= i1) & (i1 <= i2) & (i1 > 0)  # sorted, so i1 > 0 leaves at most one zero
    res = np.sqrt(i0**2 + i1**2 + i2**2)[ok] / 2
    i = int(np.argmin(np.abs(res - a_over_lambda)))
    return {
        "nearest_a_over_lambda": float(res[i]),
        "distance": float(abs(res[i] / a_over_lambda - 1)),
    }


def sphere_resonance(ka: float) -> dict:
    """Nearest interior resonance of the sphere: zeros of j_n(x) and (x j_n(x))', n >= 1."""
    x = np.linspace(0.5, ka * 1.5 + 2, 20001)
    zeros = []
    for n in range(1, int(ka) + 6):
        for g in (
            special.spherical_jn(n, x),
            special.spherical_jn(n, x) + x * special.spherical_jn(n, x, derivative=True),
        ):
            s = np.nonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0]
            zeros += list(x[s])
    zeros = np.array(zeros)
    i = int(np.argmin(np.abs(zeros - ka)))
    return {"nearest_ka": float(zeros[i]), "distance": float(abs(zeros[i] / ka - 1))}


# --- the boundary element solve -------------------------------------------------------------


class Efie:
    """The EFIE of one closed mesh at one wavenumber: bempp's dense matrix, LU-factorized."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, k: float):
        self.k = k
        self.grid = bempp.Grid(vertices.T.copy(), faces.T.copy())
        self.rwg = bempp.function_space(self.grid, "RWG", 0)
        self.snc = bempp.function_space(self.grid, "SNC", 0)
        t0 = time.perf_counter()
        op = bempp.operators.boundary.maxwell.electric_field(self.rwg, self.rwg, self.snc, k)
        matrix = op.weak_form().to_dense()
        self.assemble_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        self.lu = linalg.lu_factor(matrix, overwrite_a=True, check_finite=False)
        self.lu_s = time.perf_counter() - t0
        self.unknowns = self.rwg.global_dof_count
        self._basis()

    def _basis(self) -> None:
        """RWG values at quadrature points, as bempp evaluates them (Piola map x edge length x
        the space's sign), and the sparse map from (element, local function) to unknowns."""
        pts, w = rule(QUADRATURE_ORDER)
        v = self.grid.vertices.T
        e = self.grid.elements.T
        v0, v1, v2 = v[e[:, 0]], v[e[:, 1]], v[e[:, 2]]
        jac = np.stack([v1 - v0, v2 - v0], axis=2)  # (elements, 3, 2)
        det = np.linalg.norm(area_normals(v[e]), axis=1)
        length = np.stack(
            [
                np.linalg.norm(v0 - v1, axis=1),
                np.linalg.norm(v2 - v0, axis=1),
                np.linalg.norm(v1 - v2, axis=1),
            ],
            axis=1,
        )
        x, y = pts
        ref = np.stack([np.stack([x, y - 1]), np.stack([x - 1, y]), np.stack([x, y])])
        scale = length * self.rwg.local_multipliers / det[:, None]
        self.values = np.einsum("eij,fjq->efiq", jac, ref) * scale[:, :, None, None]
        self.points = v0[:, :, None] + np.einsum("eij,jq->eiq", jac, pts)  # (elements, 3, q)
        self.weights = w[None, :] * det[:, None]
        l2g = self.rwg.local2global.ravel()
        self.gather = sparse.csr_matrix(
            (np.ones(len(l2g)), (l2g, np.arange(len(l2g)))), shape=(self.unknowns, len(l2g))
        )

    def projections(self, rhat: np.ndarray, pol: np.ndarray) -> np.ndarray:
        """b[m, s] = ∫ p̂_s·f_m e^{-ik r̂_s·x} dx, (unknowns, n) for unit vectors r̂, p̂ (n, 3)."""
        out = np.empty((self.unknowns, len(rhat)), dtype=np.complex128)
        for lo in range(0, len(rhat), DIRECTION_CHUNK):
            r, p = rhat[lo : lo + DIRECTION_CHUNK], pol[lo : lo + DIRECTION_CHUNK]
            phase = np.exp(-1j * self.k * np.einsum("si,eiq->seq", r, self.points)) * self.weights
            local = np.einsum("efiq,si,seq->efs", self.values, p, phase)
            out[:, lo : lo + len(r)] = self.gather @ local.reshape(-1, len(r))
        return out

    def amplitudes(self, rhat: np.ndarray, pol: np.ndarray) -> np.ndarray:
        """The toolkit's co-polarized backscatter A (n,) for lines of sight r̂, polarizations p̂."""
        b = self.projections(rhat, pol)
        x = linalg.lu_solve(self.lu, b, check_finite=False)
        far = 1j * self.k / (4 * np.pi) * np.einsum("ms,ms->s", b, x)
        return 2 * np.sqrt(np.pi) * 1j * np.conj(far)

    def bempp_far_field(self, rhat: np.ndarray, pol: np.ndarray) -> complex:
        """The same amplitude through bempp's own pipeline (its tutorial's right-hand side
        E×n̂ projected on SNC, E^s = -far_field·Λ), for one direction: checks ``amplitudes``."""
        k = self.k
        r0, r1, r2 = (float(c) for c in rhat)
        p0, p1, p2 = (float(c) for c in pol)

        @bempp.complex_callable
        def trace(x, n, domain_index, result):
            phase = np.exp(-1j * k * (r0 * x[0] + r1 * x[1] + r2 * x[2]))
            e = np.array([p0 * phase, p1 * phase, p2 * phase])
            result[:] = np.cross(e, n)

        rhs = bempp.GridFunction(self.rwg, fun=trace, dual_space=self.snc)
        x = linalg.lu_solve(self.lu, rhs.projections(self.snc), check_finite=False)
        op = bempp.operators.far_field.maxwell.electric_field(
            self.rwg, rhat.reshape(3, 1).copy(), k
        )
        far = -(op * bempp.GridFunction(self.rwg, coefficients=x))[:, 0]
        return complex(2 * np.sqrt(np.pi) * 1j * np.conj(np.dot(pol, far)))


def cut(roll_deg: float, step_deg: float) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Aspects θ 0..90° at roll φ: lines of sight and the H, V unit vectors (radar_sim's)."""
    theta = np.arange(0.0, 90.0 + step_deg / 2, step_deg)
    rhat = line_of_sight(theta, roll_deg)
    v = polarization(rhat)
    return theta, rhat, {"VV": v, "HH": np.cross(rhat, v)}


# --- metric ---------------------------------------------------------------------------------


def db(amplitude: np.ndarray) -> np.ndarray:
    return 20 * np.log10(np.maximum(np.abs(amplitude), FLOOR))


def errors(model: np.ndarray, reference: np.ndarray) -> dict:
    """The benchmark metric of a model's cut against the reference's (both complex (n,))."""
    m, r = db(model), db(reference)
    near = r >= r.max() - PEAK_WINDOW_DB
    d = np.abs(m - r)
    return {
        "median_abs_db": float(np.median(d)),
        "mse_all_db2": float(np.mean(d**2)),
        "median_abs_within_30db_db": float(np.median(d[near])),
        "mse_within_30db_db2": float(np.mean(d[near] ** 2)),
        "angles_within_30db": int(near.sum()),
        "complex_rel": float(np.linalg.norm(model - reference) / np.linalg.norm(reference)),
    }


# --- the runs -------------------------------------------------------------------------------


def sphere_check(radius_wl: float, epw: float, freq_hz: float) -> dict:
    """bempp (this script's pipeline) vs the Mie series: the normalization and phase."""
    lam = C0 / freq_hz
    k = 2 * np.pi / lam
    radius = radius_wl * lam
    n = 1
    while max_edge(*icosphere(radius, n)) > lam / epw:
        n += 1
    v, f = icosphere(radius, n)
    solver = Efie(v, f, k)
    rhat = line_of_sight(np.array([0.0, 30.0, 75.0]), np.array([0.0, 20.0, 60.0]))
    vpol = polarization(rhat)
    both = np.concatenate([rhat, rhat]), np.concatenate([vpol, np.cross(rhat, vpol)])
    amps = solver.amplitudes(*both)
    own = solver.bempp_far_field(both[0][0], both[1][0])
    mie = complex(exact.mie_backscatter(radius, [freq_hz])[0])
    rel = np.abs(amps / mie - 1)
    out = {
        "radius_over_lambda": radius_wl,
        "ka": k * radius,
        "elements": len(f),
        "unknowns": solver.unknowns,
        "max_edge_over_lambda": max_edge(v, f) / lam,
        "resonance": sphere_resonance(k * radius),
        "mie": [mie.real, mie.imag],
        "bempp": [[a.real, a.imag] for a in amps],
        "complex_rel_max": float(rel.max()),
        "db_diff_max": float(np.abs(db(amps) - db(np.array([mie]))).max()),
        "phase_diff_deg_max": float(np.degrees(np.abs(np.angle(amps / mie))).max()),
        "vs_bempp_far_field_operator": float(abs(own / amps[0] - 1)),
        "assemble_s": solver.assemble_s,
        "lu_s": solver.lu_s,
    }
    if not (rel.max() < SPHERE_TOLERANCE and out["vs_bempp_far_field_operator"] < 1e-6):
        sys.exit(f"perf/fullwave_cube.py: the sphere check failed, conventions are off: {out}")
    return out


def solve_cube(a_wl: float, epw: float, freq_hz: float, rolls, step: float) -> dict:
    """The reference's HH and VV on every cut for one cube size and mesh density."""
    lam = C0 / freq_hz
    n = math.ceil(a_wl * epw - 1e-9)
    v, f = cube_mesh(a_wl * lam, n)
    solver = Efie(v, f, 2 * np.pi / lam)
    t0 = time.perf_counter()
    cuts = {}
    for roll in rolls:
        theta, rhat, pols = cut(roll, step)
        cuts[roll] = {"theta": theta, **{p: solver.amplitudes(rhat, pols[p]) for p in POLS}}
    return {
        "n_per_edge": n,
        "cell_over_lambda": a_wl / n,
        "elements": len(f),
        "unknowns": solver.unknowns,
        "assemble_s": solver.assemble_s,
        "lu_s": solver.lu_s,
        "solve_s": time.perf_counter() - t0,
        "cuts": cuts,
    }


def models(a: float, freq_hz: float, roll: float, theta: np.ndarray) -> dict[str, dict]:
    """PO and PO + MEC of the 12-triangle cube on one cut, per channel."""
    v, f = cube_mesh(a, 1)
    rhat = line_of_sight(theta, roll)
    out = {}
    for name, edges in (("PO", "none"), ("PO+MEC", "mec")):
        field = radar_sim.polarimetric_field(v, f, [freq_hz], rhat, mode="convex", edges=edges)
        out[name] = {p: field[:, CHANNELS.index(p), 0] for p in POLS}
    return out


def complex_list(a: np.ndarray) -> list:
    return [[float(x.real), float(x.imag)] for x in a]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=float, nargs="+", default=[0.5, 1.0], help="a/λ")
    p.add_argument("--epw", type=float, default=10.0, help="mesh cells per wavelength")
    p.add_argument("--refine-epw", type=float, default=20.0, help="solve again at; 0: skip")
    p.add_argument(
        "--refine-sizes", type=float, nargs="+", help="a/λ solved again (default: the first)"
    )
    p.add_argument("--rolls", type=float, nargs="+", default=[0.0, 45.0], help="cut rolls, deg")
    p.add_argument("--cut-step", type=float, default=1.0, help="aspect step, degrees")
    p.add_argument("--freq-ghz", type=float, default=10.0)
    p.add_argument("--sphere-radius", type=float, default=0.5, help="r/λ, 0: skip")
    p.add_argument("--out", default="fullwave_cube.json")
    args = p.parse_args()
    freq = args.freq_ghz * 1e9
    lam = C0 / freq
    t_start = time.perf_counter()
    payload = {"args": vars(args), "frequency_hz": freq, "formulation": "EFIE, RWG Galerkin, LU"}

    if args.sphere_radius > 0:
        s = sphere_check(args.sphere_radius, args.epw, freq)
        payload["sphere"] = s
        print(
            f"sphere r = {s['radius_over_lambda']:g} λ (ka {s['ka']:.2f}), {s['elements']} "
            f"triangles, edges <= λ/{1 / s['max_edge_over_lambda']:.1f}: bempp vs Mie "
            f"{s['complex_rel_max']:.3f} complex, {s['db_diff_max']:.3f} dB, "
            f"{s['phase_diff_deg_max']:.2f}°; vs bempp's far-field operator "
            f"{s['vs_bempp_far_field_operator']:.1e}; {s['assemble_s'] + s['lu_s']:.0f} s"
        )

    rows, cases = [], []
    for a_wl in args.sizes:
        res = cube_resonance(a_wl)
        if res["distance"] < RESONANCE_WARN:
            print(f"warning: a = {a_wl:g} λ is {res['distance']:.1%} from a cavity resonance")
        ref = solve_cube(a_wl, args.epw, freq, args.rolls, args.cut_step)
        case = {
            "a_over_lambda": a_wl,
            "a_m": a_wl * lam,
            "resonance": res,
            **{k: v for k, v in ref.items() if k != "cuts"},
            "cuts": {},
        }
        if a_wl in (args.refine_sizes or args.sizes[:1]) and args.refine_epw > 0:
            fine = solve_cube(a_wl, args.refine_epw, freq, args.rolls, args.cut_step)
            case["refined"] = {
                **{k: v for k, v in fine.items() if k != "cuts"},
                "vs_reference": {
                    str(roll): {
                        p: errors(ref["cuts"][roll][p], fine["cuts"][roll][p]) for p in POLS
                    }
                    for roll in args.rolls
                },
            }
        for roll, c in ref["cuts"].items():
            theta = c["theta"]
            mods = models(a_wl * lam, freq, roll, theta)
            entry = {"theta_deg": theta.tolist()}
            for pol in POLS:
                entry[pol] = complex_list(c[pol])
                for name, m in mods.items():
                    entry[f"{name} {pol}"] = complex_list(m[pol])
                    rows.append(
                        {
                            "a_over_lambda": a_wl,
                            "roll_deg": roll,
                            "pol": pol,
                            "model": name,
                            **errors(m[pol], c[pol]),
                        }
                    )
                if roll == 0.0 and len(theta) > 1 and np.allclose(theta[::-1], 90 - theta):
                    sym = np.abs(c[pol] - c[pol][::-1]).max() / np.abs(c[pol]).max()
                    entry[f"mirror_asymmetry_{pol}"] = float(sym)
            case["cuts"][str(roll)] = entry
        cases.append(case)
        print(
            f"cube a = {a_wl:g} λ: {case['elements']} triangles ({case['unknowns']} unknowns, "
            f"cells λ/{1 / case['cell_over_lambda']:.1f}), nearest cavity resonance "
            f"{res['distance']:.1%} away; assembly {case['assemble_s']:.0f} s, LU "
            f"{case['lu_s']:.0f} s, {sum(len(c['theta']) for c in ref['cuts'].values()) * 2} "
            f"right-hand sides {case['solve_s']:.1f} s",
            flush=True,
        )

    payload |= {"cases": cases, "rows": rows, "total_s": time.perf_counter() - t_start}
    payload["hardware"] = hardware()
    write_json(RESULTS / args.out, payload)
    print_tables(payload)


def print_tables(payload: dict) -> None:
    print("\nReference self-checks:")
    for c in payload["cases"]:
        size = f"a = {c['a_over_lambda']:g} λ"
        for roll, e in c["cuts"].items():
            if "mirror_asymmetry_HH" in e:
                print(
                    f"  {size} roll {roll}: mirror asymmetry (of the peak) "
                    f"HH {e['mirror_asymmetry_HH']:.1e}, VV {e['mirror_asymmetry_VV']:.1e}"
                )
        if "refined" in c:
            r = c["refined"]
            print(
                f"  {size} vs cells λ/{1 / r['cell_over_lambda']:.1f} ({r['unknowns']} "
                f"unknowns, assembly {r['assemble_s']:.0f} s):"
            )
            for roll, d in r["vs_reference"].items():
                for pol, e in d.items():
                    print(
                        f"    roll {roll} {pol}: median |Δ| {e['median_abs_db']:.3f} dB, MSE "
                        f"{e['mse_all_db2']:.4f} / {e['mse_within_30db_db2']:.4f} dB² "
                        f"(all / within 30 dB), complex {e['complex_rel']:.3f}"
                    )
    ghz = payload["frequency_hz"] / 1e9
    print(f"\nPO and PO+MEC (12-triangle cube) vs the BEM reference, {ghz:g} GHz")
    head = ("a/λ", "roll", "pol", "model", "med|Δ| dB", "MSE all", "med ≤30", "MSE ≤30", "cplx")
    print("{:>4s} {:>4s} {:>3s} {:>7s} {:>9s} {:>8s} {:>8s} {:>8s} {:>6s}".format(*head))
    for r in payload["rows"]:
        print(
            f"{r['a_over_lambda']:4g} {r['roll_deg']:4.0f} {r['pol']:>3s} {r['model']:>7s} "
            f"{r['median_abs_db']:9.2f} {r['mse_all_db2']:8.2f} "
            f"{r['median_abs_within_30db_db']:8.2f} {r['mse_within_30db_db2']:8.2f} "
            f"{r['complex_rel']:6.3f}"
        )
    print(f"total {payload['total_s']:.0f} s; {payload['hardware']['text']}")


if __name__ == "__main__":
    main()
