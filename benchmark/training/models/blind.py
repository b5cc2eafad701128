"""A mesh-blind embedding: one learned token whatever the mesh.

A model built on it sees only what the decoder is given, the object's scale, and is trained
by the same recipe as every row: the learned scale reference. The reference rows
(``scoring.references``) are nearest neighbours; this is what a neural simulator of the same
size reaches without reading the mesh, so a row's gap to it is what reading the mesh wins
(on the hidden-parameter track, where the mesh alone shows the shape's other parameters).
"""

from __future__ import annotations

import torch
from torch import nn

from benchmark.training.models.features import MeshBatch


class BlindEmbedding(nn.Module):
    """One learned token per mesh, the same for every mesh."""

    def __init__(self, dim: int):
        super().__init__()
        self.dim = dim
        self.token = nn.Parameter(torch.randn(1, 1, dim) * 0.02)

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, 1, dim) copies of the token, an all-True mask, no auxiliary loss."""
        emb = self.token.expand(batch.size, 1, self.dim)
        mask = torch.ones((batch.size, 1), dtype=torch.bool, device=emb.device)
        return emb, mask, emb.new_zeros(())
