"""The first-bounce PO kernel against its arithmetic bound, both measured in one run.

    python perf/kernel_bound.py [--faces 8000 32000 130000 500000] [--step 1] [--repeats 3]
                                [--baseline REV] [--tol T]

Meshes: UV spheres scaled to an ellipsoid with semi-axes 0.5 x 0.7 x 0.9 m (``radar_kernel.py``'s
``mesh_for``: the meshes of the documented figures and of the outside audit), mode "convex",
on the xband-v1 grid: its 1241 unique directions (every ``--step``-th of them with --step > 1,
the same sub-grid for every mesh and every code) x 128 frequencies. One core (thread limits
set before numpy loads). For each mesh, CPU seconds (``time.process_time``, median of
``--repeats``) of ``field.mesh_field`` after a warm-up call (numba compiled or loaded), split
into the compiled pass (``po_kernel.first_bounce``) and the contraction (``_Moments.contract``).

The bounds, measured on this core in this run:

* **flop bound** (the definition of docs/RADAR.md since the kernel was written, and the one
  the outside audit used): the direct frequency sums at BLAS speed, (4·n_k real multiply-adds
  per lit vertex and direction + 10 per lit facet and direction) / R, R = real multiply-adds
  per second of a single-threaded 1024³ dgemm (median over the run; one dgemm before every
  timed call). It is a yardstick, not a lower bound of this algorithm, whose moments need
  fewer operations per vertex than 4·n_k.
* **work floor**: this algorithm's irreducible work, with its own compiled code on data that
  is already in the cache: per lit vertex and direction one accurate phasor and M moment
  updates (``po_kernel._add_moments`` on synthetic positions, scaled from 32 directions), plus
  the contraction as one BLAS zgemm of the same shape (no zero skipping).

Reported: time / flop bound, time / work floor, ns per face per direction, the contraction
with the portable product and with BLAS, the load average around each mesh, and the facets the
kernel evaluates by its exact near-specular series (``po_kernel._add_series``): their number
per direction (the kernel's rule applied in numpy) and their share of the time, that number
times the CPU time of one call on a sample of those very facets (spread over the directions).
Their number grows about as the face count to the power 1.8 (docs/RADAR.md, "The rise, net,
is the series facets"). The counts assume a closed mesh (no facet lit from behind). With
``--baseline REV``, ``radar_sim`` and ``basic_shapes`` at REV (read with git archive)
are timed in the same run, interleaved with the working tree's code, and the two outputs are
compared bit for bit (sha256 of the complex128 array). With ``--tol T``, the working tree's
code is also timed at accuracy T instead of ``field.DEFAULT_TOL`` (fewer facets take the exact
series forms, fewer moment terms), with its largest difference from the default's output
relative to the output's largest magnitude.
Writes perf/results/kernel_bound.json (or ``--out``) and prints a table.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402 - thread limits are set before numpy loads
import contextlib  # noqa: E402
import hashlib  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

import radar_sim  # noqa: E402
from basic_shapes.infra import atomic_path, hardware  # noqa: E402
from radar_sim import facet, po_kernel, scene  # noqa: E402
from radar_sim import field as current_field  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from radar_kernel import lit_counts, mesh_for  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).parent / "results"
FLOOR_DIRECTIONS = 32
SERIES_SAMPLE = 4096


def load_baseline(rev: str, tmp: Path):
    """``radar_sim`` and ``basic_shapes`` at ``rev`` as the packages ``baseline_radar_sim``
    and ``baseline_basic_shapes`` (both whole: an old kernel imports helpers that have since
    moved); returns the baseline's ``field``."""
    for package in ("radar_sim", "basic_shapes"):
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", rev, package], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(tmp)], input=archive, check=True)
        (tmp / package).rename(tmp / f"baseline_{package}")
    for path in tmp.glob("baseline_*/*.py"):
        text = re.sub(r"\b(radar_sim|basic_shapes)\b", r"baseline_\1", path.read_text())
        path.write_text(text)
    sys.path.insert(0, str(tmp))
    return importlib.import_module("baseline_radar_sim.field")


