"""The labels' own physics error: physical optics (PO) against exact answers, in the benchmark's
metric. PEC spheres (Mie series) and infinite PEC cylinders seen broadside (2-D exact:
eigenfunction series, method of moments), both polarizations.

    python perf/physics_budget.py [--parts spheres prisms] [--radii 0.05 0.1 ...] [--grid 31x7]
                                  [--cut-step 1] [--length 1.0] [--refine]

Spheres. For a perfectly conducting sphere of each radius, the label pipeline (the sphere's
simulation mesh, ``radar_sim.simulate`` on the xband-v1 band with the grid coarsened to
``--grid``) against the exact answer: the Mie series' backscattered amplitude at the same 128
frequencies (``radar_sim.exact.mie_backscatter``, whose phase convention tests/test_exact.py
checks against the simulator), turned into range profiles by the same window and transform
(``RadarConfig.range_profiles``). A sphere scatters the same for every direction and
polarization, so this is the polarization-free part of the budget.

Prisms (cylinders at aspect 90°). Cross-sections: circles of radius 0.3 and 1 m (exact: the
eigenfunction series) and a 0.3 m square, a cube's cut (exact: ``exact.mom_2d``, combined-field
MoM, segments <= λ/20 at 12 GHz graded at the corners; ``--refine`` also solves it at λ/40 and
reports the difference, the reference's own error in the metric). Roll (cut) angles 0..180°
every ``--cut-step`` degrees, the xband-v1 band (8-12 GHz, 128 frequencies, Hann window); the
2-D amplitudes are mapped to a prism of length ``--length`` (default 1 m) by ``exact.to_3d``
(σ = 2L²σ_2D/λ) and turned into range profiles as above. PO is ``exact.po_2d`` mapped the same
way, which is exactly the simulator's PO of the prism mesh at aspect 90° (checked on every run:
``radar_sim.rcs`` on ``exact.prism_mesh``). Rows: (a) PO vs exact, per polarization (TM = E
along the axis = V, TE = H along the axis = H); (b) exact TE vs exact TM (TM as the target):
how much the polarization alone changes the target, which PO (polarization-blind) cannot see.

Metric, as the benchmark scores (targets 20 log10 max(|profile|, 1e-4), -80 dB floor): MSE in
dB² over all range bins, and over the bins within 30 dB of each exact (target) profile's peak.

To add a model's column (e.g. PO + edge diffraction, once radar_sim/edges.py exists), call
``score_prism_model(name, model, references, config, length_m)`` with ``model(contour_xy,
length_m, freq_hz, roll_rad, pol) -> complex (n_angle, n_freq)``, the 3-D amplitudes of the
prism ``exact.prism_mesh(contour_xy, length_m)`` at aspect 90° and rolls ``roll_rad`` for pol
"TM" (VV) or "TE" (HH); ``references = prism_references(config, ...)``. Note that the
reference is the infinite cylinder mapped to length L (ends neglected), a finite prism's cap
edges are not in it. ``main`` does exactly that for PO (``po_prism``).

Writes perf/results/physics_budget.json (spheres) and perf/results/physics_budget_2d.json
(prisms), and prints tables.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import radar_sim
from basic_shapes.analytic import simulation_mesh, solid_for
from basic_shapes.infra import hardware, write_json
from radar_sim import exact
from radar_sim.field import C0

RESULTS = Path(__file__).parent / "results"
FLOOR = 1e-4  # benchmark.scoring.data.FLOOR_AMPLITUDE: -80 dB
PEAK_WINDOW_DB = 30.0
SEGMENTS_PER_WAVELENGTH = 20.0  # polygons standing for circles (PO), and the MoM default
POLS = ("TM", "TE")

# model(contour_xy, length_m, freq_hz, roll_rad, pol) -> complex (n_angle, n_freq)
PrismModel = Callable[[np.ndarray, float, np.ndarray, np.ndarray, str], np.ndarray]


def db(profiles: np.ndarray) -> np.ndarray:
    return 20 * np.log10(np.maximum(np.abs(profiles), FLOOR))


def profile_errors(model_db: np.ndarray, target_db: np.ndarray) -> dict:
    """The benchmark metric of (..., n_range) dB profiles against target dB profiles: MSE over
    all bins and over the bins within 30 dB of each target profile's peak."""
    target_db = np.broadcast_to(target_db, model_db.shape)
    near = target_db >= target_db.max(axis=-1, keepdims=True) - PEAK_WINDOW_DB
    err = (model_db - target_db) ** 2
    return {
        "mse_all_db2": float(err.mean()),
        "mse_within_30db_db2": float(err[near].mean()),
        "bins_within_30db": float(near.mean()),
    }


