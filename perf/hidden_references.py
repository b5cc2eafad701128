"""Does class + scale still solve the hidden-parameter track? The reference rows beside the oracle.

    python perf/hidden_references.py DATA_DIR [--out perf/results/hidden_references.json]

DATA_DIR is a labelled dataset (for example ``benchmark dataset hidden-cpu-v3``). Prints the
four reference rows of benchmark.scoring.references (what ``benchmark evaluate`` shows) and the
``oracle`` (benchmark.scoring.references.oracle_row, also in ``benchmark report``'s table: nearest
training objects in log scale and the hidden shape parameters), each with Simple / Complex
MSE and 95% intervals over the test objects, and the paired oracle - class-scale-nn
difference. ``--floor N`` adds the error floor of any predictor blind to the hidden
parameters, per class and overall: each test object's label against the mean target over N
values of its class's parameter spread over its interval (``analytic.HIDDEN``: the frustum's
top ratio, the rounded box's edge radius), simulated at the object's exact scale with the
dataset's own radar config. Under the metric (MSE in dB) and the uniform draw, that mean is
the best prediction knowing class and scale but not the parameter (to the quadrature's
accuracy). Writes a JSON beside the table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from basic_shapes.infra import atomic_path
from benchmark.scoring.data import BenchmarkData, db_target
from benchmark.scoring.references import REFERENCES, References, oracle_row, summary

RESULTS = Path(__file__).parent / "results"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--out", type=Path, default=RESULTS / "hidden_references.json")
    parser.add_argument("--floor", type=int, default=0, help="parameter values per test object")
    args = parser.parse_args(argv)
    with BenchmarkData(args.data) as data:
        scorers = References(data).score()
        rows = {name: summary(scorers[name]) for name in REFERENCES}
        rows["oracle"] = oracle_row(data, scorers)
        paired = rows["oracle"].pop("vs_class_scale_nn")
        hidden = rows["oracle"].pop("hidden")
        floor = blind_floor(data, args.floor) if args.floor else None
        print(data.describe())
    print(f"hidden parameters: {', '.join(hidden)}")
    print(f"{'reference':15} {'Simple MSE':>24} {'Complex MSE':>24} {'objects':>8}")
    for name, r in rows.items():
        cells = [
            f"{r[m]:7.2f} [{r[m + '_ci'][0]:6.2f}, {r[m + '_ci'][1]:6.2f}]"
            if r[m] is not None
            else "-"
            for m in ("simple_mse", "complex_mse")
        ]
        print(f"{name:15} {cells[0]:>24} {cells[1]:>24} {r['n_objects']:8d}")
    for m, p in paired.items():
        print(
            f"oracle - class-scale-nn, {m}: {p['diff']:+.2f} [{p['ci'][0]:+.2f}, "
            f"{p['ci'][1]:+.2f}] ({p['verdict']})"
        )
    if floor:
        per_class = ", ".join(f"{c} {m:.2f}" for c, m in floor["per_class_mse"].items())
        print(
            f"parameter-blind floor ({args.floor} values at the exact scale): "
            f"{floor['mse']:.2f} dB^2 over {floor['n_objects']} test objects ({per_class}; "
            f"relabel at the true value: {floor['relabel_mse']:.2g})"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out) as tmp:
        tmp.write_text(
            json.dumps(
                {
                    "data": str(args.data),
                    "hidden": hidden,
                    "rows": rows,
                    "oracle_vs_class_scale_nn": paired,
                    "parameter_blind_floor": floor,
                },
                indent=1,
            )
            + "\n"
        )


def blind_floor(data: BenchmarkData, n: int) -> dict:
    """Mean over test objects (and per class) of MSE(mean target over n values of the class's
    hidden parameter at the object's scale, its target)."""
    import radar_sim
    from basic_shapes.analytic import HIDDEN, simulation_mesh, solid_for
    from basic_shapes.shards import Shard

    with Shard(data.paths[0]) as s:
        config = radar_sim.RadarConfig(**s.radar.config)

    def label(kind, scale, params):
        v, f = simulation_mesh(solid_for(kind, scale, params), config.f_stop_hz)
        return db_target(radar_sim.simulate(v, f, config).range_profiles).astype(np.float64)

    params = data.object_params()
    errors, relabel, classes = [], [], []
    for obj in data.test_objects():
        kind = data.class_names[int(data.objects["class_index"][obj])]
        ((key, (lo, hi)),) = HIDDEN[kind].items()
        scale = data.objects["scale"][obj].astype(np.float64)
        target = data.target(int(obj)).astype(np.float64)
        relabel.append(float(np.mean((label(kind, scale, params[obj]) - target) ** 2)))
        values = lo + (np.arange(n) + 0.5) / n * (hi - lo)
        blind = np.mean([label(kind, scale, {key: float(x)}) for x in values], axis=0)
        errors.append(float(np.mean((blind - target) ** 2)))
        classes.append(kind)
    return {
        "mse": float(np.mean(errors)),
        "per_class_mse": {
            c: float(np.mean([e for e, k in zip(errors, classes) if k == c]))
            for c in sorted(set(classes))
        },
        "per_object": errors,
        "classes": classes,
        "n_objects": len(errors),
        "values_per_object": n,
        "relabel_mse": float(np.max(relabel)),
    }


if __name__ == "__main__":
    main()
