"""Speed against error of three ways to evaluate the physical-optics facet integral.

    python perf/radar_accuracy.py [--quick]

Side by side, on the same meshes, directions and frequencies, single-threaded:
  exact     radar_sim.monostatic_field (closed-form facet integral, one geometric pass)
  centroid  the one-point rule: each facet is one scatterer of its area at its centroid
  brute-M   quadrature: each facet split into M x M sub-triangles, centroid rule on each
over mesh resolution, against two exact references:
  sphere    PO closed form, sigma / (pi a^2) = |1 + j (1 - exp(-2jka)) / (2ka)|^2, on icospheres
            (the error then also holds the faceting error, which no rule can remove);
  plate     square plate of side L, |A| = (2 sqrt(pi) / lambda) L^2 |cos t| |sinc(kLu) sinc(kLv)|,
            meshed as n x n squares, 2 triangles each (flat: the exact rule has no mesh error).
Error = max over directions and frequencies of ||A| - |A_ref|| / max |A_ref| (peak-relative, so
pattern nulls do not blow it up); for the sphere also the max dB error (dB = 20 log10|A|).
Writes perf/results/radar_accuracy.json and radar_accuracy.png and prints tables.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: numbers comparable with the per-core goals

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

import radar_sim  # noqa: E402
from basic_shapes import geometry  # noqa: E402
from basic_shapes.geometry import area_normals  # noqa: E402
from basic_shapes.infra import hardware  # noqa: E402

C = 299792458.0
RESULTS = Path(__file__).parent / "results"
MAX_POINTS = 600_000  # quadrature points beyond which a brute-force run is skipped (minutes)


# --- the two alternatives to the exact integral ---------------------------------------------
def quadrature_points(vertices, faces, m: int):
    """Centroids (P,3) and area vectors (P,3) of the m*m sub-triangles of every facet."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area_vec = area_normals(tri) / 2 / m**2
    bary = [((i + 1 / 3) / m, (j + 1 / 3) / m) for i in range(m) for j in range(m - i)]
    bary += [((i + 2 / 3) / m, (j + 2 / 3) / m) for i in range(m - 1) for j in range(m - 1 - i)]
    s, t = np.array(bary).T
    points = a[:, None] + s[None, :, None] * e1[:, None] + t[None, :, None] * e2[:, None]
    return points.reshape(-1, 3), np.repeat(area_vec, len(s), axis=0)


def centroid_field(vertices, faces, frequencies_hz, directions, m: int = 1) -> np.ndarray:
    """PO with the one-point rule on m*m sub-triangles per facet, back faces culled.

    A(d, k) = (k / sqrt(pi)) * sum_p (a_p . d)^+ exp(2j k d . c_p); sigma = |A|^2.
    """
    points, area_vec = quadrature_points(vertices, faces, m)
    k = 2 * np.pi * np.asarray(frequencies_hz, np.float64) / C
    out = np.empty((len(directions), len(k)), np.complex128)
    for i, d in enumerate(np.asarray(directions, np.float64)):
        w = area_vec @ d
        lit = w > 0
        phase = points[lit] @ d
        out[i] = np.exp(2j * np.outer(k, phase)) @ w[lit]
    return out * (k / np.sqrt(np.pi))


# --- references --------------------------------------------------------------------------
def sphere_reference(radius: float, frequencies_hz) -> np.ndarray:
    """|A| of the PO sphere (closed form), per frequency."""
    b = 2 * (2 * np.pi * np.asarray(frequencies_hz) / C) * radius
    return np.sqrt(np.pi) * radius * np.abs(1 + 1j * (1 - np.exp(-1j * b)) / b)


def plate_reference(side: float, frequencies_hz, directions) -> np.ndarray:
    """|A| (n_dir, n_freq) of a square PEC plate in z = 0, normal +z, PO."""
    k = 2 * np.pi * np.asarray(frequencies_hz) / C
    d = np.asarray(directions)
    u = k[None, :] * side * d[:, :1]
    v = k[None, :] * side * d[:, 1:2]
    pattern = np.abs(np.sinc(u / np.pi) * np.sinc(v / np.pi) * d[:, 2:3])
    return 2 * np.sqrt(np.pi) * side**2 * (k / (2 * np.pi)) * pattern


def plate_mesh(side: float, n: int):
    xs = np.linspace(-side / 2, side / 2, n + 1)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], -1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    )
    return vertices, faces


def line_of_sight(aspect_deg, roll_deg):
    """Every aspect at every roll, aspect-major (``basic_shapes.geometry.line_of_sight`` on a
    grid)."""
    t, p = np.meshgrid(aspect_deg, roll_deg, indexing="ij")
    return geometry.line_of_sight(t.ravel(), p.ravel())


# --- measurement -------------------------------------------------------------------------
def best_time(fn, budget_s: float = 1.0):
    """Result and best wall time of ``fn()`` over repeats that fit in ``budget_s``."""
    t0 = time.perf_counter()
    result = fn()
    best = time.perf_counter() - t0
    spent = best
    while spent + best < budget_s:
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        best, spent = min(best, dt), spent + dt
    return result, best


def methods(brute: tuple[int, ...]):
    out = {
        "exact": lambda v, f, fr, d: radar_sim.monostatic_field(v, f, fr, d, mode="convex"),
        "centroid": lambda v, f, fr, d: centroid_field(v, f, fr, d, 1),
    }
    for m in brute:
        out[f"brute-{m}"] = lambda v, f, fr, d, m=m: centroid_field(v, f, fr, d, m)
    return out


