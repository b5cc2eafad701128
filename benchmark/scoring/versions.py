"""Named dataset versions: each a recipe defined here once, proved by a committed manifest.

A version fixes everything its meshes and labels depend on: the generator's sizes and seed
(splits, variants and OOD meshes follow from them), the radar grid (``xband-v1`` with some
axes coarsened), the per-mesh physics asked for, and (through ``constraints.txt``) the
software stack; the simulation-mesh rule comes with the toolkit. Its manifest
(``benchmark/manifests/NAME.json``: per shard and per object, mesh and label hashes apart)
is what a build must reproduce, byte for byte, on any machine of the supported stack
(docs/DATASETS.md). ``benchmark dataset NAME`` builds it (or a slice of its shards), checks a
directory against it, packs a built one into a release archive, or fetches and verifies one.
``leaderboard submit`` accepts only datasets that are a registered version.

Adding a version is one entry in VERSIONS; ``--record`` writes its manifest after the first
build, and a second build on another machine must then match it.
"""

from __future__ import annotations

import functools
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from basic_shapes.infra import atomic_path
from basic_shapes.shards import SHARD_FORMAT

MANIFESTS = Path(__file__).parents[1] / "manifests"
# the packages whose code computes stored bytes (pinned in constraints.txt)
BYTE_PACKAGES = (
    "numpy",
    "bpy",
    "pymeshlab",
    "numba",
    "llvmlite",
    "embreex",
    "h5py",
    "scipy",
    "trimesh",
)


class VersionError(ValueError):
    """An unknown version name, or a directory that is not a registered version."""


@dataclass(frozen=True)
class DatasetVersion:
    """One named dataset: generator sizes, radar grid, mesh labels; its manifest on disk."""

    name: str
    summary: str
    objects_per_class: int
    variants: int
    classes: tuple[str, ...] = ("cube", "cylinder", "sphere")
    seed: int = 0
    radar: dict = field(default_factory=dict)  # grid changes to the named RadarConfig
    mesh_labels: str = "none"  # radar-sim label --mesh-labels
    physics: str = "xband-v1"  # the named RadarConfig: "xband-v2" adds channels and edges
    hidden_ood: bool = False  # OOD test meshes for hidden-parameter classes too (GenerateConfig)
    shard_format: int = SHARD_FORMAT  # how /radar is written: as when the version was recorded

    @property
    def manifest_path(self) -> Path:
        return MANIFESTS / f"{self.name}.json"

    @property
    def manifest(self) -> dict | None:
        """The committed manifest, or None where none is recorded yet."""
        return _manifest(self.manifest_path)

    @property
    def fingerprints(self) -> dict:
        """{"mesh": sha256, "label": sha256} recorded in the manifest ({} if none)."""
        return dict(self.manifest["fingerprints"]) if self.manifest else {}

    def generator(self, seed: int | None = None):
        """The version's GenerateConfig, with ``seed`` instead of its own for a held-out build."""
        from basic_shapes.generate import GenerateConfig

        return GenerateConfig(
            classes=tuple(self.classes),
            objects_per_class=self.objects_per_class,
            variants=self.variants,
            seed=self.seed if seed is None else seed,
            hidden_ood=self.hidden_ood,
        )

    def radar_config(self):
        """The version's RadarConfig (``physics``), renamed when a grid axis is coarsened."""
        from radar_sim import RadarConfig

        return RadarConfig.named(self.physics).with_grid(**self.radar)

    def grid(self) -> str:
        c = self.radar_config()
        return f"{c.n_aspect} aspects x {c.n_roll} rolls x {c.n_range} range bins"

    def describe(self) -> dict:
        """What the board shows about the version."""
        return {
            "name": self.name,
            "summary": self.summary,
            "classes": list(self.classes),
            "objects_per_class": self.objects_per_class,
            "variants": self.variants,
            "seed": self.seed,
            "grid": self.grid(),
            "radar_config": self.radar_config().name,
            "physics": self.physics,
        }


@functools.cache
def _manifest(path: Path) -> dict | None:
    from basic_shapes import manifest

    return manifest.load(path) if path.exists() else None


