"""The paper's neural simulators g = d(a(f(V, F))), one topology-invariant model, one blind
to the mesh (the learned scale reference), and three beyond the paper: a mesh graph network,
a surface point-cloud model and a class-and-scale regressor (the learned class reference).

``build_model(name, ...)`` makes any of them from a JSON-able config; ``MeshSimulator``
is the full model, ``ClassificationHead`` / ``ReconstructionHead`` are the pretraining heads.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from benchmark.training.models.aggregator import Aggregator
from benchmark.training.models.blind import BlindEmbedding
from benchmark.training.models.decoder import Decoder
from benchmark.training.models.direct import DirectEmbedding
from benchmark.training.models.features import N_BINS, MeshBatch, collate, featurize
from benchmark.training.models.graph import GraphEmbedding
from benchmark.training.models.invariant import ProbeEmbedding
from benchmark.training.models.meshgraph import MeshGraphEmbedding
from benchmark.training.models.pointcloud import PointCloudEmbedding
from benchmark.training.models.regressor import RegressorEmbedding
from benchmark.training.models.token import TokenEmbedding


@dataclass(frozen=True)
class Embedding:
    """One entry of the registry: how to build the embedding and how the table shows it.

    Forward contract of every embedding: ``module(batch) -> (emb (B, L, dim), mask (B, L)
    bool, aux loss scalar)``. ``face``: one of the paper's face encoders (one token per face),
    so it is pretrained on a corpus and has an Ideal row (the rows beyond the paper, meshgraph
    included, have a basic row only); ``needs``: the optional mesh features it reads
    (``featurize(v, f, needs)``, names of ``features.OPTIONAL``); ``cost``: relative training
    time (reproduce schedules the longest runs first).
    """

    build: Callable[..., nn.Module]
    face: bool
    colour: str
    needs: tuple[str, ...] = ()
    cost: float = 1.0


REGISTRY: dict[str, Embedding] = {
    "direct": Embedding(lambda dim, **_: DirectEmbedding(dim), face=True, colour="tab:blue"),
    "graph": Embedding(
        lambda dim, embed_layers, **_: GraphEmbedding(dim, embed_layers),
        face=True,
        colour="tab:orange",
    ),
    "token": Embedding(
        lambda dim, embed_layers, codebook_size, n_quantizers, **_: TokenEmbedding(
            dim, embed_layers, codebook_size, n_quantizers
        ),
        face=True,
        colour="tab:green",
    ),
    "invariant": Embedding(
        lambda dim, **_: ProbeEmbedding(dim),
        face=False,
        colour="tab:red",
        needs=("probes",),
        cost=0.5,
    ),
    "blind": Embedding(
        lambda dim, **_: BlindEmbedding(dim), face=False, colour="tab:gray", cost=0.3
    ),
    "meshgraph": Embedding(
        lambda dim, embed_layers, **_: MeshGraphEmbedding(dim, embed_layers),
        face=False,
        colour="tab:purple",
        cost=2.0,  # a training step ~2.1x direct's (cpu preset model, demo meshes)
    ),
    "pointcloud": Embedding(
        lambda dim, embed_layers, **_: PointCloudEmbedding(dim, embed_layers),
        face=False,
        colour="tab:brown",
        needs=("points", "neighbours"),
        cost=2.5,  # ~2.7x direct's: 512 tokens per mesh
    ),
    "regressor": Embedding(
        lambda dim, embed_layers, **_: RegressorEmbedding(dim, embed_layers),
        face=False,
        colour="tab:olive",
        needs=("descriptor",),
        cost=0.3,  # one token, as blind (~0.7x direct's step)
    ),
}
"""Adding an embedding is one entry here: the CLI choices, the table's rows and the plot's
colours all derive from it."""
EMBEDDINGS = tuple(REGISTRY)  # every model name (the CLI choices)
FACE_EMBEDDINGS = tuple(name for name, e in REGISTRY.items() if e.face)  # the paper's


class MeshSimulator(nn.Module):
    """Face (or point) embedding -> transformer aggregator -> MLP decoder with scale."""

    def __init__(self, embedding: nn.Module, aggregator: Aggregator, decoder: Decoder):
        super().__init__()
        self.embedding, self.aggregator, self.decoder = embedding, aggregator, decoder

    def embed_faces(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, L, dim) embeddings, their mask, and the embedding's auxiliary loss."""
        return self.embedding(batch)

    def encode(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor]:
        emb, mask, aux = self.embed_faces(batch)
        return self.aggregator(emb, mask), aux

    def forward(self, batch: MeshBatch) -> tuple[torch.Tensor, torch.Tensor]:
        """Predicted dB response (B, n_outputs) and the auxiliary loss to add in training."""
        z, aux = self.encode(batch)
        return self.decoder(z, batch.scale_bin), aux


class ClassificationHead(nn.Module):
    """Pretraining by shape classification: a linear layer on the CLS output."""

    def __init__(self, dim: int, n_classes: int):
        super().__init__()
        self.linear = nn.Linear(dim, n_classes)

    def loss(self, model: MeshSimulator, batch: MeshBatch) -> tuple[torch.Tensor, dict]:
        z, aux = model.encode(batch)
        logits = self.linear(z)
        ce = F.cross_entropy(logits, batch.label)
        acc = (logits.argmax(1) == batch.label).float().mean()
        return ce + aux, {"ce": ce.item(), "acc": acc.item()}


class ReconstructionHead(nn.Module):
    """MeshGPT-style autoencoder: every face embedding must reproduce that face's nine
    discretized corner coordinates (a classification over ``N_BINS`` levels each)."""

    def __init__(self, dim: int, hidden: int = 256):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, 9 * N_BINS))

    def loss(self, model: MeshSimulator, batch: MeshBatch) -> tuple[torch.Tensor, dict]:
        emb, mask, aux = model.embed_faces(batch)
        logits = self.mlp(emb[mask]).unflatten(-1, (9, N_BINS))
        target = batch.tokens[mask][:, :9]
        ce = F.cross_entropy(logits.flatten(0, 1), target.flatten())
        acc = (logits.argmax(-1) == target).float().mean()
        return ce + aux, {"ce": ce.item(), "acc": acc.item()}


def build_model(
    name: str,
    n_outputs: int,
    n_scale_bins: int,
    dim: int = 64,
    embed_layers: int = 3,
    agg_layers: int = 2,
    n_heads: int = 4,
    decoder_hidden: int = 256,
    codebook_size: int = 128,
    n_quantizers: int = 2,
) -> MeshSimulator:
    """One of ``EMBEDDINGS`` with the shared aggregator and decoder. Every argument is a
    plain number, so the call's keyword arguments are the model's JSON config."""
    if name not in REGISTRY:
        raise ValueError(f"unknown model {name!r}; choose one of {', '.join(EMBEDDINGS)}")
    embedding = REGISTRY[name].build(
        dim=dim, embed_layers=embed_layers, codebook_size=codebook_size, n_quantizers=n_quantizers
    )
    return MeshSimulator(
        embedding,
        Aggregator(dim, agg_layers, n_heads),
        Decoder(dim, n_outputs, n_scale_bins, hidden=decoder_hidden),
    )


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


__all__ = [
    "EMBEDDINGS",
    "FACE_EMBEDDINGS",
    "REGISTRY",
    "Embedding",
    "MeshSimulator",
    "MeshBatch",
    "ClassificationHead",
    "ReconstructionHead",
    "build_model",
    "collate",
    "count_parameters",
    "featurize",
]
