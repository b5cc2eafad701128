"""Milliseconds per test mesh to score a predictions file, and to run a model end to end.

    python perf/scoring_speed.py [--objects-per-class 20] [--grid 61 21 107]

On the tests' analytic fixture dataset (tests/benchmark_fixture.py: 3 meshes per object,
the full xband-v1 grid by default), side by side:
  score     scoring.protocol.score_predictions (validate + stream the file, object by object)
  evaluate  scoring.evaluate.evaluate with NearestScaleModel: read meshes, predict, write the
            predictions file, score it
and the time these would take on the paper's test split (300 objects x 100 meshes).
Writes perf/results/scoring_speed.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from basic_shapes.infra import hardware
from benchmark.scoring.evaluate import evaluate
from benchmark.scoring.protocol import load_model, score_predictions
from benchmark_fixture import make_dataset

PAPER_TEST_MESHES = 300 * 100


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--objects-per-class", type=int, default=20)
    ap.add_argument(
        "--grid", type=int, nargs=3, default=[61, 21, 107], metavar=("ASPECT", "ROLL", "RANGE")
    )
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "scoring_speed.json"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data = make_dataset(
            Path(tmp) / "data",
            objects_per_class=args.objects_per_class,
            n_test_per_class=args.objects_per_class // 2,
            grid=tuple(args.grid),
        )
        preds = Path(tmp) / "preds.h5"
        model = load_model("benchmark.scoring.protocol:NearestScaleModel", {"data_dir": str(data)})
        t0 = time.perf_counter()
        results = evaluate(data, model=model, write_predictions=preds, progress=False)
        t_eval = time.perf_counter() - t0
        t0 = time.perf_counter()
        score_predictions(data, preds)
        t_score = time.perf_counter() - t0
    n = results["metrics"]["n_meshes"]
    rows = [
        {
            "step": step,
            "ms_per_mesh": round(1000 * t / n, 3),
            "paper_test_split_s": round(t / n * PAPER_TEST_MESHES, 1),
        }
        for step, t in (("score", t_score), ("evaluate", t_eval))
    ]
    print(f"{'step':>10} {'ms/mesh':>9} {'vs score':>9} {'paper test split (s)':>21}")
    for r in rows:
        print(
            f"{r['step']:>10} {r['ms_per_mesh']:>9.3f} "
            f"{r['ms_per_mesh'] / rows[0]['ms_per_mesh']:>8.2f}x "
            f"{r['paper_test_split_s']:>21.1f}"
        )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "grid": args.grid,
                "test_meshes": n,
                "rows": rows,
                "hardware": hardware()["text"],
                "python": platform.python_version(),
            },
            indent=2,
        )
        + "\n"
    )
    print(f"written to {out}")


if __name__ == "__main__":
    main()
