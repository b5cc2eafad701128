"""Cost of the hardened reading of shards and predictions (issue 12), against plain reading.

    python perf/shard_checks.py [--objects 8] [--meshes 100] [--repeat 5]

Builds one shard like a generated one (objects x meshes, icospheres of ~1280 faces) and times:
opening it (``open_hdf5`` checks + ``Shard._validate``), ``Shard.verify`` (every face index and
the fingerprint), and reading every mesh (what any job that uses the shard pays anyway); then
how long a 6 KB predictions file declaring 1e9 rows takes to be refused. Writes
perf/results/shard_checks.json and prints a table. Report ratios, not absolute times:
the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import trimesh

from basic_shapes.infra import InputError, open_hdf5
from basic_shapes.shards import MeshRecord, ObjectRecord, Shard, write_shard


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--objects", type=int, default=8)
    ap.add_argument("--meshes", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "shard_checks.json"))
    args = ap.parse_args()
    sphere = trimesh.creation.icosphere(subdivisions=3)
    v, f = sphere.vertices.astype(np.float32), sphere.faces.astype(np.int32)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "shard-00000.h5"
        objects = [
            ObjectRecord(
                i,
                0,
                np.ones(3),
                i,
                "train",
                [MeshRecord(k, v, f, 0.0, {}) for k in range(args.meshes)],
            )
            for i in range(args.objects)
        ]
        write_shard(path, objects, ["sphere"], {"bench": True}, "0")

        def open_close():
            Shard(path).close()

        def verify():
            with Shard(path) as s:
                s.verify()

        def read_all():
            with Shard(path) as s:
                for _ in s.iter_meshes():
                    pass

        bomb = Path(tmp) / "bomb.h5"
        with h5py.File(bomb, "w") as h:
            h.create_dataset("target_db", (10**9, 61, 21, 107), np.float32, chunks=(1, 61, 21, 107))

        def refuse_bomb():
            try:
                open_hdf5(bomb).close()
            except InputError:
                return
            raise AssertionError("the bomb was accepted")

        rows = {
            "open + validate": best(open_close, args.repeat),
            "verify (faces + fingerprint)": best(verify, args.repeat),
            "read every mesh": best(read_all, args.repeat),
            "refuse 1e9-row predictions": best(refuse_bomb, args.repeat),
        }
        size = {"shard_bytes": path.stat().st_size, "bomb_bytes": bomb.stat().st_size}
    base = rows["read every mesh"]
    print(f"{'step':30} {'ms':>9} {'vs reading':>10}")
    for name, s in rows.items():
        print(f"{name:30} {1000 * s:9.2f} {s / base:10.2f}")
    result = {
        "objects": args.objects,
        "meshes_per_object": args.meshes,
        "faces_per_mesh": len(f),
        **size,
        "seconds_best_of": args.repeat,
        "seconds": {k: round(s, 5) for k, s in rows.items()},
        "ratio_to_reading": {k: round(s / base, 3) for k, s in rows.items()},
    }
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
