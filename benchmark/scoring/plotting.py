"""The charts drawn one way for the reproduction table and the board: speed against error,
the errors per class, and the validation curves.

Labels never overlap: every point's name sits in one column right of the axes, at the height
of its point where there is room and pushed apart by one line height where there is not, with
a thin leader line back to the point. The figure grows taller when the column needs it, so
the rule holds for any number of rows (an annotation next to each point smears as soon as two
models have similar errors, which is the usual case).
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.lines import Line2D
from matplotlib.ticker import (
    FormatStrFormatter,
    LogFormatter,
    MaxNLocator,
    SymmetricalLogLocator,
)

FONT_PT = 8.0
LINE = 1.35  # label pitch in font heights
AXES_IN = (5.0, 3.6)  # axes width and minimal height, inches
MARGIN_IN = dict(left=0.9, right=3.0, bottom=0.65, top=0.45)  # right: the label column


@dataclass(frozen=True)
class Point:
    """One model on the chart: ms per mesh, Complex MSE with its 95% interval."""

    x: float
    y: float
    label: str
    ci: tuple[float, float] | None = None
    colour: str = "tab:blue"
    marker: str = "o"
    size: float = 46.0
    hollow: bool = False  # no skill: drawn hollow with a red edge


def literal(label: str) -> str:
    """Shown literally: matplotlib would parse $...$ as math (and fail on some)."""
    return label.replace("$", r"\$")


def spread(wanted: list[float], gap: float, lo: float, hi: float) -> list[float]:
    """Positions, bottom to top in the given order, as close as possible to ``wanted`` with
    neighbours at least ``gap`` apart, inside [lo, hi] when ``len(wanted) * gap <= hi - lo``:
    push up from the bottom, then back down from the top."""
    pos = [min(max(w, lo), hi) for w in wanted]
    for k in range(1, len(pos)):
        pos[k] = max(pos[k], pos[k - 1] + gap)
    if pos and pos[-1] > hi:
        pos[-1] = hi
        for k in range(len(pos) - 2, -1, -1):
            pos[k] = min(pos[k], pos[k + 1] - gap)
    return pos


def png(fig) -> bytes:
    """The figure as PNG bytes (no software tag: same input, same bytes); closes it."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def speed_vs_error(
    points: list[Point],
    references: dict[str, float] | None = None,
    simulator: tuple[float, float] | None = None,
    title: str | None = None,
    xlabel: str = "ms per mesh (log scale; lower is faster)",
    front: list[tuple[float, float]] | None = None,
    marker_key: dict[str, str] | None = None,
):
    """The figure of ms per mesh (log) against Complex MSE (symlog, from 0 = the physics):
    ``references`` name -> Complex MSE as dashed lines (they cost nothing to run: a model
    must be below them), ``simulator`` (ms, MSE) as a star, ``front`` (the Pareto front's
    points, fastest first) as a step line, ``marker_key`` (what each marker means -> marker)
    as a legend."""
    references = {k: v for k, v in (references or {}).items() if v is not None}
    n_labels = len(points) + len(references) + (simulator is not None) + bool(front)
    line_in = LINE * FONT_PT / 72
    axes_h = max(AXES_IN[1], n_labels * line_in + 0.1)
    width = MARGIN_IN["left"] + AXES_IN[0] + MARGIN_IN["right"]
    key_in = 0.25 if marker_key else 0.0  # a row above the axes for the marker key
    height = MARGIN_IN["bottom"] + axes_h + MARGIN_IN["top"] + key_in
    fig = plt.figure(figsize=(width, height))
    ax = fig.add_axes(
        (
            MARGIN_IN["left"] / width,
            MARGIN_IN["bottom"] / height,
            AXES_IN[0] / width,
            axes_h / height,
        )
    )
    labels = []  # (x, y, text, colour) in data coordinates
    for p in points:
        if p.ci:
            ax.errorbar(
                [p.x],
                [p.y],
                yerr=[[p.y - p.ci[0]], [p.ci[1] - p.y]],
                fmt="none",
                ecolor="0.65",
                zorder=2,
            )
        ax.scatter(
            [p.x],
            [p.y],
            s=p.size,
            marker=p.marker,
            zorder=3,
            facecolors="none" if p.hollow else p.colour,
            edgecolors="tab:red" if p.hollow else p.colour,
        )
        labels.append((p.x, p.y, literal(p.label) + (" (no skill)" if p.hollow else ""), "0.1"))
    if simulator is not None:
        ax.scatter([simulator[0]], [simulator[1]], s=140, marker="*", color="tab:orange", zorder=4)
        labels.append((*simulator, "physics simulator", "tab:orange"))
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=1.0)  # spans 0 (the physics) to no-skill hundreds
    # ticks at 1..9 x each decade (and halves below 3), so a range inside one decade is still
    # labelled; plain numbers on both axes
    subs = (1, 1.5, 2, 2.5, 3, 4, 5, 6, 7, 8, 9)
    ax.yaxis.set_major_locator(SymmetricalLogLocator(base=10, linthresh=1.0, subs=subs))
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(LogFormatter(labelOnlyBase=False, minor_thresholds=(1, 0.5)))
    ax.margins(x=0.15, y=0.08)
    for name, y in references.items():
        ax.axhline(y, color="0.55", lw=0.8, ls="--", zorder=1)
        labels.append((None, y, f"reference: {literal(name)}", "0.4"))
    if front:
        xs, ys = [x for x, _ in front], [y for _, y in front]
        ax.step(xs, ys, where="post", color="tab:green", lw=1.2, alpha=0.8, zorder=1)
        labels.append((xs[-1], ys[-1], "Pareto front", "tab:green"))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("Complex MSE (dB², 95% interval; symlog)")
    if title:
        ax.set_title(title, fontsize=10, pad=6 + 72 * key_in)
    ax.grid(True, which="both", alpha=0.3)
    if marker_key:  # above the axes: inside it would cover points or reference lines
        handles = [
            Line2D([], [], ls="", marker=m, color="0.35", label=k) for k, m in marker_key.items()
        ]
        ax.legend(
            handles=handles,
            fontsize=7,
            loc="lower center",
            bbox_to_anchor=(0.5, 1.0),
            ncol=len(handles),
            frameon=False,
            handletextpad=0.2,
            columnspacing=1.0,
        )
    _label_column(ax, labels, line_in / axes_h)
    return fig


