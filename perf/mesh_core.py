"""Per-stage cost of the Blender mesh core (basic_shapes.blender.object_meshes), one process.

Generates N objects x V variants per class and reports, per class, CPU milliseconds per
accepted mesh for each stage (rejected attempts included; the rest of the total is drawing
parameters and the Python loop), meshes per second, attempts per mesh, rejection reasons,
face-count quantiles and Hausdorff statistics. Writes JSON (every face count included) and
prints a table; ``--figure`` also draws the face-count histogram of docs/GENERATOR.md.

    .venv/bin/python perf/mesh_core.py --objects 20 --variants 99 \\
        --classes cube,cylinder,sphere,cone,torus --figure docs/img/face_counts.png
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from basic_shapes import blender, primitives
from basic_shapes.infra import hardware, write_json

STAGES = (
    "simple",
    "primitive",
    "loop_cuts",
    "decimate",
    "extract",
    "checks",
    "hausdorff",
    "analytic",
)


def measure(class_name: str, n_objects: int, n_variants: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    blender.STAGE_SECONDS.clear()
    blender.ATTEMPTS.clear()
    faces, distances = [], []
    wall, cpu = time.perf_counter(), time.process_time()
    for i in tqdm(range(n_objects), desc=class_name, leave=False):
        scale = rng.uniform(0.5, 2.0, size=3)
        records = blender.object_meshes(class_name, scale, seed + i, n_variants)
        faces += [len(r.faces) for r in records[1:]]
        distances += [r.hausdorff for r in records[1:]]
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    n = n_objects * (n_variants + 1)
    per_mesh = {s: 1e3 * blender.STAGE_SECONDS.get(s, 0.0) / n for s in STAGES}
    faces = np.array(faces)
    return {
        "class": class_name,
        "objects": n_objects,
        "variants": n_variants,
        "meshes": n,
        "wall_s": wall,
        "cpu_s": cpu,
        "meshes_per_s_wall": n / wall,
        "meshes_per_s_cpu": n / cpu,
        "ms_per_mesh": per_mesh,
        "ms_per_mesh_total_cpu": 1e3 * cpu / n,
        "attempts_per_variant": sum(blender.ATTEMPTS.values()) / (n_objects * n_variants),
        "outcomes": dict(blender.ATTEMPTS),
        "faces": {
            "min": int(faces.min()),
            "median": float(np.median(faces)),
            "mean": float(faces.mean()),
            "max": int(faces.max()),
            "quantiles_10_90": np.quantile(faces, [0.1, 0.9]).tolist(),
        },
        "face_counts": faces.tolist(),
        "hausdorff": {"max": float(np.max(distances)), "median": float(np.median(distances))},
    }


def table(results: list[dict]) -> str:
    head = (
        f"{'class':10s}"
        + "".join(f"{s:>10s}" for s in STAGES)
        + f"{'cpu total':>11s}{'mesh/s':>8s}{'tries':>7s}{'faces med':>10s}{'max':>6s}"
    )
    lines = [head, "-" * len(head)]
    for r in results:
        lines.append(
            f"{r['class']:10s}"
            + "".join(f"{r['ms_per_mesh'][s]:10.3f}" for s in STAGES)
            + f"{r['ms_per_mesh_total_cpu']:11.3f}{r['meshes_per_s_cpu']:8.0f}"
            f"{r['attempts_per_variant']:7.2f}{r['faces']['median']:10.0f}"
            f"{r['faces']['max']:6d}"
        )
    return "\n".join(lines) + (
        "\n(CPU ms per accepted mesh, rejected attempts included; mesh/s: 1 process, CPU time)"
    )


def figure(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4 * len(results), 3.2), squeeze=False)
    bins = np.logspace(np.log10(10), np.log10(blender.MAX_TRIANGLES * 1.05), 40)
    for ax, r in zip(axes[0], results):
        ax.hist(r["face_counts"], bins=bins, color="#4477aa")
        ax.set_xscale("log")
        ax.set_title(f"{r['class']} ({r['objects']} objects x {r['variants']} variants)")
        ax.set_xlabel("triangles per complex variant")
    axes[0][0].set_ylabel("meshes")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--classes",
        default=",".join(primitives.DEFAULT_CLASSES),
        help="comma-separated primitive classes (default: %(default)s)",
    )
    ap.add_argument("--objects", type=int, default=5, help="objects per class (default: 5)")
    ap.add_argument("--variants", type=int, default=99, help="complex variants per object")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--out", type=Path, default=Path(__file__).resolve().parent / "results" / "mesh_core.json"
    )
    ap.add_argument("--figure", type=Path, help="also write the face-count histogram (PNG)")
    args = ap.parse_args(argv)
    classes = args.classes.split(",")
    for c in classes:
        try:
            primitives.get(c)
        except ValueError as exc:
            raise SystemExit(str(exc)) from None
    start = time.process_time()
    blender.object_meshes(classes[0], np.ones(3), 0, 0)  # Blender start-up
    startup = time.process_time() - start
    warm = {c: blender.warm_up([c]) for c in classes}  # once per process, not per mesh
    results = [measure(c, args.objects, args.variants, args.seed) for c in classes]
    for r in results:
        r["primitive_cache_cpu_s"] = warm[r["class"]]
    print(table(results))
    print(
        f"once per process: Blender start-up {startup:.2f} s CPU; primitive cache "
        + ", ".join(f"{c} {warm[c]:.2f} s" for c in classes)
    )
    report = {
        "benchmark": "mesh_core",
        "platform": platform.platform(),
        "hardware": hardware(),
        "python": platform.python_version(),
        "command": " ".join(sys.argv),
        "startup_cpu_s": startup,
        "results": results,
    }
    write_json(args.out, report)
    print(f"wrote {args.out}")
    if args.figure:
        figure(results, args.figure)
        print(f"wrote {args.figure}")


if __name__ == "__main__":
    main()