class PartTimer:
    """CPU seconds spent in ``po_kernel.first_bounce`` and ``_Moments.contract`` of a field
    module, while active (wrappers installed on the module's own references)."""

    def __init__(self, field_module):
        self.field = field_module
        self.kernel = self.contract = 0.0

    @contextlib.contextmanager
    def active(self):
        kernel_module = self.field.po_kernel
        first_bounce, contract = kernel_module.first_bounce, self.field._Moments.contract

        def timed_kernel(*args):
            t0 = time.process_time()
            try:
                return first_bounce(*args)
            finally:
                self.kernel += time.process_time() - t0

        def timed_contract(plan, mom):
            t0 = time.process_time()
            try:
                return contract(plan, mom)
            finally:
                self.contract += time.process_time() - t0

        kernel_module.first_bounce, self.field._Moments.contract = timed_kernel, timed_contract
        try:
            yield self
        finally:
            kernel_module.first_bounce, self.field._Moments.contract = first_bounce, contract


def dgemm_fma_rate() -> float:
    """Real multiply-adds per second of this core: one single-threaded 1024³ dgemm."""
    a = np.random.default_rng(0).normal(size=(1024, 1024))
    a @ a
    t0 = time.process_time()
    a @ a
    return 1024**3 / (time.process_time() - t0)


def work_floor(mesh, k, n_dirs: int, lit_vertices: int) -> dict:
    """CPU seconds of the moment method's irreducible work (see the module docstring)."""
    plan = current_field._Moments(k, mesh.radius, len(mesh.vertices))
    per_dir = max(1, round(lit_vertices / n_dirs))
    rng = np.random.default_rng(0)
    s = rng.uniform(-mesh.radius, mesh.radius, per_dir)
    w = rng.normal(size=per_dir)
    row = np.zeros(2 * max(plan.width, 1))
    args = (1.0 / plan.h, plan.h, plan.b_min, plan.terms, 2.0 * plan.k_mid)
    tab, par = po_kernel.CIS_TABLE, po_kernel.CIS_PARAMS
    po_kernel._add_moments(row, s, w, per_dir, *args, tab, par)  # compile / warm the cache
    t0 = time.process_time()
    for _ in range(FLOOR_DIRECTIONS):
        po_kernel._add_moments(row, s, w, per_dir, *args, tab, par)
    vertex_s = (time.process_time() - t0) * n_dirs / FLOOR_DIRECTIONS
    group = min(64, n_dirs)
    mom = rng.normal(size=(group, plan.width)) + 1j * rng.normal(size=(group, plan.width))
    matrix = plan._block(0, plan.n_bins)
    mom @ matrix
    t0 = time.process_time()
    mom @ matrix
    blas_s = (time.process_time() - t0) * n_dirs / group
    return {
        "terms": plan.terms,
        "bins": plan.n_bins,
        "lit_vertices_per_direction": per_dir,
        "vertex_s": vertex_s,
        "contraction_blas_s": blas_s,
        "floor_s": vertex_s + blas_s,
    }


