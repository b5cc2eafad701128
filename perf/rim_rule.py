"""How finely must a rim be cut for HH to converge? Rim chords against an 8x finer mesh.

    python perf/rim_rule.py [--refinements 1,1.4,2,2.8] [--out JSON]

HH carries the perpendicular fringe of a rim's edge currents, which simulation rule 1 sums
over chords of 0.7·λ/2 (at 12 GHz). For cylinders, cones and frusta of several shapes, the
xband-v2 label (PO plus edge diffraction, full grid) is computed on rule 1's mesh with its
rim chords divided by each refinement and compared, per channel, with the chords divided by
8; the benchmark metric (MSE of 20 log10 max(|profile|, 1e-4), dB²). The smallest
refinement that keeps every shape's HH under the 0.1 dB² convergence rule with margin
becomes simulation rule 2's ``rim_refinement`` (docs/RADAR.md, "Labels v3").
Writes perf/results/rim_rule.json and prints a table.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import radar_sim
from basic_shapes import analytic
from basic_shapes.infra import hardware, write_json
from benchmark.scoring.data import db_target

RESULTS = Path(__file__).parent / "results"
SHAPES = [
    ("cylinder", (2.0, 2.0, 2.0), {}),
    ("cylinder", (0.2, 2.0, 2.0), {}),
    ("cylinder", (2.0, 2.0, 0.2), {}),
    ("cylinder", (0.3, 0.3, 0.3), {}),
    ("cone", (2.0, 2.0, 2.0), {}),
    ("cone", (2.0, 2.0, 0.2), {}),
    ("frustum", (2.0, 2.0, 2.0), {"top_ratio": 0.5}),
    ("frustum", (1.0, 0.4, 1.0), {"top_ratio": 0.9}),
]
FINEST = 8.0


def target(profiles: np.ndarray) -> np.ndarray:
    """The benchmark's target (``db_target``), in float64 for the differences."""
    return db_target(profiles).astype(np.float64)


def label(solid, refinement: float, config):
    """(channels x aspects x rolls x bins target, faces, CPU s) on rule 1's mesh with every
    edge limit (the rims' chords included) divided by ``refinement``."""
    v, f = analytic.simulation_mesh(solid, config.f_stop_hz, refinement=refinement)
    start = time.process_time()
    p = radar_sim.simulate(v, f, config, mode="convex").channel_profiles
    return target(p), len(f), time.process_time() - start


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--refinements", default="1,1.4,2,2.8")
    parser.add_argument("--out", type=Path, default=RESULTS / "rim_rule.json")
    args = parser.parse_args(argv)
    refinements = [float(x) for x in args.refinements.split(",")]
    config = radar_sim.RadarConfig.named("xband-v2")
    channels = config.channel_list
    print(f"{'class':9} {'extents (m)':13} " + " ".join(f"{'x' + str(r):>16}" for r in refinements))
    rows = []
    for kind, scale, params in SHAPES:
        solid = analytic.solid_for(kind, scale, params)
        fine, _, _ = label(solid, FINEST, config)
        row = {"class": kind, "extents_m": list(scale), "params": params, "by_refinement": []}
        for r in refinements:
            t, faces, seconds = label(solid, r, config)
            mse = np.mean((t - fine) ** 2, axis=(1, 2, 3))
            row["by_refinement"].append(
                {
                    "refinement": r,
                    "faces": faces,
                    "cpu_s": seconds,
                    **{f"mse_{c}_db2": float(m) for c, m in zip(channels, mse)},
                }
            )
        rows.append(row)
        cells = [f"HH {b['mse_HH_db2']:.4f} VV {b['mse_VV_db2']:.4f}" for b in row["by_refinement"]]
        print(f"{kind:9} {'x'.join(f'{x:g}' for x in scale):13} " + "  ".join(cells), flush=True)
    out = {
        "command": " ".join(["python perf/rim_rule.py", *(sys.argv[1:] if argv is None else argv)]),
        "config": config.to_dict(),
        "finest_refinement": FINEST,
        "rows": rows,
        "hardware": hardware(),
    }
    write_json(args.out, out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
