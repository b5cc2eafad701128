"""Direct face embedding (Kohler et al.): each face's centre, corner vectors and normal."""

from __future__ import annotations

import torch
from torch import nn

from benchmark.training.models.features import DIRECT_DIM, MeshBatch


class DirectEmbedding(nn.Module):
    """Embeds every face on its own; all context comes later from the transformer."""

    def __init__(self, dim: int):
        super().__init__()
        self.dim = dim
        self.proj = nn.Sequential(nn.Linear(DIRECT_DIM, dim), nn.GELU(), nn.Linear(dim, dim))

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, L, dim) face embeddings (zero on padding), the face mask, no auxiliary loss."""
        emb = self.proj(batch.direct) * batch.mask[..., None]
        return emb, batch.mask, emb.new_zeros(())