# --- spheres --------------------------------------------------------------------------------


def sphere_rows(radii, config: radar_sim.RadarConfig) -> list[dict]:
    rows = []
    for a in radii:
        t0 = time.perf_counter()
        v, f = simulation_mesh(solid_for("sphere", (2 * a,) * 3), config.f_stop_hz)
        label = db(radar_sim.simulate(v, f, config).range_profiles)
        exact_db = db(config.range_profiles(exact.mie_backscatter(a, config.frequency_hz)))
        ka = 2 * np.pi * config.frequency_hz[[0, -1]] * a / C0
        rows.append(
            {
                "radius_m": a,
                "ka": [float(ka[0]), float(ka[1])],
                "faces": len(f),
                **profile_errors(label, exact_db),
                "seconds": time.perf_counter() - t0,
            }
        )
    return rows


def print_spheres(rows: list[dict], grid: str) -> None:
    print(f"PO labels vs the exact Mie series, PEC spheres, xband-v1 grid {grid} (dB²)")
    print(f"{'radius m':>8s} {'ka':>11s} {'faces':>8s} {'MSE all':>8s} {'MSE <=30dB':>10s}")
    for r in rows:
        print(
            f"{r['radius_m']:8.2f} {r['ka'][0]:5.0f}-{r['ka'][1]:<5.0f} {r['faces']:8d} "
            f"{r['mse_all_db2']:8.2f} {r['mse_within_30db_db2']:10.3f}"
        )


# --- prisms ---------------------------------------------------------------------------------


def circle_polygon(radius_m: float, f_max_hz: float) -> np.ndarray:
    """Counter-clockwise regular polygon with sides <= λ/20 at f_max (a multiple of 4 of them,
    symmetric about both axes) and the circle's area."""
    h = C0 / f_max_hz / SEGMENTS_PER_WAVELENGTH
    n = 4 * int(np.ceil(2 * np.pi * radius_m / h / 4))
    r = radius_m * np.sqrt(2 * np.pi / (n * np.sin(2 * np.pi / n)))
    t = 2 * np.pi * np.arange(n) / n
    return np.c_[r * np.cos(t), r * np.sin(t)]


def square_polygon(side_m: float) -> np.ndarray:
    h = side_m / 2
    return np.array([[-h, -h], [h, -h], [h, h], [-h, h]])


@dataclass
class PrismReference:
    """One cross-section and its exact 3-D amplitudes (n_angle, n_freq) per polarization."""

    case: str
    contour: np.ndarray  # (n, 2) counter-clockwise, metres
    method: str
    roll_rad: np.ndarray
    exact_3d: dict[str, np.ndarray]
    seconds: float
    extra: dict = field(default_factory=dict)


def prism_references(
    config: radar_sim.RadarConfig,
    length_m: float,
    roll_deg: np.ndarray,
    *,
    circles=(0.3, 1.0),
    squares=(0.3,),
    refine: bool = False,
) -> list[PrismReference]:
    """Exact 3-D amplitudes of the prisms at aspect 90° (2-D exact answers through to_3d)."""
    f = config.frequency_hz
    roll = np.radians(np.asarray(roll_deg, dtype=float))
    refs = []
    for radius in circles:
        t0 = time.perf_counter()
        amps = {
            p: np.broadcast_to(
                exact.to_3d(exact.circular_cylinder_2d(radius, f, p), length_m, f),
                (len(roll), len(f)),
            )
            for p in POLS
        }
        refs.append(
            PrismReference(
                f"circle r={radius:g} m",
                circle_polygon(radius, config.f_stop_hz),
                "eigenfunction series",
                roll,
                amps,
                time.perf_counter() - t0,
            )
        )
    for side in squares:
        contour = square_polygon(side)
        t0 = time.perf_counter()
        both = exact.to_3d(exact.mom_2d(contour, f, roll, "both"), length_m, f)
        ref = PrismReference(
            f"square {side:g} m",
            contour,
            f"mom_2d cfie, λ/{SEGMENTS_PER_WAVELENGTH:g}",
            roll,
            dict(zip(POLS, both)),
            time.perf_counter() - t0,
        )
        if refine:
            t0 = time.perf_counter()
            fine = exact.to_3d(
                exact.mom_2d(contour, f, roll, "both", segments_per_wavelength=40), length_m, f
            )
            ref.extra["refined_lambda_over_40"] = {
                p: profile_errors(db(config.range_profiles(x)), db(config.range_profiles(y)))
                for p, x, y in zip(POLS, both, fine)
            }
            ref.extra["refine_seconds"] = time.perf_counter() - t0
        refs.append(ref)
    return refs


