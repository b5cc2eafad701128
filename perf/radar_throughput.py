"""Throughput of the radar simulator, and of labelling a paper-sized dataset.

    python perf/radar_throughput.py [--paper-objects 3000] [--workers 1 2]

Side by side, one core (single-threaded numpy and Embree calls) unless said otherwise:
  1. `simulate` on the full default grid (xband-v1: 61 x 21 orientations x 128 frequencies) for
     ~1k-face convex objects (a Blender-like 32x16 UV sphere, a 250-sided cylinder), in
     ms per object and orientations x frequencies per second; goal <= 50 ms per object.
  2. a 20k-face non-convex torus with Embree shadowing ("shadowed"), against the same mesh
     with back-face culling alone ("convex", wrong for it but the no-shadow cost); the
     difference is the shadowing cost, given per shadow ray (one ray per lit facet and
     orientation) against raw embreex occlusion queries on the same rays.
  3. `radar-sim label` (Dask LocalCluster, 1 and 2 worker processes) on a dataset of
     --paper-objects Basic-Shapes-like simple meshes (12-face boxes, 128-face cylinders,
     960-face UV spheres, 0.3-1.5 m) in shards of 8 objects; goal: 3000 objects <= 3 min.
     Paper shards also hold 99 complex meshes per object, which labelling does not simulate but
     copies when it rewrites a shard atomically: that copy is measured per MB and extrapolated.
Writes perf/results/radar_throughput.json and prints a table.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from radar_accuracy import best_time  # noqa: E402

import radar_sim  # noqa: E402
from basic_shapes.analytic import uv_sphere  # noqa: E402
from basic_shapes.infra import hardware  # noqa: E402
from basic_shapes.shards import (  # noqa: E402
    MeshRecord,
    ObjectRecord,
    rewrite_atomically,
    shard_name,
    write_shard,
)
from radar_sim.label import LabelRequest, label_directory  # noqa: E402

RESULTS = Path(__file__).parent / "results"
GOAL_OBJECT_S = 0.050
GOAL_PAPER_S = 180.0
PAPER_OBJECTS = 3000
# Paper-scale shard content besides the simple meshes: 99 complex meshes per object; the
# generator's complex meshes hold about this many faces on average (loop cuts + decimation).
PAPER_COMPLEX_FACES = 2000


def blender_uv_sphere(segments: int = 32, rings: int = 16, radius: float = 0.5) -> trimesh.Trimesh:
    """Blender's default UV sphere: 32 segments x 16 rings, 482 vertices, 960 triangles."""
    vertices, faces = uv_sphere(segments, rings, (radius,) * 3)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.fix_normals()
    return mesh


def convex_objects():
    sphere = blender_uv_sphere()
    cylinder = trimesh.creation.cylinder(radius=0.4, height=1.0, sections=250)
    return {"uv_sphere": sphere, "cylinder": cylinder}


def time_simulate(mesh, config, mode):
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    result, seconds = best_time(lambda: radar_sim.simulate(v, f, config, mode=mode), budget_s=3.0)
    field_s = best_time(
        lambda: radar_sim.monostatic_field(
            v, f, config.frequency_hz, config.directions(), mode=mode
        ),
        budget_s=3.0,
    )[1]
    n = len(config.aspect_deg) * len(config.roll_deg) * len(config.frequency_hz)
    return {
        "faces": int(len(f)),
        "mode": result.mode,
        "seconds": seconds,
        "field_seconds": field_s,
        "orientation_frequencies_per_second": n / seconds,
    }


def shadow_rays(mesh, directions):
    """Origins/directions of one occlusion ray per lit facet (centroid) and orientation."""
    centres, normals = mesh.triangles_center, mesh.face_normals
    origins, dirs = [], []
    for d in directions:
        lit = normals @ d > 0
        origins.append(centres[lit])
        dirs.append(np.broadcast_to(d, (int(lit.sum()), 3)))
    return (
        np.ascontiguousarray(np.concatenate(origins), np.float32),
        np.ascontiguousarray(np.concatenate(dirs), np.float32),
    )


