"""The simulator run on the representation meshes: the board's physics reference model.

An object's label is the physics of its analytic primitive (``radar-sim label``); a stored
mesh is only a representation of it. The simulator given a representation mesh is therefore
a model like the others, scored like them: its "predictions" are the physics on each mesh
(``/radar/mesh_response``, from ``radar-sim label --mesh-labels all``), scored by the
benchmark's own ``Scorer`` against the object's label, per class. Simple MSE: physics on
the simple mesh vs the label; Complex MSE: physics on complex meshes vs the label; Variation
MSE: between the two. Test objects whose simple mesh has no physics label are left out; a
dataset with none is refused. Its speed is measured by timing ``radar_sim.simulate`` on a
face-count-stratified sample of test meshes, or given by hand (``--ms-per-mesh``) when
radar_sim is elsewhere.
"""

from __future__ import annotations

import os
import time

import numpy as np

from basic_shapes.infra import utc_timestamp
from basic_shapes.shards import Shard, is_ood_variant
from benchmark.scoring.data import BenchmarkData, db_target
from benchmark.scoring.evaluate import speed_block
from benchmark.scoring.metrics import Scorer
from leaderboard.store import (
    DEFAULT_ENTRIES,
    ENTRY_VERSION,
    dataset_record,
    entries_lock,
    validate_entry,
    write_entry,
)

TIMING_MESHES = 24
MEASURED = "simulator on the representation meshes vs the object's label (its analytic primitive)"


def mesh_physics_scores(data: BenchmarkData) -> tuple[dict, int]:
    """(metrics of the simulator on representation meshes, number of test objects scored).

    Every test object with a stored complex-mesh physics (``--mesh-labels``) is scored; where
    its simple mesh's physics was not stored (``sample:K`` draws among all meshes), it is
    simulated here with the labels' config and mode, as ``radar-sim label`` would have."""
    scorer = Scorer(data.class_names)
    test = set(data.object_rows("test").tolist())
    for k, path in enumerate(data.paths):
        with Shard(path) as shard:
            radar = shard.radar
            in_shard = np.flatnonzero(data.meshes["shard"] == k)
            by_row = dict(zip(data.meshes["row"][in_shard].tolist(), in_shard.tolist()))
            physics: dict[int, dict[int, int]] = {}  # object -> variant -> index into mesh_*
            for j, row in enumerate(radar.mesh_index.tolist()):
                mesh = by_row[row]
                obj = int(data.meshes["object"][mesh])
                variant = int(data.meshes["variant"][mesh])
                if obj in test and not is_ood_variant(variant):  # OOD meshes: scored apart
                    physics.setdefault(obj, {})[variant] = j
            for obj, variants in sorted(physics.items()):
                if 0 in variants:
                    simple = db_target(radar.mesh_response(variants.pop(0)))
                else:
                    simple = db_target(_simple_physics(data, obj))
                complex_ = np.array(
                    [db_target(radar.mesh_response(j)) for _, j in sorted(variants.items())]
                )
                scorer.add(
                    int(data.objects["class_index"][obj]),
                    data.target(obj),
                    simple,
                    complex_.reshape(len(variants), *simple.shape),
                )
    if not scorer.rows:
        raise ValueError(
            f"{data.directory}: no test object has the physics of a stored mesh "
            f"(/radar/mesh_response): label with `radar-sim label "
            f"--mesh-labels all` (or sample:K)"
        )
    return scorer.result(), len(scorer.rows)


def _simple_physics(data: BenchmarkData, obj: int) -> np.ndarray:
    """The physics of object row ``obj``'s simple mesh (complex64 range profiles), with the
    labels' config and mode, as ``radar-sim label --mesh-labels`` would have stored it."""
    from radar_sim import RadarConfig, simulate

    config = RadarConfig(**radar_config(data))
    mode = radar_config(data, options=True).get("mode", "auto")
    simple_row = int(data.meshes_of(obj)[0])  # variant 0 comes first
    return simulate(*data.mesh(simple_row), config, mode=mode).range_profiles.astype(np.complex64)


def radar_config(data: BenchmarkData, options: bool = False) -> dict:
    """The radar config of the dataset's labels (or the labelling options: mode, ...)."""
    with Shard(data.paths[0]) as s:
        return s.radar.options if options else s.radar.config


def measure_ms_per_mesh(data: BenchmarkData, n: int = TIMING_MESHES) -> float:
    """Mean wall time of ``radar_sim.simulate`` per mesh over ``n`` test meshes spread evenly
    over the face-count order, the OOD meshes included: the models' ms/mesh is a mean over
    the test split too, while one object's meshes time one size (a cube's 4 ms for a dataset
    of spheres). Uses the dataset's own radar config and physics mode; a warm-up call
    (imports, Embree scene set-up) is not counted."""
    from benchmark.scoring.protocol import scored_mesh_rows
    from radar_sim import RadarConfig, simulate

    config = RadarConfig(**radar_config(data))
    mode = radar_config(data, options=True).get("mode", "auto")
    rows = scored_mesh_rows(data)
    order = rows[np.argsort(np.asarray(data.meshes["n_faces"])[rows], kind="stable")]
    step = max(1, len(order) // n)
    meshes = [data.mesh(int(r)) for r in order[step // 2 :: step][:n]]
    simulate(*meshes[0], config, mode=mode)
    t0 = time.perf_counter()
    for v, f in meshes:
        simulate(v, f, config, mode=mode)
    return 1000.0 * (time.perf_counter() - t0) / len(meshes)


def _track(data_dir) -> str:
    """``heldout`` for a held-out build (the simulator is the ranked track's reference point
    too), else ``public``."""
    from benchmark.scoring import heldout

    try:
        follows = heldout.recipe_of(data_dir)
    except (OSError, ValueError):
        return "public"
    return "heldout" if follows is not None and follows[1] != follows[0].seed else "public"


def record(
    data_dir: str | os.PathLike,
    entries_dir: str | os.PathLike = DEFAULT_ENTRIES,
    ms_per_mesh: float | None = None,
    hardware_text: str | None = None,
):
    """Write (or replace) the simulator entry of a dataset; return its path."""
    with BenchmarkData(data_dir) as data:
        metrics, scored = mesh_physics_scores(data)
        fingerprint = data.fingerprint
        timed = ms_per_mesh is None
        if timed:
            ms_per_mesh = measure_ms_per_mesh(data)
        config = radar_config(data)
        dataset = dataset_record(data)  # no version field (as simulator entries always were)
    name = f"radar_sim on the representation mesh {config.get('name', '')}".strip()
    entry = {
        "entry_version": ENTRY_VERSION,
        "id": f"physics-{fingerprint[:12]}",
        "kind": "simulator",
        "origin": "simulator",
        "track": _track(data_dir),
        "name": name,
        "link": None,
        "params": None,
        "dataset": dataset,
        "metrics": metrics,
        "complex_mse_source": f"{MEASURED}, {scored} test objects",
        "speed": {
            **(
                speed_block(ms_per_mesh)
                if timed
                else {**speed_block(ms_per_mesh, self_reported=True), "hardware": hardware_text}
            ),
            "source": "measured by leaderboard simulator" if timed else "given by hand",
        },
        "submitted": utc_timestamp(),
        "sample": None,
    }
    validate_entry(entry)  # before the lock creates the folder
    with entries_lock(entries_dir):
        return write_entry(entries_dir, entry, replace=True)
