"""Label shards in place: add the ``/radar`` group (docs/ARCHITECTURE.md, "Shards").

An object's label is the physics of its analytic primitive (``basic_shapes.analytic``),
computed on the deterministic simulation mesh for the config's top frequency, not on any
stored mesh. ``--mesh-labels`` also keeps the physics on stored representation meshes, which
measures how far the simulator run on a representation is from the object's label.

One Dask task per object, so the work balances across workers whatever the shard sizes. The
client writes each finished object at once to a small file of its own
(``<dataset>/.labels/<shard stem>/object-NNNNN.h5``, atomically); when a shard's objects are
all there it merges them into the shard (one atomic rewrite) and removes them. A killed run
loses at most the objects in flight, and a rerun reuses the finished ones. Each label depends
only on its object and the config, never on the worker or on interruptions, so the bytes of a
labelled shard do not depend on the number of workers or on how often the run was resumed.

Resume is a small state machine per shard (``plan_shard``) and per object, decided from the
disk alone, so any kill leaves a state the next run knows:

    shard state                                   next run
    ---------------------------------------------------------------------------------------
    labelled, same request, fingerprint holds     done: skipped (``plan_shard`` -> None)
    labelled, same request, fingerprint broken    relabelled, with a warning
    labelled, other request                       refused unless --overwrite
    unlabelled (or being relabelled)              planned; each object is one of:

    object state (its file in .labels/)           next run
    ---------------------------------------------------------------------------------------
    no file                                       computed
    file stamped with this request and shard      done (reused, never recomputed)
    file with another stamp, or unreadable        stale: deleted once every shard is valid,
                                                  then computed
    all objects done                              merged into the shard (one atomic rewrite),
                                                  then the shard's .labels/ folder removed

A kill during the merge leaves the old shard intact (the rewrite is atomic) and every object
file in place; a kill after it leaves only the object files, which the next run removes
(their shard plans as done). The stamp (``_stamp``) is the request plus the shard's mesh
fingerprint, so an object computed for other meshes or another config is never reused.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from basic_shapes.analytic import SIMULATION_RULES, simulation_mesh, solid_for
from basic_shapes.cluster import TaskError, dask_client, run_tasks
from basic_shapes.infra import warn
from basic_shapes.shards import (
    SHARD_FORMAT,
    Shard,
    atomic_path,
    list_shards,
    rewrite_atomically,
    write_radar,
)
from radar_sim.field import MODES

SIDECAR = ".labels"
CONVEX_KINDS = ("cube", "cylinder", "sphere", "cone")  # primitives that bound a convex body


class LabelError(ValueError):
    """A dataset cannot be labelled as asked (config mismatch, bad mesh, bad request)."""


def parse_mesh_labels(spec: str) -> tuple[str, int]:
    """``"none"`` | ``"sample:K"`` | ``"all"`` -> (kind, K); K is 0 unless sampling."""
    if spec in ("none", "all"):
        return spec, 0
    kind, _, k = spec.partition(":")
    if kind == "sample" and k.isdigit() and int(k) > 0:
        return "sample", int(k)
    raise LabelError(f"--mesh-labels {spec!r}: expected none, all or sample:K with K >= 1")


@dataclass(frozen=True)
class LabelRequest:
    """What a label depends on. Stored with the labels; a rerun with an equal request skips."""

    config: object  # radar_sim.RadarConfig
    mesh_labels: str = "none"
    mode: str = "auto"
    frequency_response: bool = False
    shard_format: int = SHARD_FORMAT  # how /radar is written; not part of the label's identity

    def __post_init__(self):
        parse_mesh_labels(self.mesh_labels)
        if self.mode not in MODES:
            raise LabelError(f"mode {self.mode!r}: expected one of {', '.join(MODES)}")

    def attrs(self) -> dict[str, str]:
        """The /radar attributes that identify this request."""
        options = {
            "mesh_labels": self.mesh_labels,
            "mode": self.mode,
            "frequency_response": self.frequency_response,
        }
        return {
            "config": self.config.to_json(),
            "options": json.dumps(options, sort_keys=True),
            "simulation_rule": json.dumps(
                SIMULATION_RULES[self.config.simulation_rule], sort_keys=True
            ),
        }


def _differences(stored: dict[str, dict], attrs: dict[str, str]) -> list[str]:
    """Names of the request attributes that the stored labels differ in."""
    return [k for k, v in attrs.items() if stored.get(k) != json.loads(v)]


def select_mesh_rows(shard: Shard, mesh_labels: str) -> list[np.ndarray]:
    """Per object, the rows of the stored meshes (the simple one included) to label as well.

    ``sample:K`` draws K meshes per object from a generator seeded by the object's own seed,
    so the choice is the same on every run and every machine.
    """
    kind, k = parse_mesh_labels(mesh_labels)
    oi = shard.mesh_table()["object_index"]
    seeds = shard.objects()["seed"]
    rows = []
    for obj in range(shard.n_objects):
        mine = np.flatnonzero(oi == obj)
        if kind == "none":
            mine = mine[:0]
        elif kind == "sample" and k < len(mine):
            rng = np.random.default_rng(np.random.SeedSequence(int(seeds[obj]), spawn_key=(k,)))
            mine = np.sort(rng.choice(mine, k, replace=False))
        rows.append(mine.astype(np.int64))
    return rows


@dataclass
class ObjectPlan:
    """One object to label: its primitive, the representation rows, the estimated work."""

    index: int
    object_id: int
    class_name: str
    scale: np.ndarray
    params: dict
    mesh_rows: np.ndarray
    work: float  # faces x directions x frequencies, simulation mesh and representations


@dataclass
class ShardPlan:
    """One shard to label: the objects still to compute, and where finished ones wait."""

    path: Path
    fingerprint: str
    objects: list[ObjectPlan]
    object_ids: np.ndarray  # /objects/id, the /radar/object coordinate
    done: set = field(default_factory=set)  # object indices with a sidecar file
    stale: list = field(default_factory=list)  # sidecar files of another request or shard

    @property
    def sidecar(self) -> Path:
        return self.path.parent / SIDECAR / self.path.stem

    @property
    def n_objects(self) -> int:
        return len(self.object_ids)

    def object_file(self, k: int) -> Path:
        return self.sidecar / f"object-{k:05d}.h5"


def _sidecar_matches(path: Path, stamp: str) -> bool:
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("request") == stamp
    except OSError:
        return False


def _stamp(request: LabelRequest, fingerprint: str) -> str:
    """What a finished object's file must carry to be reused: the request and the shard."""
    return json.dumps({**request.attrs(), "shard_fingerprint": fingerprint}, sort_keys=True)


