"""What "auto" mode detection costs on generated spheres: the former rule against the current one.

    python perf/mode_detection.py [--objects 3] [--variants 19] [--n-aspect 16] [--n-roll 5]

Generates sphere objects with the real generator (Blender), detects each mesh's mode with the
former rule (edges convex within 1e-6 R; "bounce2" for any re-hit) and the current one (1e-4 R;
re-hits only count after crossing 0.1 R), and times ``simulate`` in both modes on a coarse
grid (all 128 frequencies), in the same run. Also reports how far the cheaper mode's label is
from the former one in the benchmark metric (dB²), for the meshes whose mode changed.
Writes perf/results/mode_detection.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from basic_shapes.generate import GenerateConfig, generate
from basic_shapes.shards import Shard, list_shards
from benchmark.scoring.data import db_target
from radar_sim import RadarConfig, scene, simulate

FORMER = {"CONVEX_TOL": 1e-6, "SEE_DISTANCE": 0.0}


def detect(vertices, faces, rule: dict) -> str:
    """``scene.detect_mode`` with the module's thresholds set to ``rule`` for this call."""
    saved = {k: getattr(scene, k) for k in rule}
    try:
        for k, v in rule.items():
            setattr(scene, k, v)
        return scene.detect_mode(vertices, faces)
    finally:
        for k, v in saved.items():
            setattr(scene, k, v)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--objects", type=int, default=3)
    ap.add_argument("--variants", type=int, default=19)
    ap.add_argument("--n-aspect", type=int, default=16)
    ap.add_argument("--n-roll", type=int, default=5)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "mode_detection.json"))
    args = ap.parse_args()
    config = RadarConfig(name="bench", n_aspect=args.n_aspect, n_roll=args.n_roll)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cfg = GenerateConfig(
            classes=("sphere",), objects_per_class=args.objects, variants=args.variants, seed=0
        )
        generate(Path(tmp) / "d", cfg, workers=0, progress=False)
        for path in list_shards(Path(tmp) / "d"):
            with Shard(path) as s:
                for i in range(s.n_meshes):
                    v, f = s.mesh(i)
                    old, new = detect(v, f, FORMER), scene.detect_mode(v, f)
                    row = {"mesh": i, "faces": len(f), "former": old, "current": new}
                    if old != new:
                        labels = {}
                        for mode in (old, new):
                            t0 = time.perf_counter()
                            labels[mode] = db_target(
                                simulate(v, f, config, mode=mode).range_profiles
                            )
                            row[f"seconds_{mode}"] = round(time.perf_counter() - t0, 4)
                        row["mse_db2"] = float(
                            np.mean((labels[old].astype(np.float64) - labels[new]) ** 2)
                        )
                    rows.append(row)
    changed = [r for r in rows if r["former"] != r["current"]]
    counts = {
        rule: {m: sum(r[rule] == m for r in rows) for m in ("convex", "shadowed", "bounce2")}
        for rule in ("former", "current")
    }
    print(
        f"{len(rows)} generated sphere meshes; modes former {counts['former']}, "
        f"current {counts['current']}"
    )
    print(
        f"{'mesh':>5} {'faces':>6} {'former':>9} {'current':>9} {'s former':>9} {'s current':>9}"
        f" {'ratio':>7} {'dB^2':>8}"
    )
    for r in changed:
        a, b = r[f"seconds_{r['former']}"], r[f"seconds_{r['current']}"]
        print(
            f"{r['mesh']:>5} {r['faces']:>6} {r['former']:>9} {r['current']:>9} {a:>9.3f} "
            f"{b:>9.3f} {a / b:>7.1f} {r['mse_db2']:>8.3g}"
        )
    Path(args.out).write_text(
        json.dumps(
            {
                "command": "python perf/mode_detection.py",
                "grid": config.to_dict(),
                "counts": counts,
                "rows": rows,
            },
            indent=1,
        )
        + "\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
