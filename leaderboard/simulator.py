"""The physics simulator itself as the reference point of the speed-vs-error chart.

Its Complex MSE is the physics-level variation between meshes of one object: for every test
object with per-mesh labels (``/radar/variant_response``, from ``radar-sim label --variants``),
the MSE in the benchmark's dB target between the object's label (its simple mesh) and the
label of each complex mesh, averaged as the benchmark averages (per object, then over objects).
Its Simple MSE is 0 (the labels are its own output) and its Variation MSE equals its Complex
MSE. Without per-mesh labels the point is drawn at 0, and the entry says so
(``complex_mse_source``). Its speed is measured by timing ``radar_sim.simulate`` on the
example object's meshes, or given by hand (``--ms-per-mesh``) when radar_sim is elsewhere.
"""

from __future__ import annotations

import json
import os
import time
from datetime import datetime, timezone

import numpy as np

from basic_shapes.shards import Shard
from benchmark.data import BenchmarkData, db_target
from benchmark.evaluate import speed_block
from benchmark.metrics import mse
from leaderboard import example
from leaderboard.store import DEFAULT_ENTRIES, ENTRY_VERSION, write_entry

MEASURED = "variation between per-mesh physics labels of one object"
ASSUMED_ZERO = "no per-mesh physics labels in the dataset: drawn at 0"


def physics_variation(data: BenchmarkData) -> tuple[dict, str]:
    """(per-class and overall metrics of the simulator, source of its Complex MSE)."""
    per_object: dict[int, list[float]] = {}
    for k, path in enumerate(data.paths):
        with Shard(path) as shard:
            g = shard.file["radar"]
            if "variant_mesh_index" not in g:
                continue
            in_shard = np.flatnonzero(data.meshes["shard"] == k)
            by_row = dict(zip(data.meshes["row"][in_shard].tolist(), in_shard.tolist()))
            for j, row in enumerate(g["variant_mesh_index"][()]):
                mesh = by_row[int(row)]
                obj = int(data.meshes["object"][mesh])
                if data.objects["split"][obj] == "test" and data.meshes["variant"][mesh] > 0:
                    per_object.setdefault(obj, []).append(
                        mse(data.target(obj), db_target(g["variant_response"][j])))
    source = MEASURED if per_object else ASSUMED_ZERO
    values = {obj: float(np.mean(v)) for obj, v in per_object.items()}

    def block(objs: np.ndarray) -> dict:
        v = [values[o] for o in objs if o in values]
        x = float(np.mean(v)) if v else 0.0
        return {"simple_mse": 0.0, "complex_mse": x, "variation_mse": x, "n_objects": len(objs)}

    test = data.object_rows("test")
    metrics = {**block(test), "no_skill": False, "per_class": {}}
    for c, name in enumerate(data.class_names):
        objs = test[data.objects["class_index"][test] == c]
        if len(objs):
            metrics["per_class"][name] = block(objs)
    return metrics, source


def radar_attrs(data: BenchmarkData) -> dict:
    with Shard(data.paths[0]) as s:
        return dict(s.file["radar"].attrs)


def measure_ms_per_mesh(data: BenchmarkData, repeats: int = 3) -> float:
    """Median wall time of ``radar_sim.simulate`` over the example object's meshes.

    Uses the dataset's own radar config and physics mode; the first call (warm-up: imports,
    Embree scene set-up) is not counted.
    """
    from radar_sim import RadarConfig, simulate

    attrs = radar_attrs(data)
    config = RadarConfig(**json.loads(attrs["config"]))
    mode = json.loads(attrs.get("options", "{}")).get("mode", "auto")
    meshes = [data.mesh(int(r)) for r in data.meshes_of(example.example_object(data))]
    simulate(*meshes[0], config, mode=mode)
    times = []
    for _ in range(repeats):
        for v, f in meshes:
            t0 = time.perf_counter()
            simulate(v, f, config, mode=mode)
            times.append(time.perf_counter() - t0)
    return 1000.0 * float(np.median(times))


def record(data_dir: str | os.PathLike, entries_dir: str | os.PathLike = DEFAULT_ENTRIES,
           ms_per_mesh: float | None = None, hardware_text: str | None = None):
    """Write (or replace) the simulator entry of a dataset; return its path."""
    with BenchmarkData(data_dir) as data:
        metrics, source = physics_variation(data)
        fingerprint = data.fingerprint
        timed = ms_per_mesh is None
        if timed:
            ms_per_mesh = measure_ms_per_mesh(data)
        config = json.loads(radar_attrs(data).get("config", "{}"))
        dataset = {"fingerprint": fingerprint, "classes": data.class_names,
                   "test_objects": len(data.object_rows("test")),
                   "test_meshes": len(data.mesh_rows("test"))}
    name = f"radar_sim {config.get('name', '')}".strip()
    entry = {
        "entry_version": ENTRY_VERSION, "id": f"physics-{fingerprint[:12]}", "kind": "simulator",
        "name": name, "link": None, "params": None, "dataset": dataset, "metrics": metrics,
        "complex_mse_source": source,
        "speed": {**(speed_block(ms_per_mesh) if timed else
                     {**speed_block(ms_per_mesh, self_reported=True), "hardware": hardware_text}),
                  "source": "measured by leaderboard simulator" if timed else "given by hand"},
        "submitted": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "sample": None,
    }
    return write_entry(entries_dir, entry, replace=True)
