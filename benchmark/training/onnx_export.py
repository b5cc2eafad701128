"""`benchmark export-onnx`: a trained checkpoint -> an ONNX file under the board's contract.

The contract (``benchmark.scoring.onnx_model``): one mesh per call, the mesh arrays (and the
board-computed features a model declares) in, the dB label grid out. ``OnnxSimulator`` wraps
a checkpoint's ``MeshSimulator`` with the same weights, written with export-friendly operators
for one mesh:

- the graph embedding's sparse one-hot product is the gather of its 16 token tables and the
  projection (the same linear map, unfolded, so the file stores the model's own weights);
- SAGEConv's mean over neighbours is a scatter-add over ``face_edges`` divided by the degree;
- the token embedding's residual VQ is the nearest codebook vector per quantizer (eval mode:
  codebooks fixed), summed;
- the meshgraph, pointcloud and regressor embeddings run their own code on one mesh
  (``packed``, ``encode``, ``embed``: scatter-add, dense EdgeConv, an MLP);
- the aggregator's attention is written out (one mesh: no padding mask);
- the object's scale bins are computed in the graph from ``scale_m`` and the checkpoint's own
  bin edges (float64), as ``CheckpointModel`` recomputes them.

``export`` writes the file with torch's TorchScript-based exporter (``dynamo=False``: no
onnxscript needed), validates it with the board's own ``inspect``, then runs it with
onnxruntime (one thread) on check meshes and compares with the PyTorch model
(``CheckpointModel.predict``): the largest absolute difference in dB must be at most
``tolerance`` or the file is removed. Check meshes: every test mesh of ``--check-data``, or
(default) a box, a cylinder and an icosphere.
"""

from __future__ import annotations

import io
import json
import math
import os
import sys
import warnings
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from basic_shapes.infra import atomic_path
from benchmark.scoring import onnx_model
from benchmark.scoring.data import ScaleBins, normalize_mesh
from benchmark.training.models import MeshSimulator
from benchmark.training.models.checkpoint import CheckpointModel, load_checkpoint
from benchmark.training.models.token import TokenEmbedding

OPSET = 17
TOLERANCE_DB = 0.01  # default: largest |ONNX - PyTorch| allowed on any check mesh, in dB
# the contract inputs each embedding reads (besides scale_m)
INPUT_NAMES = {
    "direct": ("face_direct",),
    "graph": ("face_tokens", "face_edges"),
    "token": ("face_tokens", "face_edges"),
    "invariant": ("ray_probes",),
    "blind": (),
    "meshgraph": ("face_direct", "face_edges"),
    "pointcloud": ("surface_points", "surface_neighbours"),
    "regressor": ("normal_descriptor",),
}
DYNAMIC = {"face_direct": {0: "F"}, "face_tokens": {0: "F"}, "face_edges": {1: "E"}}