def _plan_object(
    path: Path, objs: dict, k: int, name: str, params: dict, faces: int, rows: np.ndarray, config
) -> ObjectPlan:
    """One object's plan; ``LabelError`` if its primitive is invalid or outside the window.

    ``faces``: the total face count of the stored meshes in ``rows``.
    """
    oid, scale = int(objs["id"][k]), objs["scale"][k]
    try:
        v, f = simulation_mesh(
            solid_for(name, scale, params), config.f_stop_hz, rule=config.simulation_rule
        )
    except ValueError as exc:
        raise LabelError(f"{path}: object {oid}: {exc}") from None
    radius = float(np.sqrt((v * v).sum(axis=1).max()))
    if radius > config.max_radius_m:
        raise LabelError(
            f"{path}: object {oid} ({name}, {' x '.join(f'{x:.4g}' for x in scale)}"
            f" m) extends {radius:.4g} m from the origin, beyond the "
            f"±{config.max_radius_m:.4g} m range window of radar config "
            f"{config.name!r}"
        )
    work = float(len(f) + faces) * config.n_aspect * config.n_roll * config.n_freq
    return ObjectPlan(k, oid, name, scale, params, rows, work)


def plan_shard(path: Path, request: LabelRequest, overwrite: bool) -> ShardPlan | None:
    """Validate one shard; None if it already holds labels for this very request.

    Refuses (``LabelError``) objects whose primitive does not fit the config's range window,
    before any work starts. Finished objects of an interrupted run with the same request are
    marked done; sidecar files of another request or shard content are listed as stale.
    """
    with Shard(path) as s:
        s.verify()  # labels computed from edited meshes must not pass as done, nor be made
        if s.has_labels:
            radar = s.radar
            stored = {
                "config": radar.config,
                "options": radar.options,
                "simulation_rule": radar.simulation_rule,
            }
            differ = _differences(stored, request.attrs())
            if not differ and radar.computed_fingerprint() == radar.fingerprint:
                return None
            if not differ:  # the same request, but the stored labels were edited: redo them
                warn(
                    f"{path}: stored labels do not match their fingerprint (edited or "
                    f"corrupted); labelling the shard again"
                )
            elif not overwrite:
                raise LabelError(
                    f"{path}: already labelled, with different radar "
                    f"{' and '.join(differ)} (stored options: "
                    f"{json.dumps(stored['options'])}); to finish it as it was, pass --config "
                    f"{stored['config'].get('name')} and those options; to relabel, --overwrite"
                )
        objs, names, n_faces = s.objects(), s.class_names, s.mesh_table()["n_faces"]
        params, rows = s.object_params(), select_mesh_rows(s, request.mesh_labels)
        plans = [
            _plan_object(
                path,
                objs,
                k,
                names[int(objs["class"][k])],
                params[k],
                int(n_faces[rows[k]].sum()),
                rows[k],
                request.config,
            )
            for k in range(s.n_objects)
        ]
        plan = ShardPlan(path, s.fingerprint, plans, objs["id"])
    stamp = _stamp(request, plan.fingerprint)
    for k in range(plan.n_objects):
        p = plan.object_file(k)
        if p.is_file() and _sidecar_matches(p, stamp):
            plan.done.add(k)
        elif p.exists():
            plan.stale.append(p)
    plan.objects = [o for o in plan.objects if o.index not in plan.done]
    return plan


