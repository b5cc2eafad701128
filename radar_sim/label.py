"""Label shards in place: add the ``/radar`` group (docs/ARCHITECTURE.md, "Shards").

One Dask task per object (its simple mesh, plus the variants asked for), so the work
balances across workers whatever the shard sizes; the client gathers an object's labels and
rewrites its shard once, atomically, when the shard's last object is done. A killed run
therefore leaves every shard either untouched or fully labelled, and a rerun skips the
labelled ones. Each label depends only on its mesh and the config, never on which worker
computed it, so the bytes do not depend on the number of workers.
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from basic_shapes.cluster import dask_client
from basic_shapes.shards import Shard, list_shards, rewrite_atomically
from radar_sim.field import MODES


class LabelError(ValueError):
    """A dataset cannot be labelled as asked (config mismatch, bad mesh, bad request)."""


def parse_variants(spec: str) -> tuple[str, int]:
    """``"none"`` | ``"sample:K"`` | ``"all"`` -> (kind, K); K is 0 unless sampling."""
    if spec in ("none", "all"):
        return spec, 0
    kind, _, k = spec.partition(":")
    if kind == "sample" and k.isdigit() and int(k) > 0:
        return "sample", int(k)
    raise LabelError(f"--variants {spec!r}: expected none, all or sample:K with K >= 1")


@dataclass(frozen=True)
class LabelRequest:
    """What a label depends on. Stored with the labels; a rerun with an equal request skips."""

    config: object  # radar_sim.RadarConfig
    variants: str = "none"
    mode: str = "auto"
    frequency_response: bool = False

    def __post_init__(self):
        parse_variants(self.variants)
        if self.mode not in MODES:
            raise LabelError(f"mode {self.mode!r}: expected one of {', '.join(MODES)}")

    def attrs(self) -> dict[str, str]:
        """The /radar attributes that identify this request."""
        options = {"variants": self.variants, "mode": self.mode,
                   "frequency_response": self.frequency_response}
        return {"config": self.config.to_json(), "options": json.dumps(options, sort_keys=True)}


def _differences(group: h5py.Group, attrs: dict[str, str]) -> list[str]:
    """Names of the request attributes ("config", "options") that the stored labels differ in."""
    def parsed(value):
        try:
            return json.loads(value)
        except (TypeError, ValueError):
            return None

    return [k for k, v in attrs.items() if parsed(group.attrs.get(k)) != json.loads(v)]


def select_variants(shard: Shard, variants: str) -> list[np.ndarray]:
    """Per object, the rows of the complex meshes to label besides the simple one.

    ``sample:K`` draws K complex meshes per object from a generator seeded by the object's
    own seed, so the choice is the same on every run and every machine.
    """
    kind, k = parse_variants(variants)
    oi = shard.file["meshes/object_index"][()]
    var = shard.file["meshes/variant"][()]
    seeds = shard.file["objects/seed"][()]
    rows = []
    for obj in range(shard.n_objects):
        complex_rows = np.flatnonzero((oi == obj) & (var > 0))
        if kind == "none":
            complex_rows = complex_rows[:0]
        elif kind == "sample" and k < len(complex_rows):
            rng = np.random.default_rng(np.random.SeedSequence(int(seeds[obj]), spawn_key=(k,)))
            complex_rows = np.sort(rng.choice(complex_rows, k, replace=False))
        rows.append(complex_rows.astype(np.int64))
    return rows


@dataclass
class ShardPlan:
    """One shard to label: which mesh rows per object, and the labels as they arrive."""

    path: Path
    simple: np.ndarray  # (n_objects,) row of each object's simple mesh
    variant_rows: list[np.ndarray]
    object_ids: np.ndarray
    results: dict = field(default_factory=dict)  # object index -> list of per-mesh labels

    @property
    def n_objects(self) -> int:
        return len(self.simple)


def plan_shard(path: Path, request: LabelRequest, overwrite: bool) -> ShardPlan | None:
    """Validate one shard; None if it already holds labels for this very request."""
    with Shard(path) as s:
        s.verify()  # labels computed from edited meshes must not pass as done, nor be made
        if "radar" in s.file:
            differ = _differences(s.file["radar"], request.attrs())
            if not differ:
                return None
            if not overwrite:
                stored = s.file["radar"].attrs.get("options", "unknown options")
                raise LabelError(f"{path}: already labelled, with different radar "
                                 f"{' and '.join(differ)} (stored options: {stored}); pass "
                                 f"--overwrite to relabel")
        simple = s.simple_mesh_index()
        missing = np.flatnonzero(simple < 0)
        if len(missing):
            raise LabelError(f"{path}: object index {int(missing[0])} has no simple mesh "
                             f"(variant 0)")
        return ShardPlan(path, simple, select_variants(s, request.variants), s.file["objects/id"][()])


def label_meshes(meshes: list[tuple[int, np.ndarray, np.ndarray]], config, mode: str,
                 frequency_response: bool) -> list[tuple]:
    """Worker task: (range profiles, frequency response or None, mode) per (row, V, F), complex64."""
    from radar_sim import MeshError, simulate

    out = []
    for row, vertices, faces in meshes:
        try:
            r = simulate(vertices, faces, config, mode=mode)
        except MeshError as exc:
            raise MeshError(f"mesh row {row}: {exc}") from None
        freq = r.frequency_response.astype(np.complex64) if frequency_response else None
        out.append((r.range_profiles.astype(np.complex64), freq, r.mode))
    return out


def write_labels(plan: ShardPlan, request: LabelRequest) -> None:
    """Rewrite one shard atomically with its complete /radar group."""
    from radar_sim import __version__

    config = request.config
    per_object = [plan.results[k] for k in range(plan.n_objects)]
    strings = h5py.string_dtype()

    def edit(f: h5py.File) -> None:
        if "radar" in f:
            del f["radar"]
        g = f.create_group("radar")
        for key, value in request.attrs().items():
            g.attrs[key] = value
        g.attrs["radar_sim_version"] = __version__

        def put(name, data, dtype=None):
            g.create_dataset(name, data=np.asarray(data, dtype=dtype), track_times=False)

        for name in ("aspect_deg", "roll_deg", "frequency_hz", "range_m"):
            put(name, getattr(config, name), np.float64)
        put("response", [labels[0][0] for labels in per_object])
        if request.frequency_response:
            put("frequency_response", [labels[0][1] for labels in per_object])
        put("mode", [labels[0][2].encode() for labels in per_object], strings)
        if request.variants != "none":
            put("variant_mesh_index", np.concatenate(plan.variant_rows), np.int64)
            variant_labels = [lab for labels in per_object for lab in labels[1:]]
            shape = (0, *per_object[0][0][0].shape)
            put("variant_response", [lab[0] for lab in variant_labels] or np.zeros(shape),
                np.complex64)
            put("variant_mode", [lab[2].encode() for lab in variant_labels], strings)

    rewrite_atomically(plan.path, edit)


@dataclass
class LabelSummary:
    labelled: list[Path]
    skipped: list[Path]
    objects: int


def _object_tasks(plans: list[ShardPlan]):
    """(plan, object index, [(row, V, F), ...]) per object; each shard is read once, then closed."""
    for plan in plans:
        with Shard(plan.path) as s:
            items = [(plan, k, [(int(r), *s.mesh(int(r)))
                                for r in (plan.simple[k], *plan.variant_rows[k])])
                     for k in range(plan.n_objects)]
        yield from items


def label_directory(directory: str | os.PathLike, request: LabelRequest, *,
                    workers: int | None = None, scheduler: str | None = None,
                    overwrite: bool = False, progress: bool = True) -> LabelSummary:
    """Label every shard of ``directory`` that is not already labelled with ``request``.

    Every shard is validated before any work starts, so a foreign or truncated shard, or a
    config mismatch, fails fast and changes nothing.
    """
    from distributed import as_completed
    from tqdm import tqdm

    from radar_sim import MeshError

    paths = list_shards(directory)
    plans = {p: plan_shard(p, request, overwrite) for p in paths}
    todo = [plan for plan in plans.values() if plan is not None]
    summary = LabelSummary([], [p for p, plan in plans.items() if plan is None],
                           sum(plan.n_objects for plan in todo))
    if not todo:
        return summary

    with contextlib.ExitStack() as stack:
        try:
            client = stack.enter_context(dask_client(workers, scheduler))
        except OSError as exc:
            raise LabelError(f"{directory}: cannot use the Dask cluster "
                             f"{scheduler or '(local)'}: {exc}") from None
        bar = stack.enter_context(tqdm(total=summary.objects, unit="object", desc="radar labels",
                                       disable=not progress))
        window = 4 * max(1, sum(client.nthreads().values()))
        tasks = _object_tasks(todo)
        running = as_completed()
        owner = {}

        def submit_next() -> None:
            item = next(tasks, None)
            if item is not None:
                plan, k, meshes = item
                future = client.submit(label_meshes, meshes, request.config, request.mode,
                                       request.frequency_response, pure=False)
                owner[future.key] = (plan, k)
                running.add(future)

        for _ in range(window):
            submit_next()
        for future in running:
            plan, k = owner.pop(future.key)
            try:
                plan.results[k] = future.result()
            except MeshError as exc:
                raise LabelError(f"{plan.path}: object {int(plan.object_ids[k])}: {exc}") from None
            future.release()
            if len(plan.results) == plan.n_objects:
                write_labels(plan, request)
                plan.results.clear()
                summary.labelled.append(plan.path)
            bar.update()
            submit_next()
    return summary
