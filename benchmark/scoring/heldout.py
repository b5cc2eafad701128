"""Held-out builds of a dataset version: the same recipe with a secret seed (the ranked track).

The test labels of a public version are public (they ship in its shards), and so is the
physics simulator, so error on a public test split can always be topped. The ranked track
scores models on a *held-out build* instead: a registered version's recipe (sizes, classes,
radar grid, mesh labels, software stack: ``benchmark.scoring.versions``) generated from a seed
derived from a secret. Its public identity is the recipe and its fingerprints; the data and the
secret stay with the board's maintainer, outside git.

``benchmark dataset NAME --data DIR --secret-seed-file FILE`` builds one (or ``--check``s one,
or ``--record``s its fingerprints in ``benchmark/manifests/heldout/NAME.json``); what it prints
and records is the version, the timings and the two fingerprints, never the seed or the secret.
(The shards themselves hold their generator config, seed included, as every build does: the
held-out directory is secret as a whole.) ``identify`` tells a held-out build from the public
one: same recipe, another seed; where fingerprints are recorded, they must match.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from basic_shapes.infra import atomic_path, load_json
from benchmark.scoring.versions import (
    MANIFESTS,
    VERSIONS,
    DatasetVersion,
    VersionError,
    _generator_config,
    stack,
    stored_configs,
)

RECORDS = MANIFESTS / "heldout"
SECRET_MIN_BYTES = 16
SECRET_MAX_BYTES = 4096
SEED_SALT = b"basic-shapes held-out seed v1\0"


class HeldOutError(VersionError):
    """A secret that cannot seed a held-out build, or a directory that is not one."""


def read_secret(path: str | os.PathLike | None = None, env: str | None = None) -> bytes:
    """The secret, from a file (surrounding whitespace stripped) or an environment variable;
    at least ``SECRET_MIN_BYTES`` bytes (``head -c 32 /dev/urandom | base64 > FILE``)."""
    if path is not None:
        from basic_shapes.infra import regular_file

        regular_file(path, HeldOutError)
        with open(path, "rb") as fh:
            secret, where = fh.read(SECRET_MAX_BYTES + 1).strip(), str(path)
    elif env is not None:
        secret, where = os.environ.get(env, "").strip().encode(), f"${env}"
    else:
        raise HeldOutError(
            "a held-out build needs a secret: --secret-seed-file or --secret-seed-env"
        )
    if not SECRET_MIN_BYTES <= len(secret) <= SECRET_MAX_BYTES:
        raise HeldOutError(
            f"{where}: the secret must be {SECRET_MIN_BYTES} to {SECRET_MAX_BYTES} bytes "
            f"(e.g. head -c 32 /dev/urandom | base64 > FILE)"
        )
    return secret


def seed_of(secret: bytes, version: DatasetVersion) -> int:
    """The generator seed of ``version``'s held-out build: sha256 of a salt, the version's
    name and the secret, 63 bits; never the public seed."""
    digest = hashlib.sha256(SEED_SALT + version.name.encode() + b"\0" + secret).digest()
    seed = int.from_bytes(digest[:8], "big") >> 1
    return seed + 1 if seed == version.seed else seed


def record_path(version: DatasetVersion) -> Path:
    return RECORDS / f"{version.name}.json"


def recorded(version: DatasetVersion) -> dict | None:
    """The recorded fingerprints of ``version``'s held-out build ({"mesh", "label"}), or None."""
    path = record_path(version)
    if not path.exists():
        return None
    return dict(load_json(path, max_bytes=1 << 16, error=HeldOutError)["fingerprints"])


def fingerprints(directory: str | os.PathLike) -> dict:
    from benchmark.scoring.data import BenchmarkData

    with BenchmarkData(directory) as data:
        return {"mesh": data.fingerprint, "label": data.label_fingerprint}


def build(
    version: DatasetVersion,
    directory: str | os.PathLike,
    secret: bytes,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    quiet: bool = False,
) -> dict:
    """Generate and label ``version``'s recipe with the secret's seed into ``directory``
    (resumes); return the version, timings and fingerprints (never the seed)."""
    from benchmark.scoring import versions

    seed = seed_of(secret, version)
    timings = versions.make(
        version, directory, seed=seed, workers=workers, scheduler=scheduler, quiet=quiet
    )
    return {**timings, **check(version, directory)}


