"""Is a frustum's label converged, and how far does the hidden ratio move it?

    python perf/frustum_convergence.py [--grid coarse|full] [--ratios 0.05,0.45,0.9]

For the three extreme extents of perf/label_convergence.py and several top_ratio values,
the label on basic_shapes.analytic.simulation_mesh is compared (benchmark metric, dB^2) with
the same rule at refinement 2, with an independent fine mesh (trimesh's revolution of the
frustum's profile, 2048 sections, scaled per axis), and with the label of the same extents at
the first ratio (how much the hidden parameter moves the label). Writes
perf/results/frustum_convergence.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).parent))
from label_convergence import F_MAX, GRIDS, RESULTS, SCALES, label, mse

from basic_shapes import analytic
from basic_shapes.infra import atomic_path


def independent_frustum(scale, ratio: float):
    """trimesh's revolution of the profile (0, -1/2) (1/2, -1/2) (ratio/2, 1/2) (0, 1/2)."""
    profile = [[0.0, -0.5], [0.5, -0.5], [0.5 * ratio, 0.5], [0.0, 0.5]]
    m = trimesh.creation.revolve(profile, sections=2048)
    return (
        np.asarray(m.vertices, np.float64) * np.asarray(scale, np.float64),
        np.asarray(m.faces, np.int32),
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", choices=sorted(GRIDS), default="coarse")
    parser.add_argument("--ratios", default="0.05,0.45,0.9")
    parser.add_argument("--out", type=Path, default=RESULTS / "frustum_convergence.json")
    args = parser.parse_args(argv)
    config = GRIDS[args.grid]
    ratios = [float(r) for r in args.ratios.split(",")]
    print(f"grid {config.name}: {config.n_aspect} aspects x {config.n_roll} rolls")
    print(
        f"{'extents (m)':13} {'ratio':>5} {'faces':>6} {'MSE 2x':>8} {'MSE indep':>9} "
        f"{'MSE vs ratio ' + str(ratios[0]):>18}"
    )
    rows = []
    for scale in SCALES:
        first = None
        for ratio in ratios:
            solid = analytic.solid_for("frustum", scale, {"top_ratio": ratio})
            v1, f1 = analytic.simulation_mesh(solid, F_MAX)
            p1, seconds = label(v1, f1, config, "frustum")
            p2, _ = label(
                *analytic.simulation_mesh(solid, F_MAX, refinement=2.0), config, "frustum"
            )
            p3, _ = label(*independent_frustum(scale, ratio), config, "frustum")
            first = p1 if first is None else first
            row = {
                "extents_m": list(scale),
                "top_ratio": ratio,
                "faces": len(f1),
                "mse_vs_2x_db2": mse(p1, p2),
                "mse_vs_independent_db2": mse(p1, p3),
                "mse_vs_first_ratio_db2": mse(p1, first),
                "seconds": seconds,
            }
            rows.append(row)
            print(
                f"{'x'.join(f'{x:g}' for x in scale):13} {ratio:5.2f} {len(f1):6d} "
                f"{row['mse_vs_2x_db2']:8.4f} {row['mse_vs_independent_db2']:9.4f} "
                f"{row['mse_vs_first_ratio_db2']:18.1f}",
                flush=True,
            )
    out = {
        "grid": config.name,
        "config": config.to_dict(),
        "rule": analytic.SIMULATION_RULE,
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out) as tmp:
        tmp.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