VERSIONS: dict[str, DatasetVersion] = {
    v.name: v
    for v in (
        DatasetVersion(
            "tiny-v1",
            "the test suite's dataset: 2 objects per class, 3 meshes each",
            objects_per_class=2,
            variants=2,
            radar={"n_aspect": 7, "n_roll": 3},
            shard_format=1,
        ),
        DatasetVersion(
            "demo-v1",
            "the README demo: 4 objects per class, 10 meshes each, every mesh labelled",
            objects_per_class=4,
            variants=9,
            radar={"n_aspect": 31, "n_roll": 7},
            mesh_labels="all",
            shard_format=1,
        ),
        DatasetVersion(
            "cpu-v1",
            "the CPU benchmark: 500 objects per class (150 test objects), 10 meshes "
            "each plus OOD test meshes, 31 x 7 grid",
            objects_per_class=500,
            variants=9,
            radar={"n_aspect": 31, "n_roll": 7},
            mesh_labels="sample:1",
            shard_format=1,
        ),
        DatasetVersion(
            "hidden-cpu-v1",
            "the hidden-parameter track: 500 frustums (50 test objects) whose "
            "top-to-base radius ratio is hidden (class + scale cannot tell it), 10 meshes each, "
            "31 x 7 grid",
            objects_per_class=500,
            variants=9,
            classes=("frustum",),
            radar={"n_aspect": 31, "n_roll": 7},
            mesh_labels="sample:1",
            shard_format=1,
        ),
        DatasetVersion(
            "paper-v1",
            "the paper's scale: 1000 objects per class, 100 meshes each, full grid",
            objects_per_class=1000,
            variants=99,
        ),
    )
}
# The v2 labels (docs/RADAR.md "Polarization", "Edge diffraction"): each v1 recipe with the
# xband-v2 physics, PO plus edge diffraction in HH, VV and HV; VV stays the task's target.
VERSIONS.update(
    {
        v.name.replace("-v1", "-v2"): replace(
            v,
            name=v.name.replace("-v1", "-v2"),
            summary=v.summary + "; polarimetric labels with edge diffraction (xband-v2)",
            physics="xband-v2",
        )
        for v in list(VERSIONS.values())
    }
)
# The hidden-parameter track's second round: a second family whose hidden parameter moves the
# label strongly (the rounded box's edge radius), 150 test objects, and OOD test meshes from
# the remeshers that represent each hidden class (basic_shapes.remesh.SUPPORTED).
VERSIONS["hidden-cpu-v3"] = DatasetVersion(
    "hidden-cpu-v3",
    "the hidden-parameter track, second round: 750 frustums (hidden top-to-base radius ratio) "
    "and 750 rounded boxes (hidden edge radius over the smallest extent), 150 test objects "
    "with OOD meshes, 10 meshes each, 31 x 7 grid; polarimetric labels with edge diffraction "
    "(xband-v2)",
    objects_per_class=750,
    variants=9,
    classes=("frustum", "roundbox"),
    radar={"n_aspect": 31, "n_roll": 7},
    mesh_labels="sample:1",
    physics="xband-v2",
    hidden_ood=True,
    shard_format=1,
)

# The v3 labels (docs/RADAR.md, "Labels v3"): xband-v3 physics, xband-v2's with rims cut finer
# (HH converged) and range profiles from a portable DFT (the same bytes under any numpy); the
# v1 recipes and the hidden track's second round (hidden-cpu-v3, whose name was taken: -v4).
VERSIONS.update(
    {
        new: replace(
            VERSIONS[old],
            name=new,
            summary=VERSIONS[old].summary.replace("(xband-v2)", "(xband-v3)"),
            physics="xband-v3",
            shard_format=SHARD_FORMAT,
        )
        for old, new in (
            ("tiny-v2", "tiny-v3"),
            ("demo-v2", "demo-v3"),
            ("cpu-v2", "cpu-v3"),
            ("paper-v2", "paper-v3"),
            ("hidden-cpu-v3", "hidden-cpu-v4"),
        )
    }
)


def get(name: str) -> DatasetVersion:
    try:
        return VERSIONS[name]
    except KeyError:
        raise VersionError(
            f"unknown dataset version {name!r}; known: {', '.join(VERSIONS)}"
        ) from None


def build(
    version: DatasetVersion,
    directory: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    quiet: bool = False,
    shards: list[int] | None = None,
) -> dict:
    """Generate and label ``version`` into ``directory`` (both resume), or only the shards
    numbered ``shards`` (a slice: the same bytes as in a whole build); return timings and the
    comparison with the version's manifest (``check``)."""
    timings = make(
        version, directory, workers=workers, scheduler=scheduler, quiet=quiet, shards=shards
    )
    return {"version": version.name, **timings, **check(version, Path(directory))}


