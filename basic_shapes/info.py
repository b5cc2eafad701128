"""`basic-shapes info`: what a dataset holds, read from metadata only (no geometry): as text,
or (``--figure``) as one row of histograms per class."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from basic_shapes.infra import save_png
from basic_shapes.shards import (
    Shard,
    dataset_fingerprint,
    is_ood_variant,
    label_fingerprint,
    list_shards,
)

BAR = 40
KINDS = ("simple", "complex", "OOD")  # the meshes of an object, as the statistics split them


@dataclass
class ClassStats:
    """One class's objects and meshes: counts, extents, and per mesh kind (KINDS) the face
    counts and Hausdorff distances to the simple mesh (relative to the bbox diagonal)."""

    splits: dict = field(default_factory=lambda: {"train": 0, "val": 0, "test": 0})
    labelled: int = 0
    scales: list = field(default_factory=list)
    faces: dict = field(default_factory=lambda: {k: [] for k in KINDS})
    hausdorff: dict = field(default_factory=lambda: {k: [] for k in KINDS})

    @property
    def objects(self) -> int:
        return sum(self.splits.values())

    def of(self, what: str, kind: str) -> np.ndarray:
        return np.concatenate(getattr(self, what)[kind]) if getattr(self, what)[kind] else []


def statistics(directory: str | Path) -> tuple[dict, dict[str, ClassStats]]:
    """(the dataset's header: shards, config, fingerprints; ClassStats by class name). Every
    shard is verified first (``dataset_fingerprint``)."""
    shards = list_shards(directory)
    header = {"shards": len(shards), "mesh_fingerprint": dataset_fingerprint(directory)}
    per_class: dict[str, ClassStats] = defaultdict(ClassStats)
    for p in shards:
        with Shard(p) as s:
            header["config"] = s.config
            names = s.class_names
            objs = s.objects()
            table = s.mesh_table()
            for k, c in enumerate(objs["class"]):
                d = per_class[names[c]]
                d.splits[objs["split"][k]] += 1
                d.labelled += int(s.has_labels)
                d.scales.append(objs["scale"][k])
            cls_of_mesh = objs["class"][table["object_index"]]
            ood = is_ood_variant(table["variant"])
            kind = {
                "simple": table["variant"] == 0,
                "complex": (table["variant"] > 0) & ~ood,
                "OOD": ood,
            }
            for c in np.unique(cls_of_mesh):
                for name, sel in kind.items():
                    sel = sel & (cls_of_mesh == c)
                    per_class[names[c]].faces[name].append(table["n_faces"][sel])
                    per_class[names[c]].hausdorff[name].append(table["hausdorff"][sel])
    header["labels"] = _labels(directory)
    return header, dict(per_class)


def _histogram(n_faces: np.ndarray) -> list[str]:
    """Log-spaced face-count histogram as text bars (face counts span 12 to thousands)."""
    edges = np.unique(np.geomspace(max(n_faces.min(), 1), n_faces.max() + 1, 9).astype(int))
    counts, _ = np.histogram(n_faces, bins=edges)
    top = max(counts.max(), 1)
    return [
        f"    {lo:>7d}-{hi - 1:<7d} {'#' * int(round(BAR * c / top)):<{BAR}s} {c}"
        for lo, hi, c in zip(edges[:-1], edges[1:], counts)
    ]


def _labels(directory) -> str:
    """The dataset's label fingerprint and radar config, or why there is none."""
    for p in list_shards(directory):
        with Shard(p) as s:
            if not s.has_labels:
                return "(not every shard is labelled: run `radar-sim label`)"
    fingerprint = label_fingerprint(directory)  # refuses labels edited since they were stored
    with Shard(list_shards(directory)[0]) as s:
        return f"{fingerprint} (radar config {s.radar.config.get('name')!r})"


def summary(directory: str | Path) -> str:
    header, per_class = statistics(directory)
    config = header.get("config", {})
    lines = [
        f"dataset {directory}: {header['shards']} shards, seed {config.get('seed', '?')}, "
        f"{config.get('variants', '?')} complex variants per object",
        f"mesh fingerprint  {header['mesh_fingerprint']}",
        f"label fingerprint {header['labels']}",
    ]
    for name, d in per_class.items():
        faces = np.concatenate([d.of("faces", "simple"), d.of("faces", "complex")])
        h = d.of("hausdorff", "complex")
        n_ood = len(d.of("faces", "OOD"))
        lines.append(
            f"\n{name}: {d.objects} objects ({d.splits['train']} train / {d.splits['val']} val"
            f" / {d.splits['test']} test), {len(faces)} meshes"
            + (f" + {n_ood} out-of-distribution" if n_ood else "")
            + f", {d.labelled} objects radar-labelled"
        )
        lines.append(
            f"  faces: min {faces.min()}, median {int(np.median(faces))}, max {faces.max()}"
        )
        lines.extend(_histogram(faces))
        if len(h):
            lines.append(
                f"  Hausdorff / bbox diagonal (complex vs simple): median {np.median(h):.2e}, "
                f"99th pct {np.percentile(h, 99):.2e}, max {h.max():.2e}"
            )
    return "\n".join(lines)


COLOURS = {"simple": "tab:gray", "complex": "tab:blue", "OOD": "tab:orange"}


def figure(directory: str | Path, out: str | Path) -> None:
    """Per class: face counts and Hausdorff distances of the simple, complex and OOD meshes
    (log axes: both span decades), and the objects' extents per axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, per_class = statistics(directory)
    fig, axes = plt.subplots(
        len(per_class), 3, figsize=(12, 2.8 * len(per_class) + 0.6), squeeze=False
    )
    for row, (name, d) in zip(axes, per_class.items()):
        _log_histograms(row[0], {k: d.of("faces", k) for k in KINDS}, "faces per mesh")
        _log_histograms(
            row[1],
            {k: d.of("hausdorff", k) for k in KINDS[1:]},
            "Hausdorff to the simple mesh / bbox diagonal",
        )
        scales = np.asarray(d.scales)
        row[2].hist(list(scales.T), bins=12, label=["x", "y", "z"], histtype="step", lw=1.5)
        row[2].set_xlabel("bbox extent (m)")
        row[2].legend(fontsize=8, frameon=False)
        row[0].set_ylabel(f"{name} ({d.objects} objects)\nmeshes", fontsize=11)
        row[1].set_ylabel("meshes")
        row[2].set_ylabel("objects")
    fig.suptitle(f"{Path(directory).name}: meshes and objects per class", fontsize=12)
    fig.tight_layout()
    save_png(fig, out)


def _log_histograms(ax, values: dict, xlabel: str) -> None:
    """Step histograms of positive values on shared log-spaced bins, one per mesh kind."""
    from matplotlib.ticker import NullFormatter

    present = {k: np.asarray(v) for k, v in values.items() if len(v)}
    positive = np.concatenate([v[v > 0] for v in present.values()] or [np.zeros(0)])
    if not len(positive):
        counts = ", ".join(f"{k}: {len(v)}" for k, v in present.items())
        text = f"all 0 ({counts})" if present else "none"
        ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
        ax.set_xlabel(xlabel)
        return
    lo, hi = positive.min(), positive.max()
    bins = np.geomspace(lo, hi * 1.001, 20) if hi > lo else np.array([lo * 0.9, hi * 1.1])
    for kind, v in present.items():
        zeros = int(np.sum(v <= 0))  # no place on a log axis: counted in the legend
        ax.hist(
            v[v > 0],
            bins=bins,
            histtype="step",
            lw=1.5,
            color=COLOURS[kind],
            label=f"{kind} ({len(v)}" + (f"; {zeros} at 0, not drawn)" if zeros else ")"),
        )
    ax.set_xscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())  # decades only: no overlap
    ax.set_xlabel(xlabel)
    ax.legend(fontsize=8, frameon=False)
