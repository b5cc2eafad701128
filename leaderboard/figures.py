"""The board's figures, as PNG bytes (matplotlib, Agg; no fonts or files fetched).

Speed against error puts every model of one dataset at (ms per mesh, Complex MSE) with its
95% interval, the physics simulator as the reference point (a model is only useful left of it,
and only as good as it is low) and the harness's reference rows as dashed lines (they cost
nothing to run: a model must be below them). Speeds the harness did not measure (every
``leaderboard submit`` entry's, ``store.speed_self_reported``) are drawn as diamonds. On the
ranked track the Pareto front of the board-measured points (and the simulator) is drawn: the
models worth running at their speed.
The per-class figure shows each model's Simple and Complex MSE per class, ranked order.
The training curves show, for the entries that carry them, each seed's validation MSE per
epoch with the selected epoch: whether a model had finished learning.
The example shows one test object's physics response beside the best models' predictions for
its simple mesh and for a complex mesh of exactly the same shape.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from benchmark.scoring import plotting
from benchmark.scoring.plotting import Point, literal
from leaderboard.store import speed_self_reported

EXAMPLE_ROWS = 4
CURVE_PANELS = 20  # training-curve panels: the first entries in board order (a figure's height)
DB_RANGE = 60.0  # colour scale: the physics peak down to DB_RANGE dB below it


def plottable(models: list[dict]) -> list[dict]:
    """Models with both a speed and a Complex MSE (either may be null in a results JSON)."""
    return [
        e for e in models if e["speed"]["ms_per_mesh"] and e["metrics"]["complex_mse"] is not None
    ]


def pareto_front(models: list[dict], simulator: dict | None) -> list[tuple[str, float, float]]:
    """(name, ms per mesh, Complex MSE) of the points no other point beats on both axes (faster
    and lower), fastest first: the models whose speed the board measured (never a
    self-reported one) and the timed physics simulator."""
    points = [
        (e["name"], e["speed"]["ms_per_mesh"], e["metrics"]["complex_mse"])
        for e in plottable(models)
        if not speed_self_reported(e)
    ]
    if (
        simulator is not None
        and simulator["metrics"]["complex_mse"] is not None
        and simulator["speed"].get("ms_per_mesh")
        and not speed_self_reported(simulator)
    ):
        sim = simulator["speed"]["ms_per_mesh"], simulator["metrics"]["complex_mse"]
        points.append(("physics simulator", *sim))
    front, best = [], float("inf")
    for name, ms, err in sorted(points, key=lambda p: (p[1], p[2], p[0])):
        if err < best:
            front.append((name, ms, err))
            best = err
    return front


def speed_vs_error(
    models: list[dict],
    simulator: dict | None,
    references: dict | None = None,
    front: bool = False,
) -> bytes:
    """Every plottable model at (ms per mesh, Complex MSE); models without skill hollow,
    self-reported speeds as diamonds (``benchmark.scoring.plotting`` draws it, as for the table);
    with ``front``, the Pareto front of the board-measured points as a step line."""
    points = []
    for e in plottable(models):
        m, own = e["metrics"], speed_self_reported(e)
        points.append(
            Point(
                e["speed"]["ms_per_mesh"],
                m["complex_mse"],
                e["name"] + (" (self-reported speed)" if own else ""),
                ci=m.get("complex_mse_ci"),
                marker="D" if own else "o",
                hollow=bool(m.get("no_skill", m.get("mode_collapse"))),
            )
        )
    sim = None  # a simulator entry without a Complex MSE (no complex mesh labelled) is not drawn
    if simulator is not None and simulator["metrics"]["complex_mse"] is not None:
        sim = (simulator["speed"]["ms_per_mesh"], simulator["metrics"]["complex_mse"])
    return plotting.png(
        plotting.speed_vs_error(
            points,
            {k: r.get("complex_mse") for k, r in (references or {}).items()},
            sim,
            front=[(x, y) for _, x, y in pareto_front(models, simulator)] if front else None,
        )
    )


def per_class(models: list[dict], title: str) -> bytes:
    """Each model's Simple and Complex MSE per class with intervals, in the board's order."""
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    return plotting.png(
        plotting.per_class(
            [
                (e["name"], e["metrics"]["per_class"], colours[k % len(colours)])
                for k, e in enumerate(models)
            ],
            title,
        )
    )


def with_curves(models: list[dict]) -> list[dict]:
    """Models whose entry carries validation curves (``training``; results made before it
    carry none)."""
    return [e for e in models if any(e.get("training", {}).get("val_curves") or [])]


def training_curves(models: list[dict], title: str) -> bytes:
    """Each model's validation MSE per epoch, one line per training seed, in the board's order
    (the first ``CURVE_PANELS`` that carry curves)."""

    def seeds(e: dict) -> list:
        s = e.get("seeds") or {}
        n = len(e["training"]["val_curves"])
        listed = s.get("train_all") or [s.get("train")]
        return listed if len(listed) == n else list(range(n))

    return plotting.png(
        plotting.training_curves(
            [
                (
                    e["name"],
                    seeds(e),
                    e["training"]["val_curves"],
                    e["training"]["epochs_to_plateau"],
                )
                for e in with_curves(models)[:CURVE_PANELS]
            ],
            title,
        )
    )


def example(models: list[dict]) -> bytes:
    """Rows: up to EXAMPLE_ROWS models; columns: physics, simple- and complex-mesh prediction."""
    rows = models[:EXAMPLE_ROWS]
    s = rows[0]["sample"]
    physics = np.array(s["physics_db"])
    vmax = float(physics.max())
    extent = [s["range_m"][0], s["range_m"][-1], s["aspect_deg"][0], s["aspect_deg"][-1]]
    fig, axes = plt.subplots(
        len(rows), 3, figsize=(10, 2.6 * len(rows) + 0.6), squeeze=False, layout="constrained"
    )
    simple, complex_ = s["meshes"]
    titles = [
        "physics response",
        f"simple mesh ({simple['n_faces']} faces)",
        f"complex mesh ({complex_['n_faces']} faces)",
    ]
    for r, e in enumerate(rows):
        images = [physics] + [np.array(m["predicted_db"]) for m in e["sample"]["meshes"]]
        for c, img in enumerate(images):
            ax = axes[r, c]
            im = ax.imshow(
                img,
                extent=extent,
                aspect="auto",
                cmap="viridis",
                vmin=vmax - DB_RANGE,
                vmax=vmax,
                interpolation="nearest",
                origin="lower",  # aspect upwards, as radar-sim plot draws it
            )
            ax.set_title(titles[c] if c == 0 else f"{literal(e['name'])}\n{titles[c]}", fontsize=9)
            ax.set_xlabel("range (m)", fontsize=8)
            ax.set_ylabel("aspect (deg)", fontsize=8)
            ax.tick_params(labelsize=7)
    fig.colorbar(im, ax=axes, shrink=0.8, extend="min", label=f"dB (the top {DB_RANGE:g} dB)")
    fig.suptitle(
        f"object {s['object_id']} ({literal(s['class'])}), roll {s['roll_deg']:g}°", fontsize=10
    )
    return plotting.png(fig)
