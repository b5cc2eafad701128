"""Plan a dataset, build its shards on Dask workers, write them atomically, resume after a kill.

Determinism: every random choice flows from the dataset seed through ``SeedSequence`` keyed
by class and object id, and each shard is built by one task from its own plan alone, so the
bytes do not depend on the number of workers or on scheduling.
"""

from __future__ import annotations

import json
import math
import time
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from basic_shapes import __version__
from basic_shapes.infra import atomic_path, load_json, one_line
from basic_shapes.scales import MIN_DISTANCE, SCALE_RANGE, ScaleError, capacity, sample_scales
from basic_shapes.shards import (
    OOD_FIRST,
    OOD_REMESHERS,
    OOD_SLOT,
    ObjectRecord,
    Shard,
    ShardError,
    shard_name,
    write_shard,
)

CONFIG_FILE = "dataset.json"
TEST_FRACTION = 0.1
VAL_FRACTION = 0.1  # model selection only (benchmark.training.train); never scored
# Rejection sampling of dissimilar scales jams near 36% of ``scales.capacity`` (measured: 6203
# of 17361 at the default range and distance); beyond this fraction refuse at once instead of
# spinning for minutes.
PACKING = 0.3
MESHES_PER_SECOND_PER_WORKER = 83.0  # 1 / CPU s per mesh (12.1 ms), perf/generate_throughput.py


LATER_FIELDS = {"hidden_ood": False}
"""GenerateConfig fields added after the first recorded versions, and their defaults.
``hidden_ood``: test objects of hidden-parameter classes get OOD meshes too (hidden-cpu-v1 and
-v2 predate the remeshers that represent them and were built without)."""


@dataclass(frozen=True)
class GenerateConfig:
    classes: tuple[str, ...] = ("cube", "cylinder", "sphere")
    objects_per_class: int = 1000
    variants: int = 99
    seed: int = 0
    objects_per_shard: int = 8
    scale_range: tuple[float, float] = SCALE_RANGE
    min_scale_distance: float = MIN_DISTANCE
    test_fraction: float = TEST_FRACTION
    val_fraction: float = VAL_FRACTION
    ood_variants_per_remesher: int = 3
    hidden_ood: bool = False
    toolkit_version: str = field(default=__version__)

    def validate(self) -> None:
        from basic_shapes.primitives import PRIMITIVES

        unknown = [c for c in self.classes if c not in PRIMITIVES]
        if unknown:
            raise ValueError(f"unknown class {', '.join(unknown)}; known: {', '.join(PRIMITIVES)}")
        if not self.classes or len(set(self.classes)) != len(self.classes):
            raise ValueError(
                f"classes must be non-empty and distinct, got {','.join(self.classes)}"
            )
        for name, lo in (("objects_per_class", 1), ("variants", 0), ("objects_per_shard", 1)):
            if getattr(self, name) < lo:
                raise ValueError(f"{name} must be >= {lo}, got {getattr(self, name)}")
        if self.variants >= OOD_FIRST:
            raise ValueError(
                f"variants must be < {OOD_FIRST} (mesh ids reserve 3 digits, "
                f"{OOD_FIRST}-999 for OOD meshes), got {self.variants}"
            )
        if not 0 <= self.ood_variants_per_remesher <= OOD_SLOT:
            raise ValueError(
                f"ood_variants_per_remesher must be in 0..{OOD_SLOT}, "
                f"got {self.ood_variants_per_remesher}"
            )
        if not 0 <= self.test_fraction < 1:
            raise ValueError(f"test_fraction must be in [0, 1), got {self.test_fraction}")
        if not 0 <= self.val_fraction < 1 - self.test_fraction:
            raise ValueError(
                f"val_fraction must be in [0, 1 - test_fraction), got {self.val_fraction}"
            )
        self._validate_scales()

    def _validate_scales(self) -> None:
        """Scale flags are checked before any sampling (no ZeroDivisionError, no NaN counts)."""
        lo, hi = self.scale_range
        if not all(math.isfinite(x) and x > 0 for x in (lo, hi)) or lo >= hi:
            raise ValueError(
                f"--scale-range must be finite, positive and LOW < HIGH, got {lo} {hi}"
            )
        if not (math.isfinite(self.min_scale_distance) and self.min_scale_distance > 0):
            raise ValueError(
                f"--min-scale-distance must be a finite number > 0, got {self.min_scale_distance}"
            )
        practical = int(PACKING * capacity(self.scale_range, self.min_scale_distance))
        if self.objects_per_class > practical:
            raise ScaleError(
                f"cannot place {self.objects_per_class} dissimilar scales per class "
                f"in {list(self.scale_range)} m with --min-scale-distance "
                f"{self.min_scale_distance}: at most about {practical} fit; ask for "
                f"fewer objects, a wider --scale-range or a smaller distance"
            )

    def to_dict(self) -> dict:
        """Fields added after the first recorded versions appear only where set, so those
        versions keep their config (and with it their mesh fingerprints)."""
        d = asdict(self)
        d["classes"] = list(self.classes)
        d["scale_range"] = list(self.scale_range)
        for name, default in LATER_FIELDS.items():
            if d[name] == default:
                del d[name]
        return d


