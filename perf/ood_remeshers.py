"""Out-of-distribution remeshers (basic_shapes.remesh): face counts, distances, cost, one process.

For N objects per class (per-axis scales log-uniform in the generator's range, as generated;
a hidden-parameter class's parameter spread evenly over its whole interval, so that every
part of the range is tried) it makes each object's simple mesh with Blender, then
``--per-remesher`` OOD meshes from every remesher, and reports per remesher and class:
triangle counts (min / median / max), the two-sided distance to the smooth primitive and to
the simple mesh (relative to the bbox diagonal; max and median, and the max as a fraction of
the class tolerance), CPU milliseconds per accepted mesh (rejected tries and verification
included) and tries per mesh. Writes JSON and prints a table; ``--figure`` draws one
object's simple mesh, a training variant and its OOD meshes (docs/img/ood.png).

    .venv/bin/python perf/ood_remeshers.py --objects 10 --per-remesher 3 \\
        --figure docs/img/ood.png
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from basic_shapes import analytic, blender, primitives, remesh, verify
from basic_shapes.infra import hardware, write_json
from basic_shapes.render import draw_mesh
from basic_shapes.scales import SCALE_RANGE
from basic_shapes.shards import OOD_REMESHERS


def _stats(x) -> dict:
    x = np.asarray(x, np.float64)
    return {"min": float(x.min()), "median": float(np.median(x)), "max": float(x.max())}


def spread(class_name: str, i: int, n: int) -> dict:
    """Object i of n's hidden parameters: the middles of n equal parts of each interval."""
    return {
        k: lo + (i + 0.5) / n * (hi - lo)
        for k, (lo, hi) in analytic.HIDDEN.get(class_name, {}).items()
    }


def measure(class_name: str, n_objects: int, per: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    remesh.TRIES.clear()
    remesh.SECONDS.clear()
    lo, hi = np.log(SCALE_RANGE)
    meshes = []
    for i in tqdm(range(n_objects), desc=class_name, leave=False):
        scale = np.exp(rng.uniform(lo, hi, 3))
        shape = spread(class_name, i, n_objects)
        simple = blender.object_meshes(class_name, scale, seed + i, 0, shape)[0]
        meshes += remesh.ood_meshes(
            class_name, scale, seed + i, simple.vertices, simple.faces, per, shape=shape
        )
    tol = verify.tolerance(class_name, {})
    rows = []
    for name in OOD_REMESHERS:
        mine = [m for m in meshes if m.params["remesher"] == name]
        if not mine:
            continue
        tries = sum(n for (r, _), n in remesh.TRIES.items() if r == name)
        prim = [m.params["primitive_distance"] for m in mine]
        rows.append(
            {
                "class": class_name,
                "remesher": name,
                "meshes": len(mine),
                "tolerance": tol,
                "faces": _stats([len(m.faces) for m in mine]),
                "primitive_distance": _stats(prim),
                "simple_distance": _stats([m.hausdorff for m in mine]),
                "max_over_tolerance": max(max(prim), max(m.hausdorff for m in mine)) / tol,
                "cpu_ms_per_mesh": 1e3 * remesh.SECONDS[name] / len(mine),
                "tries_per_mesh": tries / len(mine),
                "accepted_fraction_of_tries": len(mine) / tries,
                "outcomes": {r: n for (m, r), n in remesh.TRIES.items() if m == name},
            }
        )
    return rows


def table(rows: list[dict]) -> str:
    head = (
        f"{'class':9s}{'remesher':10s}{'meshes':>7s}{'faces min':>10s}{'median':>8s}"
        f"{'max':>6s}{'d_prim max':>11s}{'d_simple max':>13s}{'/ tol':>7s}{'cpu ms':>8s}"
        f"{'tries':>7s}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r['class']:9s}{r['remesher']:10s}{r['meshes']:7d}"
            f"{r['faces']['min']:10.0f}{r['faces']['median']:8.0f}"
            f"{r['faces']['max']:6.0f}{r['primitive_distance']['max']:11.2e}"
            f"{r['simple_distance']['max']:13.2e}{r['max_over_tolerance']:7.2f}"
            f"{r['cpu_ms_per_mesh']:8.0f}{r['tries_per_mesh']:7.2f}"
        )
    return "\n".join(lines) + (
        "\n(distances relative to the bbox diagonal; '/ tol': the larger "
        "max over the class tolerance; CPU ms per accepted mesh)"
    )


def figure(class_name: str, scale: np.ndarray, seed: int, path: Path) -> None:
    """The simple mesh, one Blender training variant and two OOD meshes per remesher."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = blender.object_meshes(class_name, scale, seed, 1)
    ood = remesh.ood_meshes(class_name, scale, seed, records[0].vertices, records[0].faces, 2)
    shown = [("simple (Blender)", records[0]), ("training variant (Blender)", records[1])]
    shown += [(f"{m.params['remesher']} (OOD, variant {m.variant})", m) for m in ood]
    ncols = 4
    nrows = math.ceil(len(shown) / ncols)
    fig = plt.figure(figsize=(3.4 * ncols, 3.4 * nrows + 0.4))
    rng = np.random.default_rng(seed)
    half = 0.5 * float(np.max(scale))
    for k, (label, m) in enumerate(shown):
        ax = fig.add_subplot(nrows, ncols, k + 1, projection="3d")
        v, f = m.vertices, m.faces
        draw_mesh(ax, v, f, half, rng)
        ax.set_title(f"{label}\n{len(f)} faces", fontsize=9)
    sx, sy, sz = scale
    fig.suptitle(
        f"{class_name} {sx:.2f} x {sy:.2f} x {sz:.2f} m: simple mesh, a training "
        f"variant and out-of-distribution test meshes",
        fontsize=11,
    )
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.88, wspace=0, hspace=0.1)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--classes",
        default=",".join(primitives.DEFAULT_CLASSES),
        help="comma-separated primitive classes (default: %(default)s)",
    )
    ap.add_argument("--objects", type=int, default=10, help="objects per class (default: 10)")
    ap.add_argument(
        "--per-remesher",
        type=int,
        default=3,
        help="OOD meshes per remesher and object (default: 3)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).resolve().parent / "results" / "ood_remeshers.json",
    )
    ap.add_argument("--figure", type=Path, help="also draw one cylinder's meshes (PNG)")
    args = ap.parse_args(argv)
    classes = args.classes.split(",")
    for c in classes:
        if not any(remesh.supports(r, c) for r in OOD_REMESHERS):
            raise SystemExit(f"--classes: no remesher supports {c!r}")
    wall = time.perf_counter()
    rows = [r for c in classes for r in measure(c, args.objects, args.per_remesher, args.seed)]
    wall = time.perf_counter() - wall
    print(table(rows))
    report = {
        "benchmark": "ood_remeshers",
        "platform": platform.platform(),
        "hardware": hardware(),
        "python": platform.python_version(),
        "command": " ".join(sys.argv),
        "wall_s": wall,
        "objects_per_class": args.objects,
        "per_remesher": args.per_remesher,
        "results": rows,
    }
    write_json(args.out, report)
    print(f"wrote {args.out}")
    if args.figure:
        figure("cylinder", np.array([1.6, 0.9, 1.2]), 3, args.figure)
        print(f"wrote {args.figure}")


if __name__ == "__main__":
    main()