def po_prism(contour_xy, length_m, freq_hz, roll_rad, pol) -> np.ndarray:
    """PO of the prism at aspect 90° (either polarization): ``to_3d(po_2d(...))``."""
    return exact.to_3d(exact.po_2d(contour_xy, freq_hz, roll_rad), length_m, freq_hz)


def po_edges_prism(contour_xy, length_m, freq_hz, roll_rad, pol) -> np.ndarray:
    """The xband-v2 physics of the prism at aspect 90°: PO plus the edge fringe of its axial
    edges only (the 2-D reference is the infinite cylinder: its ends have no cap rims), VV for
    "TM" and HH for "TE"."""
    from dataclasses import replace

    from basic_shapes.geometry import line_of_sight
    from radar_sim import edges, field

    v, faces = exact.prism_mesh(contour_xy, length_m)
    los = line_of_sight(np.full(len(roll_rad), 90.0), np.degrees(roll_rad))
    channel = {"TM": 1, "TE": 0}[pol]  # field.CHANNELS = HH, VV, HV
    po = radar_sim.polarimetric_field(v, faces, freq_hz, los, mode="convex")[:, channel]
    wedges = edges.sharp_edges((v, faces))
    axial = np.abs(wedges.tangent[:, 2]) > 0.5
    mask = dict(ends=wedges.ends[axial], normals=wedges.normals[axial], n=wedges.n[axial])
    fringe = edges.edge_field(replace(wedges, **mask), field.wavenumbers(freq_hz), los)
    return po + fringe[:, channel]


def score_prism_model(
    name: str,
    model: PrismModel,
    references: list[PrismReference],
    config: radar_sim.RadarConfig,
    length_m: float,
) -> list[dict]:
    """Rows of the benchmark metric of ``model`` against the exact references, one per
    cross-section and polarization. ``model(contour_xy, length_m, freq_hz, roll_rad, pol)``
    returns the 3-D amplitudes (n_angle, n_freq) of ``exact.prism_mesh(contour_xy,
    length_m)`` at aspect 90°, e.g. for PO + edge diffraction::

        def po_edges(contour, length, f, roll, pol):
            v, faces = exact.prism_mesh(contour, length)
            los = radar_sim.rcs.line_of_sight(np.full(len(roll), 90.0), np.degrees(roll))
            ...  # PO + fringe field, channel VV for "TM", HH for "TE"

        rows += score_prism_model("PO + edges", po_edges, refs, config, length_m)
    """
    rows = []
    f = config.frequency_hz
    for ref in references:
        for pol in POLS:
            t0 = time.perf_counter()
            amp = np.asarray(model(ref.contour, length_m, f, ref.roll_rad, pol))
            if amp.shape != ref.exact_3d[pol].shape:
                raise ValueError(
                    f"{name}: model returned shape {amp.shape} for {ref.case}, "
                    f"expected {ref.exact_3d[pol].shape}"
                )
            got = db(config.range_profiles(amp))
            target = db(config.range_profiles(ref.exact_3d[pol]))
            rows.append(
                {
                    "case": ref.case,
                    "model": name,
                    "target": f"exact {pol}",
                    "pol": pol,
                    **profile_errors(got, target),
                    "seconds": time.perf_counter() - t0,
                }
            )
    return rows


def polarization_rows(references: list[PrismReference], config) -> list[dict]:
    """Exact TE scored against exact TM (the target): the polarization's own effect."""
    return [
        {
            "case": ref.case,
            "model": "exact TE",
            "target": "exact TM",
            "pol": "TE vs TM",
            **profile_errors(
                db(config.range_profiles(ref.exact_3d["TE"])),
                db(config.range_profiles(ref.exact_3d["TM"])),
            ),
        }
        for ref in references
    ]


