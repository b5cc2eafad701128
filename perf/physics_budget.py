"""The labels' own physics error on spheres: physical optics against the exact Mie series,
in the benchmark's metric.

    python perf/physics_budget.py [--radii 0.05 0.1 0.2 0.3 0.5 0.7 0.95] [--grid 31x7]

For a perfectly conducting sphere of each radius, the label pipeline (the sphere's
simulation mesh, ``radar_sim.simulate`` on the xband-v1 band with the grid coarsened to
``--grid``) against the exact answer: the Mie series' backscattered amplitude at the same 128
frequencies, turned into range profiles by the same window and transform
(``RadarConfig.range_profiles``). Reported in dB² as the benchmark scores (targets
20 log10 max(|profile|, 1e-4), -80 dB floor): MSE over all bins, and over the bins within
30 dB of each exact profile's peak. A sphere scatters the same for every direction and
polarization, so this is the polarization-free part of the budget; it is the floor below which
differences between models on spheres are physics noise, not skill.

Mie convention: the series gives σ/(πa²) = |S|²/x² with S = Σ (-1)^n (2n+1)(b_n - a_n); the
amplitude's phase convention (conjugate or not, sign) is the one that matches the toolkit's
PO amplitude of a fine sphere at ka ≈ 40 (PO is within a few percent of Mie there, a wrong
convention is off by order one); the script checks that before measuring.
Writes perf/results/physics_budget.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy import special

import radar_sim
from basic_shapes.analytic import simulation_mesh, solid_for
from basic_shapes.infra import atomic_path, hardware
from radar_sim.field import C0

RESULTS = Path(__file__).parent / "results"
FLOOR = 1e-4
PEAK_WINDOW_DB = 30.0


def mie_series(x: np.ndarray) -> np.ndarray:
    """S(x) = Σ (-1)^n (2n+1)(b_n - a_n) of a PEC sphere, x = ka (scipy spherical Bessel)."""
    out = []
    for xi in np.atleast_1d(x):
        n = np.arange(1, int(xi + 4 * xi ** (1 / 3) + 12))
        jn, jnp = special.spherical_jn(n, xi), special.spherical_jn(n, xi, derivative=True)
        yn, ynp = special.spherical_yn(n, xi), special.spherical_yn(n, xi, derivative=True)
        hn, hnp = jn + 1j * yn, jnp + 1j * ynp
        a_n = jn / hn
        b_n = (jn + xi * jnp) / (hn + xi * hnp)
        out.append(np.sum((-1.0) ** n * (2 * n + 1) * (b_n - a_n)))
    return np.array(out)


def mie_amplitude(a: float, freq_hz: np.ndarray, convention: tuple[bool, float]) -> np.ndarray:
    """Complex A (σ = |A|²) of the sphere centred on the origin in the toolkit's convention."""
    x = 2 * np.pi * freq_hz * a / C0
    s = np.sqrt(np.pi) * a * mie_series(x) / x
    conj, sign = convention
    return sign * (np.conj(s) if conj else s)


def pick_convention() -> tuple[bool, float]:
    """The phase convention under which Mie matches the toolkit's PO on a fine sphere."""
    a = 0.1
    freq = np.linspace(18e9, 20e9, 9)  # ka 38-42
    v, f = simulation_mesh(solid_for("sphere", (2 * a,) * 3), 2 * freq.max())
    po = radar_sim.monostatic_field(v, f, freq, np.array([[0.0, 0.0, 1.0]]))[0]
    errors = {
        (c, s): float(np.max(np.abs(mie_amplitude(a, freq, (c, s)) - po) / np.abs(po)))
        for c in (False, True)
        for s in (1.0, -1.0)
    }
    best = min(errors, key=errors.get)
    others = sorted(v for k, v in errors.items() if k != best)
    if errors[best] > 0.1 or others[0] < 0.5:
        raise SystemExit(f"no unambiguous Mie phase convention: {errors}")
    return best


def db(profiles: np.ndarray) -> np.ndarray:
    return 20 * np.log10(np.maximum(np.abs(profiles), FLOOR))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--radii", type=float, nargs="+", default=[0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 0.95])
    p.add_argument("--grid", default="31x7", help="aspects x rolls (default 31x7, cpu-v1's)")
    args = p.parse_args()
    n_aspect, n_roll = (int(x) for x in args.grid.split("x"))
    config = radar_sim.RadarConfig.named("xband-v1").with_grid(n_aspect=n_aspect, n_roll=n_roll)
    convention = pick_convention()
    rows = []
    for a in args.radii:
        t0 = time.perf_counter()
        v, f = simulation_mesh(solid_for("sphere", (2 * a,) * 3), config.f_stop_hz)
        label = db(radar_sim.simulate(v, f, config).range_profiles)
        exact_response = mie_amplitude(a, config.frequency_hz, convention)
        exact = db(config.range_profiles(exact_response))  # (n_range,)
        exact = np.broadcast_to(exact, label.shape)
        near = exact >= exact.max(axis=-1, keepdims=True) - PEAK_WINDOW_DB
        err = (label - exact) ** 2
        ka = 2 * np.pi * config.frequency_hz[[0, -1]] * a / C0
        rows.append(
            {
                "radius_m": a,
                "ka": [float(ka[0]), float(ka[1])],
                "faces": len(f),
                "mse_all_db2": float(err.mean()),
                "mse_within_30db_db2": float(err[near].mean()),
                "bins_within_30db": float(near.mean()),
                "seconds": time.perf_counter() - t0,
            }
        )
    out = {
        "grid": args.grid,
        "band_hz": [config.f_start_hz, config.f_stop_hz],
        "mie_convention": {"conjugate": convention[0], "sign": convention[1]},
        "hardware": hardware(),
        "rows": rows,
    }
    RESULTS.mkdir(exist_ok=True)
    with atomic_path(RESULTS / "physics_budget.json") as tmp:
        tmp.write_text(json.dumps(out, indent=2))
    print(f"PO labels vs the exact Mie series, PEC spheres, xband-v1 grid {args.grid} (dB²)")
    print(f"{'radius m':>8s} {'ka':>11s} {'faces':>8s} {'MSE all':>8s} {'MSE <=30dB':>10s}")
    for r in rows:
        print(
            f"{r['radius_m']:8.2f} {r['ka'][0]:5.0f}-{r['ka'][1]:<5.0f} {r['faces']:8d} "
            f"{r['mse_all_db2']:8.2f} {r['mse_within_30db_db2']:10.3f}"
        )


if __name__ == "__main__":
    main()