def make(
    version: DatasetVersion,
    directory: str | Path,
    *,
    seed: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    quiet: bool = False,
    shards: list[int] | None = None,
) -> dict:
    """Generate and label ``version``'s recipe into ``directory`` (both resume), with its own
    seed or ``seed`` (a held-out build, ``benchmark.scoring.heldout``); return the timings."""
    from basic_shapes.generate import generate
    from radar_sim.label import LabelRequest, label_directory

    directory = Path(directory)
    t0 = time.perf_counter()
    generate(
        directory,
        version.generator(seed),
        workers=workers,
        scheduler=scheduler,
        progress=not quiet,
        shards=shards,
    )
    t1 = time.perf_counter()
    label_directory(
        directory,
        LabelRequest(
            version.radar_config(), version.mesh_labels, shard_format=version.shard_format
        ),
        workers=workers,
        scheduler=scheduler,
        progress=not quiet,
    )
    return {"generate_s": round(t1 - t0, 1), "label_s": round(time.perf_counter() - t1, 1)}


def check(version: DatasetVersion, directory: str | Path) -> dict:
    """Compare a directory with the version's manifest: its fingerprints, whether they match,
    and the first differences (shard, object, mesh, data). A directory holding only some of
    the version's shards (a slice) is compared shard by shard."""
    from basic_shapes import manifest as mf

    found = mf.build(directory, version.name, stack())
    report = {"mesh": found["fingerprints"]["mesh"], "label": found["fingerprints"]["label"]}
    expected = version.manifest
    if expected is None:
        return {**report, "matches_recorded": None, "differences": []}
    names = {s["name"] for s in found["shards"]}
    if len(names) < len(expected["shards"]):
        expected = {
            **expected,
            "shards": [s for s in expected["shards"] if s["name"] in names],
            "fingerprints": found["fingerprints"],
        }  # a slice: shard by shard
        report["slice"] = sorted(names)
    differences = mf.differences(expected, found) + _coordinate_differences(version, directory)
    differences = differences[: mf.LIMIT]
    stack_changed = sorted(
        k
        for k in set(expected["stack"]) | set(found["stack"])
        if expected["stack"].get(k) != found["stack"].get(k)
    )
    return {
        **report,
        "matches_recorded": not differences,
        "differences": differences,
        "stack_differs": stack_changed,
    }


def _coordinate_differences(version: DatasetVersion, directory: str | Path) -> list[str]:
    """Shards whose radar axes are not those of the version's radar config. The fingerprints
    cover the labels and the config they name, not the axes stored beside them."""
    import numpy as np

    from basic_shapes.shards import Shard, list_shards

    config = version.radar_config()
    out = []
    for path in list_shards(directory):
        with Shard(path) as s:
            stored = s.radar.coordinates if s.has_labels else {}
            axes = [a for a, v in stored.items() if not np.array_equal(v, getattr(config, a))]
        if axes:
            out.append(f"{path.name}: radar axes differ from {config.name}'s: {', '.join(axes)}")
    return out


def stack() -> dict:
    """The software a dataset's bytes depend on (pinned in constraints.txt): recorded in each
    manifest, so a rebuild that differs can tell what else differs."""
    import platform
    from importlib import metadata

    out = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "libc": "-".join(platform.libc_ver()),
    }
    for package in BYTE_PACKAGES:
        try:
            out[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            out[package] = None
    return out


def _generator_config(version: DatasetVersion) -> dict:
    """The generator config ``build`` asks for (toolkit version aside)."""
    cfg = version.generator().to_dict()
    cfg.pop("toolkit_version")
    return cfg


def stored_configs(directory: str | Path) -> tuple[dict, dict | None]:
    """(generator config, radar config or None if unlabelled) a dataset directory was built
    with, read from its first shard: what identifies its recipe (the toolkit version aside)."""
    from basic_shapes.shards import Shard, list_shards

    with Shard(list_shards(directory)[0]) as s:
        gen = dict(s.config)
        radar = s.radar.config if s.has_labels else None
    gen.pop("toolkit_version", None)
    return gen, radar


def identify(directory: str | Path, registry: dict | None = None) -> DatasetVersion:
    """The registered version a dataset directory was built as, by its generator and radar
    configs (not by its name or path); VersionError if it is none of them."""
    gen, radar = stored_configs(directory)
    if radar is None:
        raise VersionError(f"{directory}: not labelled, so not a registered dataset version")
    for v in (registry or VERSIONS).values():
        if gen == _generator_config(v) and radar == v.radar_config().to_dict():
            return v
    raise VersionError(
        f"{directory}: not a registered dataset version (benchmark dataset "
        f"--list names them; build one with benchmark dataset NAME --data DIR)"
    )


def add_arguments(p) -> None:
    from basic_shapes.infra import add_cluster_flags, add_quiet_flag

    p.add_argument("name", nargs="?", help="dataset version (see --list)")
    p.add_argument(
        "--data",
        metavar="DIR",
        help="dataset directory: built into (resumes if it exists), checked, packed "
        "or fetched into",
    )
    p.add_argument("--list", action="store_true", help="list the registered versions and exit")
    what = p.add_mutually_exclusive_group()
    what.add_argument(
        "--check",
        action="store_true",
        help="only compare DIR with the version's manifest; name the first shard, "
        "object and mesh that differ",
    )
    what.add_argument(
        "--from",
        dest="source",
        metavar="PATH_OR_URL",
        help="fetch the version's release archive instead of building it; every "
        "shard is verified against the committed manifest (no Blender needed)",
    )
    what.add_argument(
        "--pack",
        metavar="ARCHIVE",
        help="write a built, checked DIR as the version's release archive (.tar)",
    )
    what.add_argument(
        "--record",
        action="store_true",
        help="maintainers: write the version's manifest from DIR (its first build)",
    )
    p.add_argument(
        "--shards",
        metavar="I,J,...",
        type=_indices,
        help="build only these shards of the version (a slice, checked shard by shard)",
    )
    secret = p.add_mutually_exclusive_group()
    secret.add_argument(
        "--secret-seed-file",
        metavar="FILE",
        help="build (or --check, --record) the version's held-out build: its recipe with a "
        "seed derived from the secret in FILE (benchmark.scoring.heldout; only the "
        "fingerprints are printed or recorded)",
    )
    secret.add_argument(
        "--secret-seed-env", metavar="VAR", help="as --secret-seed-file, the secret in $VAR"
    )
    add_cluster_flags(p)
    add_quiet_flag(p)


def _indices(text: str) -> list[int]:
    import argparse

    try:
        values = sorted({int(x) for x in text.split(",")})
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a comma-separated list of shard numbers"
        ) from None
    if not values or values[0] < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: shard numbers are 0 or more")
    return values


