"""`basic-shapes show`: the simple mesh beside complex ones, faces randomly coloured (Fig. 2)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from basic_shapes.infra import save_png
from basic_shapes.shards import find_object


def draw_mesh(ax, v, f, half: float, rng) -> None:
    """One mesh on a 3-D axis, faces in random colours so the topology shows, cube of +-half."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    ax.add_collection3d(
        Poly3DCollection(
            v[f], facecolors=rng.uniform(0.15, 1, (len(f), 3)), edgecolors="k", linewidths=0.15
        )
    )
    for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setter(-half, half)
    ax.set_box_aspect((1, 1, 1), zoom=1.25)
    ax.view_init(elev=22, azim=35)
    ax.set_axis_off()


def show_object(directory: str | Path, object_id: int, out: str | Path, count: int = 5) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, obj, meshes = find_object(directory, object_id)
    simple = [m for m in meshes if m[0] == 0]
    others = [m for m in meshes if m[0] > 0]
    if others:  # spread the picks over the face-count range
        others.sort(key=lambda m: len(m[2]))
        others = [
            others[i] for i in np.unique(np.linspace(0, len(others) - 1, count).round().astype(int))
        ]
    shown = simple + others
    rng = np.random.default_rng(object_id)
    ncols = min(3, len(shown))
    nrows = -(-len(shown) // ncols)
    fig = plt.figure(figsize=(3.6 * ncols, 3.6 * nrows + 0.4))
    half = 0.5 * float(np.max(obj["scale"]))
    for k, (variant, v, f) in enumerate(shown):
        ax = fig.add_subplot(nrows, ncols, k + 1, projection="3d")
        draw_mesh(ax, v, f, half, rng)
        label = "simple" if variant == 0 else f"variant {variant}"
        ax.set_title(f"{label}\n{len(f)} faces", fontsize=10)
    sx, sy, sz = obj["scale"]
    fig.suptitle(
        f"object {obj['id']} ({obj['class']}, {sx:.2f} x {sy:.2f} x {sz:.2f} m)", fontsize=11
    )
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.9, wspace=0, hspace=0.08)
    save_png(fig, out)
