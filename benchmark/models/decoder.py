"""Decoder: an MLP from the mesh embedding and the learned discretized-scale embedding to
the full dB response (n_aspect * n_roll * n_range values)."""

from __future__ import annotations

import torch
from torch import nn


class Decoder(nn.Module):
    """Meshes are scale-normalized, so the object's size enters only through ``scale_bin``."""

    def __init__(self, dim: int, n_outputs: int, n_scale_bins: int, scale_dim: int = 16,
                 hidden: int = 256):
        super().__init__()
        self.scale = nn.Embedding(n_scale_bins, scale_dim)
        self.mlp = nn.Sequential(nn.Linear(dim + scale_dim, hidden), nn.GELU(),
                                 nn.Linear(hidden, hidden), nn.GELU(),
                                 nn.Linear(hidden, n_outputs))

    def forward(self, z: torch.Tensor, scale_bin: torch.Tensor) -> torch.Tensor:
        return self.mlp(torch.cat([z, self.scale(scale_bin)], -1))

    @torch.no_grad()
    def set_output_bias(self, mean: torch.Tensor) -> None:
        """Start from the training-set mean response: dB targets sit far from zero, and
        without this most of a short CPU run is spent learning the offset."""
        self.mlp[-1].bias.copy_(mean)
