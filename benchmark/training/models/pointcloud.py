"""Point-cloud embedding (DGCNN-style EdgeConv) of a surface sample drawn uniformly by area.

Its input is ``N_POINTS`` points of the surface, drawn uniformly by area with a fixed seed,
each with the normal of its face (``benchmark.scoring.mesh_features.surface_points``).

Why it should hardly be fooled by the meshing: the distribution of its input is a property of
the surface, whatever the triangulation. What is left: two meshings give two samples of that
distribution, not the same points (sampling noise in every prediction, which the invariant
row's ray probes do not have), and the points lie on the facets, carrying facet normals, so a
coarse tessellation of a curved surface shifts them. The table tells whether that costs.

Encoder: DGCNN's EdgeConv layers (Wang et al. 2019; ``torch_geometric.nn.EdgeConv`` with max
aggregation computes the same, tests/test_new_rows.py checks it): h_i = max_j LeakyReLU(W [x_i,
x_j - x_i] + b) over the nearest points, the layers' outputs concatenated and projected, as
DGCNN does. The neighbour graph is fixed by the positions (DGCNN recomputes it in feature
space): each point's ``K_NEIGHBOURS`` nearest, computed once per mesh with the sample
(``mesh_features.point_neighbours``, the board's ``surface_neighbours``, as ``face_edges`` is
the face graph's). Written dense (every point has k neighbours), it exports to ONNX (opset 17
has no scatter-max). Every mesh yields exactly ``N_POINTS`` tokens.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from benchmark.scoring.mesh_features import POINT_DIM
from benchmark.training.models.features import MeshBatch

NEGATIVE_SLOPE = 0.2  # DGCNN's LeakyReLU


class EdgeConv(nn.Module):
    """DGCNN's EdgeConv with a one-layer h: h_i = max_j LeakyReLU(W [x_i, x_j - x_i] + b).

    LeakyReLU is increasing, so it commutes with the max: computed as LeakyReLU((W_i - W_d) x_i
    + b + max_j W_d x_j), two per-point products and a gather, never the (N, k, 2C) edges."""

    def __init__(self, n_in: int, dim: int):
        super().__init__()
        self.n_in = n_in
        self.lin = nn.Linear(2 * n_in, dim)

    def forward(self, x: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        """x (B, N, C), neighbours (B, N, k) indices into each mesh's N -> (B, N, dim)."""
        b, n, k = neighbours.shape
        w_own, w_diff = self.lin.weight[:, : self.n_in], self.lin.weight[:, self.n_in :]
        own = F.linear(x, w_own - w_diff, self.lin.bias)
        message = F.linear(x, w_diff).reshape(b * n, -1)
        rows = neighbours + n * torch.arange(b, device=x.device)[:, None, None]
        best = message.index_select(0, rows.reshape(-1)).view(b, n, k, -1).amax(2)
        return F.leaky_relu(own + best, NEGATIVE_SLOPE)


class PointCloudEmbedding(nn.Module):
    """``n_layers`` EdgeConv layers on the surface points; one token per point."""

    def __init__(self, dim: int, n_layers: int = 3):
        super().__init__()
        self.dim = dim
        self.convs = nn.ModuleList(
            EdgeConv(POINT_DIM if i == 0 else dim, dim) for i in range(n_layers)
        )
        self.proj = nn.Linear(n_layers * dim, dim)

    def encode(self, points: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        """(B, N, dim) embeddings of surface points (B, N, POINT_DIM) and their neighbours."""
        x, outs = points, []
        for conv in self.convs:
            x = conv(x, neighbours)
            outs.append(x)
        return self.proj(torch.cat(outs, -1))

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, N_POINTS, dim) point embeddings, an all-True mask, no auxiliary loss."""
        if batch.points is None or batch.neighbours is None:
            raise ValueError(
                "the pointcloud model needs surface points and their neighbours: "
                "featurize(v, f, ('points', 'neighbours'))"
            )
        emb = self.encode(batch.points, batch.neighbours)
        mask = torch.ones(emb.shape[:2], dtype=torch.bool, device=emb.device)
        return emb, mask, emb.new_zeros(())