@dataclass(frozen=True)
class ObjectPlan:
    id: int
    class_name: str
    class_index: int
    scale: tuple[float, float, float]
    seed: int
    split: str
    params: dict = field(default_factory=dict)  # hidden shape parameters (analytic.HIDDEN)


def _rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def plan_objects(cfg: GenerateConfig) -> list[ObjectPlan]:
    """Every object's class, scale, seed and split: cheap, done once by the client."""
    from basic_shapes.analytic import hidden_params  # numba: not needed to read a config

    plans = []
    for ci, name in enumerate(cfg.classes):
        key = zlib.crc32(name.encode())
        rng = _rng(cfg.seed, 0, key)
        scales = sample_scales(cfg.objects_per_class, rng, cfg.scale_range, cfg.min_scale_distance)
        n_test = round(cfg.test_fraction * cfg.objects_per_class)
        if cfg.test_fraction > 0 and cfg.objects_per_class >= 2:
            n_test = max(1, n_test)
        # test and val from one permutation: the test objects do not depend on val_fraction
        n_val = round(cfg.val_fraction * cfg.objects_per_class)
        if cfg.val_fraction > 0 and cfg.objects_per_class - n_test >= 2:
            n_val = max(1, n_val)
        perm = rng.permutation(cfg.objects_per_class).tolist()
        test, val = set(perm[:n_test]), set(perm[n_test : n_test + n_val])
        for k in range(cfg.objects_per_class):
            oid = ci * cfg.objects_per_class + k
            seed = int(_rng(cfg.seed, 1, key, k).integers(0, 2**63 - 1))
            plans.append(
                ObjectPlan(
                    oid,
                    name,
                    ci,
                    tuple(float(x) for x in scales[k]),
                    seed,
                    "test" if k in test else "val" if k in val else "train",
                    hidden_params(name, seed),
                )
            )
    return plans


def shard_plans(cfg: GenerateConfig) -> list[list[ObjectPlan]]:
    objs = plan_objects(cfg)
    n = cfg.objects_per_shard
    return [objs[i : i + n] for i in range(0, len(objs), n)]


def build_shard(path: str, plans: list[ObjectPlan], cfg_json: dict) -> dict:
    """One Dask task: make, verify and write every mesh of the shard's objects."""
    from basic_shapes.analytic import solid_for
    from basic_shapes.blender import object_meshes

    t0 = time.perf_counter()
    objects = []
    for p in plans:
        try:
            meshes = _with_ood(
                p,
                object_meshes(
                    p.class_name, np.array(p.scale), p.seed, cfg_json["variants"], p.params
                ),
                cfg_json,
            )
        except OSError as exc:  # a MeshLab child that died (killed, out of memory)
            raise OSError(f"{path}: object {p.id} ({p.class_name}): {one_line(exc)}") from None
        objects.append(
            ObjectRecord(
                p.id,
                p.class_index,
                np.array(p.scale),
                p.seed,
                p.split,
                meshes,
                params=solid_for(p.class_name, p.scale, p.params).params,
            )
        )
    write_shard(path, objects, cfg_json["classes"], cfg_json, cfg_json["toolkit_version"])
    return {
        "path": path,
        "meshes": sum(len(o.meshes) for o in objects),
        "seconds": time.perf_counter() - t0,
    }


