"""Aggregator: a transformer encoder over the face embeddings, read out at a CLS token."""

from __future__ import annotations

import torch
from torch import nn


class Aggregator(nn.Module):
    """No positional encoding: faces have no natural order, so the output is invariant to
    their permutation. Padding is excluded with the key padding mask."""

    def __init__(self, dim: int, n_layers: int = 2, n_heads: int = 4, dropout: float = 0.0):
        super().__init__()
        self.cls = nn.Parameter(torch.randn(1, 1, dim) * 0.02)
        layer = nn.TransformerEncoderLayer(dim, n_heads, 2 * dim, dropout, activation="gelu",
                                           batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, n_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(dim)

    def forward(self, emb: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """emb (B, L, dim), mask (B, L) True on real faces -> (B, dim)."""
        x = torch.cat([self.cls.expand(len(emb), -1, -1), emb], 1)
        pad = torch.cat([mask.new_zeros(len(mask), 1), ~mask], 1)
        return self.norm(self.encoder(x, src_key_padding_mask=pad)[:, 0])
