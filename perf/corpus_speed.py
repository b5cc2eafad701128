"""Build speed of the procedural pretraining corpus on one core, per family and overall, and
the cost of the HDF5 cache (cold build, cached rerun, load).

    python perf/corpus_speed.py [--meshes 5000] [--max-faces 800] [--seed 0]

Pins itself to one CPU core. The goal: a few thousand meshes in under about 90 s.
Writes perf/results/corpus_speed.json and prints two tables.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from basic_shapes.infra import hardware
from benchmark.training import corpus

GOAL_SECONDS = 90.0


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--meshes", type=int, default=5000)
    ap.add_argument("--max-faces", type=int, default=800)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "corpus_speed.json"))
    args = ap.parse_args()
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})

    n_fam = len(corpus.FAMILIES)
    seconds = np.zeros(n_fam)
    faces: list[list[int]] = [[] for _ in range(n_fam)]
    t_all = time.perf_counter()
    for i in range(args.meshes):  # the loop of procedural_corpus, timed per family
        fam = i % n_fam
        t = time.perf_counter()
        _, f = corpus.build_family_mesh(fam, np.random.default_rng([args.seed, i]), args.max_faces)
        seconds[fam] += time.perf_counter() - t
        faces[fam].append(len(f))
    total = time.perf_counter() - t_all

    rows = [
        {
            "family": name,
            "meshes": len(faces[k]),
            "ms_per_mesh": round(1e3 * seconds[k] / len(faces[k]), 3),
            "mean_faces": round(float(np.mean(faces[k])), 1),
            "max_faces_seen": int(np.max(faces[k])),
        }
        for k, name in enumerate(corpus.FAMILIES)
        if faces[k]
    ]
    mean_ms = 1e3 * total / args.meshes
    print(f"{'family':<22} {'meshes':>6} {'ms/mesh':>8} {'vs mean':>8} {'faces':>7} {'max':>5}")
    for r in rows:
        print(
            f"{r['family']:<22} {r['meshes']:>6} {r['ms_per_mesh']:>8.2f} "
            f"{r['ms_per_mesh'] / mean_ms:>8.2f} "
            f"{r['mean_faces']:>7.1f} {r['max_faces_seen']:>5}"
        )
    rate = args.meshes / total
    print(
        f"{'all':<22} {args.meshes:>6} {mean_ms:>8.2f} {1.0:>8.2f}   -> {rate:.0f} meshes/s, "
        f"{args.meshes} meshes in {total:.1f} s "
        f"(goal {GOAL_SECONDS:.0f} s: {GOAL_SECONDS / total:.1f}x margin)"
    )

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "corpus.h5"
        t = time.perf_counter()
        corpus.build_corpus_file(path, args.meshes, args.seed, args.max_faces)
        cold = time.perf_counter() - t
        t = time.perf_counter()
        corpus.build_corpus_file(path, args.meshes, args.seed, args.max_faces)
        cached = time.perf_counter() - t
        t = time.perf_counter()
        corpus.load_corpus_file(path)
        load = time.perf_counter() - t
        size_mb = path.stat().st_size / 2**20
    cache = {
        "build_cold_s": round(cold, 3),
        "build_cached_s": round(cached, 4),
        "load_s": round(load, 4),
        "file_mb": round(size_mb, 2),
    }
    print(f"\n{'cache step':<22} {'seconds':>8} {'vs cold':>8}")
    for name, s in [("build (cold)", cold), ("build (cached rerun)", cached), ("load", load)]:
        print(f"{name:<22} {s:>8.3f} {s / cold:>8.4f}")
    print(f"file size {size_mb:.1f} MiB")

    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(
        json.dumps(
            {
                "meshes": args.meshes,
                "max_faces": args.max_faces,
                "seed": args.seed,
                "seconds": round(total, 3),
                "meshes_per_second": round(rate, 1),
                "goal_seconds": GOAL_SECONDS,
                "hardware": hardware(threads=1),
                "families": rows,
                "cache": cache,
            },
            indent=2,
        )
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
