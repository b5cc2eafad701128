"""Is an object's label converged? The simulation-mesh rule against twice its resolution.

    python perf/label_convergence.py [--grid full|coarse] [--physics xband-v1|xband-v2|xband-v3]
                                     [--classes cube,sphere,...] [--independent]
                                     [--faces-sample N] [--out JSON]

For the largest objects of each class (2 x 2 x 2 m and the flattened / elongated 0.2 x 2 x 2,
2 x 2 x 0.2), the label is simulated on basic_shapes.analytic.simulation_mesh and on the same
rule with every edge-length limit halved (refinement 2). The error is the benchmark metric:
MSE over the whole response of T = 20 log10(max(|range profile|, 1e-4)), in dB^2. The rule
is converged when that MSE is <= 0.1 dB^2 on the full default grid ("xband-v1").
``--physics xband-v2`` labels as the v2 versions do (PO plus edge diffraction, HH, VV and HV)
and reports the MSE of each channel (VV is the task's target); ``--physics xband-v3`` adds
simulation rule 2 (rims cut at half the chords; docs/RADAR.md, "Labels v3").
``--independent`` also compares the label with an independent fine mesh of the same primitive
(trimesh icosphere / cylinder / cone, scaled per axis); the issue's bound is 1 dB^2.
``--faces-sample N`` reports mean / max faces over N log-uniform scales (0.2 - 2 m per axis).
Writes perf/results/label_convergence.json and prints a table.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: seconds comparable with the per-core goals

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

import radar_sim  # noqa: E402
from basic_shapes import analytic  # noqa: E402
from basic_shapes.infra import hardware, write_json  # noqa: E402

RESULTS = Path(__file__).parent / "results"
FLOOR = 1e-4
SCALES = [(2.0, 2.0, 2.0), (0.2, 2.0, 2.0), (2.0, 2.0, 0.2)]
GRIDS = {"full": {}, "coarse": {"n_aspect": 16, "n_roll": 5}}  # changes to the named physics


def target(profiles: np.ndarray) -> np.ndarray:
    """The benchmark's target: 20 log10 of the range-profile magnitude, floored."""
    return 20.0 * np.log10(np.maximum(np.abs(profiles), FLOOR))


def label(vertices, faces, config, kind):
    """Range profiles of a mesh by channel ({"VV": ...}, or every channel of a polarimetric
    config) and the seconds they took."""
    mode = "shadowed" if kind == "torus" else "convex"  # the torus sees itself (first bounce)
    start = time.perf_counter()
    result = radar_sim.simulate(vertices, faces, config, mode=mode)
    seconds = time.perf_counter() - start
    if result.channel_profiles is None:
        return {"VV": result.range_profiles}, seconds
    return dict(zip(config.channel_list, result.channel_profiles)), seconds


def independent_mesh(kind: str, scale) -> tuple[np.ndarray, np.ndarray] | None:
    """A fine mesh of the primitive built by trimesh (not by our rule), scaled per axis."""
    if kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=8)
        m.apply_scale(0.5)  # radius 1 -> unit-diameter; then per axis
    elif kind == "cylinder":
        m = trimesh.creation.cylinder(radius=0.5, height=1.0, sections=2048)
    elif kind == "cone":
        m = trimesh.creation.cone(radius=0.5, height=1.0, sections=2048)
        m.apply_translation([0.0, 0.0, -0.5])  # apex at +z/2 like Blender's cone
    else:
        return None
    v = np.asarray(m.vertices, np.float64) * np.asarray(scale, np.float64)
    return v, np.asarray(m.faces, np.int32)


def mse(a: dict, b: dict) -> dict:
    """The metric per channel."""
    return {c: float(np.mean((target(a[c]) - target(b[c])) ** 2)) for c in a}


def _suffix(channel: str) -> str:
    """Row keys: VV keeps the v1 names (``mse_vs_2x_db2``), other channels add theirs."""
    return "" if channel == "VV" else f"_{channel}"