def run(args) -> int:
    from basic_shapes import manifest as mf
    from basic_shapes import release

    if args.list or not args.name:
        for v in VERSIONS.values():
            recorded = (
                f"mesh {v.fingerprints['mesh'][:8]} label {v.fingerprints['label'][:8]}"
                if v.fingerprints
                else "no manifest recorded"
            )
            print(f"{v.name:13s} {v.grid():42s} {recorded}\n{'':13s} {v.summary}")
        by_number = sorted(VERSIONS, key=lambda n: int(n.rsplit("-v", 1)[1]))
        newest = {n.rsplit("-v", 1)[0]: n for n in by_number}  # the last of each family wins
        print(
            f"\nnewest of each: {', '.join(newest.values())}; the older ones stay buildable "
            "(committed tables and board entries rest on them: docs/RESULTS.md names each one's)"
        )
        return 0
    if not args.data:
        raise VersionError(
            "--data DIR is required (the directory to build, check, pack or fetch into)"
        )
    version = get(args.name)
    if args.shards is not None and (args.check or args.pack or args.record or args.source):
        raise VersionError(
            "--shards selects what to build; --check, --pack, --record and --from take every "
            "shard in --data (a directory holding a slice is checked shard by shard)"
        )
    if getattr(args, "secret_seed_file", None) or getattr(args, "secret_seed_env", None):
        from benchmark.scoring import heldout

        return heldout.run(args, version)
    if args.record:
        found = mf.fold_meshes(mf.build(args.data, version.name, stack()))
        with atomic_path(version.manifest_path) as tmp:
            tmp.write_text(mf.dumps(found))
        print(
            f"recorded {version.manifest_path}: mesh {found['fingerprints']['mesh']}, "
            f"label {found['fingerprints']['label']}"
        )
        return 0
    if (args.source or args.pack) and version.manifest is None:
        raise VersionError(f"{version.name}: no manifest recorded, so nothing to verify against")
    if args.source:
        release.fetch(args.source, version.manifest, args.data, progress=not args.quiet)
        report = {"version": version.name, "fetched": args.source, **check(version, args.data)}
    elif args.check or args.pack:
        report = {"version": version.name, **check(version, args.data)}
    else:
        report = build(
            version,
            args.data,
            workers=args.workers,
            scheduler=args.scheduler,
            quiet=args.quiet,
            shards=args.shards,
        )
    if report["matches_recorded"] and args.pack:
        if "slice" in report:
            raise VersionError(
                f"{args.data}: holds only a slice of {version.name}; pack a whole build"
            )
        report["archive"] = str(release.pack(args.data, version.manifest, args.pack))
    print(json.dumps(report, indent=2))
    if report["matches_recorded"] is False:
        first = report["differences"][0]
        hint = (
            f" (stack differs from the recorded one: {', '.join(report['stack_differs'])})"
            if report["stack_differs"]
            else ""
        )
        raise VersionError(f"{args.data}: not {version.name} as recorded: {first}{hint}")
    return 0