def run_case(name, meshes, frequencies, directions, reference, brute):
    rows = []
    for label, (v, f) in meshes:
        row = {"mesh": label, "faces": int(len(f)), "methods": {}}
        for method, fn in methods(brute).items():
            m = int(method.split("-")[1]) if method.startswith("brute") else 1
            if method != "exact" and len(f) * m * m > MAX_POINTS:
                continue
            field, seconds = best_time(lambda fn=fn, v=v, f=f: fn(v, f, frequencies, directions))
            amp = np.abs(field)
            with np.errstate(divide="ignore"):
                db = np.abs(20 * np.log10(amp) - 20 * np.log10(reference))
            row["methods"][method] = {
                "seconds": seconds,
                "evaluations_per_second": field.size / seconds,
                "peak_relative_error": float(np.abs(amp - reference).max() / reference.max()),
                "max_db_error": float(db.max()),
            }
        rows.append(row)
        print(
            f"  {name} {label}: "
            + ", ".join(
                f"{k} {r['peak_relative_error']:.2e} in {r['seconds'] * 1e3:.1f} ms"
                for k, r in row["methods"].items()
            ),
            flush=True,
        )
    return rows


def print_table(name, rows, brute):
    names = ["exact", "centroid", *[f"brute-{m}" for m in brute]]
    print(f"\n{name}: peak-relative error | time ratio to exact")
    print(f"{'faces':>7} " + " ".join(f"{n:>22}" for n in names))
    for row in rows:
        ex = row["methods"]["exact"]
        cells = []
        for n in names:
            r = row["methods"].get(n)
            cells.append(
                f"{'skipped':>22}"
                if r is None
                else f"{r['peak_relative_error']:>10.2e} | {r['seconds'] / ex['seconds']:>8.2f}x"
            )
        print(f"{row['faces']:>7} " + " ".join(cells))


def plot(results, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4.6))
    for ax, (name, case) in zip(np.atleast_1d(axes), results.items()):
        names = sorted(
            {m for row in case["rows"] for m in row["methods"]},
            key=lambda n: (n != "exact", n != "centroid", int(n.split("-")[-1]) if "-" in n else 0),
        )
        for n in names:
            pts = [
                (
                    row["methods"][n]["seconds"],
                    max(row["methods"][n]["peak_relative_error"], 1e-16),
                    row["faces"],
                )
                for row in case["rows"]
                if n in row["methods"]
            ]
            t, e, faces = zip(*pts)
            ax.loglog(t, e, "o-", label=n)
            for ti, ei, fi in zip(t, e, faces):
                ax.annotate(
                    str(fi), (ti, ei), fontsize=7, textcoords="offset points", xytext=(3, 3)
                )
        ax.set_xlabel("seconds (one core)")
        ax.set_ylabel("peak-relative amplitude error")
        ax.set_title(f"{name}: {case['description']}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("PO facet integral: speed against error (labels: number of faces)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true", help="fewer resolutions (a smoke run)")
    ap.add_argument("--out", default=str(RESULTS / "radar_accuracy.json"))
    args = ap.parse_args()
    load = os.getloadavg()[0]
    brute = (4, 16)
    frequencies = np.linspace(8e9, 12e9, 16)
    rng = np.random.default_rng(0)
    sphere_dirs = rng.normal(size=(24, 3))
    sphere_dirs /= np.linalg.norm(sphere_dirs, axis=1, keepdims=True)
    radius, side = 0.1, 0.5
    subdivisions = (1, 2, 3, 4) if args.quick else (1, 2, 3, 4, 5, 6)
    plate_n = (1, 4, 16) if args.quick else (1, 2, 4, 8, 16, 32, 64)

    spheres = []
    for s in subdivisions:
        mesh = trimesh.creation.icosphere(subdivisions=s, radius=radius)
        edge = float(mesh.edges_unique_length.max())
        spheres.append((f"icosphere-{s} (edge {edge * 1e3:.2f} mm)", (mesh.vertices, mesh.faces)))
    sphere_ref = np.broadcast_to(
        sphere_reference(radius, frequencies), (len(sphere_dirs), len(frequencies))
    )
    plate_dirs = line_of_sight(np.linspace(0, 60, 61), [0.0, 30.0, 45.0])
    plates = [(f"{n}x{n} squares", plate_mesh(side, n)) for n in plate_n]
    plate_ref = plate_reference(side, frequencies, plate_dirs)

    lam = C / frequencies
    results = {
        "sphere": {
            "description": f"PO sphere a = {radius} m, ka {2 * np.pi * radius / lam.max():.1f}"
            f"-{2 * np.pi * radius / lam.min():.1f}, {len(sphere_dirs)} "
            f"directions x {len(frequencies)} frequencies",
            "rows": run_case("sphere", spheres, frequencies, sphere_dirs, sphere_ref, brute),
        },
        "plate": {
            "description": f"{side} m plate, aspect 0-60 deg x roll 0/30/45 deg x "
            f"{len(frequencies)} frequencies",
            "rows": run_case("plate", plates, frequencies, plate_dirs, plate_ref, brute),
        },
    }
    for name, case in results.items():
        print_table(f"{name} ({case['description']})", case["rows"], brute)
    RESULTS.mkdir(parents=True, exist_ok=True)
    png = Path(args.out).with_suffix(".png")
    plot(results, png)
    Path(args.out).write_text(
        json.dumps(
            {
                "frequencies_hz": [frequencies[0], frequencies[-1], len(frequencies)],
                "hardware": hardware(threads=1),
                "load_average_at_start": load,
                "error": "max over directions and frequencies of ||A| - |A_ref|| / max |A_ref|",
                "cases": results,
            },
            indent=2,
        )
    )
    print(f"\nwrote {args.out} and {png}")


if __name__ == "__main__":
    main()
