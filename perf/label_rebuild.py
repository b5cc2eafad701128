"""Labels of a recorded dataset version rebuilt on another machine, compared with its manifest.

    python perf/label_rebuild.py strip VERSION --data BUILD --shards 0,1 --into DIR
    python perf/label_rebuild.py check VERSION=DIR [VERSION=DIR ...] [--workers N] [--out JSON]

``strip`` (on the machine that holds a build) copies some shards of it without their labels
(every group but ``/radar``, with the root attributes and ``dataset.json``): the meshes
exactly as generated, a few MB, so they travel where Blender (bpy, Python 3.11 only) does not.
``check`` (on the other machine) labels them with ``radar-sim``'s labeller under the version's
config (``benchmark dataset`` does the same after generating) and compares every shard with the
committed manifest shard by shard: the label fingerprint of each shard, each object's label
hash. It records the CPU, the software stack beside the one the manifest was recorded with,
and the labelling time. The generator is not run: every shard is complete, so it skips them.

Writes perf/results/label_rebuild.json (or ``--out``) and prints one line per shard.

Measured (docs/DATASETS.md, "A second machine, real"): shards of demo-v2, cpu-v2 and hidden-cpu-v3
stripped on the AMD EPYC that built them and labelled on an Intel Xeon (glibc 2.39, Python
3.12, the pinned numpy 1.26.4 and scipy 1.17.1) match their manifests
(results/label_rebuild_intel_xeon.json); with numpy 2.5.2 instead, both machines agree with
each other and not with the manifests (results/label_rebuild_numpy2.json): numpy's FFT and
complex exp in ``RadarConfig.range_profiles`` round differently across numpy versions.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import h5py

from basic_shapes.infra import atomic_path, write_json
from basic_shapes.shards import Shard, shard_name
from benchmark.scoring import versions


def strip(build: Path, shards: list[int], into: Path) -> None:
    into.mkdir(parents=True, exist_ok=True)
    (into / "dataset.json").write_bytes((build / "dataset.json").read_bytes())
    for i in shards:
        name = shard_name(i)
        with h5py.File(build / name, "r") as src, atomic_path(into / name) as tmp:
            with h5py.File(tmp, "w") as dst:
                for key, value in src.attrs.items():
                    dst.attrs[key] = value
                for key in src:
                    if key != "radar":
                        src.copy(key, dst)
        print(f"{into / name}: {os.path.getsize(into / name) / 1e6:.1f} MB without /radar")


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def check_version(name: str, data: Path, workers: int | None) -> dict:
    version = versions.get(name)
    shards = sorted(int(p.stem.split("-")[1]) for p in data.glob("shard-*.h5"))
    t0 = time.perf_counter()
    report = versions.build(version, data, workers=workers, quiet=True, shards=shards)
    wall = time.perf_counter() - t0
    recorded = {s["name"]: s["label_fingerprint"] for s in version.manifest["shards"]}
    per_shard = []
    for i in shards:
        # the fingerprint the labeller stored; check() has already compared it with the content
        with Shard(data / shard_name(i)) as shard:
            fingerprint, objects = shard.radar.fingerprint, shard.n_objects
        per_shard.append(
            {
                "shard": shard_name(i),
                "label_fingerprint": fingerprint,
                "matches": fingerprint == recorded[shard_name(i)],
                "objects": objects,
            }
        )
    stack = versions.stack()
    return {
        "version": name,
        "stack_differs": {
            k: [version.manifest["stack"].get(k), stack.get(k)] for k in report["stack_differs"]
        },
        "label_s": report["label_s"],
        "wall_s": round(wall, 1),
        "matches_recorded": report["matches_recorded"],
        "differences": report["differences"],
        "shards": per_shard,
    }


def check(pairs: list[tuple[str, Path]], workers: int | None) -> dict:
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "workers": workers,
        "stack": versions.stack(),
        "versions": [check_version(name, data, workers) for name, data in pairs],
    }


def _pair(text: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep or not path:
        raise argparse.ArgumentTypeError(f"{text!r}: expected VERSION=DIR")
    return name, Path(path)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("strip", help="copy shards of a build without their labels")
    s.add_argument("version")
    s.add_argument("--data", type=Path, required=True, help="the build")
    s.add_argument("--shards", required=True, help="shard numbers, comma-separated")
    s.add_argument("--into", type=Path, required=True, help="directory to write")
    c = sub.add_parser("check", help="label stripped shards here and compare with the manifest")
    c.add_argument(
        "pairs",
        nargs="+",
        metavar="VERSION=DIR",
        type=_pair,
        help="a version and its stripped shards (strip's --into)",
    )
    c.add_argument("--workers", type=int, default=None, help="labelling workers (default: cores)")
    c.add_argument("--out", type=Path, default=Path(__file__).parent / "results/label_rebuild.json")
    args = p.parse_args()
    if args.command == "strip":
        versions.get(args.version)  # a registered version, or a one-line error
        strip(args.data, [int(x) for x in args.shards.split(",")], args.into)
        return
    result = check(args.pairs, args.workers)
    for v in result["versions"]:
        for s in v["shards"]:
            print(
                f"{v['version']} {s['shard']}: label {s['label_fingerprint'][:16]} "
                f"{'matches' if s['matches'] else 'DIFFERS from'} the manifest"
            )
        print(
            f"{v['version']}: labelled in {v['label_s']} s; the stack differs from the "
            f"recorded one in {sorted(v['stack_differs'])}"
        )
    print(f"{result['cpu']}, {result['cores']} cores")
    write_json(args.out, result)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
