"""Token face embedding: graph features quantized by a residual VQ codebook (MeshGPT)."""

from __future__ import annotations

import torch
from torch import nn
from vector_quantize_pytorch import ResidualVQ

from benchmark.training.models.features import MeshBatch
from benchmark.training.models.graph import GraphEmbedding, padded


class TokenEmbedding(nn.Module):
    """Each face becomes the sum of ``n_quantizers`` codebook vectors (straight-through
    gradients); the commitment loss is returned as the auxiliary loss."""

    def __init__(
        self,
        dim: int,
        n_layers: int = 3,
        codebook_size: int = 128,
        n_quantizers: int = 2,
        commitment_weight: float = 0.25,
    ):
        super().__init__()
        self.dim = dim
        self.graph = GraphEmbedding(dim, n_layers)
        self.vq = ResidualVQ(
            dim=dim,
            num_quantizers=n_quantizers,
            codebook_size=codebook_size,
            decay=0.9,
            commitment_weight=commitment_weight,
            threshold_ema_dead_code=1,
        )
        self.last_codes: torch.Tensor | None = None  # (B, L, n_quantizers), -1 on padding

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Quantized face embeddings (zero on padding), the mask, the commitment loss. The
        real faces are quantized packed, as one sequence: the same codes, loss and codebook
        updates as the padded batch with its mask, without the padding's work."""
        quantized, codes, commit = self.vq(self.graph.packed(batch)[None])
        self.last_codes = padded(codes[0].detach(), batch.mask, -1)
        return padded(quantized[0], batch.mask), batch.mask, commit.sum()
