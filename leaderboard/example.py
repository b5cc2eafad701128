"""The example object of a dataset and the small dB images an entry keeps of it.

Every entry of one dataset samples the same object (the test object with the lowest id, its
simple mesh and its complex mesh with the most faces), so the site can show the models'
predictions side by side with the physics response without reading the dataset again.
Images are aspect x range at the first roll angle, strided to at most ``MAX_SIDE`` points per
axis and rounded to 0.1 dB: a few kilobytes per entry.
"""

from __future__ import annotations

import numpy as np

from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.protocol import Predictions

MAX_SIDE = 32


def example_object(data: BenchmarkData) -> int:
    """Global object row of the test object with the lowest id."""
    rows = data.object_rows("test")
    if not len(rows):
        raise ValueError(f"{data.directory}: dataset has no test-split objects")
    return int(rows[np.argmin(data.objects["id"][rows])])


def _image(db: np.ndarray, sa: int, sr: int) -> list[list[float]]:
    return np.round(np.asarray(db, np.float64)[::sa, 0, ::sr], 1).tolist()


def sample(data: BenchmarkData, predictions: Predictions) -> dict:
    """The example object's physics response and these predictions for two of its meshes."""
    obj = example_object(data)
    rows = data.meshes_of(obj)  # simple mesh first
    faces = data.meshes["n_faces"][rows]
    picks = [rows[0]] + ([rows[1 + int(np.argmax(faces[1:]))]] if len(rows) > 1 else [])
    predicted = list(predictions.read(data.meshes["uid"][picks]))
    if len(picks) == 1:  # no complex mesh: show the simple mesh twice
        picks, predicted = picks * 2, predicted * 2
    uids = data.meshes["uid"][picks]
    physics = data.target(obj)
    sa, sr = (max(1, -(-n // MAX_SIDE)) for n in physics.shape[::2])  # ceil(n / MAX_SIDE)
    return {
        "object_id": int(data.objects["id"][obj]),
        "class": data.class_names[int(data.objects["class_index"][obj])],
        "roll_deg": float(data.grid["roll_deg"][0]),
        "aspect_deg": np.round(data.grid["aspect_deg"][::sa], 3).tolist(),
        "range_m": np.round(data.grid["range_m"][::sr], 4).tolist(),
        "physics_db": _image(physics, sa, sr),
        "meshes": [
            {
                "mesh_uid": int(u),
                "variant": int(data.meshes["variant"][r]),
                "n_faces": int(data.meshes["n_faces"][r]),
                "predicted_db": _image(p, sa, sr),
            }
            for u, r, p in zip(uids, picks, predicted)
        ],
    }