def object_mode(class_name: str, mode: str) -> str:
    """The physics of a primitive: convex primitives are exact with culling alone; the torus
    (which sees itself) gets what detection finds on its simulation mesh."""
    if mode != "auto":
        return mode
    return "convex" if class_name in CONVEX_KINDS else "auto"


@functools.cache
def _warm_up() -> None:
    """Import and compile the kernels once per worker process, so that an object's time (the
    cost estimate's calibration) is its own work, not the process's start-up."""
    from radar_sim import RadarConfig, simulate

    v, f = simulation_mesh(solid_for("cube", (0.01, 0.01, 0.01)), 1e9)
    grid = {"n_aspect": 1, "n_roll": 1, "n_freq": 3, "n_range": 3}
    simulate(v, f, RadarConfig(name="warm-up", **grid), mode="convex")
    edged = RadarConfig(name="warm-up-edges", channels="HH,VV,HV", edges="mec", **grid)
    simulate(v, f, edged, mode="convex")  # the edge kernel too (a cube has edges)


def label_object(
    class_name: str, scale, params: dict, meshes: list, config, mode: str, frequency_response: bool
) -> dict:
    """Worker task: the object's label on its simulation mesh, and the physics on ``meshes``.

    ``meshes`` is [(row, vertices, faces), ...]; labels are complex64.
    """
    from radar_sim import MeshError, simulate

    _warm_up()
    t0 = time.perf_counter()
    v, f = simulation_mesh(
        solid_for(class_name, scale, params), config.f_stop_hz, rule=config.simulation_rule
    )
    try:
        r = simulate(v, f, config, mode=object_mode(class_name, mode))
    except MeshError as exc:
        raise MeshError(f"simulation mesh: {exc}") from None
    out = {
        "response": r.range_profiles.astype(np.complex64),
        "mode": r.mode,
        "frequency_response": (
            r.frequency_response.astype(np.complex64) if frequency_response else None
        ),
        "polarimetric": (
            None if r.channel_profiles is None else r.channel_profiles.astype(np.complex64)
        ),
        "mesh_rows": [],
        "mesh_responses": [],
        "mesh_modes": [],
        "faces": len(f),
    }
    for row, vertices, faces in meshes:
        try:
            m = simulate(vertices, faces, config, mode=mode)
        except MeshError as exc:
            raise MeshError(f"mesh row {row}: {exc}") from None
        out["mesh_rows"].append(row)
        out["mesh_responses"].append(m.range_profiles.astype(np.complex64))
        out["mesh_modes"].append(m.mode)
    out["seconds"] = time.perf_counter() - t0
    return out


