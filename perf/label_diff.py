"""How far apart are two label versions of the same meshes? Per class, in the benchmark metric.

    python perf/label_diff.py OLD_BUILD NEW_BUILD [--out JSON]

Two builds of one recipe (the same objects, e.g. cpu-v2 and cpu-v3) are compared object by
object on ``/radar/response``, the scored VV target: MSE of 20 log10 max(|profile|, 1e-4),
in dB², averaged per object, then mean and max per class. A table scored on the old labels
holds for the new ones to within about this much. Writes perf/results/label_diff.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from basic_shapes.infra import write_json
from basic_shapes.shards import Shard
from benchmark.scoring.data import db_target


def target(profiles: np.ndarray) -> np.ndarray:
    """The benchmark's target (``db_target``), in float64 for the differences."""
    return db_target(profiles).astype(np.float64)


def per_class(old: Path, new: Path) -> dict[str, list[float]]:
    """{class: [per-object MSE, ...]}; ValueError where the builds hold other objects."""
    out: dict[str, list[float]] = {}
    for path in sorted(old.glob("shard-*.h5")):
        with Shard(path) as a, Shard(new / path.name) as b:
            ids = a.objects()["id"]
            if not np.array_equal(ids, b.objects()["id"]):
                raise ValueError(f"{new / path.name}: other objects than {path}")
            classes = a.objects()["class"]
            for k in range(a.n_objects):
                d = np.mean((target(a.radar.response(k)) - target(b.radar.response(k))) ** 2)
                out.setdefault(a.class_names[classes[k]], []).append(float(d))
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument(
        "--out", type=Path, default=Path(__file__).parent / "results/label_diff.json"
    )
    args = parser.parse_args(argv)
    rows = {
        name: {"objects": len(v), "mean_db2": float(np.mean(v)), "max_db2": float(np.max(v))}
        for name, v in per_class(args.old, args.new).items()
    }
    for name, r in rows.items():
        print(
            f"{name:10} {r['objects']:5d} objects  mean {r['mean_db2']:.4f}  max {r['max_db2']:.4f}"
        )
    pairs = json.loads(args.out.read_text()) if args.out.exists() else {}  # one file, keyed
    pairs[f"{args.old.name} -> {args.new.name}"] = rows
    write_json(args.out, pairs)


if __name__ == "__main__":
    main()
