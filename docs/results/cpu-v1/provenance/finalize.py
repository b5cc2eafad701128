"""Assemble the cpu-v1 table on the re-recorded cpu-v1 (390cf5dc): the 22 runs re-scored by
patch_rescore.py (rescore2/) and the 17 trained on it by ``benchmark reproduce`` (run-rebuilt/)
into one ``benchmark reproduce`` layout (final/), re-time every row's first seed alone
(benchmark.runner.time_alone, the same code as reproduce), publish the rows for the board.
The table is then ``benchmark report --preset cpu --data data-rebuilt --out final``.

usage: python finalize.py   (in /work/cpurun-out, with nothing else running)
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from types import SimpleNamespace

from benchmark.presets import ROWS
from benchmark.protocol import load_results
from benchmark.runner import TIMED_ALONE, checkpoint_dir, publish_row, row_files, time_alone

HERE = Path(".").resolve()
FINAL = HERE / "final"
SOURCES = [(HERE / "rescore2", HERE / "run"), (HERE / "run-rebuilt", HERE / "run-rebuilt")]


def main() -> None:
    names = [f"{e}-{r}" for e, r in ROWS]
    for name in names:
        for seed in (0, 1, 2):
            found = [(r, c) for r, c in SOURCES if row_files(r, name, seed)[0].is_file()]
            if not found:
                raise SystemExit(f"{name}/seed-{seed}: no results")
            results_root, ckpt_root = found[0]
            src, src_preds = row_files(results_root, name, seed)
            dst, dst_preds = row_files(FINAL, name, seed)
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, dst)
            dst_preds.unlink(missing_ok=True)
            os.link(src_preds, dst_preds)
            ck = checkpoint_dir(FINAL, name, seed)
            ck.parent.mkdir(parents=True, exist_ok=True)
            if not ck.exists():
                ck.symlink_to(checkpoint_dir(ckpt_root, name, seed))
    jobs = []
    for name in names:
        record = {"results": load_results(row_files(FINAL, name, 0)[0])}
        # every first seed is re-timed here, alone: some were timed while the re-scoring ran
        record["results"]["speed"]["hardware"] = record["results"]["speed"]["hardware"].replace(
            TIMED_ALONE, "timed under load"
        )
        jobs.append((SimpleNamespace(name=name, seed=0), record))
    time_alone(FINAL, HERE / "data-rebuilt", jobs, threads=1)
    for name in names:
        publish_row(FINAL, name, [0, 1, 2])
    check_sample("direct-basic")


def check_sample(name: str) -> None:
    """The sampled timing against the full test split, one row, alone (timing-check.json)."""
    import json
    import time

    from benchmark.data import BenchmarkData
    from benchmark.evaluate import face_count_batches
    from benchmark.models.checkpoint import CheckpointModel
    from benchmark.protocol import scored_mesh_rows

    model = CheckpointModel(checkpoint_dir(FINAL, name, 0))
    with BenchmarkData(HERE / "data-rebuilt") as data:
        rows = scored_mesh_rows(data)
        batches = [data.batch(c) for c in face_count_batches(data, rows, 16)]
    model.predict(batches[0])
    t0 = time.perf_counter()
    for b in batches:
        model.predict(b)
    full = 1000.0 * (time.perf_counter() - t0) / len(rows)
    sampled = load_results(row_files(FINAL, name, 0)[0])["speed"]["ms_per_mesh"]
    (HERE / "timing-check.json").write_text(
        json.dumps(
            {
                "row": name,
                "full_ms_per_mesh": full,
                "n_full": len(rows),
                "sampled_ms_per_mesh": sampled,
                "ratio": sampled / full,
            },
            indent=1,
        )
    )
    print(
        f"{name}: sampled {sampled:.1f} ms/mesh, full split {full:.1f} (ratio {sampled / full:.3f})"
    )


if __name__ == "__main__":
    main()