def faces_sample(kind: str, n: int, rule: int, seed: int = 0) -> dict:
    """Mean / max simulation-mesh faces (``rule``) over n scales drawn log-uniform in 0.2-2 m
    per axis."""
    rng = np.random.default_rng(seed)
    scales = np.exp(rng.uniform(np.log(0.2), np.log(2.0), (n, 3)))
    counts = [
        len(analytic.simulation_mesh(analytic.solid_for(kind, s), F_MAX, rule=rule)[1])
        for s in scales
    ]
    return {"n": n, "mean_faces": float(np.mean(counts)), "max_faces": int(np.max(counts))}


F_MAX = radar_sim.RadarConfig.named("xband-v1").f_stop_hz  # every named physics: 8-12 GHz


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", choices=sorted(GRIDS), default="full")
    parser.add_argument("--physics", choices=sorted(radar_sim.config.NAMED), default="xband-v1")
    parser.add_argument("--classes", default=",".join(analytic.KINDS))
    parser.add_argument(
        "--scales",
        default=None,
        help="semicolon-separated extents, e.g. '2,2,2;0.2,2,2' (default: 3)",
    )
    parser.add_argument("--independent", action="store_true")
    parser.add_argument("--faces-sample", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS / "label_convergence.json")
    args = parser.parse_args(argv)
    config = radar_sim.RadarConfig.named(args.physics).with_grid(**GRIDS[args.grid])
    rule = analytic.SIMULATION_RULES[config.simulation_rule]
    scales = (
        [tuple(float(x) for x in s.split(",")) for s in args.scales.split(";")]
        if args.scales
        else SCALES
    )
    rows = []
    header = (
        f"{'class':9} {'extents (m)':15} {'faces':>8} {'faces 2x':>8} {'MSE 2x':>9} "
        f"{'MSE indep':>9} {'s':>7}"
    )
    print(
        f"grid {config.name}: {config.n_aspect} aspects x {config.n_roll} rolls x "
        f"{config.n_freq} freqs; rule {json.dumps(rule)}"
    )
    print(header)
    for kind in args.classes.split(","):
        for scale in scales:
            solid = analytic.solid_for(kind, scale)
            v1, f1 = analytic.simulation_mesh(solid, F_MAX, rule=config.simulation_rule)
            v2, f2 = analytic.simulation_mesh(
                solid, F_MAX, rule=config.simulation_rule, refinement=2.0
            )
            p1, seconds = label(v1, f1, config, kind)
            p2, _ = label(v2, f2, config, kind)
            row = {
                "class": kind,
                "extents_m": list(scale),
                "faces": len(f1),
                "faces_2x": len(f2),
                **{f"mse_vs_2x_db2{_suffix(c)}": v for c, v in mse(p1, p2).items()},
                "seconds": seconds,
            }
            ref = independent_mesh(kind, scale) if args.independent else None
            if ref is not None:
                row["independent_faces"] = len(ref[1])
                for c, v in mse(p1, label(*ref, config, kind)[0]).items():
                    row[f"mse_vs_independent_db2{_suffix(c)}"] = v
            rows.append(row)
            ind = row.get("mse_vs_independent_db2")
            print(
                f"{kind:9} {'x'.join(f'{x:g}' for x in scale):15} {len(f1):8d} {len(f2):8d} "
                f"{row['mse_vs_2x_db2']:9.4f} {'' if ind is None else f'{ind:9.4f}':>9} "
                f"{seconds:7.1f}"
                + (f"  HH {row['mse_vs_2x_db2_HH']:.4f}" if "mse_vs_2x_db2_HH" in row else ""),
                flush=True,
            )
    sample = (
        {
            kind: faces_sample(kind, args.faces_sample, config.simulation_rule)
            for kind in args.classes.split(",")
        }
        if args.faces_sample
        else {}
    )
    for kind, s in sample.items():
        print(
            f"faces over {s['n']} log-uniform scales, {kind}: mean {s['mean_faces']:.0f}, "
            f"max {s['max_faces']}"
        )
    out = {
        "grid": config.name,
        "config": config.to_dict(),
        "rule": rule,
        "rows": rows,
        "faces_sample": sample,
        "hardware": hardware(),
    }
    write_json(args.out, out)


if __name__ == "__main__":
    main()