class OnnxSimulator(nn.Module):
    """A checkpoint's model for one mesh, under the ONNX contract: ``forward(*inputs)`` with
    the inputs ``INPUT_NAMES[kind] + ("scale_m",)`` -> float32 (n_aspect, n_roll, n_range)."""

    def __init__(self, model: MeshSimulator, config: dict):
        super().__init__()
        self.kind = config["model"]["name"]
        if self.kind not in INPUT_NAMES:
            raise ValueError(f"no ONNX export for the embedding {self.kind!r}")
        self.model = model.eval()
        self.target_shape = tuple(int(n) for n in config["target_shape"])
        edges = ScaleBins(**config["scale_bins"]).edges
        self.register_buffer("inner_edges", torch.tensor(edges[1:-1], dtype=torch.float64))
        self.input_names = (*INPUT_NAMES[self.kind], "scale_m")

    # --- embeddings, one mesh: (L, dim) ------------------------------------------------------
    def _graph_nodes(self, graph, tokens: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
        x = torch.cat([graph.tables[g](tokens[:, j]) for j, g in enumerate(graph.positions)], -1)
        x = graph.proj(x)
        src, dst = edges[0], edges[1]
        # scatter_add, not index_add: the legacy exporter writes index_add as a ScatterElements
        # without reduction (duplicates overwrite instead of adding)
        ones = torch.ones_like(dst, dtype=x.dtype)
        degree = torch.zeros_like(x[:, 0]).scatter_add(0, dst, ones).clamp(min=1.0)
        index = dst[:, None].expand(-1, x.shape[1])
        for conv, norm in zip(graph.convs, graph.norms):
            if conv.project or conv.normalize or not conv.root_weight or conv.aggr != "mean":
                raise ValueError("only SAGEConv(aggr='mean', root_weight=True) is exported")
            total = torch.zeros_like(x).scatter_add(0, index, x.index_select(0, src))
            h = conv.lin_l(total / degree[:, None]) + conv.lin_r(x)
            x = x + F.gelu(norm(h))
        return x

    def _quantize(self, emb: TokenEmbedding, x: torch.Tensor) -> torch.Tensor:
        residual, out = x, torch.zeros_like(x)
        for layer in emb.vq.layers:
            book = layer._codebook
            if (
                not isinstance(layer.project_in, nn.Identity)
                or book.embed.shape[0] != 1
                or getattr(layer, "use_cosine_sim", False)
            ):
                raise ValueError("only a single-head Euclidean residual VQ is exported")
            codes = book.embed[0]  # (codebook_size, dim)
            dist = (
                residual.pow(2).sum(-1, keepdim=True)
                - 2 * residual @ codes.t()
                + codes.pow(2).sum(-1)[None]
            )
            q = codes.index_select(0, dist.argmin(-1))
            out, residual = out + q, residual - q
        return out

    def _embed(self, inputs: dict) -> torch.Tensor:
        emb = self.model.embedding
        if self.kind == "direct":
            return emb.proj(inputs["face_direct"])
        if self.kind == "graph":
            return self._graph_nodes(emb, inputs["face_tokens"], inputs["face_edges"])
        if self.kind == "token":
            x = self._graph_nodes(emb.graph, inputs["face_tokens"], inputs["face_edges"])
            return self._quantize(emb, x)
        if self.kind == "invariant":
            return emb.mlp(inputs["ray_probes"])
        if self.kind == "meshgraph":
            return emb.packed(inputs["face_direct"], inputs["face_edges"])
        if self.kind == "pointcloud":
            return emb.encode(inputs["surface_points"][None], inputs["surface_neighbours"][None])[0]
        if self.kind == "regressor":
            return emb.embed(inputs["normal_descriptor"][None], inputs["scale_m"][None])
        return emb.token[0]  # blind: (1, dim)

    # --- aggregator, one mesh ----------------------------------------------------------------
    @staticmethod
    def _attention(layer, h: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
        """Multi-head attention of ``query`` rows (Q, dim) over ``h`` (N, dim), in eval."""
        attn = layer.self_attn
        d, heads = h.shape[-1], attn.num_heads
        w, b = attn.in_proj_weight, attn.in_proj_bias
        q = F.linear(query, w[:d], b[:d]).view(-1, heads, d // heads).transpose(0, 1)
        k = F.linear(h, w[d : 2 * d], b[d : 2 * d]).view(-1, heads, d // heads).transpose(0, 1)
        v = F.linear(h, w[2 * d :], b[2 * d :]).view(-1, heads, d // heads).transpose(0, 1)
        scores = q @ k.transpose(1, 2) / math.sqrt(d // heads)
        o = torch.softmax(scores, -1) @ v  # (heads, Q, dim / heads)
        return attn.out_proj(o.transpose(0, 1).reshape(-1, d))

    def _aggregate(self, emb: torch.Tensor) -> torch.Tensor:
        agg = self.model.aggregator
        x = torch.cat([agg.cls[0], emb], 0)  # (1 + L, dim)
        *inner, last = agg.encoder.layers
        for layer in inner:  # pre-norm layers, every row
            h = layer.norm1(x)
            x = x + self._attention(layer, h, h)
            x = x + layer._ff_block(layer.norm2(x))
        h = last.norm1(x)  # the last layer for the CLS row alone (Aggregator._cls_only)
        y = x[:1] + self._attention(last, h, h[:1])
        y = y + last._ff_block(last.norm2(y))
        return agg.norm(y)  # (1, dim)

    def forward(self, *args: torch.Tensor) -> torch.Tensor:
        inputs = dict(zip(self.input_names, args))
        scale = inputs["scale_m"]
        bins = (scale[:, None] >= self.inner_edges[None, :]).to(torch.int64).sum(-1)
        z = self._aggregate(self._embed(inputs))
        out = self.model.decoder(z, bins[None])
        return out.reshape(self.target_shape)


def example_inputs(module: OnnxSimulator, vertices, faces, scale_m) -> tuple[torch.Tensor, ...]:
    feeds = onnx_model.mesh_inputs(module.input_names, vertices, faces, scale_m)
    return tuple(torch.from_numpy(feeds[n]) for n in module.input_names)


def check_meshes(data_dir: str | os.PathLike | None = None, limit: int | None = None) -> list:
    """(normalized vertices, faces int64, scale_m) of the meshes an export is checked on."""
    if data_dir is not None:
        from benchmark.scoring.data import BenchmarkData
        from benchmark.scoring.protocol import scored_mesh_rows

        with BenchmarkData(data_dir) as data:
            rows = scored_mesh_rows(data)[:limit]
            out = []
            for r in rows:
                b = data.batch(np.array([r]))
                out.append((b["vertices"][0], b["faces"][0].astype(np.int64), b["scale_m"][0]))
            return out
    import trimesh

    meshes = [
        trimesh.creation.box(extents=(0.4, 0.7, 1.1)),
        trimesh.creation.cylinder(radius=0.3, height=0.8, sections=24),
        trimesh.creation.icosphere(subdivisions=2, radius=0.45),
    ]
    out = []
    for m in meshes[:limit]:
        scale = m.extents.astype(np.float64)
        out.append((normalize_mesh(m.vertices, scale), m.faces.astype(np.int64), scale))
    return out


def to_onnx(module: OnnxSimulator, example: tuple[torch.Tensor, ...]) -> bytes:
    """The ONNX bytes of ``module`` (opset ``OPSET``, dynamic face and edge counts)."""
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the legacy exporter's deprecation and tracer notes
        torch.onnx.export(
            module,
            example,
            buf,
            dynamo=False,
            opset_version=OPSET,
            input_names=list(module.input_names),
            output_names=["target_db"],
            dynamic_axes={n: DYNAMIC[n] for n in module.input_names if n in DYNAMIC},
            do_constant_folding=True,
        )
    return buf.getvalue()


def with_metadata(raw: bytes, metadata: dict) -> bytes:
    """``raw`` with ``metadata`` as the model's metadata_props (empty values left out) and
    this exporter as its producer."""
    import onnx

    from benchmark import __version__

    model = onnx.load_model_from_string(raw)
    model.producer_name, model.producer_version = "basic-shapes export-onnx", __version__
    for key, value in metadata.items():
        if value:
            prop = model.metadata_props.add()
            prop.key, prop.value = key, str(value)
    return model.SerializeToString()


def agreement(raw: bytes, checkpoint: str | os.PathLike, meshes: list) -> list[float]:
    """Largest |ONNX - PyTorch| in dB per mesh: onnxruntime (one thread) against the
    checkpoint's own protocol adapter (``CheckpointModel``), mesh by mesh."""
    info = onnx_model.inspect("exported model", raw)
    sess = onnx_model.session(raw, threads=1)
    reference = CheckpointModel(checkpoint)
    diffs = []
    for v, f, s in meshes:
        feeds = onnx_model.mesh_inputs(info.inputs, v, f, s)
        (got,) = sess.run(None, feeds)
        want = reference.predict(
            {"vertices": [v], "faces": [f], "scale_m": np.asarray(s, np.float64)[None]}
        )[0]
        diffs.append(float(np.max(np.abs(got.astype(np.float64) - want.astype(np.float64)))))
    return diffs


def export(
    checkpoint: str | os.PathLike,
    out: str | os.PathLike,
    *,
    check_data: str | os.PathLike | None = None,
    check_limit: int | None = None,
    tolerance: float = TOLERANCE_DB,
) -> dict:
    """Export one checkpoint to ``out`` and check it (see the module doc); return the report.
    Over ``tolerance`` the file is not written and ``ValueError`` says by how much."""
    model, config = load_checkpoint(checkpoint)
    module = OnnxSimulator(model, config).eval()
    meshes = check_meshes(check_data, check_limit)
    raw = with_metadata(
        to_onnx(module, example_inputs(module, *meshes[0])),
        {
            "contract": onnx_model.CONTRACT,
            "embedding": config["model"]["name"],
            "regime": config.get("regime") or "",
            "name": config.get("name") or Path(checkpoint).name,
        },
    )
    info = onnx_model.inspect(out, raw)
    diffs = agreement(raw, checkpoint, meshes)
    worst = max(diffs)
    report = {
        "checkpoint": str(checkpoint),
        "onnx": str(out),
        "sha256": info.sha256,
        "bytes": info.n_bytes,
        "inputs": list(info.inputs),
        "params_graph": info.params,
        "params_checkpoint": int(config.get("params", 0)),
        "meshes_checked": len(diffs),
        "max_abs_db": worst,
        "median_max_abs_db": float(np.median(diffs)),
        "tolerance_db": tolerance,
    }
    if not worst <= tolerance:
        raise ValueError(
            f"{checkpoint}: the ONNX export differs from the PyTorch model by up to "
            f"{worst:.3g} dB (tolerance {tolerance:g} dB) on {sum(d > tolerance for d in diffs)}"
            f" of {len(diffs)} check meshes; not written"
        )
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(raw)
    return report


def row_checkpoints(reproduce_out: str | os.PathLike) -> dict[str, Path]:
    """Each row of a ``benchmark reproduce --out`` folder -> its first training seed's
    checkpoint (OUT/checkpoints/<row>/seed-<s>/, the lowest s with a config.json)."""
    found = {}
    for row in sorted(Path(reproduce_out, "checkpoints").iterdir()):
        seeds = sorted(
            (p for p in row.glob("seed-*") if (p / "config.json").is_file()),
            key=lambda p: int(p.name.removeprefix("seed-")),
        )
        if seeds and row.is_dir():
            found[row.name] = seeds[0]
    if not found:
        raise ValueError(f"{reproduce_out}: no checkpoints/<row>/seed-<s>/ (benchmark reproduce)")
    return found


# --- CLI ---------------------------------------------------------------------------------
def add_arguments(p) -> None:
    from basic_shapes.infra import add_quiet_flag, number

    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("checkpoint", nargs="?", help="checkpoint directory (model.pt, config.json)")
    src.add_argument(
        "--from",
        dest="reproduce",
        metavar="OUT",
        help="every row of `benchmark reproduce --out OUT` (its first seed): OUT/checkpoints/"
        "<row>/seed-<s>/ -> --out DIR/<row>.onnx",
    )
    p.add_argument(
        "--out", required=True, help="the .onnx file to write (with --from: a directory)"
    )
    p.add_argument(
        "--check-data",
        metavar="DIR",
        help="check agreement on every test mesh of this dataset (default: a box, a "
        "cylinder and an icosphere)",
    )
    p.add_argument(
        "--check-limit",
        type=number(int, minimum=1),
        help="check on the first N test meshes of --check-data only",
    )
    p.add_argument(
        "--tolerance",
        type=number(float, minimum=0),
        default=TOLERANCE_DB,
        help="largest |ONNX - PyTorch| allowed on a check mesh, dB (default: %(default)s)",
    )
    add_quiet_flag(p)


def run(args) -> int:
    from basic_shapes.infra import separate_outputs

    torch.set_num_threads(1)
    jobs = (
        {
            row: (ckpt, Path(args.out) / f"{row}.onnx")
            for row, ckpt in row_checkpoints(args.reproduce).items()
        }
        if args.reproduce
        else {Path(args.checkpoint).name: (Path(args.checkpoint), Path(args.out))}
    )
    separate_outputs(
        {"--out": args.out},
        {
            "CHECKPOINT": args.checkpoint,
            "--from": Path(args.reproduce) / "checkpoints" if args.reproduce else None,
            "--check-data": args.check_data,
        },
    )
    reports = []
    for ckpt, out in jobs.values():
        reports.append(
            export(
                ckpt,
                out,
                check_data=args.check_data,
                check_limit=args.check_limit,
                tolerance=args.tolerance,
            )
        )
        if not args.quiet:
            r = reports[-1]
            print(
                f"exported {r['onnx']}: {r['params_graph']} parameters in the graph, "
                f"max |ONNX - PyTorch| {r['max_abs_db']:.2e} dB on {r['meshes_checked']} "
                f"meshes",
                file=sys.stderr,
                flush=True,
            )
    print(json.dumps(reports[0] if len(reports) == 1 and not args.reproduce else reports, indent=2))
    return 0