def _with_ood(p: ObjectPlan, meshes: list, cfg_json: dict) -> list:
    """A test object's meshes followed by its out-of-distribution ones (basic_shapes/remesh.py,
    variants OOD_FIRST..999): other remeshers than the training variants', test split only."""
    from basic_shapes.remesh import ood_meshes

    per = cfg_json.get("ood_variants_per_remesher", 0)
    if p.split != "test" or not per or not _ood_remeshers(p.class_name, cfg_json):
        return meshes
    from basic_shapes.meshcheck import topology_key

    seen = {topology_key(m.faces, len(m.vertices)) for m in meshes}
    return meshes + ood_meshes(
        p.class_name,
        np.array(p.scale),
        p.seed,
        meshes[0].vertices,
        meshes[0].faces,
        per,
        seen,
        p.params,
    )


def _ood_remeshers(class_name: str, cfg_json: dict) -> int:
    """How many remeshers make OOD meshes of this class's test objects: none for a class with
    hidden shape parameters unless the config asks for them (``hidden_ood``)."""
    from basic_shapes.primitives import get
    from basic_shapes.remesh import supports

    if get(class_name).shape is not None and not cfg_json.get("hidden_ood", False):
        return 0
    return sum(supports(r, class_name) for r in OOD_REMESHERS)


def _check_out_dir(out: Path, cfg: GenerateConfig) -> bool:
    """Refuse a directory that holds another dataset; True while this config is unrecorded.
    Reads only: nothing is written before the cluster is up (a bad --scheduler leaves no trace)."""
    cfg_path = out / CONFIG_FILE
    if cfg_path.exists():
        old = load_json(cfg_path, max_bytes=1 << 16, error=ShardError)
        if not isinstance(old, dict):
            raise ShardError(f"{cfg_path}: dataset config is not a JSON object")
        if old != cfg.to_dict():
            diff = sorted(
                k for k in set(old) | set(cfg.to_dict()) if old.get(k) != cfg.to_dict().get(k)
            )
            raise ShardError(
                f"{out}: holds a dataset with a different config "
                f"({', '.join(diff)} differ); use another --data"
            )
        return False
    if any(out.glob("shard-*.h5")):
        raise ShardError(f"{out}: holds shards but no {CONFIG_FILE}; use another --data")
    return True


def _record_config(out: Path, cfg: GenerateConfig) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / CONFIG_FILE) as tmp:
        tmp.write_text(json.dumps(cfg.to_dict(), indent=2, sort_keys=True))


def _is_done(path: Path, cfg: GenerateConfig) -> bool:
    if not path.exists():
        return False
    try:
        with Shard(path) as s:
            if s.config != cfg.to_dict():
                return False
            s.verify()  # an edited shard with its fingerprint kept is rebuilt, not skipped
            return True
    except ShardError:
        return False


