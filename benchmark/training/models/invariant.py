"""A topology-invariant embedding: the surface seen along fixed rays, not the faces.

Its input is the ray probes of ``benchmark.training.models.probes`` (nearest and farthest hit along
``N_RAYS`` fixed rays): properties of the surface alone, so the model is invariant by
construction, with no sampling noise. Every star-shaped surface (all
Basic Shapes primitives) is seen completely; for others the probes see the innermost and
outermost layer along each ray. A point-set encoder (shared MLP + the transformer
aggregator, no positional encoding) turns the probes into the mesh embedding.
"""

from __future__ import annotations

import torch
from torch import nn

from benchmark.training.models.features import MeshBatch
from benchmark.training.models.probes import PROBE_DIM


class ProbeEmbedding(nn.Module):
    """Embeds the ray probes with a shared MLP; every mesh yields exactly ``N_RAYS`` tokens."""

    def __init__(self, dim: int):
        super().__init__()
        self.dim = dim
        self.mlp = nn.Sequential(nn.Linear(PROBE_DIM, dim), nn.GELU(), nn.Linear(dim, dim))

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, N_RAYS, dim) probe embeddings, an all-True mask, no auxiliary loss."""
        if batch.probes is None:
            raise ValueError("the invariant model needs ray probes: featurize(..., probes=True)")
        emb = self.mlp(batch.probes)
        mask = torch.ones(emb.shape[:2], dtype=torch.bool, device=emb.device)
        return emb, mask, emb.new_zeros(())
