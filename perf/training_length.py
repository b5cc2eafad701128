"""Are the CPU table's baselines short of training? Complex MSE against epochs, and references.

    python perf/training_length.py DATA_DIR --work DIR [--rows invariant-basic,direct-basic]
        [--epochs 8,32,128] [--seeds 0,1,2] [--jobs 2]

Trains each (row, epochs, seed) with the cpu preset's model and every setting but ``epochs``
(``benchmark train``, one torch thread per job, ``--jobs`` at once) and evaluates it on the
test split. Finished runs are kept under ``--work`` (``<row>-e<epochs>/seed-<s>/``) and reused,
so an interrupted sweep resumes. The summary covers every run under ``--work``: per (row,
epochs), Complex MSE averaged over seeds per test object, with its 95% interval, and its
paired difference to ``class-scale-nn``, to the same row's fewest epochs and to
``blind-basic`` at the same epochs (what reading the mesh wins), the chosen
(best validation) epoch and the training time. Writes perf/results/training_length.json and
prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from basic_shapes.infra import atomic_path
from benchmark.reproduction.presets import PRESETS
from benchmark.reproduction.runner import _train_flags, row_config
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.metrics import metric_block
from benchmark.scoring.references import reference_scores, summary
from benchmark.scoring.uncertainty import paired, verdict

RESULTS = Path(__file__).parent / "results"


def run_one(data: str, work: Path, row: str, epochs: int, seed: int) -> Path:
    """Train and evaluate one (row, epochs, seed) unless its results exist; its folder."""
    folder = work / f"{row}-e{epochs}" / f"seed-{seed}"
    if (folder / "results.json").is_file():
        return folder
    embedding, regime = row.split("-", 1)
    cfg = replace(row_config(PRESETS["cpu"], embedding, regime, seed, None), epochs=epochs)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "train.log", "w") as log:
        subprocess.run(
            [
                sys.executable,
                "-m",
                "benchmark.cli",
                "train",
                "--data",
                data,
                "--out",
                str(folder / "checkpoint"),
                "--results",
                str(folder / "results.json"),
                "--quiet",
                *_train_flags(cfg),
            ],
            check=True,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    print(f"{row} epochs {epochs} seed {seed}: done", flush=True)
    return folder


def collect(work: Path) -> dict:
    """{(row, epochs): [(results, checkpoint config) per seed]} of every finished run."""
    runs: dict = {}
    for path in sorted(work.glob("*-e*/seed-*/results.json")):
        row, epochs = path.parent.parent.name.rsplit("-e", 1)
        config = json.loads((path.parent / "checkpoint" / "config.json").read_text())
        runs.setdefault((row, int(epochs)), []).append((json.loads(path.read_text()), config))
    return runs


def summarize(data: BenchmarkData, runs: dict) -> list[dict]:
    _, scorers = reference_scores(data)
    ref = scorers["class-scale-nn"].per_object()
    out, per_object = [], {}
    order = sorted(runs, key=lambda k: (k[0] != "blind-basic", k))  # blind first: others pair
    for row, epochs in order:
        seeds = runs[row, epochs]
        po = {
            k: np.array(
                [[np.nan if x is None else x for x in r["per_object"][k]] for r, _ in seeds],
                np.float64,
            ).mean(axis=0)
            for k in ("simple_mse", "complex_mse", "variation_mse")
        }
        po["class_index"] = np.array(seeds[0][0]["per_object"]["class_index"])
        if seeds[0][0]["per_object"]["object_id"] != ref["object_id"].tolist():
            raise ValueError(f"{row} epochs {epochs}: scored on other test objects")
        per_object[row, epochs] = po
        first = min(e for r, e in runs if r == row)
        vs_ref = paired(po["complex_mse"], ref["complex_mse"], po["class_index"])
        vs_first = (
            paired(po["complex_mse"], per_object[row, first]["complex_mse"], po["class_index"])
            if epochs != first
            else None
        )
        blind = per_object.get(("blind-basic", epochs)) if row != "blind-basic" else None
        vs_blind = (
            None
            if blind is None
            else paired(po["complex_mse"], blind["complex_mse"], po["class_index"])
        )
        block = metric_block(po, po["class_index"])
        out.append(
            {
                "row": row,
                "epochs": epochs,
                "seeds": len(seeds),
                **{k: block[k] for k in ("complex_mse", "complex_mse_ci", "variation_mse")},
                "vs_class_scale_nn": {**vs_ref, "verdict": verdict(vs_ref["ci"])},
                "vs_fewest_epochs": None
                if vs_first is None
                else {"epochs": first, **vs_first, "verdict": verdict(vs_first["ci"])},
                "vs_blind": None
                if vs_blind is None
                else {**vs_blind, "verdict": verdict(vs_blind["ci"])},
                "selected_epoch": [c["selection"]["epoch"] + 1 for _, c in seeds],
                "train_seconds": float(np.mean([c["train_seconds"] for _, c in seeds])),
            }
        )
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--work", type=Path, required=True, help="runs are kept (and reused) here")
    parser.add_argument("--rows", default="invariant-basic,direct-basic")
    parser.add_argument("--epochs", default="8,32,128")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS / "training_length.json")
    args = parser.parse_args(argv)
    todo = [
        (row, int(e), int(s))
        for row in args.rows.split(",")
        for e in args.epochs.split(",")
        for s in args.seeds.split(",")
    ]
    with ThreadPoolExecutor(args.jobs) as pool:
        list(pool.map(lambda t: run_one(args.data, args.work, *t), todo))
    with BenchmarkData(args.data) as data:
        rows = summarize(data, collect(args.work))
        refs = {k: summary(v)["complex_mse"] for k, v in reference_scores(data)[1].items()}
        description = data.describe()
    print(description)
    print("references, Complex MSE: " + ", ".join(f"{k} {v:.1f}" for k, v in refs.items()))
    print(
        f"{'row':18} {'epochs':>6} {'seeds':>5} {'Complex MSE':>22} {'vs class-scale-nn':>24} "
        f"{'vs fewest epochs':>24} {'vs blind-basic':>24} {'best epoch':>12} {'train s':>8}"
    )

    def cell(p):
        return "-" if p is None else f"{p['diff']:+.1f} [{p['ci'][0]:+.1f}, {p['ci'][1]:+.1f}]"

    for r in rows:
        print(
            f"{r['row']:18} {r['epochs']:6d} {r['seeds']:5d} {r['complex_mse']:7.1f} "
            f"[{r['complex_mse_ci'][0]:5.1f}, {r['complex_mse_ci'][1]:5.1f}] "
            f"{cell(r['vs_class_scale_nn']):>24} {cell(r['vs_fewest_epochs']):>24} "
            f"{cell(r['vs_blind']):>24} {','.join(map(str, r['selected_epoch'])):>12} "
            f"{r['train_seconds']:8.0f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out) as tmp:
        tmp.write_text(
            json.dumps(
                {"data": description, "references_complex_mse": refs, "rows": rows}, indent=1
            )
            + "\n"
        )


if __name__ == "__main__":
    main()
