"""CPU seconds per verified mesh of `basic-shapes generate`, per stage, old code vs new, one run.

The machine is shared, so wall-clock throughput is unreliable; CPU time of one process is not
(much). Each code version runs in its own child process (``PYTHONPATH`` = its tree) over the
same objects at the paper's settings and reports CPU ms per accepted mesh for: the Blender
build, the topology checks, the Hausdorff distance to the simple mesh, the distance to the
analytic primitive, the HDF5 write, and the rest (drawing parameters, the Python loop). The
2-worker bound is 2 / (CPU seconds per mesh): what two busy cores give with no other load.
Out-of-distribution test meshes (basic_shapes/remesh.py) are timed apart, new code only.

    python perf/generate_throughput.py --compare old=/tmp/old [--objects-per-class 3]

``--compare``: a checkout of other code, e.g. ``git worktree add /tmp/old 8e35ef8``; naming
this tree first too (``--compare new_first=.``) measures it before and after the others, so
that load drifting during the run shows in the stages no version changed. ``--wall``
also times `generate` on 1 and 2 Dask workers (only meaningful on a quiet machine, load < 1).
Writes perf/results/generate_throughput.json and prints a table. The paper-scale goal is
300,000 meshes in 15 minutes on this 2-core machine (333 meshes/s); issue 10 asks for 450.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from basic_shapes.infra import hardware, write_json

GOAL = 450.0
ROOT = Path(__file__).resolve().parents[1]
BUILD = ("simple", "primitive", "loop_cuts", "decimate", "extract")
STAGES = ("blender", "checks", "hausdorff", "analytic", "hdf5", "other")


def measure(objects_per_class: int, variants: int, ood: int) -> dict:
    """Child process: CPU ms per accepted mesh per stage for the code on PYTHONPATH."""
    import numpy as np

    from basic_shapes import blender
    from basic_shapes.generate import GenerateConfig, plan_objects
    from basic_shapes.shards import ObjectRecord, write_shard

    cfg = GenerateConfig(objects_per_class=objects_per_class, variants=variants)
    plans = plan_objects(cfg)
    blender.object_meshes("cube", np.ones(3), 0, 0)  # Blender start-up: once per process
    blender.warm_up(cfg.classes)
    out, done = {"classes": {}}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in cfg.classes:
            blender.STAGE_SECONDS.clear()
            blender.ATTEMPTS.clear()
            objects, hdf5 = [], 0.0
            start = time.process_time()
            for p in (p for p in plans if p.class_name == name):
                meshes = blender.object_meshes(name, np.array(p.scale), p.seed, variants)
                objects.append(
                    ObjectRecord(p.id, p.class_index, np.array(p.scale), p.seed, "train", meshes)
                )
                t = time.process_time()
                write_shard(
                    Path(tmp) / f"{p.id}.h5",
                    objects[-1:],
                    list(cfg.classes),
                    cfg.to_dict(),
                    cfg.toolkit_version,
                )
                hdf5 += time.process_time() - t
            total = time.process_time() - start
            n = sum(len(o.meshes) for o in objects)
            sec = dict(blender.STAGE_SECONDS)
            row = {
                "blender": sum(sec.get(s, 0.0) for s in BUILD),
                "checks": sec.get("checks", 0.0),
                "hausdorff": sec.get("hausdorff", 0.0),
                "analytic": sec.get("analytic", 0.0),
                "hdf5": hdf5,
            }
            row["other"] = total - sum(row.values())
            out["classes"][name] = {
                "meshes": n,
                "ms_per_mesh": {k: 1e3 * v / n for k, v in row.items()},
                "attempts": dict(blender.ATTEMPTS),
            }
            done[name] = objects
    for name, objects in done.items() if ood else ():  # after: nothing of it leaks into the rest
        out["classes"][name]["ood"] = _ood(objects, name, ood)
    return out


def _ood(objects, name: str, per_remesher: int) -> dict:
    """CPU ms per OOD mesh (remesh + verify) of the class's objects, new code only."""
    from basic_shapes import meshcheck, remesh

    start, n = time.process_time(), 0
    for o in objects:
        seen = {meshcheck.topology_key(m.faces, len(m.vertices)) for m in o.meshes}
        n += len(
            remesh.ood_meshes(
                name, o.scale, o.seed, o.meshes[0].vertices, o.meshes[0].faces, per_remesher, seen
            )
        )
    return {"meshes": n, "ms_per_mesh": 1e3 * (time.process_time() - start) / max(n, 1)}


