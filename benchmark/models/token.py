"""Token face embedding: graph features quantized by a residual VQ codebook (MeshGPT)."""

from __future__ import annotations

import torch
from torch import nn
from vector_quantize_pytorch import ResidualVQ

from benchmark.models.features import MeshBatch
from benchmark.models.graph import GraphEmbedding


class TokenEmbedding(nn.Module):
    """Each face becomes the sum of ``n_quantizers`` codebook vectors (straight-through
    gradients); the commitment loss is returned as the auxiliary loss."""

    def __init__(self, dim: int, n_layers: int = 3, codebook_size: int = 128,
                 n_quantizers: int = 2, commitment_weight: float = 0.25):
        super().__init__()
        self.dim = dim
        self.graph = GraphEmbedding(dim, n_layers)
        self.vq = ResidualVQ(dim=dim, num_quantizers=n_quantizers, codebook_size=codebook_size,
                             decay=0.9, commitment_weight=commitment_weight,
                             threshold_ema_dead_code=1)
        self.last_codes: torch.Tensor | None = None  # (B, L, n_quantizers), -1 on padding

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        emb, _, _ = self.graph(batch)
        quantized, codes, commit = self.vq(emb, mask=batch.mask)
        self.last_codes = codes.detach()
        return quantized * batch.mask[..., None], batch.mask, commit.sum()