def check(version: DatasetVersion, directory: str | os.PathLike) -> dict:
    """The held-out build's fingerprints and whether they match the recorded ones (None:
    nothing recorded)."""
    found = fingerprints(directory)
    expected = recorded(version)
    return {
        "version": version.name,
        "heldout": True,
        **found,
        "matches_recorded": None if expected is None else expected == found,
    }


@dataclass(frozen=True)
class HeldOut:
    """A held-out build: the version whose recipe it follows and whether its fingerprints are
    the recorded ones (None: none recorded)."""

    version: DatasetVersion
    fingerprint: str
    label_fingerprint: str
    recorded: bool | None


def recipe_of(directory: str | os.PathLike) -> tuple[DatasetVersion, int | None] | None:
    """(the registered version whose recipe ``directory`` was built with, whatever its seed;
    that seed), or None if it follows none (or is not labelled). Where two versions share a
    recipe, the one whose seed it has (its public build) is named."""
    gen, radar = stored_configs(directory)
    if radar is None:
        return None
    seed = gen.pop("seed", None)
    found = []
    for v in VERSIONS.values():
        recipe = _generator_config(v)
        recipe.pop("seed")
        if gen == recipe and radar == v.radar_config().to_dict():
            found.append(v)
    found.sort(key=lambda v: v.seed != seed)
    return (found[0], seed) if found else None


def identify(directory: str | os.PathLike) -> HeldOut:
    """The version ``directory`` is a held-out build of (same recipe, another seed);
    ``HeldOutError`` if it is a public build (its labels are public), no version's recipe, or
    differs from the recorded held-out fingerprints."""
    found_recipe = recipe_of(directory)
    if found_recipe is None:
        raise HeldOutError(
            f"{directory}: not a held-out build of a registered dataset version (its generator "
            f"and radar configs follow no recipe of benchmark dataset --list)"
        )
    v, seed = found_recipe
    if seed == v.seed:
        raise HeldOutError(
            f"{directory}: the public build of {v.name}, whose test labels are "
            f"public; the ranked track runs on a held-out build (benchmark dataset "
            f"{v.name} --secret-seed-file FILE)"
        )
    found = fingerprints(directory)
    expected = recorded(v)
    if expected is not None and expected != found:
        raise HeldOutError(
            f"{directory}: not the recorded held-out build of {v.name} (mesh "
            f"{found['mesh'][:12]}..., recorded {expected['mesh'][:12]}...)"
        )
    return HeldOut(v, found["mesh"], found["label"], None if expected is None else True)


def record(version: DatasetVersion, directory: str | os.PathLike) -> Path:
    """Write the public identity of ``version``'s held-out build: its fingerprints and stack."""
    found = fingerprints(directory)
    path = record_path(version)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = {
        "version": version.name,
        "recipe": f"{version.name} with a secret seed (benchmark.scoring.heldout)",
        "fingerprints": found,
        "stack": stack(),
    }
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(body, indent=1, sort_keys=True) + "\n")
    return path


def run(args, version: DatasetVersion) -> int:
    """``benchmark dataset NAME --data DIR --secret-seed-file F|--secret-seed-env VAR``."""
    if args.source or args.pack or args.shards:
        raise HeldOutError(
            "a held-out build is built whole and never released: --from, --pack and "
            "--shards do not go with a secret seed"
        )
    secret = read_secret(args.secret_seed_file, args.secret_seed_env)
    if args.check or args.record:
        if seed_of(secret, version) != _stored_seed(args.data):
            raise HeldOutError(f"{args.data}: not {version.name} built from this secret")
        report = check(version, args.data)
        if args.record:
            report["recorded"] = str(record(version, args.data))
    else:
        report = build(
            version,
            args.data,
            secret,
            workers=args.workers,
            scheduler=args.scheduler,
            quiet=args.quiet,
        )
    print(json.dumps(report, indent=2))
    if report["matches_recorded"] is False and not args.record:
        raise HeldOutError(f"{args.data}: not the recorded held-out build of {version.name}")
    return 0


def _stored_seed(directory) -> int | None:
    from basic_shapes.shards import Shard, list_shards

    with Shard(list_shards(directory)[0]) as s:
        return s.config.get("seed")