def series_facets(mesh, k, dirs, tol) -> tuple[int, np.ndarray]:
    """Σ over directions of the lit facets that ``po_kernel.first_bounce`` evaluates by its
    near-specular series (its classification, in numpy), and about SERIES_SAMPLE of them,
    evenly spaced within every direction, as rows (P, s0, s1, s2)."""
    phase_error = current_field._Moments(k, mesh.radius, len(mesh.vertices)).phase_error
    area = facet.area_vectors(mesh.vertices[mesh.faces])
    v, f = mesh.vertices, mesh.faces
    k_lo, k_hi = float(k.min()), float(k.max())
    count, sample = 0, []
    per_direction = -(-SERIES_SAMPLE // len(dirs))  # spread over every direction
    for r in dirs:
        p = area[:, 0] * r[0] + area[:, 1] * r[1] + area[:, 2] * r[2]
        s = v[:, 0] * r[0] + v[:, 1] * r[1] + v[:, 2] * r[2]
        lit = p > 0
        s0, s1, s2 = (s[f[lit, i]] for i in range(3))
        a, b, c = s0 - s1, s1 - s2, s2 - s0
        abc = a * b * c
        d_max = np.maximum(np.maximum(np.abs(a), np.abs(b)), np.abs(c))
        weights = (abc != 0) & (d_max * phase_error <= tol * k_lo**2 * np.abs(abc))
        series = ~weights & ((2 * k_hi * d_max) ** 16 * po_kernel._SERIES_NEXT <= tol)
        count += int(series.sum())
        rows = np.stack([p[lit], s0, s1, s2], axis=1)[series]
        sample.append(rows[:: max(1, len(rows) // per_direction)][:per_direction])
    rows = np.concatenate(sample) if sample else np.zeros((0, 4))
    return count, np.ascontiguousarray(rows)


@njit
def _series_calls(rows, k, two_dk, tol, work, coef, tab, par):
    row = np.zeros(len(k), dtype=np.complex128)
    k_hi = k.max()  # once, as first_bounce does
    for p, s0, s1, s2 in rows:
        po_kernel._add_series(row, k, k_hi, two_dk, tol, p, s0, s1, s2, work, coef, tab, par)
    return row


def series_call_s(rows: np.ndarray, k, tol) -> float:
    """CPU seconds of one ``po_kernel._add_series`` call, the mean over ``rows`` (repeated
    to at least 10⁵ calls) on the grid ``k``."""
    if len(rows) == 0:
        return 0.0
    work = np.empty((7, len(k)))
    work[4] = k * k
    coef = np.empty(po_kernel._SERIES_N)
    two_dk = 2.0 * current_field._uniform_step(k)
    args = (k, two_dk, tol, work, coef, po_kernel.CIS_TABLE, po_kernel.CIS_PARAMS)
    _series_calls(rows[:2], *args)  # compile
    reps = -(-100_000 // len(rows))
    t0 = time.process_time()
    for _ in range(reps):
        _series_calls(rows, *args)
    return (time.process_time() - t0) / (reps * len(rows))


def measure(field_module, tol, mesh, k, dirs, rates: list) -> tuple[dict, np.ndarray]:
    rates.append(dgemm_fma_rate())
    timer = PartTimer(field_module)
    load = os.getloadavg()[0]
    with timer.active():
        t0 = time.process_time()
        out = field_module.mesh_field(mesh, k, dirs, "convex", tol=tol)
        total = time.process_time() - t0
    return {
        "total_s": total,
        "kernel_s": timer.kernel,
        "contract_s": timer.contract,
        "rest_s": total - timer.kernel - timer.contract,
        "load_1m": load,
    }, out


def digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, dtype=np.complex128).tobytes()).hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--faces", type=int, nargs="+", default=[8000, 32000, 130000, 500000])
    ap.add_argument("--step", type=int, default=1, help="every STEP-th unique direction")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline", help="git revision whose kernel is timed alongside")
    ap.add_argument("--tol", type=float, help="also time the current code at this accuracy")
    ap.add_argument("--out", type=Path, default=RESULTS / "kernel_bound.json", help="JSON path")
    args = ap.parse_args(argv)
    config = radar_sim.RadarConfig.named("xband-v1")
    k = current_field.wavenumbers(config.frequency_hz)
    all_dirs = np.unique(config.directions(), axis=0)
    dirs = np.ascontiguousarray(all_dirs[:: args.step])
    current_field._keep_heap()
    codes = {"current": (current_field, current_field.DEFAULT_TOL)}
    if args.tol:
        codes[f"tol {args.tol:g}"] = (current_field, args.tol)
    rates: list[float] = []
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        if args.baseline:
            baseline = load_baseline(args.baseline, Path(tmp))
            codes["baseline"] = (baseline, baseline.DEFAULT_TOL)
        v0, f0 = mesh_for(2000)
        warm = scene.prepare(v0, f0)
        for code, _ in codes.values():
            code.mesh_field(warm, k, dirs[:9], "convex")  # numba: compile or load
        start_load = os.getloadavg()
        for n_faces in args.faces:
            v, f = mesh_for(n_faces)
            mesh = scene.prepare(v, f)
            runs = {name: [] for name in codes}
            digests, outputs = {}, {}
            for rep in range(args.repeats):
                order = list(codes) if rep % 2 == 0 else list(codes)[::-1]
                for name in order:
                    timing, out = measure(*codes[name], mesh, k, dirs, rates)
                    runs[name].append(timing)
                    digests.setdefault(name, digest(out))
                    outputs.setdefault(name, out)
            lit_f, lit_v = lit_counts(mesh, dirs)
            n_series, sample = series_facets(mesh, k, dirs, current_field.DEFAULT_TOL)
            series_s = n_series * series_call_s(sample, k, current_field.DEFAULT_TOL)
            row = {
                "faces": len(mesh.faces),
                "vertices": len(mesh.vertices),
                "lit_facet_directions": lit_f,
                "lit_vertex_directions": lit_v,
                "work_floor": work_floor(mesh, k, len(dirs), lit_v),
                "series_facets_per_direction": n_series / len(dirs),
                "series_call_ns": series_s / max(n_series, 1) * 1e9,
                "series_ns_per_face_direction": series_s / (len(mesh.faces) * len(dirs)) * 1e9,
                "sha256": digests,
            }
            if "baseline" in digests:
                row["bit_identical_to_baseline"] = digests["baseline"] == digests["current"]
            ref = outputs["current"]
            row["max_difference_to_current"] = {
                name: float(np.abs(out - ref).max() / np.abs(ref).max())
                for name, out in outputs.items()
            }
            for name, timings in runs.items():
                row[name] = {key: float(np.median([t[key] for t in timings])) for key in timings[0]}
                row[name]["repeats"] = timings
            rows.append(row)
            print(f"  {row['faces']} faces done", flush=True)
    rate = float(np.median(rates))
    for row in rows:
        flop_bound = (
            4.0 * len(k) * row["lit_vertex_directions"] + 10.0 * row["lit_facet_directions"]
        ) / rate
        row["flop_bound_s"] = flop_bound
        for name in codes:
            r = row[name]
            r["over_flop_bound"] = r["total_s"] / flop_bound
            r["over_work_floor"] = r["total_s"] / row["work_floor"]["floor_s"]
            r["ns_per_face_direction"] = r["total_s"] / (row["faces"] * len(dirs)) * 1e9
    result = {
        "hardware": hardware(threads=1),
        "load_1m_5m_15m_at_start": list(start_load),
        "load_1m_5m_15m_at_end": list(os.getloadavg()),
        "grid": {
            "config": config.name,
            "directions": len(dirs),
            "of_unique_directions": len(all_dirs),
            "step": args.step,
            "frequencies": len(k),
        },
        "dgemm_fma_per_s": {"median": rate, "min": min(rates), "max": max(rates)},
        "baseline": args.baseline,
        "repeats": args.repeats,
        "meshes": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out) as tmp_path:
        tmp_path.write_text(json.dumps(result, indent=2) + "\n")
    print(
        f"\nfirst-bounce PO kernel (mesh_field, mode convex), {len(dirs)} of {len(all_dirs)} "
        f"directions x {len(k)} frequencies, one core, CPU s, median of {args.repeats}; "
        f"{result['hardware']['text']}"
    )
    print(
        f"dgemm {2 * rate / 1e9:.1f} GFLOP/s (median of {len(rates)}, "
        f"{2 * min(rates) / 1e9:.1f}-{2 * max(rates) / 1e9:.1f}); load average "
        f"{start_load[0]:.1f} at start, {result['load_1m_5m_15m_at_end'][0]:.1f} at end"
    )
    head = (
        f"{'faces':>8} {'code':>9} {'total s':>8} {'kernel':>7} {'contr.':>7} "
        f"{'BLAS':>6} {'flop bd':>7} {'x bound':>7} {'floor':>6} {'x floor':>7} "
        f"{'ns/f/dir':>8} {'series/dir':>10} {'series ns':>9} {'same bits':>9} {'max diff':>8}"
    )
    print(head)
    for row in rows:
        for name in codes:
            r = row[name]
            same = row.get("bit_identical_to_baseline")
            print(
                f"{row['faces']:>8} {name:>9} {r['total_s']:8.3f} {r['kernel_s']:7.3f} "
                f"{r['contract_s']:7.3f} {row['work_floor']['contraction_blas_s']:6.3f} "
                f"{row['flop_bound_s']:7.3f} {r['over_flop_bound']:7.2f} "
                f"{row['work_floor']['floor_s']:6.3f} {r['over_work_floor']:7.2f} "
                f"{r['ns_per_face_direction']:8.2f} {row['series_facets_per_direction']:10.1f} "
                f"{row['series_ns_per_face_direction']:9.2f} "
                f"{'-' if same is None else str(same):>9} "
                f"{row['max_difference_to_current'][name]:8.1e}"
            )
    print(
        "kernel: po_kernel.first_bounce; contr.: the contraction (portable fixed-order "
        "product); BLAS: the same contraction as one zgemm; flop bd: (4 n_k per lit vertex + "
        "10 per lit facet) multiply-adds at the dgemm rate; floor: phasor + M moment updates "
        "per lit vertex in cache + the BLAS contraction; series/dir: facets per direction "
        "taking the near-specular series; series ns: their time per face and direction (count "
        "x one call's time); max diff: largest |output - current's| / largest |current's|"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