def _label_column(ax, labels: list[tuple], gap: float) -> None:
    """Each label right of the axes at its point's height, spread apart by ``gap`` (axes
    fraction), with a leader line; reference lines' labels lead to the right axis edge."""
    ax.figure.canvas.draw()  # final limits and transforms
    to_axes = ax.transAxes.inverted()
    xmax = ax.get_xlim()[1]
    wanted = [
        float(to_axes.transform(ax.transData.transform((xmax if x is None else x, y)))[1])
        for x, y, _, _ in labels
    ]
    # bottom to top; points within a line height of each other left to right, so their
    # leader lines do not cross
    order = sorted(
        range(len(labels)),
        key=lambda i: (round(wanted[i] / gap), labels[i][0] or float("inf"), wanted[i]),
    )
    labels, wanted = [labels[i] for i in order], [wanted[i] for i in order]
    for (x, y, text, colour), want, pos in zip(labels, wanted, spread(wanted, gap, 0.0, 1.0)):
        on_edge = x is None  # a reference line: lead to where it meets the right edge
        ax.annotate(
            text,
            xy=(1.0, want) if on_edge else (x, y),
            xycoords="axes fraction" if on_edge else "data",
            xytext=(1.04, pos),
            textcoords="axes fraction",
            va="center",
            fontsize=FONT_PT - on_edge,
            color=colour,
            annotation_clip=False,
            arrowprops=dict(arrowstyle="-", color="0.75", lw=0.5, shrinkA=0, shrinkB=2),
        )


REFERENCE_GREY = "0.45"


def per_class(entries: list[tuple[str, dict, str]], title: str):
    """One panel per class: each entry's Simple (hollow) and Complex (filled) MSE with its 95%
    interval, one line per entry in the given order. ``entries``: (name, per-class metric
    blocks as the results JSON holds them, colour). Where each model fails, and whether it
    beats the references, shows at a glance."""
    classes = list(dict.fromkeys(c for _, blocks, _ in entries for c in blocks))
    fig, axes = plt.subplots(
        1,
        max(len(classes), 1),
        figsize=(3.4 * max(len(classes), 1) + 2.2, 0.28 * len(entries) + 1.4),
        sharey=True,
        squeeze=False,
    )
    y = np.arange(len(entries))[::-1]
    for ax, cname in zip(axes[0], classes):
        for yk, (_, blocks, colour) in zip(y, entries):
            block = blocks.get(cname) or {}
            for metric, fill, dy in (("simple_mse", "none", 0.15), ("complex_mse", colour, -0.15)):
                if block.get(metric) is None:
                    continue
                v = block[metric]
                lo, hi = block.get(metric + "_ci") or (v, v)
                ax.errorbar(
                    v,
                    yk + dy,
                    xerr=[[v - lo], [hi - v]],
                    fmt="o",
                    ms=4,
                    color=colour,
                    mfc=fill,
                    elinewidth=0.8,
                    capsize=0,
                )
        n = next(b[cname]["n_objects"] for _, b, _ in entries if cname in b)
        ax.set_title(f"{literal(cname)} ({n} test objects)", fontsize=9)
        ax.set_xlabel("MSE (dB²)", fontsize=FONT_PT)
        ax.tick_params(labelsize=7)
        ax.set_xlim(left=0)
        ax.grid(axis="x", lw=0.3)
    axes[0, 0].set_yticks(y, [literal(n) for n, _, _ in entries], fontsize=7)
    fig.suptitle(f"{title} (hollow: Simple MSE, filled: Complex MSE)", fontsize=10)
    fig.tight_layout()
    return fig


def training_curves(rows: list[tuple[str, list, list, list]], title: str):
    """Validation MSE against epoch, one panel per row, one line per training seed, the
    selected (best) epoch marked. ``rows``: (name, seeds, curves, selected epochs), a curve or
    epoch None where a run kept none. Whether a run had stopped learning shows at a glance."""
    cols = min(4, len(rows))
    grid = (len(rows) + cols - 1) // cols
    fig, axes = plt.subplots(
        grid, cols, figsize=(3.2 * cols + 1.6, 2.4 * grid + 1.2), squeeze=False
    )
    for ax, (name, seeds, curves, best_epochs) in zip(axes.flat, rows):
        for seed, curve, best in zip(seeds, curves, best_epochs):
            if not curve:
                continue
            line = ax.plot(range(1, len(curve) + 1), curve, lw=1, label=f"seed {seed}")[0]
            if best is not None:
                ax.plot([best], [curve[best - 1]], "o", ms=4, color=line.get_color())
        ax.set_title(literal(name), fontsize=9)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    for ax in axes.flat[len(rows) :]:
        ax.set_visible(False)
    axes[0, 0].legend(fontsize=7)
    fig.supxlabel("epoch (dot: the selected epoch)")
    fig.supylabel("validation MSE (dB²)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
