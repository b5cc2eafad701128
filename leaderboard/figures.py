"""The board's two figures, as PNG bytes (matplotlib, Agg; no fonts or files fetched).

Speed against error puts every model of one dataset at (ms per mesh, Complex MSE) with its
95% interval, the physics simulator as the reference point (a model is only useful left of it,
and only as good as it is low) and the harness's reference rows as dashed lines (they cost
nothing to run: a model must be below them). Self-reported speeds are drawn as diamonds.
The example shows one test object's physics response beside the best models' predictions for
its simple mesh and for a complex mesh of exactly the same shape.
"""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import FormatStrFormatter, SymmetricalLogLocator

DPI = 100
EXAMPLE_ROWS = 4
DB_RANGE = 60.0  # colour scale: the physics peak down to DB_RANGE dB below it


def _text(label: str) -> str:
    """Entry text shown literally: matplotlib would parse $...$ as math (and fail on some)."""
    return label.replace("$", r"\$")


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def plottable(models: list[dict]) -> list[dict]:
    """Models with both a speed and a Complex MSE (either may be null in a results JSON)."""
    return [
        e for e in models if e["speed"]["ms_per_mesh"] and e["metrics"]["complex_mse"] is not None
    ]


def speed_vs_error(models: list[dict], simulator: dict | None,
                   references: dict | None = None) -> bytes:
    """Scatter of ms per mesh (log) against Complex MSE; models without skill hollow."""
    fig, ax = plt.subplots(figsize=(7.5, 4.6), layout="constrained")
    for e in plottable(models):
        m = e["metrics"]
        x, y = e["speed"]["ms_per_mesh"], m["complex_mse"]
        flagged = bool(m.get("no_skill", m.get("mode_collapse")))
        ci = m.get("complex_mse_ci")
        if ci:
            ax.errorbar([x], [y], yerr=[[y - ci[0]], [ci[1] - y]], fmt="none", ecolor="0.6",
                        zorder=2)
        own = e["speed"].get("self_reported")
        ax.scatter([x], [y], s=46, marker="D" if own else "o",
                   facecolors="none" if flagged else "tab:blue",
                   edgecolors="tab:red" if flagged else "tab:blue", zorder=3)
        label = _text(e["name"]) + (" (no skill)" if flagged else "") \
            + (" (self-reported speed)" if own else "")
        ax.annotate(label, (x, y), textcoords="offset points", xytext=(5, 4), fontsize=8)
    for name, ref in (references or {}).items():
        if ref.get("complex_mse") is not None:
            ax.axhline(ref["complex_mse"], color="0.55", lw=0.8, ls="--", zorder=1)
            ax.annotate(f"reference: {_text(name)}", (0.005, ref["complex_mse"]), fontsize=7,
                        color="0.4", xycoords=("axes fraction", "data"),
                        textcoords="offset points", xytext=(0, 2))
    if simulator is not None:
        x, y = simulator["speed"]["ms_per_mesh"], simulator["metrics"]["complex_mse"]
        ax.scatter([x], [y], s=140, marker="*", color="tab:orange", zorder=4)
        ax.annotate("physics simulator", (x, y), textcoords="offset points", xytext=(6, 4),
                    fontsize=8, color="tab:orange")
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=1.0)  # spans 0 (the physics) to no-skill models' hundreds
    # ticks at 1..9 x each decade, so a range inside one decade is still labelled
    ax.yaxis.set_major_locator(SymmetricalLogLocator(base=10, linthresh=1.0, subs=range(1, 10)))
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.set_xlabel("ms per mesh (log scale; lower is faster)")
    ax.set_ylabel("Complex MSE (dB², 95% interval; symlog; lower is better)")
    ax.margins(x=0.25, y=0.1)  # room for the labels
    ax.grid(True, which="both", alpha=0.3)
    return _png(fig)


def example(models: list[dict]) -> bytes:
    """Rows: up to EXAMPLE_ROWS models; columns: physics, simple- and complex-mesh prediction."""
    rows = models[:EXAMPLE_ROWS]
    s = rows[0]["sample"]
    physics = np.array(s["physics_db"])
    vmax = float(physics.max())
    extent = [s["range_m"][0], s["range_m"][-1], s["aspect_deg"][-1], s["aspect_deg"][0]]
    fig, axes = plt.subplots(len(rows), 3, figsize=(10, 2.6 * len(rows) + 0.6), squeeze=False,
                             layout="constrained")
    simple, complex_ = s["meshes"]
    titles = ["physics response", f"simple mesh ({simple['n_faces']} faces)",
              f"complex mesh ({complex_['n_faces']} faces)"]
    for r, e in enumerate(rows):
        images = [physics] + [np.array(m["predicted_db"]) for m in e["sample"]["meshes"]]
        for c, img in enumerate(images):
            ax = axes[r, c]
            im = ax.imshow(img, extent=extent, aspect="auto", cmap="viridis",
                           vmin=vmax - DB_RANGE, vmax=vmax, interpolation="nearest")
            ax.set_title(titles[c] if c == 0 else f"{_text(e['name'])}: {titles[c]}", fontsize=9)
            ax.set_xlabel("range (m)", fontsize=8)
            ax.set_ylabel("aspect (deg)", fontsize=8)
            ax.tick_params(labelsize=7)
    fig.colorbar(im, ax=axes, shrink=0.8, label="dB")
    fig.suptitle(
        f"object {s['object_id']} ({_text(s['class'])}), roll {s['roll_deg']:g}°", fontsize=10
    )
    return _png(fig)
