"""What machine-independent labels cost: the fixed-order matrix product against BLAS.

    python perf/portable_matmul.py [--grid 31x7] [--scale 1.0]

The labels' frequency sums are a complex matrix product. BLAS (OpenBLAS, one thread here)
rounds by CPU model and thread count; ``basic_shapes.portable.matmul`` sums in one order on
every machine (docs/DATASETS.md, "Rebuilding byte for byte"). For the simulation mesh of one
object per class at ``--scale`` metres, on the ``xband-v1`` grid coarsened to ``--grid``,
this times ``radar_sim.simulate`` (best of 3, after a warm-up) with each product in
``radar_sim.field`` and reports the ratio and the largest difference between the two labels
relative to the label's peak. One core (thread limits set before numpy loads).
Writes perf/results/portable_matmul.json and prints a table.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402 - thread limits are set before numpy loads
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import radar_sim  # noqa: E402
from basic_shapes.analytic import simulation_mesh, solid_for  # noqa: E402
from basic_shapes.infra import hardware, write_json  # noqa: E402
from basic_shapes.portable import matmul  # noqa: E402
from radar_sim import field  # noqa: E402

RESULTS = Path(__file__).parent / "results"
CLASSES = ("cube", "cylinder", "sphere", "frustum")


def blas(a, b):
    return np.asarray(a) @ np.asarray(b)


def timed(vertices, faces, config, product) -> tuple[float, np.ndarray]:
    field.matmul = product
    # the contraction multiplies by a matrix split into real and imaginary parts once
    field.matmul_parts = lambda a, parts: product(a, parts[0] + 1j * parts[1])
    radar_sim.simulate(vertices, faces, config)  # warm-up (numba, caches)
    best, result = float("inf"), None
    for _ in range(3):
        t0 = time.perf_counter()
        result = radar_sim.simulate(vertices, faces, config)
        best = min(best, time.perf_counter() - t0)
    return best, result.frequency_response


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--grid", default="31x7", help="aspects x rolls (default 31x7, cpu-v1's)")
    p.add_argument("--scale", type=float, default=1.0, help="object extent in metres")
    args = p.parse_args()
    n_aspect, n_roll = (int(x) for x in args.grid.split("x"))
    config = radar_sim.RadarConfig.named("xband-v1").with_grid(n_aspect=n_aspect, n_roll=n_roll)
    rows = []
    for name in CLASSES:
        scale = (args.scale, 0.8 * args.scale, 0.6 * args.scale)
        params = {"top_ratio": 0.5} if name == "frustum" else {}
        v, f = simulation_mesh(solid_for(name, scale, params), config.f_stop_hz)
        t_blas, a = timed(v, f, config, blas)
        t_fixed, b = timed(v, f, config, matmul)
        rows.append(
            {
                "class": name,
                "faces": len(f),
                "blas_s": t_blas,
                "portable_s": t_fixed,
                "ratio": t_fixed / t_blas,
                "max_rel_difference": float(np.abs(a - b).max() / np.abs(a).max()),
            }
        )
    out = {"grid": args.grid, "scale_m": args.scale, "hardware": hardware(), "rows": rows}
    write_json(RESULTS / "portable_matmul.json", out)
    print(f"simulate on the xband-v1 grid {args.grid}, one core, best of 3")
    print(
        f"{'class':9s} {'faces':>7s} {'BLAS s':>8s} {'fixed s':>8s} {'ratio':>6s} "
        f"{'max |diff|/peak':>16s}"
    )
    for r in rows:
        print(
            f"{r['class']:9s} {r['faces']:7d} {r['blas_s']:8.3f} {r['portable_s']:8.3f} "
            f"{r['ratio']:6.2f} {r['max_rel_difference']:16.2e}"
        )


if __name__ == "__main__":
    main()
