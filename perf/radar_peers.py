"""Speed-up over the way peer tools evaluate PO, at equal accuracy.

    python perf/radar_peers.py [--aspects 61]

PO-SBR-Python and radarsimpy re-evaluate the geometry for every frequency: illumination (and
shadow rays), then a per-facet sum at that wavenumber. radar_sim makes one geometric pass per
orientation that serves every frequency. Side by side, on the same orientations (--aspects
aspects at roll 17.1 deg, the second roll of the default grid) and all 128 frequencies of
xband-v1, one core:
  radar_sim     radar_sim.monostatic_field, one call for all frequencies
  per-freq      the same exact integral, but the geometry (culling, shadow rays, facet
                weights) redone for every frequency: radar_sim called once per frequency
  peer-style    the peers' facet rule (one-point centroid PO, occlusion ray per facet centroid
                with embreex for non-convex meshes), looped over frequencies, with each facet
                split into M x M sub-facets, M doubled until its error reaches the target
Accuracy: peak-relative amplitude error max||A| - |A_ref|| / max|A_ref| against
  cube    the analytic PO of a box (each face a rectangle: ab sinc(k a d.e1) sinc(k b d.e2)),
  sphere  the exact facet integral on the same 960-face mesh (independent of the facet rule
          only through the mesh; the tests validate it against the closed forms),
  torus   likewise, 20k faces, non-convex, with shadowing.
The target is max(1 %, radar_sim's own error). Times for the full 61 x 21 grid are these times
x (1281 / orientations). Writes perf/results/radar_peers.json and prints a table.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from radar_accuracy import C, line_of_sight, quadrature_points  # noqa: E402
from radar_throughput import blender_uv_sphere  # noqa: E402

import radar_sim  # noqa: E402
from basic_shapes.infra import hardware  # noqa: E402

RESULTS = Path(__file__).parent / "results"
TARGET = 1e-2
MAX_M = 64
BOX = (0.8, 0.5, 0.3)


def box_reference(extents, frequencies_hz, directions) -> np.ndarray:
    """|A| of a PEC box centred at the origin: sum of its lit rectangular faces, analytic."""
    k = 2 * np.pi * np.asarray(frequencies_hz) / C
    total = np.zeros((len(directions), len(k)), complex)
    ext = np.asarray(extents, float)
    for axis in range(3):
        e1, e2 = (axis + 1) % 3, (axis + 2) % 3
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            cosine = np.asarray(directions) @ n
            lit = np.clip(cosine, 0, None)[:, None]
            centre_phase = np.exp(
                2j * np.outer(np.asarray(directions)[:, axis] * sign * ext[axis] / 2, k)
            )
            sa = np.sinc(np.outer(np.asarray(directions)[:, e1], k) * ext[e1] / np.pi)
            sb = np.sinc(np.outer(np.asarray(directions)[:, e2], k) * ext[e2] / np.pi)
            total += lit * ext[e1] * ext[e2] * centre_phase * sa * sb
    return np.abs(total * k / np.sqrt(np.pi))


def peer_style(vertices, faces, frequencies_hz, directions, m: int, shadows: bool) -> np.ndarray:
    """Per frequency, per orientation: illumination, shadow rays, one-point PO sum."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces)
    points, area_vec = quadrature_points(vertices, faces, m)
    centres = vertices[faces].mean(axis=1)
    facet_of_point = np.repeat(np.arange(len(faces)), m * m)
    scene = None
    if shadows:
        scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene, np.ascontiguousarray(vertices[faces], np.float32))
    eps = 1e-6 * float(np.ptp(vertices, axis=0).max())
    out = np.empty((len(directions), len(frequencies_hz)), complex)
    for j, freq in enumerate(frequencies_hz):
        k = 2 * np.pi * freq / C
        for i, d in enumerate(np.asarray(directions, np.float64)):
            w = area_vec @ d
            lit_facet = (area_vec[:: m * m] @ d) > 0
            if shadows:
                idx = np.flatnonzero(lit_facet)
                origins = np.ascontiguousarray(centres[idx] + eps * d, np.float32)
                rays = np.ascontiguousarray(np.broadcast_to(d, origins.shape), np.float32)
                lit_facet[idx[scene.run(origins, rays, query="OCCLUDED") != -1]] = False
            lit = lit_facet[facet_of_point] & (w > 0)
            out[i, j] = np.exp(2j * k * (points[lit] @ d)) @ w[lit] * k / np.sqrt(np.pi)
    return out


def error(field, reference) -> float:
    return float(np.abs(np.abs(field) - reference).max() / reference.max())


