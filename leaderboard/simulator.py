"""The simulator run on the representation meshes: the board's physics reference model.

An object's label is the physics of its analytic primitive (``radar-sim label``); a stored
mesh is only a representation of it. The simulator given a representation mesh is therefore
a model like the others, scored like them: its "predictions" are the physics on each mesh
(``/radar/mesh_response``, from ``radar-sim label --mesh-labels all``), scored by the
benchmark's own ``Scorer`` against the object's label, per class. Simple MSE: physics on
the simple mesh vs the label; Complex MSE: physics on complex meshes vs the label; Variation
MSE: between the two. Test objects whose simple mesh has no physics label are left out; a
dataset with none is refused. Its speed is measured the way the ranked track times an ONNX
model (``measure_ms_per_mesh``: one thread in a child process, every scored test mesh), or
given by hand (``--ms-per-mesh``) when radar_sim is elsewhere.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from tqdm import tqdm

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

MEASURED = "simulator on the representation meshes vs the object's label (its analytic primitive)"


def mesh_physics_scores(data: BenchmarkData, progress: bool = False) -> tuple[dict, int]:
    """(metrics of the simulator on representation meshes, number of test objects scored).

    Every test object with a stored complex-mesh physics (``--mesh-labels``) is scored; where
    its simple mesh's physics was not stored (``sample:K`` draws among all meshes), it is
    simulated here with the labels' config and mode, as ``radar-sim label`` would have."""
    scorer = Scorer(data.class_names)
    test = set(data.object_rows("test").tolist())
    shards = tqdm(data.paths, desc="simulator: score", unit="shard", disable=not progress)
    for k, path in enumerate(shards):
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


def measure_ms_per_mesh(data_dir: str | os.PathLike, progress: bool = False) -> dict:
    """Time ``radar_sim.simulate`` as ``leaderboard evaluate-model`` times an ONNX model: in a
    child process with one thread (``evaluate_model.CHILD_ENV``), on every scored test mesh
    (the OOD meshes included) after one untimed warm-up call, with the dataset's own radar
    config and physics mode. Returns ``{"ms_per_mesh", "n_meshes", "warmup_ms"}``.

    The child reports each mesh on a stdout line (outside the timed calls) for the bar here;
    its stderr goes to a file, not a pipe, so a chatty child cannot block."""
    from leaderboard.evaluate_model import CHILD_ENV

    result = None
    with (
        tempfile.TemporaryFile("w+") as err,
        tqdm(desc="simulator: time", unit="mesh", disable=not progress) as bar,
    ):
        with subprocess.Popen(
            [sys.executable, "-m", "leaderboard.simulator", os.fspath(data_dir)],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
            env={**os.environ, **CHILD_ENV},
        ) as proc:
            for line in proc.stdout:
                message = _message(line)
                if "total" in message:
                    bar.reset(total=message["total"])
                elif "done" in message:
                    bar.update()
                elif "ms_per_mesh" in message:
                    result = message
        err.seek(0)
        lines = err.read().strip().splitlines()
    if proc.returncode != 0 or result is None:
        raise ValueError(f"{data_dir}: timing the simulator failed: {lines[-1] if lines else ''}")
    return result


def _message(line: str) -> dict:
    try:
        message = json.loads(line)
    except ValueError:
        return {}  # something else printed to stdout
    return message if isinstance(message, dict) else {}


def _time_every_mesh(data_dir: str, report=lambda message: None) -> dict:
    """The child's work (``measure_ms_per_mesh``); ``report`` is called between timed calls."""
    from benchmark.scoring.protocol import scored_mesh_rows
    from radar_sim import RadarConfig, simulate

    with BenchmarkData(data_dir) as data:
        config = RadarConfig(**radar_config(data))
        mode = radar_config(data, options=True).get("mode", "auto")
        rows = scored_mesh_rows(data)
        report({"total": len(rows)})
        t0 = time.perf_counter()
        simulate(*data.mesh(int(rows[0])), config, mode=mode)
        warmup = time.perf_counter() - t0
        total = 0.0
        for row in rows:
            v, f = data.mesh(int(row))
            t0 = time.perf_counter()
            simulate(v, f, config, mode=mode)
            total += time.perf_counter() - t0
            report({"done": 1})
    return {
        "ms_per_mesh": 1000.0 * total / len(rows),
        "n_meshes": len(rows),
        "warmup_ms": 1000.0 * warmup,
    }


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
    progress: bool = False,
):
    """Write (or replace) the simulator entry of a dataset; return its path."""
    with BenchmarkData(data_dir) as data:
        metrics, scored = mesh_physics_scores(data, progress)
        fingerprint, labels = data.fingerprint, data.label_fingerprint
        timed = ms_per_mesh is None
        config = radar_config(data)
        dataset = dataset_record(data)  # no version field (as simulator entries always were)
    timing = measure_ms_per_mesh(data_dir, progress) if timed else None
    if timed:
        ms_per_mesh = timing["ms_per_mesh"]
    name = f"radar_sim on the representation mesh {config.get('name', '')}".strip()
    entry = {
        "entry_version": ENTRY_VERSION,
        "id": f"physics-{fingerprint[:12]}-{labels[:8]}",  # versions can share meshes
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
                speed_block(ms_per_mesh, threads=1)
                if timed
                else {**speed_block(ms_per_mesh, self_reported=True), "hardware": hardware_text}
            ),
            "source": (
                f"measured by leaderboard simulator: one thread in a child process, every "
                f"scored test mesh ({timing['n_meshes']}), as evaluate-model times a model"
            )
            if timed
            else "given by hand",
        },
        "submitted": utc_timestamp(),
        "sample": None,
    }
    validate_entry(entry)  # before the lock creates the folder
    with entries_lock(entries_dir):
        return write_entry(entries_dir, entry, replace=True)


def _print(message: dict) -> None:
    print(json.dumps(message), flush=True)


if __name__ == "__main__":  # the timing child of measure_ms_per_mesh
    _print(_time_every_mesh(sys.argv[1], report=_print))
