"""Speed of the first-bounce PO kernel on fine ellipsoid meshes, against the kernel it replaced.

    python perf/radar_kernel.py [--faces 2000 30000 130000 500000] [--old-max-faces 150000]

One core (OMP/OPENBLAS/MKL/NUMBA threads = 1), one run. Meshes: UV spheres scaled to an
ellipsoid with semi-axes 0.5 x 0.7 x 0.9 m (n segments x n/2 rings, or n x n for ~130k faces),
on the full default grid (xband-v1: 1281 directions x 128 frequencies), mode "convex".
For each mesh, CPU seconds (time.process_time) of
  * the old kernel (`radar_sim` at commit OLD_COMMIT, loaded from git into a temporary package;
    meshes above --old-max-faces are skipped: ~4 min at 500k faces),
  * the new kernel (`field.mesh_field` on a prepared mesh) and `simulate` end to end (mesh
    checks included), after a warm-up call so that numba's compile time is not in them,
  * the arithmetic bound: (4·n_k real multiply-adds per lit vertex and direction for the
    frequency sums + 10 per lit facet and direction for the weights) at this core's dgemm rate,
and the new labels' largest difference from the old ones and from the stable per-frequency sum
Σ facet.facet_field (checked against mpmath in tests/test_facet.py) on 16 directions, both
relative to the label's peak |A|. Compile time: CPU seconds of numba's first call in a fresh
process with an empty cache (compile + cache write), and with that cache (load), as Dask
workers see it.
Writes perf/results/radar_kernel.json and prints a table.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402 - thread limits are set before numpy loads
import importlib  # noqa: E402 - thread limits are set before numpy loads
import json  # noqa: E402 - thread limits are set before numpy loads
import re  # noqa: E402 - thread limits are set before numpy loads
import subprocess  # noqa: E402 - thread limits are set before numpy loads
import sys  # noqa: E402 - thread limits are set before numpy loads
import tempfile  # noqa: E402 - thread limits are set before numpy loads
import time  # noqa: E402 - thread limits are set before numpy loads
from pathlib import Path  # noqa: E402 - thread limits are set before numpy loads

import numpy as np  # noqa: E402 - thread limits are set before numpy loads

import radar_sim  # noqa: E402 - thread limits are set before numpy loads
from basic_shapes.analytic import uv_sphere  # noqa: E402 - thread limits are set before numpy loads
from basic_shapes.infra import hardware  # noqa: E402 - thread limits are set before numpy loads
from radar_sim import facet, field, scene  # noqa: E402 - thread limits are set before numpy loads

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).parent / "results"
OLD_COMMIT = "8e35ef8"  # the numpy kernel (vertex weights + block phasor products)
AXES = np.array([0.5, 0.7, 0.9])
GOAL_130K_S = 10.0
REFERENCE_DIRECTIONS = 16


def ellipsoid(segments: int, rings: int):
    """UV sphere (Blender's layout: poles plus rings x segments) scaled to AXES."""
    return uv_sphere(segments, rings, AXES)


def mesh_for(faces: int):
    """The UV ellipsoid with about ``faces`` faces: 2·s·(r − 1) faces for s segments, r rings."""
    square = faces > 100_000  # n x n (as the issue's 256 x 256), else 2n x n
    n = round(np.sqrt(faces / 2.0)) if square else round(np.sqrt(faces) / 2.0)
    return ellipsoid(n, n) if square else ellipsoid(2 * n, n)


def old_package(tmp: Path):
    """`radar_sim` at OLD_COMMIT as the package `old_radar_sim` (imports renamed)."""
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", OLD_COMMIT, "radar_sim"],
        check=True,
        capture_output=True,
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(tmp)], input=archive, check=True)
    (tmp / "radar_sim").rename(tmp / "old_radar_sim")
    for path in (tmp / "old_radar_sim").glob("*.py"):
        text = re.sub(r"\bradar_sim\b", "old_radar_sim", path.read_text())
        path.write_text(text)
    sys.path.insert(0, str(tmp))
    return importlib.import_module("old_radar_sim")


def cpu(fn):
    t0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - t0, time.perf_counter() - w0


def dgemm_fma_rate() -> float:
    """Real multiply-adds per second of this core (best of 3 single-threaded dgemm)."""
    a = np.random.default_rng(0).normal(size=(1024, 1024))
    best = min(cpu(lambda: a @ a)[1] for _ in range(3))
    return 1024**3 / best


def lit_counts(mesh, dirs):
    """Σ over directions of lit facets and of vertices of lit facets."""
    area = facet.area_vectors(mesh.vertices[mesh.faces])
    facets = vertices = 0
    for lo in range(0, len(dirs), 64):
        lit = area @ dirs[lo : lo + 64].T > 0
        facets += int(lit.sum())
        for col in lit.T:
            seen = np.zeros(len(mesh.vertices), dtype=bool)
            seen[mesh.faces[col].ravel()] = True
            vertices += int(seen.sum())
    return facets, vertices


