"""Does class + scale still solve the hidden-parameter track? The reference rows beside the oracle.

    python perf/hidden_references.py DATA_DIR [--out perf/results/hidden_references.json]

DATA_DIR is a labelled dataset (for example ``benchmark dataset hidden-cpu-v1``). Prints the
four reference rows of benchmark.references (what ``benchmark evaluate`` shows) and the
``oracle`` (benchmark.references.OracleReference: nearest training objects in log scale and
the hidden shape parameters), each with Simple / Complex MSE and 95% intervals over the test
objects, and the paired oracle - class-scale-nn difference. Writes a JSON beside the table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from benchmark.data import BenchmarkData
from benchmark.references import REFERENCES, OracleReference, References, compare, summary

RESULTS = Path(__file__).parent / "results"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--out", type=Path, default=RESULTS / "hidden_references.json")
    args = parser.parse_args(argv)
    with BenchmarkData(args.data) as data:
        refs = References(data)
        scorers = refs.score()
        oracle = OracleReference(refs)
        scorers["oracle"] = oracle.score()
        rows = {name: summary(scorers[name]) for name in (*REFERENCES, "oracle")}
        paired = compare(scorers["oracle"].per_object(), scorers["class-scale-nn"].per_object())
        print(data.describe())
    print(f"hidden parameters: {', '.join(oracle.keys) or 'none'}")
    print(f"{'reference':15} {'Simple MSE':>24} {'Complex MSE':>24} {'objects':>8}")
    for name, r in rows.items():
        cells = [f"{r[m]:7.2f} [{r[m + '_ci'][0]:6.2f}, {r[m + '_ci'][1]:6.2f}]"
                 if r[m] is not None else "-" for m in ("simple_mse", "complex_mse")]
        print(f"{name:15} {cells[0]:>24} {cells[1]:>24} {r['n_objects']:8d}")
    for m, p in paired.items():
        print(f"oracle - class-scale-nn, {m}: {p['diff']:+.2f} [{p['ci'][0]:+.2f}, "
              f"{p['ci'][1]:+.2f}] ({p['verdict']})")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps({"data": str(args.data), "hidden": oracle.keys, "rows": rows,
                               "oracle_vs_class_scale_nn": paired}, indent=1) + "\n")
    tmp.replace(args.out)


if __name__ == "__main__":
    main()