def timed(fn):
    t0 = time.perf_counter()
    result = fn()
    return result, time.perf_counter() - t0


def run_case(name, vertices, faces, mode, frequencies, directions, reference):
    ours, t_ours = timed(
        lambda: radar_sim.monostatic_field(vertices, faces, frequencies, directions, mode=mode)
    )
    reference_name = "analytic" if reference is not None else "radar_sim"
    if reference is None:
        reference = np.abs(ours)
    per_freq, t_per_freq = timed(
        lambda: np.concatenate(
            [
                radar_sim.monostatic_field(vertices, faces, [f], directions, mode=mode)
                for f in frequencies
            ],
            axis=1,
        )
    )
    target = max(TARGET, error(ours, reference))
    peer_rows = []
    m = 1
    while m <= MAX_M:
        field, seconds = timed(
            lambda m=m: peer_style(vertices, faces, frequencies, directions, m, mode != "convex")
        )
        peer_rows.append({"m": m, "seconds": seconds, "error": error(field, reference)})
        print(
            f"  {name}: peer-style M={m}: error {peer_rows[-1]['error']:.2e} in {seconds:.2f} s",
            flush=True,
        )
        if peer_rows[-1]["error"] <= target:
            break
        m *= 2
    reached = peer_rows[-1]["error"] <= target
    return {
        "faces": int(len(faces)),
        "mode": mode,
        "target": target,
        "reference": reference_name,
        "radar_sim": {"seconds": t_ours, "error": error(ours, reference)},
        "per_frequency": {"seconds": t_per_freq, "error": error(per_freq, reference)},
        "peer_style": {
            "runs": peer_rows,
            "reached_target": reached,
            "seconds": peer_rows[-1]["seconds"],
            "m": peer_rows[-1]["m"],
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--aspects", type=int, default=61, help="orientations per case (default 61)")
    ap.add_argument("--out", default=str(RESULTS / "radar_peers.json"))
    args = ap.parse_args()
    load = os.getloadavg()[0]
    config = radar_sim.RadarConfig.named("xband-v1")
    frequencies = config.frequency_hz
    roll = float(config.roll_deg[1])
    directions = line_of_sight(np.linspace(0, 180, args.aspects), [roll])
    box = trimesh.creation.box(extents=BOX)
    sphere = blender_uv_sphere()
    torus = trimesh.creation.torus(0.5, 0.15, major_sections=200, minor_sections=50)
    cases = {
        "cube": (box, "convex", box_reference(BOX, frequencies, directions)),
        "sphere": (sphere, "convex", None),
        "torus": (torus, "shadowed", None),
    }
    results = {}
    for name, (mesh, mode, reference) in cases.items():
        results[name] = run_case(
            name,
            np.asarray(mesh.vertices),
            np.asarray(mesh.faces),
            mode,
            frequencies,
            directions,
            reference,
        )
    scale = len(config.aspect_deg) * len(config.roll_deg) / len(directions)
    print(
        f"\n{len(directions)} orientations x {len(frequencies)} frequencies; seconds (error); "
        f"speed-up = other / radar_sim"
    )
    print(
        f"{'case':>7} {'faces':>6} {'radar_sim':>18} {'per-freq':>18} {'peer-style':>24} "
        f"{'x per-freq':>10} {'x peer':>8}"
    )
    for name, r in results.items():
        ours, pf, peer = r["radar_sim"], r["per_frequency"], r["peer_style"]
        ours_error = "ref" if r["reference"] == "radar_sim" else f"{ours['error']:.0e}"
        peer_cell = f"{peer['seconds']:.2f} ({peer['runs'][-1]['error']:.0e}) M={peer['m']}" + (
            "" if peer["reached_target"] else "!"
        )
        print(
            f"{name:>7} {r['faces']:>6} {ours['seconds']:>8.3f} ({ours_error:>5}) "
            f"{pf['seconds']:>8.3f} ({pf['error']:.0e}) {peer_cell:>24} "
            f"{pf['seconds'] / ours['seconds']:>10.1f} {peer['seconds'] / ours['seconds']:>8.1f}"
        )
    print(
        "('!': the peer-style rule did not reach the target within M = "
        f"{MAX_M}; its speed-up is then a lower bound)"
    )
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(
        json.dumps(
            {
                "hardware": hardware(threads=1),
                "load_average_at_start": load,
                "orientations": len(directions),
                "frequencies": len(frequencies),
                "full_grid_factor": scale,
                "target_peak_relative_error": TARGET,
                "cases": results,
            },
            indent=2,
        )
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