def po_consistency(references: list[PrismReference], config, length_m: float) -> dict:
    """max |radar_sim.rcs(prism mesh) - to_3d(po_2d)| / max |.| per cross-section: the PO column
    is the simulator's own PO of the prism (it factorizes exactly at aspect 90°)."""
    out = {}
    f = config.frequency_hz
    for ref in references:
        v, faces = exact.prism_mesh(ref.contour, length_m)
        roll_deg = np.degrees(ref.roll_rad)
        sim = radar_sim.rcs(v, faces, f, np.full(len(roll_deg), 90.0), roll_deg, mode="convex")
        mine = po_prism(ref.contour, length_m, f, ref.roll_rad, "TM")
        out[ref.case] = float(np.abs(sim - mine).max() / np.abs(sim).max())
    return out


def print_prisms(rows: list[dict], length_m: float, n_angle: int) -> None:
    print(
        f"\nInfinite PEC cylinders at aspect 90° as {length_m:g} m prisms, xband-v1 band, "
        f"{n_angle} cut angles 0-180° (dB²)"
    )
    print(f"{'case':>18s} {'model':>12s} {'target':>9s} {'MSE all':>8s} {'MSE <=30dB':>10s}")
    for r in rows:
        print(
            f"{r['case']:>18s} {r['model']:>12s} {r['target']:>9s} "
            f"{r['mse_all_db2']:8.2f} {r['mse_within_30db_db2']:10.3f}"
        )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--parts", nargs="+", choices=("spheres", "prisms"), default=["spheres", "prisms"]
    )
    p.add_argument("--radii", type=float, nargs="+", default=[0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 0.95])
    p.add_argument("--grid", default="31x7", help="aspects x rolls (default 31x7, cpu-v1's)")
    p.add_argument("--cut-step", type=float, default=1.0, help="cut angle step, degrees")
    p.add_argument("--length", type=float, default=1.0, help="prism length, metres")
    p.add_argument("--refine", action="store_true", help="also solve the square at λ/40")
    args = p.parse_args()
    band = radar_sim.RadarConfig.named("xband-v1")
    if "spheres" in args.parts:
        n_aspect, n_roll = (int(x) for x in args.grid.split("x"))
        config = band.with_grid(n_aspect=n_aspect, n_roll=n_roll)
        rows = sphere_rows(args.radii, config)
        write_json(
            RESULTS / "physics_budget.json",
            {
                "grid": args.grid,
                "band_hz": [config.f_start_hz, config.f_stop_hz],
                "mie": "radar_sim.exact.mie_backscatter",
                "hardware": hardware(),
                "rows": rows,
            },
        )
        print_spheres(rows, args.grid)
    if "prisms" in args.parts:
        roll_deg = np.arange(0.0, 180.0 + args.cut_step / 2, args.cut_step)
        refs = prism_references(band, args.length, roll_deg, refine=args.refine)
        rows = score_prism_model("PO", po_prism, refs, band, args.length)
        rows += score_prism_model("PO + edges", po_edges_prism, refs, band, args.length)
        rows += polarization_rows(refs, band)
        consistency = po_consistency(refs, band, args.length)
        write_json(
            RESULTS / "physics_budget_2d.json",
            {
                "band_hz": [band.f_start_hz, band.f_stop_hz],
                "n_freq": band.n_freq,
                "window": band.window,
                "length_m": args.length,
                "cut_deg": [float(roll_deg[0]), float(roll_deg[-1]), len(roll_deg)],
                "references": [
                    {
                        "case": r.case,
                        "method": r.method,
                        "vertices": len(r.contour),
                        "seconds": r.seconds,
                        **r.extra,
                    }
                    for r in refs
                ],
                "po_vs_simulator_max_rel": consistency,
                "hardware": hardware(),
                "rows": rows,
            },
        )
        print_prisms(rows, args.length, len(roll_deg))
        for r in refs:
            print(f"  {r.case}: {r.method}, {r.seconds:.0f} s", end="")
            for pol, e in r.extra.get("refined_lambda_over_40", {}).items():
                print(
                    f"; {pol} λ/20 vs λ/40: {e['mse_all_db2']:.2g} / "
                    f"{e['mse_within_30db_db2']:.2g} dB²",
                    end="",
                )
            print()
        print("  PO column vs radar_sim.rcs on the prism mesh (max rel):", consistency)


if __name__ == "__main__":
    main()
