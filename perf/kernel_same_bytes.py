"""Whether the PO kernel's output kept every bit against a git revision, on the hard cases.

    python perf/kernel_same_bytes.py --baseline REV [--out FILE]

A kernel change meant to be faster must leave the labels' bytes alone (docs/RADAR.md, "The
kernel against its arithmetic bound"). ``perf/kernel_bound.py --baseline`` compares the two on
its ellipsoids only; this script hashes (sha256 of the complex128 array) ``field.mesh_field``
of the working tree and of ``radar_sim`` at REV on the cases that reach every branch: UV
ellipsoids up to 500k faces (special facets, the gather, chunked set-up), the rule-2
simulation meshes of five classes with axis-aligned views (exact pair and specular forms;
the torus shadowed), an open plate (two-sided), accuracies 1e-6 and 1e-14 (the stable
per-frequency kernel), an irregular grid, 8,192 frequencies (the contraction in chunks), and
``polarimetric_field`` with edge currents. Writes perf/results/kernel_same_bytes.json and
prints a table; exit 1 if any case differs.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

import radar_sim
from basic_shapes import analytic
from basic_shapes.infra import hardware, write_json
from radar_sim import field, scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from kernel_bound import digest, load_baseline
from radar_kernel import mesh_for

RESULTS = Path(__file__).parent / "results"
AXES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, 0, -1], [0.6, 0.8, 0]], float)


def plate(n: int = 21):
    """An open square sheet of 2(n-1)² triangles."""
    g = np.linspace(-0.5, 0.5, n)
    x, y = np.meshgrid(g, g)
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    q = np.arange(n * n).reshape(n, n)
    a, b, c, d = q[:-1, :-1].ravel(), q[1:, :-1].ravel(), q[:-1, 1:].ravel(), q[1:, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])


def cases(config):
    """(name, prepared mesh, wavenumbers, directions, mode, tol) of every case."""
    k = field.wavenumbers(config.frequency_hz)
    dirs = np.ascontiguousarray(np.unique(config.directions(), axis=0))
    views = np.vstack([dirs[::16], AXES])
    for faces, step in ((32000, 4), (130000, 40), (500000, 160)):
        yield (
            f"ellipsoid {faces}",
            scene.prepare(*mesh_for(faces)),
            k,
            dirs[::step],
            "convex",
            1e-10,
        )
    f_max = float(config.frequency_hz.max())
    for kind, scale in (
        ("cube", (0.3, 0.5, 0.7)),
        ("cylinder", (0.4, 0.4, 1.0)),
        ("sphere", (0.5, 0.6, 0.7)),
        ("cone", (0.5, 0.5, 0.8)),
        ("torus", (0.6, 0.6, 0.2)),
    ):
        mesh = scene.prepare(
            *analytic.simulation_mesh(analytic.solid_for(kind, scale), f_max, rule=2)
        )
        yield (
            f"{kind} simulation mesh",
            mesh,
            k,
            views,
            "shadowed" if kind == "torus" else "convex",
            1e-10,
        )
    yield "open plate", scene.prepare(*plate()), k, views, "convex", 1e-10
    small = scene.prepare(*mesh_for(8000))
    yield "ellipsoid 8000, tol 1e-6", small, k, dirs[::8], "convex", 1e-6
    yield "ellipsoid 8000, tol 1e-14", small, k, dirs[::8], "convex", 1e-14
    irregular = np.sort(np.concatenate([k[::3], k[::7] * 1.0001]))
    yield "irregular grid", small, irregular, dirs[::8], "convex", 1e-10
    wide = field.wavenumbers(np.linspace(8e9, 12e9, 8192))
    yield "8192 frequencies", small, wide, dirs[::64], "convex", 1e-10


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", required=True, help="git revision to compare with")
    ap.add_argument("--out", type=Path, default=RESULTS / "kernel_same_bytes.json")
    args = ap.parse_args(argv)
    config = radar_sim.RadarConfig.named("xband-v1")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        baseline = load_baseline(args.baseline, Path(tmp))
        for name, mesh, k, dirs, mode, tol in cases(config):
            now = digest(field.mesh_field(mesh, k, dirs, mode, tol=tol))
            before = digest(baseline.mesh_field(mesh, k, dirs, mode, tol=tol))
            rows.append({"case": name, "faces": len(mesh.faces), "directions": len(dirs),
                         "sha256": now, "same": now == before})  # fmt: skip
        v, f = analytic.simulation_mesh(
            analytic.solid_for("cylinder", (0.4, 0.4, 1.0)), 12e9, rule=2
        )
        dirs = np.unique(config.directions(), axis=0)[::16]
        now, before = (
            digest(code.polarimetric_field(v, f, config.frequency_hz, dirs, edges="mec"))
            for code in (field, baseline)
        )
        rows.append({"case": "polarimetric cylinder, edge currents", "faces": len(f),
                     "directions": len(dirs), "sha256": now, "same": now == before})  # fmt: skip
    write_json(args.out, {"hardware": hardware(), "baseline": args.baseline, "cases": rows})
    for r in rows:
        same = "same" if r["same"] else "DIFFERENT"
        print(f"{r['case']:38s} {r['faces']:7d} faces {r['directions']:5d} dirs {same}")
    print(f"{sum(r['same'] for r in rows)} of {len(rows)} cases bit-identical to {args.baseline}")
    return 0 if all(r["same"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
