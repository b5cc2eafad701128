"""Verified meshes per second of `basic-shapes generate` (generation + verification + writing)
at 1 and 2 worker processes, side by side, plus the in-process run without Dask.

    python perf/generate_throughput.py [--objects-per-class 4] [--variants 99]

Writes perf/results/generate_throughput.json and prints a table. The paper-scale goal
is 300,000 meshes in 15 minutes on this 2-core machine: 333 meshes/s.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
from pathlib import Path

from basic_shapes.generate import GenerateConfig, generate

GOAL = 300_000 / (15 * 60)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--objects-per-class", type=int, default=4)
    ap.add_argument("--variants", type=int, default=99)
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument(
        "--out", default=str(Path(__file__).parent / "results" / "generate_throughput.json")
    )
    args = ap.parse_args()
    cfg = GenerateConfig(objects_per_class=args.objects_per_class, variants=args.variants,
                         objects_per_shard=1)
    rows = []
    for w in args.workers:
        with tempfile.TemporaryDirectory() as tmp:
            s = generate(Path(tmp) / "d", cfg, workers=w, progress=False)
        rows.append({"workers": w, "meshes": s["meshes"], "seconds": round(s["seconds"], 3),
                     "meshes_per_second": round(s["meshes_per_second"], 1)})
    base = rows[0]["meshes_per_second"]
    print(
        f"{'workers':>8} {'meshes':>7} {'seconds':>8} {'mesh/s':>8} {'vs first':>8} {'vs goal':>8}"
    )
    for r in rows:
        label = "0 (no Dask)" if r["workers"] == 0 else str(r["workers"])
        print(f"{label:>8} {r['meshes']:>7} {r['seconds']:>8.1f} {r['meshes_per_second']:>8.1f} "
              f"{r['meshes_per_second'] / base:>8.2f} {r['meshes_per_second'] / GOAL:>8.2f}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({
        "config": cfg.to_json(), "goal_meshes_per_second": GOAL, "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(), "rows": rows}, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
