"""Per-face features and ragged-batch collation shared by every baseline encoder.

Features are computed once per mesh in numpy (``featurize``) and cached by the caller, so
training epochs only pad and stack (``collate``). Meshes arrive scale-normalized
(``benchmark.scoring.data.normalize_mesh``: the longest axis spans [-0.5, 0.5]); discretization
covers ``[-COORD_RANGE, COORD_RANGE]`` and clips anything outside.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from basic_shapes.meshcheck import directed_edges
from benchmark.training.models.probes import ray_probes

N_BINS = 128  # discretization levels per quantity, as in MeshGPT
COORD_RANGE = 0.5
DIRECT_DIM = 15  # centre (3) + corner vectors (9) + unit normal (3)
N_TOKENS = 16  # discretized: coordinates (9) + interior angles (3) + area (1) + normal (3)
TOKEN_GROUPS = (("coord", 9), ("angle", 3), ("area", 1), ("normal", 3))
MAX_LOG_AREA, MIN_LOG_AREA = 0.0, -14.0  # natural log of a face area in normalized units


def face_adjacency(faces: np.ndarray) -> np.ndarray:
    """(2, E) int64 directed edges between faces that share a mesh edge (both directions).

    Faces around a non-manifold edge are all connected pairwise. Sorted, without duplicates.
    """
    faces = np.asarray(faces, np.int64)
    n_faces = len(faces)
    if n_faces == 0:
        return np.zeros((2, 0), np.int64)
    edges = np.sort(directed_edges(faces), axis=1)  # undirected: either winding meets
    keys = edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1]
    owner = np.tile(np.arange(n_faces), 3)  # row k * F + i of directed_edges is face i's
    order = np.argsort(keys, kind="stable")
    keys, owner = keys[order], owner[order]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    lengths = np.diff(np.r_[starts, len(keys)])
    pairs = [np.stack([owner[starts[lengths == 2]], owner[starts[lengths == 2] + 1]], 1)]
    for s, n in zip(starts[lengths > 2], lengths[lengths > 2]):
        group = owner[s : s + n]
        i, j = np.triu_indices(n, 1)
        pairs.append(np.stack([group[i], group[j]], 1))
    pairs = np.concatenate(pairs)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]  # a face repeating an edge is not its own neighbour
    both = np.concatenate([pairs, pairs[:, ::-1]])
    both = np.unique(both, axis=0)
    return np.ascontiguousarray(both.T)


def _discretize(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    q = np.floor((np.asarray(x, np.float64) - lo) / (hi - lo) * N_BINS)
    return np.clip(q, 0, N_BINS - 1).astype(np.int64)


def face_geometry(vertices: np.ndarray, faces: np.ndarray) -> dict[str, np.ndarray]:
    """Triangles, centres, areas, unit normals and interior angles of every face."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]  # (F, 3, 3)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normal = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
    angles = np.empty((len(tri), 3))
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        cos = np.einsum("ij,ij->i", a, b) / np.maximum(na * nb, 1e-30)
        angles[:, k] = np.arccos(np.clip(cos, -1.0, 1.0))
    return {
        "triangles": tri,
        "centre": tri.mean(1),
        "area": 0.5 * norm,
        "normal": normal,
        "angles": angles,
    }


@dataclass
class MeshFeatures:
    """Everything an encoder needs from one mesh; numpy, so it can be cached and pickled."""

    direct: np.ndarray  # (F, 15) float32
    tokens: np.ndarray  # (F, 16) int64 in [0, N_BINS)
    area: np.ndarray  # (F,) float32
    edge_index: np.ndarray  # (2, E) int64, local face indices
    probes: np.ndarray | None = None  # (N_RAYS, PROBE_DIM) float32, invariant model only

    @property
    def n_faces(self) -> int:
        return len(self.direct)


def featurize(vertices: np.ndarray, faces: np.ndarray, probes: bool = False) -> MeshFeatures:
    """Direct (Kohler et al.) and discretized MeshGPT-style features of one normalized mesh;
    with ``probes``, also the ray probes of the invariant model."""
    g = face_geometry(vertices, faces)
    # Corners in a canonical order, sorted by (z, y, x) as MeshGPT does, so that neither
    # embedding depends on which corner a file lists first (the normal keeps the winding).
    tri = g["triangles"]
    order = np.lexsort((tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]), axis=1)
    canon = np.take_along_axis(tri, order[:, :, None], 1)
    corners = canon - g["centre"][:, None]
    direct = np.concatenate([g["centre"], corners.reshape(-1, 9), g["normal"]], 1)
    log_area = np.log(np.maximum(g["area"], np.exp(MIN_LOG_AREA)))
    tokens = np.concatenate(
        [
            _discretize(canon.reshape(-1, 9), -COORD_RANGE, COORD_RANGE),
            _discretize(np.take_along_axis(g["angles"], order, 1), 0.0, np.pi),
            _discretize(log_area[:, None], MIN_LOG_AREA, MAX_LOG_AREA),
            _discretize(g["normal"], -1.0, 1.0),
        ],
        1,
    )
    return MeshFeatures(
        direct=direct.astype(np.float32),
        tokens=tokens,
        area=g["area"].astype(np.float32),
        edge_index=face_adjacency(faces),
        probes=ray_probes(vertices, faces) if probes else None,
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


def collate(items: list[MeshFeatures], scale_bin=None, target=None, label=None) -> MeshBatch:
    """Pad a list of per-mesh features into one ``MeshBatch``."""
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
        probes=None
        if any(it.probes is None for it in items)
        else torch.from_numpy(np.stack([it.probes for it in items])),
    )
