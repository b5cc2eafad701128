"""A bounded bit-flip fuzzer over shards, predictions files and results JSONs (fixed seed).

Each case flips one bit of one file: most often inside a randomly chosen HDF5 dataset's stored
bytes, sometimes anywhere in the file (metadata, attributes, free space). The readers that
trust these files then run in-process exactly as the CLIs call them; a case passes when it is
refused with the project's own error naming the file (``ShardError``, ``PredictionsError``,
``ResultsError``, each a ValueError the CLI boundary prints as one line), or when everything
read is byte-identical to the unflipped file's (the bit was in unused space). Any other
exception (a KeyError, an h5py error without the file, a RecursionError...) is a failure: the
CLI would print "internal error". ``FUZZ_CASES`` scales the budget (default: 90 shard, 40
predictions and 40 results cases, a few seconds).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from basic_shapes.shards import Shard, ShardError, list_shards
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.protocol import (
    PredictionsError,
    ResultsError,
    load_results,
    score_predictions,
    write_predictions,
)
from benchmark_fixture import make_dataset

SEED = 20261126
SCALE = float(os.environ.get("FUZZ_CASES", "1"))


def read_shards(directory: Path) -> str:
    """Everything the readers hand out, hashed: fingerprints, objects, meshes, labels."""
    h = hashlib.sha256()
    with BenchmarkData(directory) as data:
        h.update((data.fingerprint + data.label_fingerprint).encode())
    for p in list_shards(directory):
        with Shard(p) as s:
            s.verify()
            s.verify_labels()
            for value in s.objects().values():
                h.update(np.ascontiguousarray(value).tobytes())
            for i in range(s.n_meshes):
                for a in s.mesh(i):
                    h.update(a.tobytes())
            for k in range(s.n_objects):
                h.update(s.radar.response(k).tobytes())
    return h.hexdigest()


def dataset_regions(path: Path) -> list[tuple[str, int, int]]:
    """(name, byte offset, size) of every contiguous dataset stored in the file."""
    regions = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            offset = obj.id.get_offset()
            size = obj.id.get_storage_size()
            if offset is not None and size:
                regions.append((name, offset, size))

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return regions


def flip(path: Path, rng: np.random.Generator, regions) -> str:
    """Flip one bit: in a random dataset's bytes (3 cases in 4) or anywhere in the file."""
    data = bytearray(path.read_bytes())
    if regions and rng.random() < 0.75:
        name, offset, size = regions[rng.integers(len(regions))]
        at = offset + int(rng.integers(size))
    else:
        name, at = "(anywhere)", int(rng.integers(len(data)))
    data[at] ^= 1 << int(rng.integers(8))
    path.write_bytes(bytes(data))
    return f"{name} byte {at}"


def check(case: str, path: Path, run, expected, refusals) -> str | None:
    """None if ``run()`` refuses naming ``path`` or gives ``expected``; else what went wrong."""
    try:
        got = run()
    except refusals as exc:
        named = path.name in str(exc) or str(path.parent) in str(exc)  # the file or its dataset
        return None if named else f"{case}: refusal without the file: {exc}"
    except Exception as exc:  # any other exception is the finding
        return f"{case}: {type(exc).__name__}: {str(exc)[:120]}"
    return None if got == expected else f"{case}: accepted with different content"


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    data = make_dataset(root / "data", objects_per_class=2, n_test_per_class=1, n_shards=1)
    with BenchmarkData(data) as d:
        rows = d.mesh_rows("test")
        targets = np.stack([d.target(int(d.meshes["object"][r])) for r in rows]) + 1.0
        write_predictions(
            root / "pred.h5",
            d.fingerprint,
            d.meshes["uid"][rows],
            targets,
            label_fingerprint=d.label_fingerprint,
        )
    from benchmark.scoring.evaluate import evaluate
    from benchmark.scoring.protocol import write_results

    write_results(
        root / "results.json", evaluate(data, predictions=root / "pred.h5", progress=False)
    )
    return root


def test_flipped_shards_are_refused_or_read_identically(clean, tmp_path):
    rng = np.random.default_rng(SEED)
    source = clean / "data"
    expected = read_shards(source)
    regions = dataset_regions(source / "shard-00000.h5")
    failures = []
    n = int(90 * SCALE)
    for i in range(n):
        work = tmp_path / f"case-{i}"
        shutil.copytree(source, work)
        shard = work / "shard-00000.h5"
        where = flip(shard, rng, regions)
        problem = check(
            f"shard case {i} ({where})", shard, lambda w=work: read_shards(w), expected, ShardError
        )
        if problem:
            failures.append(problem)
        shutil.rmtree(work)
    assert not failures, f"{len(failures)} of {n} cases:\n" + "\n".join(failures[:10])


def test_flipped_predictions_are_refused_or_score_identically(clean, tmp_path):
    rng = np.random.default_rng(SEED + 1)
    source = clean / "pred.h5"
    data = clean / "data"

    def scored(path):
        return json.dumps(score_predictions(data, path), sort_keys=True, default=str)

    expected = scored(source)
    regions = dataset_regions(source)
    failures = []
    n = int(40 * SCALE)
    for i in range(n):
        work = tmp_path / f"pred-{i}.h5"
        shutil.copyfile(source, work)
        where = flip(work, rng, regions)
        problem = check(
            f"predictions case {i} ({where})",
            work,
            lambda w=work: scored(w),
            expected,
            (PredictionsError, ShardError),
        )
        # predictions carry no hash of their own: a flipped value is another prediction, scored
        if problem and "accepted with different content" not in problem:
            failures.append(problem)
    assert not failures, f"{len(failures)} of {n} cases:\n" + "\n".join(failures[:10])


def test_flipped_results_are_refused_or_load_identically(clean, tmp_path):
    rng = np.random.default_rng(SEED + 2)
    source = clean / "results.json"
    expected = json.dumps(load_results(source), sort_keys=True)
    failures = []
    n = int(40 * SCALE)
    for i in range(n):
        work = tmp_path / f"results-{i}.json"
        shutil.copyfile(source, work)
        where = flip(work, rng, [])
        problem = check(
            f"results case {i} ({where})",
            work,
            lambda w=work: json.dumps(load_results(w), sort_keys=True),
            expected,
            ResultsError,
        )
        # a flipped digit is a different but valid result: load_results cannot know; the
        # board re-scores it against the predictions (tests/test_leaderboard.py)
        if problem and "accepted with different content" not in problem:
            failures.append(problem)
    assert not failures, f"{len(failures)} of {n} cases:\n" + "\n".join(failures[:10])