def generate(
    out: str | Path,
    cfg: GenerateConfig,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    shards: list[int] | None = None,
) -> dict:
    """Generate (or finish generating) the dataset in ``out``; returns run statistics.

    ``shards``: build only these shard numbers of the plan (a slice of the dataset, each
    shard byte-identical to the same shard of a whole build).

    ``workers=0`` builds in this process, on its main thread (Blender's, see
    ``cluster.batch_client``); otherwise a LocalCluster with ``workers`` single-threaded
    processes (default: one per core), or the cluster at ``scheduler``. With ``progress``, the
    plan line on stdout and a bar on stderr, as ``radar-sim label``.
    """
    from basic_shapes.cluster import TaskError, batch_client, run_tasks, worker_threads

    cfg.validate()
    out = Path(out)
    unrecorded = _check_out_dir(out, cfg)
    tasks = [(str(out / shard_name(i)), plans) for i, plans in enumerate(shard_plans(cfg))]
    if shards is not None:
        if max(shards, default=0) >= len(tasks):
            raise ValueError(
                f"shard {max(shards)} does not exist: the dataset has {len(tasks)} "
                f"shards (0..{len(tasks) - 1})"
            )
        tasks = [tasks[i] for i in sorted(set(shards))]
    todo = [t for t in tasks if not _is_done(Path(t[0]), cfg)]
    t0 = time.perf_counter()
    meshes = 0
    if todo:
        # checks --workers and --scheduler before anything is written
        with batch_client(workers, scheduler, main_thread=True) as client:
            if unrecorded:
                _record_config(out, cfg)
            for path, _ in tasks:  # only our own leftovers: never other files in the directory
                Path(path + ".tmp").unlink(missing_ok=True)
            cfg_json = cfg.to_dict()
            if progress:
                print(plan_text(cfg, tasks, worker_threads(client), scheduler), flush=True)
            with _bar(todo, cfg_json, progress) as bar:
                jobs = ((path, (path, plans, cfg_json)) for path, plans in todo)
                try:
                    for _, r in run_tasks(client, build_shard, jobs):
                        bar.update(r["meshes"])
                        meshes += r["meshes"]
                except TaskError as exc:
                    raise exc.error from None
    wall = time.perf_counter() - t0
    return {
        "shards": len(tasks),
        "built": len(todo),
        "skipped": len(tasks) - len(todo),
        "meshes": meshes,
        "seconds": wall,
        "meshes_per_second": meshes / wall if wall else 0.0,
    }


def plan_text(cfg: GenerateConfig, tasks: list, threads: int, scheduler: str | None) -> str:
    """One line saying what a run will do, printed before it starts (a run can take days):
    the shards of ``tasks`` (all of the dataset's, or the slice asked for)."""
    objects = sum(len(plans) for _, plans in tasks)
    meshes = _mesh_count(tasks, cfg.to_dict())
    every = -(-len(cfg.classes) * cfg.objects_per_class // cfg.objects_per_shard)
    shards = f"{len(tasks)} shards" if len(tasks) == every else f"{len(tasks)} of {every} shards"
    where = (
        f"the cluster at {scheduler} ({threads} worker thread(s))"
        if scheduler
        else f"{threads} local worker(s)"
    )
    hours = meshes / (MESHES_PER_SECOND_PER_WORKER * threads) / 3600
    eta = (
        f"about {hours:.1f} h"
        if hours >= 1
        else f"about {round(hours * 60)} min"
        if hours >= 1 / 60
        else "under a minute"
    )
    return (
        f"generate: {objects} objects ({', '.join(cfg.classes)}), {meshes} meshes, {shards} "
        f"on {where}; {eta} if nothing is done yet "
        f"(at {MESHES_PER_SECOND_PER_WORKER:.0f} meshes/s per worker)"
    )


def _mesh_count(tasks, cfg_json) -> int:
    """Meshes the shards of ``tasks`` hold: each object's variants + 1, and the OOD meshes of
    test objects."""
    ood = {
        c: cfg_json.get("ood_variants_per_remesher", 0) * _ood_remeshers(c, cfg_json)
        for c in cfg_json["classes"]
    }
    return sum(
        cfg_json["variants"] + 1 + ood[p.class_name] * (p.split == "test")
        for _, ps in tasks
        for p in ps
    )


def _bar(todo, cfg_json, progress):
    """The job's tqdm bar on stderr, advanced by meshes (OOD meshes of test objects included)."""
    from tqdm import tqdm

    total = _mesh_count(todo, cfg_json)
    return tqdm(total=total, unit="mesh", disable=not progress, desc="generate")
