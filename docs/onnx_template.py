"""Template: a PyTorch model exported to the board's ONNX contract (docs/SUBMITTING.md, section 2).

Copy this file, replace ``TinyMeshModel`` by your model, keep ``forward``'s signature: one mesh
per call, inputs named as the contract names them (here ``vertices``, ``faces``, ``scale_m``;
any subset of ``benchmark.scoring.onnx_model.INPUTS``), one output, the dB grid
float32 [n_aspect, n_roll, n_range] of the dataset. Then

    python onnx_template.py --data data/tiny-v1 --out my-model.onnx --epochs 20

trains it on the dataset's training split (simple meshes), exports it with torch's
TorchScript-based exporter (``dynamo=False``: no onnxscript needed), validates the file as the
board will (``inspect``: standard operators only, no external data) and checks that
onnxruntime (one thread, as on the board) gives the PyTorch model's predictions on test meshes.
Its last line is the largest difference in dB. Submit the .onnx file (docs/SUBMITTING.md).

Needs torch and basic-shapes[board] (onnx, onnxruntime).
"""

from __future__ import annotations

import argparse
import io
import math
import warnings

import numpy as np
import torch
from torch import nn

from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.onnx_model import OnnxModel, inspect


class TinyMeshModel(nn.Module):
    """Per-face MLP on (centre, unit normal), area-weighted mean over faces (so a finer meshing
    of the same surface changes little), the log scale, an MLP to the grid."""

    def __init__(self, target_shape: tuple[int, int, int], hidden: int = 64):
        super().__init__()
        self.target_shape = tuple(target_shape)
        n_out = math.prod(self.target_shape)
        self.face_mlp = nn.Sequential(nn.Linear(6, hidden), nn.GELU(), nn.Linear(hidden, hidden))
        self.head = nn.Sequential(
            nn.Linear(hidden + 3, hidden), nn.GELU(), nn.Linear(hidden, n_out)
        )
        self.register_buffer("offset", torch.zeros(n_out))

    def forward(self, vertices: torch.Tensor, faces: torch.Tensor, scale_m: torch.Tensor):
        tri = vertices[faces]  # (F, 3, 3)
        a, b = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        cross = torch.stack(  # written out: torch.linalg.cross has no ONNX export
            [
                a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
            ],
            -1,
        )
        area = cross.norm(dim=-1, keepdim=True)
        normal = cross / area.clamp_min(1e-12)
        weight = area / area.sum().clamp_min(1e-12)
        pooled = (self.face_mlp(torch.cat([tri.mean(1), normal], -1)) * weight).sum(0)
        x = torch.cat([pooled, torch.log(scale_m).to(torch.float32)])
        return (self.offset + self.head(x)).reshape(self.target_shape)


def examples(data: BenchmarkData, split: str, variants: str = "simple"):
    """(vertices, faces, scale_m, target dB) of every mesh of ``split`` (the inputs as the board
    gives them: ``BenchmarkData.batch``)."""
    for row in data.mesh_rows(split, variants=variants):
        b = data.batch(np.array([row]))
        obj = int(data.meshes["object"][row])
        yield (
            torch.from_numpy(b["vertices"][0]),
            torch.from_numpy(b["faces"][0].astype(np.int64)),
            torch.from_numpy(b["scale_m"][0]),
            torch.from_numpy(data.target(obj)),
        )


def train(model: TinyMeshModel, data: BenchmarkData, epochs: int, lr: float = 3e-3) -> None:
    items = list(examples(data, "train"))
    with torch.no_grad():
        model.offset.copy_(torch.stack([t.flatten() for *_, t in items]).mean(0))
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(0)
    for epoch in range(epochs):
        total = 0.0
        for i in torch.randperm(len(items), generator=gen).tolist():
            v, f, s, target = items[i]
            loss = torch.mean((model(v, f, s) - target) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item()
        print(f"epoch {epoch + 1}: train MSE {total / len(items):.2f} dB²", flush=True)


def export(model: TinyMeshModel, example: tuple, path: str) -> None:
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the legacy exporter's deprecation notice
        torch.onnx.export(
            model.eval(),
            example,
            buf,
            dynamo=False,
            opset_version=17,
            input_names=["vertices", "faces", "scale_m"],  # the contract's names
            output_names=["target_db"],
            dynamic_axes={"vertices": {0: "V"}, "faces": {0: "F"}},
        )
    with open(path, "wb") as fh:
        fh.write(buf.getvalue())


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="a public labelled dataset (for training)")
    p.add_argument("--out", required=True, help="the .onnx file to write")
    p.add_argument("--epochs", type=int, default=20)
    args = p.parse_args(argv)
    torch.manual_seed(0)
    torch.set_num_threads(1)
    with BenchmarkData(args.data) as data:
        model = TinyMeshModel(data.target_shape)
        train(model, data, args.epochs)
        model.eval()
        test = list(examples(data, "test", "all"))[:8]
        export(model, test[0][:3], args.out)
        info = inspect(args.out)  # what the board checks first
        runner = OnnxModel(args.out)  # onnxruntime, one thread
        worst = 0.0
        for v, f, s, _ in test:
            with torch.no_grad():
                want = model(v, f, s).numpy()
            got = runner.predict(
                {"vertices": [v.numpy()], "faces": [f.numpy()], "scale_m": s.numpy()[None]}
            )[0]
            worst = max(worst, float(np.max(np.abs(got - want))))
    print(f"{args.out}: {info.params} parameters counted from the graph, inputs {info.inputs}")
    print(f"max |ONNX - PyTorch| on {len(test)} test meshes: {worst:.2e} dB")


if __name__ == "__main__":
    main()
