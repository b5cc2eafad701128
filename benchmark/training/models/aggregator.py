"""Aggregator: a transformer encoder over the face embeddings, read out at a CLS token."""

from __future__ import annotations

import contextlib

import torch
import torch.nn.functional as F
from torch import nn


class Aggregator(nn.Module):
    """No positional encoding: faces have no natural order, so the output is invariant to
    their permutation. Padding is excluded with the key padding mask.

    Only the CLS token's output is read, so the last layer is computed for that token alone
    (``_cls_only``): the same arithmetic as the full layer's row 0, in time linear in the
    face count instead of quadratic (with one layer, the cpu preset's, no face attends to
    another at all).

    The other layers run without PyTorch's inference fast path (``_inner_path``), so
    prediction takes the same arithmetic as training."""

    def __init__(self, dim: int, n_layers: int = 2, n_heads: int = 4, dropout: float = 0.0):
        super().__init__()
        self.cls = nn.Parameter(torch.randn(1, 1, dim) * 0.02)
        layer = nn.TransformerEncoderLayer(
            dim, n_heads, 2 * dim, dropout, activation="gelu", batch_first=True, norm_first=True
        )
        self.encoder = nn.TransformerEncoder(layer, n_layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(dim)

    def forward(self, emb: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """emb (B, L, dim), mask (B, L) True on real faces -> (B, dim)."""
        x = torch.cat([self.cls.expand(len(emb), -1, -1), emb], 1)
        pad = torch.cat([mask.new_zeros(len(mask), 1), ~mask], 1)
        *inner, last = self.encoder.layers
        with _inner_path():
            for layer in inner:
                x = layer(x, src_key_padding_mask=pad)
        return self.norm(_cls_only(last, x, pad))


@contextlib.contextmanager
def _inner_path():
    """Without grad, ``nn.TransformerEncoderLayer`` takes a fast path that forms every head's
    full attention matrix when a padding mask is given: predicting 32 meshes of 3,000-4,000
    faces with the paper preset's aggregator (6 layers, width 256, 8 heads) peaked at 61.8 GiB
    on an H200, against 1.1 GiB (and 174 instead of 280 ms) through
    ``scaled_dot_product_attention`` as in training (perf/results/paper_speed.json,
    ``aggregator_probe``; ``perf/paper_speed.py --probe``)."""
    enabled = torch.backends.mha.get_fastpath_enabled()
    torch.backends.mha.set_fastpath_enabled(False)
    try:
        yield
    finally:
        torch.backends.mha.set_fastpath_enabled(enabled)


def _cls_only(
    layer: nn.TransformerEncoderLayer, x: torch.Tensor, pad: torch.Tensor
) -> torch.Tensor:
    """Row 0 of a pre-norm encoder layer's output, (B, dim): the CLS query attends over
    every token's keys and values; the other rows' attention and feed-forward are skipped.
    The attention is ``layer.self_attn``'s arithmetic written out for one query, without
    its transposed copies of every token's keys and values."""
    attn = layer.self_attn
    b, n, d = x.shape
    heads = attn.num_heads
    h = layer.norm1(x)
    w, bias = attn.in_proj_weight, attn.in_proj_bias  # rows: query, key, value
    q = F.linear(h[:, 0], w[:d], bias[:d]).view(b, heads, 1, d // heads)
    k, v = F.linear(h, w[d:], bias[d:]).view(b, n, 2, heads, d // heads).permute(2, 0, 3, 1, 4)
    o = F.scaled_dot_product_attention(
        q, k, v, attn_mask=~pad[:, None, None, :], dropout_p=attn.dropout if layer.training else 0.0
    )
    x = x[:, 0] + layer.dropout1(attn.out_proj(o.reshape(b, d)))
    return x + layer._ff_block(layer.norm2(x))
