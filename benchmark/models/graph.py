"""Graph face embedding (MeshGPT-style): discretized face geometry, then SAGEConv layers
over the face adjacency graph (faces sharing an edge are neighbours)."""

from __future__ import annotations

import torch
from torch import nn
from torch_geometric.nn import SAGEConv

from benchmark.models.features import N_BINS, TOKEN_GROUPS, MeshBatch


class GraphEmbedding(nn.Module):
    """Per-face embedding tables for coordinates, angles, area and normal, projected and then
    refined by residual SAGEConv message passing between adjacent faces."""

    def __init__(self, dim: int, n_layers: int = 3, token_dim: int = 16):
        super().__init__()
        self.dim = dim
        self.tables = nn.ModuleList(nn.Embedding(N_BINS, token_dim) for _ in TOKEN_GROUPS)
        n_tokens = sum(n for _, n in TOKEN_GROUPS)
        self.proj = nn.Linear(n_tokens * token_dim, dim)
        self.convs = nn.ModuleList(SAGEConv(dim, dim) for _ in range(n_layers))
        self.norms = nn.ModuleList(nn.LayerNorm(dim) for _ in range(n_layers))

    def node_features(self, batch: MeshBatch) -> torch.Tensor:
        """(N, dim) features of the packed real faces, before message passing."""
        tokens = batch.tokens[batch.mask]  # (N, 16)
        parts, start = [], 0
        for table, (_, n) in zip(self.tables, TOKEN_GROUPS):
            parts.append(table(tokens[:, start:start + n]).flatten(1))
            start += n
        return self.proj(torch.cat(parts, 1))

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.node_features(batch)
        for conv, norm in zip(self.convs, self.norms):
            x = x + torch.nn.functional.gelu(norm(conv(x, batch.edge_index)))
        out = x.new_zeros(*batch.mask.shape, self.dim)
        out[batch.mask] = x
        return out, batch.mask, x.new_zeros(())
