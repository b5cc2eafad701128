"""Per-face features and ragged-batch collation shared by every baseline encoder.

Features are computed once per mesh in numpy (``featurize``, from the torch-free
``benchmark.scoring.mesh_features``, which the board's ONNX contract shares) and cached by the
caller, so training epochs only pad and stack (``collate``). Meshes arrive scale-normalized
(``benchmark.scoring.data.normalize_mesh``: the longest axis spans [-0.5, 0.5]); discretization
covers ``[-COORD_RANGE, COORD_RANGE]`` and clips anything outside.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, fields

import numpy as np
import torch

from benchmark.scoring.mesh_features import (  # noqa: F401  (re-exported: the models' names)
    COORD_RANGE,
    DIRECT_DIM,
    MAX_LOG_AREA,
    MIN_LOG_AREA,
    N_BINS,
    N_TOKENS,
    TOKEN_GROUPS,
    face_adjacency,
    face_features,
    face_geometry,
    normal_descriptor,
    point_neighbours,
    ray_probes,
    surface_points,
)

OPTIONAL = {
    "probes": ray_probes,
    "points": surface_points,
    "neighbours": lambda v, f: point_neighbours(surface_points(v, f)),
    "descriptor": lambda v, f: normal_descriptor(v, f).astype(np.float32),
}
"""The per-mesh inputs only some embeddings read (``Embedding.needs``): computed only when asked
for, as the board computes only the ONNX inputs a model declares."""


@dataclass
class MeshFeatures:
    """Everything an encoder needs from one mesh; numpy, so it can be cached and pickled."""

    direct: np.ndarray  # (F, 15) float32
    tokens: np.ndarray  # (F, 16) int64 in [0, N_BINS)
    area: np.ndarray  # (F,) float32
    edge_index: np.ndarray  # (2, E) int64, local face indices
    probes: np.ndarray | None = None  # (N_RAYS, PROBE_DIM) float32, invariant model only
    points: np.ndarray | None = None  # (N_POINTS, POINT_DIM) float32, point-cloud model only
    neighbours: np.ndarray | None = None  # (N_POINTS, K_NEIGHBOURS) int64, the points' kNN
    descriptor: np.ndarray | None = None  # (DESCRIPTOR_DIM,) float32, regressor only

    @property
    def n_faces(self) -> int:
        return len(self.direct)


def featurize(vertices: np.ndarray, faces: np.ndarray, needs: Iterable[str] = ()) -> MeshFeatures:
    """Direct (Kohler et al.) and discretized MeshGPT-style features of one normalized mesh,
    and the ``OPTIONAL`` ones named in ``needs``."""
    unknown = set(needs) - set(OPTIONAL)
    if unknown:
        raise ValueError(f"unknown mesh features {sorted(unknown)}; choose from {list(OPTIONAL)}")
    direct, tokens, area = face_features(vertices, faces)
    return MeshFeatures(
        direct=direct,
        tokens=tokens,
        area=area,
        edge_index=face_adjacency(faces),
        **{name: OPTIONAL[name](vertices, faces) for name in needs},
    )


@dataclass
class MeshBatch:
    """A padded batch of meshes. ``mask`` is True on real faces, False on padding.

    ``edge_index`` indexes the packed real faces (row-major order of ``mask``), which is
    the node order the graph encoders use.
    """

    direct: torch.Tensor  # (B, L, 15) float
    tokens: torch.Tensor  # (B, L, 16) long
    area: torch.Tensor  # (B, L) float
    mask: torch.Tensor  # (B, L) bool
    edge_index: torch.Tensor  # (2, E) long
    scale_bin: torch.Tensor  # (B, 3) long, per-axis discretized object scale
    target: torch.Tensor | None = None  # (B, T) float, dB
    label: torch.Tensor | None = None  # (B,) long, pretraining class
    probes: torch.Tensor | None = None  # (B, N_RAYS, PROBE_DIM) float, invariant model
    points: torch.Tensor | None = None  # (B, N_POINTS, POINT_DIM) float, point-cloud model
    neighbours: torch.Tensor | None = None  # (B, N_POINTS, K_NEIGHBOURS) long, per mesh
    descriptor: torch.Tensor | None = None  # (B, DESCRIPTOR_DIM) float, regressor
    scale_m: torch.Tensor | None = None  # (B, 3) float64, the objects' extents in metres

    def to(self, device) -> MeshBatch:
        return MeshBatch(
            **{
                f.name: None if getattr(self, f.name) is None else getattr(self, f.name).to(device)
                for f in fields(self)
            }
        )

    @property
    def size(self) -> int:
        return len(self.mask)


def collate(
    items: list[MeshFeatures], scale_bin=None, target=None, label=None, scale_m=None
) -> MeshBatch:
    """Pad a list of per-mesh features into one ``MeshBatch``; an ``OPTIONAL`` feature is
    batched when every item has it."""
    n = [it.n_faces for it in items]
    if min(n) == 0:
        raise ValueError("cannot batch a mesh with no faces")
    b, length = len(items), max(n)
    direct = np.zeros((b, length, DIRECT_DIM), np.float32)
    tokens = np.zeros((b, length, N_TOKENS), np.int64)
    area = np.zeros((b, length), np.float32)
    mask = np.zeros((b, length), bool)
    offsets = np.concatenate([[0], np.cumsum(n)])
    for i, it in enumerate(items):
        direct[i, : n[i]] = it.direct
        tokens[i, : n[i]] = it.tokens
        area[i, : n[i]] = it.area
        mask[i, : n[i]] = True
    edges = np.concatenate([it.edge_index + offsets[i] for i, it in enumerate(items)], 1)
    scale_bin = (
        np.zeros((b, 3), np.int64)
        if scale_bin is None
        else np.asarray(scale_bin, np.int64).reshape(b, 3)
    )
    return MeshBatch(
        direct=torch.from_numpy(direct),
        tokens=torch.from_numpy(tokens),
        area=torch.from_numpy(area),
        mask=torch.from_numpy(mask),
        edge_index=torch.from_numpy(np.ascontiguousarray(edges, np.int64)),
        scale_bin=torch.from_numpy(scale_bin),
        target=None if target is None else torch.as_tensor(np.asarray(target, np.float32)),
        label=None if label is None else torch.as_tensor(np.asarray(label, np.int64)),
        scale_m=None
        if scale_m is None
        else torch.from_numpy(np.asarray(scale_m, np.float64).reshape(b, 3)),
        **{
            name: None
            if any(getattr(it, name) is None for it in items)
            else torch.from_numpy(np.stack([getattr(it, name) for it in items]))
            for name in OPTIONAL
        },
    )