def compile_seconds() -> dict:
    """numba's first call (tiny mesh) in fresh processes: empty cache, then that cache."""
    code = (
        "import time, numpy as np; t = time.process_time(); import radar_sim; "
        "from radar_sim import monostatic_field as m; i = time.process_time(); "
        "w = time.perf_counter(); v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.]]); "
        "m(v, [[0, 1, 2]], [1e10], [0, 0, 1]); "
        "print(i - t, time.process_time() - i, time.perf_counter() - w)"
    )
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT))
        for label in ("compile", "cached"):
            run = subprocess.run(
                [sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True
            )
            imp, first, wall = map(float, run.stdout.split())
            out.update({f"{label}_s": first, f"{label}_wall_s": wall, "import_s": imp})
    return out


def stable_reference(mesh, k, dirs):
    return np.stack([facet.facet_field(mesh.vertices[mesh.faces], d, k).sum(axis=0) for d in dirs])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--faces", type=int, nargs="+", default=[2000, 30000, 130000, 500000])
    ap.add_argument("--old-max-faces", type=int, default=150000)
    args = ap.parse_args(argv)
    config = radar_sim.RadarConfig.named("xband-v1")
    k = field.wavenumbers(config.frequency_hz)
    dirs = np.unique(config.directions(), axis=0)
    rate = dgemm_fma_rate()
    compiled = compile_seconds()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        old = old_package(Path(tmp))
        old_field = importlib.import_module("old_radar_sim.field")
        old_geometry = importlib.import_module("old_radar_sim.geometry")
        v0, f0 = mesh_for(2000)
        field.mesh_field(scene.prepare(v0, f0), k, dirs[:2], "convex")  # warm-up (numba)
        for n_faces in args.faces:
            v, f = mesh_for(n_faces)
            mesh = scene.prepare(v, f)
            new, new_s, new_wall = cpu(lambda m=mesh: field.mesh_field(m, k, dirs, "convex"))
            _, sim_s, _ = cpu(lambda v=v, f=f: radar_sim.simulate(v, f, config, mode="convex"))
            lit_f, lit_v = lit_counts(mesh, dirs)
            bound_s = (4.0 * len(k) * lit_v + 10.0 * lit_f) / rate
            row = {
                "faces": len(mesh.faces),
                "vertices": len(mesh.vertices),
                "new_s": new_s,
                "new_wall_s": new_wall,
                "simulate_s": sim_s,
                "lit_facet_directions": lit_f,
                "lit_vertex_directions": lit_v,
                "bound_s": bound_s,
                "new_over_bound": new_s / bound_s,
            }
            peak = float(np.abs(new).max())
            pick = np.linspace(0, len(dirs) - 1, REFERENCE_DIRECTIONS).astype(int)
            if len(mesh.faces) <= 40000:
                ref = stable_reference(mesh, k, dirs[pick])
                row["new_vs_stable_rel_peak"] = float(np.abs(new[pick] - ref).max() / peak)
            if len(mesh.faces) <= args.old_max_faces:
                old_mesh = old_geometry.prepare(v, f)
                was, old_s, old_wall = cpu(
                    lambda m=old_mesh: old_field.mesh_field(m, k, dirs, "convex")
                )
                row.update(
                    old_s=old_s,
                    old_wall_s=old_wall,
                    speedup=old_s / new_s,
                    new_vs_old_rel_peak=float(np.abs(new - was).max() / peak),
                    complex64_equal_fraction=float(
                        np.mean(new.astype(np.complex64) == was.astype(np.complex64))
                    ),
                )
                if "new_vs_stable_rel_peak" in row:
                    row["old_vs_stable_rel_peak"] = float(np.abs(was[pick] - ref).max() / peak)
            rows.append(row)
            print(f"  {row['faces']} faces done", flush=True)
        del old
    result = {
        "hardware": hardware(threads=1),
        "grid": {"config": config.name, "directions": len(dirs), "frequencies": len(k)},
        "old_commit": OLD_COMMIT,
        "dgemm_fma_per_s": rate,
        "numba_first_call": compiled,
        "goal_130k_s": GOAL_130K_S,
        "meshes": rows,
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "radar_kernel.json").write_text(json.dumps(result, indent=2) + "\n")
    print(
        f"\nfirst-bounce PO kernel, {len(dirs)} directions x {len(k)} frequencies, one core; "
        f"CPU s (old: radar_sim@{OLD_COMMIT})"
    )
    print(
        f"numba first call (CPU s): compile {compiled['compile_s']:.2f} s (wall "
        f"{compiled['compile_wall_s']:.1f}), from cache {compiled['cached_s']:.2f} s "
        f"(import radar_sim {compiled['import_s']:.2f} s)"
    )
    head = (
        f"{'faces':>8} {'old s':>8} {'new s':>7} {'old/new':>7} {'simulate':>8} "
        f"{'bound s':>7} {'new/bnd':>7} {'new-old':>8} {'new-ref':>8} {'old-ref':>8}"
    )
    print(head)

    def fmt(x, spec):
        return format(x, spec) if x is not None else "-"

    for r in rows:
        print(
            f"{r['faces']:>8} {fmt(r.get('old_s'), '8.2f'):>8} {r['new_s']:7.2f} "
            f"{fmt(r.get('speedup'), '7.1f'):>7} {r['simulate_s']:8.2f} {r['bound_s']:7.2f} "
            f"{r['new_over_bound']:7.2f} {fmt(r.get('new_vs_old_rel_peak'), '8.1e'):>8} "
            f"{fmt(r.get('new_vs_stable_rel_peak'), '8.1e'):>8} "
            f"{fmt(r.get('old_vs_stable_rel_peak'), '8.1e'):>8}"
        )
    print(
        "new-old, new-ref, old-ref: max |difference| / peak |A| of the label (ref: Σ "
        f"facet_field on {REFERENCE_DIRECTIONS} directions, meshes <= 40k faces)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