def write_object(plan: ShardPlan, k: int, result: dict, stamp: str) -> None:
    """Keep one finished object on disk (atomically) until its shard is complete."""
    path = plan.object_file(k)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w", libver="earliest") as f:
            f.attrs["request"] = stamp
            f.attrs["mode"] = result["mode"]
            f.create_dataset("response", data=result["response"], track_times=False)
            for name in ("frequency_response", "polarimetric"):
                if result[name] is not None:
                    f.create_dataset(name, data=result[name], track_times=False)
            f.create_dataset(
                "mesh_rows", data=np.asarray(result["mesh_rows"], np.int64), track_times=False
            )
            shape = (0, *result["response"].shape)
            f.create_dataset(
                "mesh_response",
                data=np.asarray(result["mesh_responses"] or np.zeros(shape), np.complex64),
                track_times=False,
            )
            f.create_dataset(
                "mesh_mode",
                data=[m.encode() for m in result["mesh_modes"]],
                dtype=h5py.string_dtype(),
                track_times=False,
            )


def merge_shard(plan: ShardPlan, request: LabelRequest) -> None:
    """Rewrite the shard atomically with its complete /radar group, then drop the sidecar."""
    from radar_sim import __version__

    files = [plan.object_file(k) for k in range(plan.n_objects)]
    config = request.config

    def rows(name):
        for p in files:
            with h5py.File(p, "r") as f:
                yield f[name][()]

    def mesh_rows(name):
        for p in files:
            with h5py.File(p, "r") as f:
                yield from f[name][()]

    def edit(f: h5py.File) -> None:
        modes = []
        for p in files:
            with h5py.File(p, "r") as o:
                modes.append(str(o.attrs["mode"]))
        with_meshes = request.mesh_labels != "none"
        polarimetric = len(config.channel_list) > 1
        write_radar(
            f,
            attrs={**request.attrs(), "radar_sim_version": __version__},
            coordinates={
                n: getattr(config, n) for n in ("aspect_deg", "roll_deg", "range_m", "frequency_hz")
            },
            object_ids=plan.object_ids,
            modes=modes,
            responses=rows("response"),
            frequency_responses=rows("frequency_response") if request.frequency_response else None,
            mesh_index=np.fromiter(mesh_rows("mesh_rows"), np.int64) if with_meshes else None,
            mesh_modes=[m.decode() for m in mesh_rows("mesh_mode")] if with_meshes else None,
            mesh_responses=mesh_rows("mesh_response") if with_meshes else None,
            channels=config.channel_list if polarimetric else None,
            channel_responses=rows("polarimetric") if polarimetric else None,
            shard_format=request.shard_format,
        )

    rewrite_atomically(plan.path, edit)
    shutil.rmtree(plan.sidecar, ignore_errors=True)
    with contextlib.suppress(OSError):
        plan.sidecar.parent.rmdir()  # only when no other shard's objects wait there


@dataclass
class LabelSummary:
    labelled: list[Path]
    skipped: list[Path]
    objects: int
    reused: int = 0


def _tasks(plans: list[ShardPlan]):
    """(plan, object plan, [(row, V, F), ...]) per object, the most work first: the first
    object then calibrates the estimate on real work (a 12-face cube first is all overhead: it
    made a 2-hour paper-scale job read 74 h), and no long object is left to end the run on
    one worker. Each shard is read once per object."""
    queue = [(plan, obj) for plan in plans for obj in plan.objects]
    for plan, obj in sorted(queue, key=lambda item: -item[1].work):
        with Shard(plan.path) as s:
            meshes = [(int(r), *s.mesh(int(r))) for r in obj.mesh_rows]
        yield plan, obj, meshes


