"""Graph face embedding (MeshGPT-style): discretized face geometry, then SAGEConv layers
over the face adjacency graph (faces sharing an edge are neighbours)."""

from __future__ import annotations

import torch
from torch import nn
from torch_geometric.nn import SAGEConv

from benchmark.training.models.features import N_BINS, TOKEN_GROUPS, MeshBatch


class GraphEmbedding(nn.Module):
    """Per-face embedding tables for coordinates, angles, area and normal, projected and then
    refined by residual SAGEConv message passing between adjacent faces."""

    def __init__(self, dim: int, n_layers: int = 3, token_dim: int = 16):
        super().__init__()
        self.dim = dim
        self.tables = nn.ModuleList(nn.Embedding(N_BINS, token_dim) for _ in TOKEN_GROUPS)
        self.positions = [g for g, (_, n) in enumerate(TOKEN_GROUPS) for _ in range(n)]
        self.proj = nn.Linear(len(self.positions) * token_dim, dim)  # token j's group
        self.convs = nn.ModuleList(SAGEConv(dim, dim) for _ in range(n_layers))
        self.norms = nn.ModuleList(nn.LayerNorm(dim) for _ in range(n_layers))

    def node_features(self, batch: MeshBatch) -> torch.Tensor:
        """(N, dim) features of the packed real faces, before message passing: ``proj`` of
        the 16 tokens' embeddings, concatenated.

        Computed as a sparse (N, 16 x 128) one-hot sum times the folded table (token j's
        table times its slice of ``proj.weight``): the same linear map, associated so that
        no (N, 256) concatenation is made and multiplied (most of this embedding's work on
        large meshes)."""
        tokens = batch.tokens[batch.mask]  # (N, 16)
        n, k = tokens.shape
        weight = self.proj.weight.view(self.dim, k, -1)  # (dim, 16, token_dim)
        tables = torch.stack([self.tables[g].weight for g in self.positions])
        folded = torch.einsum("jvt,djt->jvd", tables, weight).flatten(0, 1)  # (16 * 128, dim)
        device = tokens.device
        cols = (tokens + N_BINS * torch.arange(k, device=device)).flatten()  # sorted per row
        rows = torch.arange(n, device=device).repeat_interleave(k)
        onehot = torch.sparse_coo_tensor(
            torch.stack([rows, cols]),
            folded.new_ones(n * k),
            (n, k * N_BINS),
            is_coalesced=True,
            check_invariants=True,
        )
        return torch.sparse.mm(onehot, folded) + self.proj.bias

    def packed(self, batch: MeshBatch) -> torch.Tensor:
        """(N, dim) embeddings of the packed real faces, after message passing."""
        x = self.node_features(batch)
        for conv, norm in zip(self.convs, self.norms):
            x = x + torch.nn.functional.gelu(norm(conv(x, batch.edge_index)))
        return x

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.packed(batch)
        return padded(x, batch.mask), batch.mask, x.new_zeros(())


def padded(x: torch.Tensor, mask: torch.Tensor, fill: float = 0) -> torch.Tensor:
    """Rows of packed ``x`` (N, ...) placed at the True positions of ``mask`` (B, L), the
    rest ``fill``: (B, L, ...)."""
    out = x.new_full((*mask.shape, *x.shape[1:]), fill)
    out[mask] = x
    return out