def run_child(tree: Path, args, ood: int) -> dict:
    # one thread per process, as on Dask workers (their nannies set these): idle BLAS threads
    # would otherwise spin and charge CPU time to whatever stage runs next
    env = dict(
        os.environ,
        PYTHONPATH=str(tree),
        OMP_NUM_THREADS="1",
        MKL_NUM_THREADS="1",
        OPENBLAS_NUM_THREADS="1",
    )
    cmd = [
        sys.executable,
        __file__,
        "--child",
        "--objects-per-class",
        str(args.objects_per_class),
        "--variants",
        str(args.variants),
        "--ood",
        str(ood),
    ]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tree)
    if res.returncode:
        raise SystemExit(f"{tree}: benchmark child failed:\n{res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def summarize(result: dict) -> dict:
    """Mean over classes (equal mesh counts per class, as in a generated dataset)."""
    rows = list(result["classes"].values())
    n = sum(r["meshes"] for r in rows)
    ms = {s: sum(r["ms_per_mesh"][s] * r["meshes"] for r in rows) / n for s in STAGES}
    total = sum(ms.values())
    return {"ms_per_mesh": ms, "total_ms": total, "bound_2_workers": 2e3 / total}


def wall(objects_per_class: int, variants: int) -> list[dict]:
    from basic_shapes.generate import GenerateConfig, generate

    cfg = GenerateConfig(
        objects_per_class=objects_per_class,
        variants=variants,
        objects_per_shard=1,
        test_fraction=0.0,
    )
    rows = []
    for w in (1, 2):
        with tempfile.TemporaryDirectory() as tmp:
            s = generate(Path(tmp) / "d", cfg, workers=w, progress=False)
        rows.append(
            {
                "workers": w,
                "meshes": s["meshes"],
                "seconds": round(s["seconds"], 3),
                "meshes_per_second": round(s["meshes_per_second"], 1),
                "load_average": os.getloadavg()[0],
            }
        )
    return rows


def table(results: dict) -> str:
    lines = [
        f"{'code':6s} {'class':9s}"
        + "".join(f"{s:>10s}" for s in STAGES)
        + f"{'total':>9s}{'2w bound':>10s}"
    ]
    for code, res in results.items():
        for name, r in list(res["classes"].items()) + [("mean", res["summary"])]:
            ms = r["ms_per_mesh"]
            total = sum(ms[s] for s in STAGES)
            lines.append(
                f"{code:6s} {name:9s}"
                + "".join(f"{ms[s]:10.2f}" for s in STAGES)
                + f"{total:9.2f}{2e3 / total:10.0f}"
            )
    lines.append(
        "(CPU ms per accepted mesh, rejected attempts included; 2w bound: "
        "2 / CPU s per mesh, meshes/s)"
    )
    for name, r in results["new"]["classes"].items():
        if "ood" in r:
            lines.append(
                f"OOD {name}: {r['ood']['meshes']} meshes, "
                f"{r['ood']['ms_per_mesh']:.1f} CPU ms each (not in the figure above)"
            )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--compare",
        action="append",
        default=[],
        metavar="NAME=PATH",
        help="also measure the checkout at PATH (e.g. old=/tmp/old); repeatable",
    )
    ap.add_argument("--objects-per-class", type=int, default=3)
    ap.add_argument("--variants", type=int, default=99)
    ap.add_argument("--ood", type=int, default=3, help="OOD meshes per remesher (new code)")
    ap.add_argument("--wall", action="store_true", help="also time generate on 1 and 2 workers")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument(
        "--out", type=Path, default=ROOT / "perf" / "results" / "generate_throughput.json"
    )
    args = ap.parse_args()
    if args.child:
        print(json.dumps(measure(args.objects_per_class, args.variants, args.ood)))
        return
    trees = []
    for item in args.compare:
        name, _, path = item.partition("=")
        if not name or not (Path(path) / "basic_shapes" / "blender.py").is_file():
            raise SystemExit(f"--compare {item}: not NAME=PATH of a basic-shapes checkout")
        trees.append((name, Path(path).resolve(), 0))
    trees.append(("new", ROOT, args.ood))
    load = os.getloadavg()[0]
    results = {}
    for code, tree, ood in trees:
        results[code] = run_child(tree, args, ood)
        results[code]["summary"] = summarize(results[code])
    print(table(results))
    report = {
        "benchmark": "generate_throughput",
        "command": " ".join(sys.argv),
        "objects_per_class": args.objects_per_class,
        "variants": args.variants,
        "goal_meshes_per_second": GOAL,
        "load_average_at_start": load,
        "hardware": hardware(),
        "results": results,
    }
    if args.wall:
        report["wall"] = wall(args.objects_per_class, args.variants)
        for r in report["wall"]:
            print(
                f"wall, {r['workers']} worker(s): {r['meshes_per_second']} meshes/s "
                f"(load {r['load_average']:.2f})"
            )
    write_json(args.out, report)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
