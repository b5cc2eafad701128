"""Decoder: an MLP from the mesh embedding and the learned discretized-scale embedding to
the full dB response (n_aspect * n_roll * n_range values)."""

from __future__ import annotations

import torch
from torch import nn


class Decoder(nn.Module):
    """Meshes are scale-normalized, so the object's size enters only here: each axis's scale
    bin (``benchmark.scoring.data.ScaleBins``) has its own learned embedding, concatenated.

    The MLP works in standardized units: the output is ``offset + spread * mlp(...)``, with
    the training set's mean response and overall standard deviation (buffers, saved with
    the weights). dB targets sit tens of dB from zero with a spread of tens of dB; without
    this, most of a short CPU run is spent learning the offset and the output gain.
    """

    def __init__(
        self, dim: int, n_outputs: int, n_scale_bins: int, scale_dim: int = 16, hidden: int = 256
    ):
        super().__init__()
        self.n_scale_bins = n_scale_bins
        self.scale = nn.Embedding(3 * n_scale_bins, scale_dim)
        self.mlp = nn.Sequential(
            nn.Linear(dim + 3 * scale_dim, hidden),
            nn.GELU(),
            nn.Linear(hidden, hidden),
            nn.GELU(),
            nn.Linear(hidden, n_outputs),
        )
        self.register_buffer("offset", torch.zeros(n_outputs))
        self.register_buffer("spread", torch.ones(()))

    def forward(self, z: torch.Tensor, scale_bin: torch.Tensor) -> torch.Tensor:
        """z (B, dim), scale_bin (B, 3) -> (B, n_outputs)."""
        axis = torch.arange(3, device=scale_bin.device) * self.n_scale_bins
        h = self.mlp(torch.cat([z, self.scale(scale_bin + axis).flatten(1)], -1))
        return self.offset + self.spread * h

    @torch.no_grad()
    def set_output_statistics(self, targets: torch.Tensor) -> None:
        """Set ``offset`` / ``spread`` from training targets (N, n_outputs)."""
        self.offset.copy_(targets.mean(0))
        self.spread.fill_(float((targets - targets.mean(0)).std().clamp_min(1e-3)))
