"""Re-score the cpu-v1 checkpoints trained on the first build (mesh f304e7b4) on the
re-recorded cpu-v1 (mesh 390cf5dc) without predicting all 2,850 test meshes again.

The two builds differ only in some OOD test meshes (MeshLab's remeshers depended on memory
layout; basic_shapes/meshlab_child.py). A model's prediction for a mesh depends only on what
``BenchmarkData.batch`` gives it, so: compare that per mesh uid between the builds, predict
only the meshes that differ (the harness's CheckpointModel, face-count batches), keep the run's
predictions for the others, write a predictions file for 390cf5dc and score it with the
harness (``benchmark.evaluate.evaluate(predictions=...)``). Validated against full
re-evaluations (``--check``).

usage: python patch_rescore.py OLD_DATA NEW_DATA RUN_DIR OUT_DIR [--check FULL_RESULTS_DIR]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import h5py
import numpy as np
from benchmark.data import BenchmarkData
from benchmark.evaluate import evaluate, face_count_batches
from benchmark.models.checkpoint import CheckpointModel
from benchmark.protocol import PredictionsWriter, load_results, scored_mesh_rows, write_results


def batches_by_uid(data: BenchmarkData) -> dict[int, tuple]:
    rows = scored_mesh_rows(data)
    out = {}
    for start in range(0, len(rows), 256):
        chunk = rows[start : start + 256]
        b = data.batch(chunk)
        for k, row in enumerate(chunk):
            out[int(data.meshes["uid"][row])] = (
                np.asarray(b["vertices"][k]),
                np.asarray(b["faces"][k]),
                np.asarray(b["scale_m"][k]),
            )
    return out


def changed_uids(old: BenchmarkData, new: BenchmarkData) -> list[int]:
    a, b = batches_by_uid(old), batches_by_uid(new)
    if set(a) != set(b):
        raise SystemExit("the two builds score different mesh uids")
    return sorted(
        u
        for u in b
        if any(x.shape != y.shape or not np.array_equal(x, y) for x, y in zip(a[u], b[u]))
    )


def main() -> None:
    old_dir, new_dir, run, out = (Path(x) for x in sys.argv[1:5])
    check = Path(sys.argv[6]) if len(sys.argv) > 6 and sys.argv[5] == "--check" else None
    with BenchmarkData(old_dir) as old, BenchmarkData(new_dir) as new:
        changed = changed_uids(old, new)
        rows = scored_mesh_rows(new)
        uid_of_row = {int(new.meshes["uid"][r]): int(r) for r in rows}
        changed_rows = np.array([uid_of_row[u] for u in changed])
        print(
            f"{len(changed)} of {len(rows)} scored meshes differ between the builds "
            f"(objects {sorted({u // 1000 for u in changed})})",
            flush=True,
        )
        ckpts = sorted(run.glob("checkpoints/*/seed-*/config.json"))
        for cfg_path in ckpts:
            ckpt = cfg_path.parent
            row, seed = ckpt.parent.name, int(ckpt.name.split("-")[1])
            dest = out / "results" / row / f"seed-{seed}"
            if (dest / "results.json").is_file():
                continue
            old_preds = run / "results" / row / f"seed-{seed}" / "predictions.h5"
            dest.mkdir(parents=True, exist_ok=True)
            if not old_preds.is_file():  # its evaluation in the run was interrupted
                record = evaluate(
                    new_dir,
                    model=CheckpointModel(ckpt),
                    train_seed=seed,
                    write_predictions=dest / "predictions.h5",
                    progress=False,
                )
                write_results(dest / "results.json", record)
                print(
                    f"{row}/seed-{seed}: evaluated in full, complex "
                    f"{record['metrics']['complex_mse']:.4f}",
                    flush=True,
                )
                continue
            with h5py.File(old_preds, "r") as f:
                if f.attrs["dataset_fingerprint"] != old.fingerprint:
                    raise SystemExit(f"{old_preds}: not made for {old_dir}")
                kept = dict(zip(f["mesh_uid"][:].tolist(), f["target_db"][:]))
            model = CheckpointModel(ckpt)
            for chunk in face_count_batches(new, changed_rows, 16):
                for u, p in zip(new.meshes["uid"][chunk], model.predict(new.batch(chunk))):
                    kept[int(u)] = np.asarray(p, np.float32)
            with PredictionsWriter(
                dest / "predictions.h5",
                new.fingerprint,
                len(rows),
                new.target_shape,
                label_fingerprint=new.label_fingerprint,
            ) as w:
                uids = new.meshes["uid"][rows]
                w.write(uids, np.stack([kept[int(u)] for u in uids]))
            before = load_results(run / "results" / row / f"seed-{seed}" / "results.json")
            record = evaluate(
                new_dir,
                predictions=dest / "predictions.h5",
                overrides=dict(before["model"]),
                train_seed=seed,
                progress=False,
            )
            record["speed"] = before["speed"]  # the same checkpoint's timing in the run
            write_results(dest / "results.json", record)
            m = record["metrics"]
            print(
                f"{row}/seed-{seed}: complex {m['complex_mse']:.4f} (first build "
                f"{before['metrics']['complex_mse']:.4f}), ood complex "
                f"{m['ood_complex_mse']:.4f} (first build "
                f"{before['metrics']['ood_complex_mse']:.4f})",
                flush=True,
            )
            if check and (check / row / f"seed-{seed}" / "results.json").is_file():
                full = load_results(check / row / f"seed-{seed}" / "results.json")
                diff = max(
                    abs(m[k] - full["metrics"][k])
                    for k in (
                        "simple_mse",
                        "complex_mse",
                        "variation_mse",
                        "ood_complex_mse",
                        "ood_variation_mse",
                    )
                )
                with (
                    h5py.File(check / row / f"seed-{seed}" / "predictions.h5", "r") as a,
                    h5py.File(dest / "predictions.h5", "r") as b,
                ):
                    pa = dict(zip(a["mesh_uid"][:].tolist(), a["target_db"][:]))
                    pb = dict(zip(b["mesh_uid"][:].tolist(), b["target_db"][:]))
                    pdiff = max(float(np.abs(pa[u] - pb[u]).max()) for u in pa)
                print(
                    f"  check against the full re-evaluation: metrics differ by at most "
                    f"{diff:.2e} dB², predictions by at most {pdiff:.2e} dB",
                    flush=True,
                )
                json.dump(
                    {
                        "row": row,
                        "seed": seed,
                        "metric_max_abs_diff": diff,
                        "prediction_max_abs_diff_db": pdiff,
                    },
                    open(out / f"check-{row}-{seed}.json", "w"),
                )


if __name__ == "__main__":
    main()
