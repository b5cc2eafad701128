"""A topology-invariant embedding: area-weighted points on the surface, not faces.

The encoder sees only points sampled uniformly on the surface (with the normal there), so
any two meshings of the same surface give the same input *distribution*. Sampling is
stratified along the cumulative face area, which keeps the sampling noise small; in eval
mode the random numbers come from a fixed table, so a prediction is deterministic.
"""

from __future__ import annotations

import torch
from torch import nn

from benchmark.models.features import MeshBatch


def sample_surface(batch: MeshBatch, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Area-weighted stratified surface samples -> points (B, N, 3) and normals (B, N, 3).

    ``u`` (B, N, 3) uniform in [0, 1): u[..., 0] jitters the stratum, the rest pick the
    barycentric position inside the chosen face.
    """
    n = u.shape[1]
    centre, corners = batch.direct[..., :3], batch.direct[..., 3:12].unflatten(-1, (3, 3))
    normal = batch.direct[..., 12:15]
    tri = centre[:, :, None] + corners  # (B, L, 3, 3)
    area = batch.area * batch.mask
    cdf = torch.cumsum(area, 1)
    cdf = cdf / cdf[:, -1:].clamp_min(1e-30)
    strata = (torch.arange(n, dtype=u.dtype, device=u.device) + u[..., 0]) / n
    face = torch.searchsorted(cdf.contiguous(), strata.contiguous(), right=True)
    n_faces = batch.mask.sum(1, keepdim=True)
    face = torch.minimum(face, n_faces - 1)
    t = torch.gather(tri, 1, face[..., None, None].expand(-1, -1, 3, 3))  # (B, N, 3, 3)
    r1 = u[..., 1].sqrt()
    w = torch.stack([1 - r1, r1 * (1 - u[..., 2]), r1 * u[..., 2]], -1)  # (B, N, 3)
    points = (w[..., None] * t).sum(2)
    normals = torch.gather(normal, 1, face[..., None].expand(-1, -1, 3))
    return points, normals


class PointEmbedding(nn.Module):
    """Embeds ``n_points`` surface samples (position + normal) with a shared MLP. The output
    mask is all True: every mesh yields exactly ``n_points`` tokens."""

    def __init__(self, dim: int, n_points: int = 256, seed: int = 0):
        super().__init__()
        self.dim, self.n_points = dim, n_points
        self.mlp = nn.Sequential(nn.Linear(6, dim), nn.GELU(), nn.Linear(dim, dim))
        g = torch.Generator().manual_seed(seed)
        self.register_buffer("eval_u", torch.rand(n_points, 3, generator=g), persistent=False)

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        b = batch.size
        if self.training:
            u = torch.rand(b, self.n_points, 3, device=batch.direct.device)
        else:
            u = self.eval_u.to(batch.direct.device).expand(b, -1, -1)
        points, normals = sample_surface(batch, u)
        emb = self.mlp(torch.cat([points, normals], -1))
        mask = torch.ones(b, self.n_points, dtype=torch.bool, device=emb.device)
        return emb, emb.new_zeros(()), mask
