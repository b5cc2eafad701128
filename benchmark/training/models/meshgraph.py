"""Mesh graph network (MeshGraphNets, Pfaff et al. 2021) on the face graph: encode, then process.

Nodes are the faces, edges join faces sharing a mesh edge (``face_edges``). Encoders: per face
its centre, unit normal and log area (no corners: nothing of the triangle's shape beyond its
size and orientation); per edge the relative position of the two centres and its length
(MeshGraphNets' relative edge features; absolute position enters through the centres only).
Each of ``n_steps`` processor steps updates every edge from itself and its two faces, then
every face from itself and the sum of its incoming edges, each an MLP ending in LayerNorm,
with residuals. The shared aggregator and decoder are the decode stage.

Why it should be fooled by the meshing: the faces are its tokens, so their number and their
density over the surface change with the triangulation, and so does the reach of its
message passing (``n_steps`` hops of one face each, a distance that scales with the face
size). It reads less of each triangle than direct and graph (no corners), which may make it
less sensitive; the aggregator still weighs every face equally, whatever its area.

Sums over edges are ``scatter_add`` (as the ONNX export of the graph row writes them), so one
code path serves training and ``benchmark export-onnx``.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from benchmark.training.models.features import MIN_LOG_AREA, MeshBatch
from benchmark.training.models.graph import padded

NODE_DIM = 7  # centre (3), unit normal (3), log area (1)
EDGE_DIM = 4  # centre difference (3), its length (1)


def mlp(n_in: int, dim: int) -> nn.Sequential:
    """MeshGraphNets' MLP: two layers, then LayerNorm."""
    return nn.Sequential(nn.Linear(n_in, dim), nn.GELU(), nn.Linear(dim, dim), nn.LayerNorm(dim))


def node_features(direct: torch.Tensor) -> torch.Tensor:
    """(F, NODE_DIM) from ``face_direct`` rows (F, 15): centre, normal, log area (the area
    from the corner vectors, clamped at ``MIN_LOG_AREA`` as the tokens are)."""
    corners = direct[:, 3:12].reshape(-1, 3, 3)
    cross = torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    log_area = torch.log((0.5 * cross.norm(dim=1)).clamp_min(math.exp(MIN_LOG_AREA)))
    return torch.cat([direct[:, :3], direct[:, 12:15], log_area[:, None]], 1)


class MeshGraphEmbedding(nn.Module):
    """Per-face embeddings after ``n_steps`` edge-then-node updates over the face graph."""

    def __init__(self, dim: int, n_steps: int = 3):
        super().__init__()
        self.dim = dim
        self.node_encoder, self.edge_encoder = mlp(NODE_DIM, dim), mlp(EDGE_DIM, dim)
        self.edge_updates = nn.ModuleList(mlp(3 * dim, dim) for _ in range(n_steps))
        self.node_updates = nn.ModuleList(mlp(2 * dim, dim) for _ in range(n_steps))

    def packed(self, direct: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
        """(F, dim) embeddings of one set of faces: ``direct`` (F, 15), ``edges`` (2, E)
        [source, destination] into those rows."""
        src, dst = edges[0], edges[1]
        x = self.node_encoder(node_features(direct))
        rel = direct[:, :3].index_select(0, dst) - direct[:, :3].index_select(0, src)
        e = self.edge_encoder(torch.cat([rel, rel.norm(dim=1, keepdim=True)], 1))
        index = dst[:, None].expand(-1, self.dim)
        for edge_update, node_update in zip(self.edge_updates, self.node_updates):
            e = e + edge_update(torch.cat([e, x.index_select(0, src), x.index_select(0, dst)], 1))
            incoming = torch.zeros_like(x).scatter_add(0, index, e)
            x = x + node_update(torch.cat([x, incoming], 1))
        return x

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, L, dim) face embeddings (zero on padding), the face mask, no auxiliary loss."""
        x = self.packed(batch.direct[batch.mask], batch.edge_index)
        return padded(x, batch.mask), batch.mask, x.new_zeros(())
