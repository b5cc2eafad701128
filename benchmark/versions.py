"""Named dataset versions: each defined here once, built by one command, identified by content.

A version fixes everything its meshes and labels depend on: the generator's sizes and seed
(splits, variants and OOD meshes follow from them), the radar grid (``xband-v1`` with some
axes coarsened) and the per-mesh physics asked for; the simulation-mesh rule comes with the
toolkit. ``benchmark dataset NAME --data DIR`` builds it with the toolkit's own CLIs
(resumable, byte-deterministic) and compares the fingerprints with the ones recorded here
from a reference build. ``leaderboard submit`` accepts only datasets that are a registered
version (same generator config and radar config), and the board names the version.

Adding a version is one entry in VERSIONS; record ``fingerprints`` after its first build.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from basic_shapes.infra import atomic_path


class VersionError(ValueError):
    """An unknown version name, or a directory that is not a registered version."""


@dataclass(frozen=True)
class DatasetVersion:
    """One named dataset: generator sizes, radar grid, mesh labels, recorded fingerprints."""

    name: str
    summary: str
    objects_per_class: int
    variants: int
    classes: tuple[str, ...] = ("cube", "cylinder", "sphere")
    seed: int = 0
    radar: dict = field(default_factory=dict)  # changes to the "xband-v1" RadarConfig
    mesh_labels: str = "none"  # radar-sim label --mesh-labels
    fingerprints: dict = field(default_factory=dict)  # {"mesh": sha256, "label": sha256}

    def radar_config(self):
        """The version's RadarConfig: ``xband-v1``, renamed when a grid axis is coarsened."""
        from radar_sim import RadarConfig

        config = RadarConfig.named("xband-v1")
        if not self.radar:
            return config
        grid = "x".join(str(self.radar.get(k, getattr(config, k)))
                        for k in ("n_aspect", "n_roll", "n_range"))
        return dataclasses.replace(config, name=f"xband-v1-{grid}", **self.radar)

    def grid(self) -> str:
        c = self.radar_config()
        return f"{c.n_aspect} aspects x {c.n_roll} rolls x {c.n_range} range bins"

    def describe(self) -> dict:
        """What the board shows about the version."""
        return {"name": self.name, "summary": self.summary, "classes": list(self.classes),
                "objects_per_class": self.objects_per_class, "variants": self.variants,
                "seed": self.seed, "grid": self.grid(), "radar_config": self.radar_config().name}


VERSIONS: dict[str, DatasetVersion] = {v.name: v for v in (
    DatasetVersion(
        "tiny-v1", "the test suite's dataset: 2 objects per class, 3 meshes each",
        objects_per_class=2, variants=2, radar={"n_aspect": 7, "n_roll": 3}),
    DatasetVersion(
        "demo-v1", "the README demo: 4 objects per class, 10 meshes each, every mesh labelled",
        objects_per_class=4, variants=9, radar={"n_aspect": 31, "n_roll": 7},
        mesh_labels="all"),
    DatasetVersion(
        "cpu-v1", "the CPU benchmark: 500 objects per class (150 test objects), 10 meshes "
        "each plus OOD test meshes, 31 x 7 grid",
        objects_per_class=500, variants=9, radar={"n_aspect": 31, "n_roll": 7},
        mesh_labels="sample:1",
        # recorded from the build of commit adb9fc1 with the fixed-layout MeshLab child
        # (generate 551 s on 1 worker, label 1,532 s, under load); the same mesh fingerprint as
        # an earlier build of that fix on 2 workers. The CPU table's first data, f304e7b4...
        # (commit ca53a6c), differs in 31-42 OOD meshes of 9 test objects (docs/DATASETS.md).
        fingerprints={"mesh": "390cf5dc79c0a3f47a640ce71992406bee2541cf00a714390b69ca8497dac91d",
                      "label": "bf31dd56dadd86c5594a7d4432b579b754c11c982e543195f05537f2bdbebd76"}),
    DatasetVersion(
        "hidden-cpu-v1", "the hidden-parameter track: 500 frustums (50 test objects) whose "
        "top-to-base radius ratio is hidden (class + scale cannot tell it), 10 meshes each, "
        "31 x 7 grid",
        objects_per_class=500, variants=9, classes=("frustum",),
        radar={"n_aspect": 31, "n_roll": 7}, mesh_labels="sample:1",
        # recorded from two builds of commit d0907a8 (2 workers each: generate 268 / 275 s,
        # label 16 / 18 s), the same fingerprints
        fingerprints={"mesh": "d9b522c8fae114620cce0ccfe709787f0b438d67e13b976e2526f0dac94b7ee8",
                      "label": "2c086c47cc524017416a3bac16b05fc490cd4ec264b9603d1aaf6b52917ed364"}),
    DatasetVersion(
        "paper-v1", "the paper's scale: 1000 objects per class, 100 meshes each, full grid",
        objects_per_class=1000, variants=99),
)}


def get(name: str) -> DatasetVersion:
    try:
        return VERSIONS[name]
    except KeyError:
        raise VersionError(f"unknown dataset version {name!r}; known: "
                           f"{', '.join(VERSIONS)}") from None


