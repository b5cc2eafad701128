"""How far the stored meshes are from the object (the analytic primitive), per class and kind.

    python perf/primitive_distance.py

For each class, 4 objects (one 2 x 2 x 2 m, three with extents log-uniform in 0.2-2 m per axis,
seed 0) x (simple mesh + 15 variants) from basic_shapes.blender.object_meshes: the stored
``primitive_distance`` (two-sided, relative to the bbox diagonal) by variant kind (simple,
undecimated, collapse, unsubdiv), its bound ``verify.primitive_tolerance`` and the distance in
wavelengths at 12 GHz. Writes perf/results/primitive_distance.json and prints a table.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from basic_shapes import analytic, blender, verify
from basic_shapes.infra import write_json

OUT = Path(__file__).parent / "results" / "primitive_distance.json"


def main() -> None:
    rng = np.random.default_rng(0)
    rows = defaultdict(list)
    for kind in analytic.KINDS:
        for k in range(4):
            scale = (
                np.exp(rng.uniform(np.log(0.2), np.log(2.0), 3)) if k else np.array([2.0, 2.0, 2.0])
            )
            for m in blender.object_meshes(kind, scale, 100 + k, 15):
                how = "simple" if m.variant == 0 else m.params["decimate"]["kind"]
                rows[kind, how].append(
                    (
                        m.primitive_distance,
                        verify.primitive_tolerance(kind, m.params),
                        verify.in_wavelengths(m.primitive_distance, scale),
                    )
                )
    table = []
    print(
        f"{'class':9} {'kind':9} {'n':>3} {'max rel':>9} {'bound':>9} {'max/bound':>9} {'max λ':>6}"
    )
    for (kind, how), r in sorted(rows.items()):
        a = np.array(r)
        row = {
            "class": kind,
            "kind": how,
            "n": len(a),
            "max_relative": float(a[:, 0].max()),
            "bound": float(a[:, 1].max()),
            "max_ratio": float((a[:, 0] / a[:, 1]).max()),
            "max_wavelengths": float(a[:, 2].max()),
        }
        table.append(row)
        print(
            f"{kind:9} {how:9} {len(a):3d} {row['max_relative']:9.2e} {row['bound']:9.2e} "
            f"{row['max_ratio']:9.2f} {row['max_wavelengths']:6.3f}"
        )
    write_json(OUT, table)


if __name__ == "__main__":
    main()