def _bar(n_todo: int, total_work: float, progress: bool):
    """The job's tqdm bar on stderr, as every long job of the toolkit: advanced by each
    object's work (faces x directions x frequencies), so the time left is right although the
    largest objects come first; the objects done and the last one are shown beside it."""
    from tqdm import tqdm

    return tqdm(
        total=total_work,
        desc="label",
        disable=not progress,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}{postfix}]",
        postfix=f"0/{n_todo} objects",
    )


def label_directory(
    directory: str | os.PathLike,
    request: LabelRequest,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> LabelSummary:
    """Label every shard of ``directory`` that is not already labelled with ``request``.

    Every shard is validated before any work starts, so a foreign or truncated shard, a config
    mismatch or an object outside the range window fails fast and changes nothing. Prints the
    planned work (stdout), then a progress bar weighted by work (stderr).
    """
    from radar_sim import MeshError

    def log(text: str) -> None:  # stdout: stderr is kept for the one-line error
        if progress:
            print(text, flush=True)

    paths = list_shards(directory)
    for path in [Path(directory), *paths]:  # labels go into the shards: fail before any work
        if not os.access(path, os.W_OK):
            raise LabelError(
                f"{path}: not writable (labels are written into the dataset in "
                f"place); label a writable copy"
            )
    plans = {p: plan_shard(p, request, overwrite) for p in paths}
    for path in [p for p, plan in plans.items() if plan is None]:  # killed after its merge
        shutil.rmtree(path.parent / SIDECAR / path.stem, ignore_errors=True)
        with contextlib.suppress(OSError):
            (path.parent / SIDECAR).rmdir()
    todo = [plan for plan in plans.values() if plan is not None]
    for plan in todo:  # every shard is valid: now drop what cannot be reused
        for stale in plan.stale:
            stale.unlink()
    summary = LabelSummary(
        [],
        [p for p, plan in plans.items() if plan is None],
        sum(plan.n_objects for plan in todo),
        sum(len(plan.done) for plan in todo),
    )
    for plan in [p for p in todo if not p.objects]:  # every object finished before a kill
        merge_shard(plan, request)
        summary.labelled.append(plan.path)
    todo = [plan for plan in todo if plan.objects]
    if not todo:
        return summary
    n_todo = sum(len(plan.objects) for plan in todo)
    total_work = sum(o.work for plan in todo for o in plan.objects)
    with contextlib.ExitStack() as stack:
        try:
            client = stack.enter_context(dask_client(workers, scheduler))
        except OSError as exc:
            raise LabelError(
                f"{directory}: cannot use the Dask cluster {scheduler or '(local)'}: {exc}"
            ) from None
        log(
            f"radar-sim label: {n_todo} object(s) in {len(todo)} shard(s) to compute on "
            f"{max(1, sum(client.nthreads().values()))} worker thread(s)"
            f"{f', {summary.reused} reused from an interrupted run' if summary.reused else ''}; "
            f"work {total_work:.3g} face x direction x frequency products"
        )
        tasks = (
            (
                (plan, obj),
                (
                    obj.class_name,
                    obj.scale,
                    obj.params,
                    meshes,
                    request.config,
                    request.mode,
                    request.frequency_response,
                ),
            )
            for plan, obj, meshes in _tasks(todo)
        )
        bar, count = stack.enter_context(_bar(n_todo, total_work, progress)), 0
        try:
            for (plan, obj), result in run_tasks(client, label_object, tasks):
                write_object(plan, obj.index, result, _stamp(request, plan.fingerprint))
                plan.done.add(obj.index)
                count += 1
                bar.set_postfix_str(
                    f"{count}/{n_todo} objects, last {plan.path.name} object {obj.object_id} "
                    f"({obj.class_name}, {result['faces']} faces, {result['mode']})",
                    refresh=False,
                )
                bar.update(obj.work)
                if len(plan.done) == plan.n_objects:
                    merge_shard(plan, request)
                    summary.labelled.append(plan.path)
        except TaskError as exc:
            if not isinstance(exc.error, MeshError):
                raise exc.error from None
            plan, obj = exc.tag
            raise LabelError(f"{plan.path}: object {obj.object_id}: {exc.error}") from None
    return summary