def _tool(name: str, module: str) -> list[str]:
    """The console script next to this interpreter, else ``python -m module``."""
    script = Path(sys.executable).with_name(name)
    return [str(script)] if script.exists() else [sys.executable, "-m", module]


def run_tool(cmd: list[str], what: str, quiet: bool) -> float:
    """Run one of the toolkit's CLIs; its one-line error becomes ours. Returns seconds."""
    t0 = time.perf_counter()
    result = subprocess.run(cmd, stdout=subprocess.PIPE if quiet else None,
                            stderr=subprocess.PIPE, text=True)
    if result.returncode != 0:
        tail = (result.stderr or "").strip().splitlines()
        raise VersionError(f"{what} failed: "
                           f"{tail[-1] if tail else 'exit code ' + str(result.returncode)}")
    return time.perf_counter() - t0


def build(version: DatasetVersion, directory: str | Path, *, workers: int | None = None,
          scheduler: str | None = None, quiet: bool = False) -> dict:
    """Generate and label ``version`` into ``directory`` (both steps resume); return timings
    and the fingerprints, with whether they match the recorded ones."""
    directory = Path(directory)
    directory.parent.mkdir(parents=True, exist_ok=True)
    radar = directory.parent / f"{directory.name}.radar.json"
    with atomic_path(radar) as tmp:
        tmp.write_text(version.radar_config().to_json())
    common = ["--scheduler", scheduler] if scheduler else \
        [] if workers is None else ["--workers", str(workers)]
    common += ["--quiet"] if quiet else []
    t_gen = run_tool([*_tool("basic-shapes", "basic_shapes.cli"), "generate", "--data",
                      str(directory), "--classes", ",".join(version.classes),
                      "--objects-per-class", str(version.objects_per_class),
                      "--variants", str(version.variants), "--seed", str(version.seed),
                      *common], "basic-shapes generate", quiet)
    t_label = run_tool([*_tool("radar-sim", "radar_sim.cli"), "label", "--data", str(directory),
                        "--config", str(radar), "--mesh-labels", version.mesh_labels,
                        *common], "radar-sim label", quiet)
    found = fingerprints(directory)
    expected = version.fingerprints
    return {"version": version.name, "generate_s": t_gen, "label_s": t_label, **found,
            "matches_recorded": None if not expected else found == expected}


def fingerprints(directory: str | Path) -> dict:
    """{"mesh": ..., "label": ...} of a dataset directory."""
    from basic_shapes.shards import dataset_fingerprint, label_fingerprint

    return {"mesh": dataset_fingerprint(directory), "label": label_fingerprint(directory)}


def _generator_config(version: DatasetVersion) -> dict:
    """The generator config ``build`` asks for (toolkit version aside)."""
    from basic_shapes.generate import GenerateConfig

    cfg = GenerateConfig(classes=tuple(version.classes),
                         objects_per_class=version.objects_per_class,
                         variants=version.variants, seed=version.seed).to_json()
    cfg.pop("toolkit_version")
    return cfg


def identify(directory: str | Path, registry: dict | None = None) -> DatasetVersion:
    """The registered version a dataset directory was built as, by its generator and radar
    configs (not by its name or path); VersionError if it is none of them."""
    from basic_shapes.shards import Shard, list_shards

    with Shard(list_shards(directory)[0]) as s:
        gen = dict(s.config)
        radar = s.radar.config if s.has_labels else None
    if radar is None:
        raise VersionError(f"{directory}: not labelled, so not a registered dataset version")
    gen.pop("toolkit_version", None)
    for v in (registry or VERSIONS).values():
        if gen == _generator_config(v) and radar == json.loads(v.radar_config().to_json()):
            return v
    raise VersionError(f"{directory}: not a registered dataset version (benchmark dataset "
                       f"--list names them; build one with benchmark dataset NAME --data DIR)")


def add_arguments(p) -> None:
    from basic_shapes.infra import add_cluster_flags, add_quiet_flag

    p.add_argument("name", nargs="?", help="dataset version (see --list)")
    p.add_argument("--data", metavar="DIR",
                   help="dataset directory to build into (resumes if it exists)")
    p.add_argument("--list", action="store_true", help="list the registered versions and exit")
    add_cluster_flags(p)
    add_quiet_flag(p)


def run(args) -> int:
    if args.list or not args.name:
        for v in VERSIONS.values():
            recorded = "fingerprints recorded" if v.fingerprints else "no fingerprints recorded"
            print(f"{v.name:10s} {v.grid():42s} {recorded}\n{'':10s} {v.summary}")
        return 0
    if not args.data:
        raise VersionError("--data DIR is required to build a version")
    version = get(args.name)
    report = build(version, args.data, workers=args.workers, scheduler=args.scheduler,
                   quiet=args.quiet)
    print(json.dumps(report, indent=2))
    if report["matches_recorded"] is False:
        raise VersionError(f"{args.data}: fingerprints differ from those recorded for "
                           f"{version.name} (see docs/DATASETS.md)")
    return 0
