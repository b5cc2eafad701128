"""`basic-shapes info`: what a dataset holds, read from metadata only (no geometry)."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from basic_shapes.shards import (
    Shard,
    dataset_fingerprint,
    is_ood_variant,
    label_fingerprint,
    list_shards,
)

BAR = 40


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
    per_class = defaultdict(
        lambda: {
            "objects": 0,
            "train": 0,
            "val": 0,
            "test": 0,
            "faces": [],
            "hausdorff": [],
            "labelled": 0,
            "ood": 0,
        }
    )
    shards = list_shards(directory)
    mesh_fingerprint = dataset_fingerprint(directory)  # every shard verified before reporting
    config = None
    for p in shards:
        with Shard(p) as s:
            config = s.config
            names = s.class_names
            objs = s.objects()
            table = s.mesh_table()
            for k, c in enumerate(objs["class"]):
                d = per_class[names[c]]
                d["objects"] += 1
                d[objs["split"][k]] += 1
                d["labelled"] += int(s.has_labels)
            cls_of_mesh = objs["class"][table["object_index"]]
            ood = is_ood_variant(table["variant"])  # counted apart, not in the statistics
            for c in np.unique(cls_of_mesh):
                per_class[names[c]]["ood"] += int(np.sum((cls_of_mesh == c) & ood))
                sel = (cls_of_mesh == c) & ~ood
                per_class[names[c]]["faces"].append(table["n_faces"][sel])
                complex_ = sel & (table["variant"] > 0)
                per_class[names[c]]["hausdorff"].append(table["hausdorff"][complex_])
    lines = [
        f"dataset {directory}: {len(shards)} shards, seed {config.get('seed', '?')}, "
        f"{config.get('variants', '?')} complex variants per object",
        f"mesh fingerprint  {mesh_fingerprint}",
        f"label fingerprint {_labels(directory)}",
    ]
    for name, d in per_class.items():
        faces = np.concatenate(d["faces"])
        h = np.concatenate(d["hausdorff"])
        lines.append(
            f"\n{name}: {d['objects']} objects ({d['train']} train / {d['val']} val / "
            f"{d['test']} test), {len(faces)} meshes"
            + (f" + {d['ood']} out-of-distribution" if d["ood"] else "")
            + f", {d['labelled']} objects radar-labelled"
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