def raw_embree(mesh, origins, dirs):
    """BVH build time and occlusion rays per second of embreex called directly."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    triangles = np.ascontiguousarray(mesh.vertices[mesh.faces], np.float32)

    def build():
        scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene, triangles)
        return scene

    scene, build_s = best_time(build, budget_s=1.0)
    eps = np.float32(1e-6 * mesh.scale)
    _, run_s = best_time(
        lambda: scene.run(origins + eps * dirs, dirs, query="OCCLUDED"), budget_s=3.0
    )
    return {
        "build_seconds": build_s,
        "rays": int(len(origins)),
        "rays_per_second": len(origins) / run_s,
    }


def paper_dataset(directory: Path, n_objects: int, per_shard: int = 8) -> Path:
    """Basic-Shapes-like simple meshes (what `label` simulates), classes in turn."""
    directory.mkdir(parents=True)
    rng = np.random.default_rng(0)
    base = [
        trimesh.creation.box(extents=(1, 1, 1)),
        trimesh.creation.cylinder(radius=0.5, height=1.0, sections=32),
        blender_uv_sphere(),
    ]
    objects = []
    for oid in range(n_objects):
        scale = rng.uniform(0.3, 1.5, 3)
        mesh = base[oid % 3]
        v = np.asarray(mesh.vertices * scale, np.float32)
        objects.append(
            ObjectRecord(
                oid,
                oid % 3,
                scale,
                oid,
                "train",
                [MeshRecord(0, v, np.asarray(mesh.faces, np.int32), 0.0, {})],
            )
        )
    for i in range(0, n_objects, per_shard):
        write_shard(
            directory / shard_name(i // per_shard),
            objects[i : i + per_shard],
            ["cube", "cylinder", "sphere"],
            {},
            "bench",
        )
    return directory


def copy_cost(tmp: Path) -> dict:
    """Seconds per MB of `rewrite_atomically` (copy + fsync + rename), on a paper-sized shard."""
    n_meshes = 8 * 99
    rng = np.random.default_rng(0)
    v = rng.normal(size=(PAPER_COMPLEX_FACES // 2 + 2, 3)).astype(np.float32)
    f = rng.integers(0, len(v), size=(PAPER_COMPLEX_FACES, 3)).astype(np.int32)
    objects = [
        ObjectRecord(
            o,
            0,
            np.ones(3),
            o,
            "train",
            [MeshRecord(i, v, f, 0.0, {}) for i in range(n_meshes // 8)],
        )
        for o in range(8)
    ]
    path = tmp / "copy.h5"
    write_shard(path, objects, ["cube"], {}, "bench")
    mb = path.stat().st_size / 1e6
    _, seconds = best_time(lambda: rewrite_atomically(path, lambda h5: None), budget_s=3.0)
    return {"shard_mb": mb, "seconds": seconds, "seconds_per_mb": seconds / mb}


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--paper-objects", type=int, default=PAPER_OBJECTS)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--out", default=str(RESULTS / "radar_throughput.json"))
    args = ap.parse_args()
    config = radar_sim.RadarConfig.named("xband-v1")
    out = {
        "hardware": hardware(),
        "cpu_count": os.cpu_count(),
        "load_average_at_start": os.getloadavg()[0],
        "grid": [len(config.aspect_deg), len(config.roll_deg), len(config.frequency_hz)],
    }

    print("1. convex ~1k-face objects, full default grid, one core")
    out["convex"] = {
        name: time_simulate(mesh, config, "auto") for name, mesh in convex_objects().items()
    }
    for name, r in out["convex"].items():
        print(
            f"  {name:>10} {r['faces']:>6} faces  mode {r['mode']:<8} {r['seconds'] * 1e3:8.1f} ms"
            f"  (field {r['field_seconds'] * 1e3:.1f} ms)  "
            f"{r['orientation_frequencies_per_second']:.3g}"
            f" orientation-frequencies/s  goal ratio {r['seconds'] / GOAL_OBJECT_S:.2f}"
        )

    print("2. 20k-face non-convex torus, full default grid, one core")
    torus = trimesh.creation.torus(0.5, 0.15, major_sections=200, minor_sections=50)
    shadowed = time_simulate(torus, config, "shadowed")
    culled = time_simulate(torus, config, "convex")
    origins, dirs = shadow_rays(torus, config.directions())
    raw = raw_embree(torus, origins, dirs)
    shadow_s = shadowed["field_seconds"] - culled["field_seconds"]
    out["nonconvex"] = {
        "auto_mode": radar_sim.detect_mode(torus.vertices, torus.faces),
        "shadowed": shadowed,
        "culling_only": culled,
        "raw_embreex": raw,
        "shadow_seconds": shadow_s,
        "simulator_shadow_rays_per_second": raw["rays"] / shadow_s,
    }
    print(f"  auto mode: {out['nonconvex']['auto_mode']}")
    for name, r in (("shadowed", shadowed), ("culling only", culled)):
        print(
            f"  {name:>12} {r['seconds'] * 1e3:8.1f} ms  "
            f"{r['orientation_frequencies_per_second']:.3g} orientation-frequencies/s"
        )
    print(
        f"  shadowing costs {shadow_s * 1e3:.1f} ms for {raw['rays']} rays: "
        f"{raw['rays'] / shadow_s / 1e6:.2f} M rays/s in the simulator vs "
        f"{raw['rays_per_second'] / 1e6:.2f} M rays/s raw embreex "
        f"(ratio {raw['rays'] / shadow_s / raw['rays_per_second']:.2f}); "
        f"BVH build {raw['build_seconds'] * 1e3:.1f} ms"
    )

    print(f"3. `radar-sim label` on {args.paper_objects} simple meshes")
    with tempfile.TemporaryDirectory() as tmp:
        request = LabelRequest(config)
        rows = []
        for w in args.workers:
            data = paper_dataset(Path(tmp) / f"data{w}", args.paper_objects)
            t0 = time.perf_counter()
            summary = label_directory(data, request, workers=w, progress=False)
            seconds = time.perf_counter() - t0
            rows.append(
                {
                    "workers": w,
                    "objects": summary.objects,
                    "seconds": seconds,
                    "objects_per_second": summary.objects / seconds,
                    "paper_seconds": PAPER_OBJECTS * seconds / summary.objects,
                }
            )
        copy = copy_cost(Path(tmp))
    paper_mb = PAPER_OBJECTS / 8 * copy["shard_mb"]
    out["label"] = {
        "rows": rows,
        "rewrite": copy,
        "paper_dataset_mb_estimate": paper_mb,
        "paper_rewrite_seconds_estimate": paper_mb * copy["seconds_per_mb"],
    }
    print(
        f"  {'workers':>7} {'objects':>7} {'seconds':>8} {'obj/s':>7} {'paper s':>8} "
        f"{'vs 1st':>7} {'vs goal':>7}"
    )
    for r in rows:
        print(
            f"  {r['workers']:>7} {r['objects']:>7} {r['seconds']:>8.1f} "
            f"{r['objects_per_second']:>7.1f} {r['paper_seconds']:>8.1f} "
            f"{rows[0]['seconds'] / r['seconds']:>7.2f} {r['paper_seconds'] / GOAL_PAPER_S:>7.2f}"
        )
    print(
        f"  atomic rewrite of a paper-sized shard ({copy['shard_mb']:.1f} MB, 8 objects x 99 "
        f"complex"
        f" meshes of {PAPER_COMPLEX_FACES} faces): {copy['seconds'] * 1e3:.0f} ms; "
        f"paper dataset (~{paper_mb / 1e3:.1f} GB) adds "
        f"~{out['label']['paper_rewrite_seconds_estimate']:.0f} s"
    )
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
