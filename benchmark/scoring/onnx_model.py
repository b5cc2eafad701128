"""The ONNX model contract of the ranked track: one mesh in, its label grid out.

Documented for submitters in docs/SUBMITTING.md, section 3.

A model for the board is an ONNX file: data only (a graph of standard operators and its
tensors), no pickles, no code. The board runs it with onnxruntime, one mesh per call. Its
graph inputs are a subset of ``INPUTS``, by name; the board computes each one the model declares
and nothing else:

====================== ========= ========= =========================================================
name                   dtype     shape     value
====================== ========= ========= =========================================================
``vertices``           float32   [V, 3]    the mesh's vertices, normalized as
                                           ``benchmark.scoring.data.normalize_mesh`` does (centred
                                           on the mesh's bounding box, divided by the object's
                                           largest extent: the longest axis spans [-0.5, 0.5])
``faces``              int64     [F, 3]    0-based triangle indices
``scale_m``            float64   [3]       the object's bounding-box extents in metres
``scale_bins``         int64     [3]       the dataset's per-axis scale bins (``ScaleBins.index``)
``face_direct``        float32   [F, 15]   ``mesh_features.face_features`` (centre, corner
                                           vectors in the canonical corner order, unit normal)
``face_tokens``        int64     [F, 16]   ``mesh_features.face_features`` (discretized
                                           coordinates, angles, log area, normal; 0..127)
``face_edges``         int64     [2, E]    ``mesh_features.face_adjacency`` (faces sharing an
                                           edge, both directions, sorted)
``ray_probes``         float32   [256, 12] ``mesh_features.ray_probes`` (nearest and farthest
                                           hit along 256 fixed rays from the bounding-box centre)
``surface_points``     float32   [512, 6]  ``mesh_features.surface_points`` (points uniform by
                                           area on the surface, fixed seed, with the normal of
                                           their face)
``surface_neighbours`` int64     [512, 16] ``mesh_features.point_neighbours`` (each surface
                                           point's 16 nearest, itself first)
``normal_descriptor``  float32   [22]      ``mesh_features.normal_descriptor`` (area-weighted
                                           face-normal statistics that name the primitive)
====================== ========= ========= =========================================================

The last seven are deterministic numpy functions of ``vertices`` and ``faces``
(``benchmark.scoring.mesh_features``); a model may compute its own from ``vertices`` and
``faces`` instead. The one output (any name) is the predicted label grid in dB,
float32 [n_aspect, n_roll, n_range] on the dataset's radar grid (``BenchmarkData.target_shape``):
``20 log10(max(|profile|, 1e-4))``, as ``benchmark.scoring.data.db_target``.

``inspect`` validates a file before anything runs it (ONNX checker; standard operator domains
only, no custom operators or local functions; no external data; inputs from ``INPUTS`` with
their dtype and rank; one float output of rank 3) and counts its parameters from the graph:
every element of every stored tensor (initializers, sparse initializers, tensor attributes
such as ``Constant`` values), whatever the file claims. ``OnnxModel`` runs one behind the
benchmark's model protocol (``benchmark evaluate --model
benchmark.scoring.onnx_model:OnnxModel --model-arg path=model.onnx``), single-threaded.

Needs ``onnx`` and ``onnxruntime`` (the ``board`` extra); imported only when used.
"""

from __future__ import annotations

import hashlib
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np

CONTRACT = "basic-shapes-onnx-1"
MAX_MODEL_BYTES = 1 << 31  # protobuf's own limit for one file without external data
# name -> (numpy dtype, rank)
INPUTS: dict[str, tuple[str, int]] = {
    "vertices": ("float32", 2),
    "faces": ("int64", 2),
    "scale_m": ("float64", 1),
    "scale_bins": ("int64", 1),
    "face_direct": ("float32", 2),
    "face_tokens": ("int64", 2),
    "face_edges": ("int64", 2),
    "ray_probes": ("float32", 2),
    "surface_points": ("float32", 2),
    "surface_neighbours": ("int64", 2),
    "normal_descriptor": ("float32", 1),
}
STANDARD_DOMAINS = ("", "ai.onnx")  # the ONNX standard operators; no ai.onnx.ml, no contrib
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


class OnnxModelError(ValueError):
    """A model file breaks the contract, or running it failed (one line naming the file)."""


@dataclass(frozen=True)
class ModelInfo:
    """What the board records about a model file, all read from the file itself."""

    path: str
    sha256: str
    n_bytes: int
    params: int  # elements of every stored tensor of the graph
    inputs: tuple[str, ...]
    output: str
    opset: int
    producer: str
    metadata: tuple[tuple[str, str], ...] = ()  # the file's metadata_props: declared, unchecked


def _onnx():
    try:
        import onnx
    except ImportError as exc:
        raise OnnxModelError(
            f"the ONNX contract needs the onnx package ({exc}); install basic-shapes[board]"
        ) from None
    return onnx


def read_model_bytes(path: str | os.PathLike, max_bytes: int = MAX_MODEL_BYTES) -> bytes:
    """The bytes of a model file: a regular file, never read through a symbolic link."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        if os.path.islink(path):
            raise OnnxModelError(f"{path}: a symbolic link (pass its target)") from None
        raise OnnxModelError(f"{path}: {exc.strerror or exc.__class__.__name__}") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise OnnxModelError(f"{path}: not a regular file")
        raw = fh.read(min(st.st_size, max_bytes) + 1)  # read(n) reserves n bytes up front
    if len(raw) > max_bytes:
        raise OnnxModelError(f"{path}: larger than {max_bytes} bytes")
    return raw


def _subgraphs(graph):
    """``graph`` and every graph nested in its nodes' attributes (If, Loop, Scan bodies)."""
    yield graph
    for node in graph.node:
        for attr in node.attribute:
            if attr.HasField("g"):
                yield from _subgraphs(attr.g)
            for g in attr.graphs:
                yield from _subgraphs(g)


def _numel(dims) -> int:
    n = 1
    for d in dims:
        n *= int(d)
    return n


def count_parameters(model) -> int:
    """Elements of every tensor stored in the graph: initializers, sparse initializers (their
    stored values) and tensor-valued node attributes (``Constant`` and the like), in every
    subgraph. Shape constants count too (a handful of int64 elements in an exported graph)."""
    onnx = _onnx()
    total = 0
    for g in _subgraphs(model.graph):
        total += sum(_numel(t.dims) for t in g.initializer)
        total += sum(_numel(s.values.dims) for s in g.sparse_initializer)
        for node in g.node:
            for a in node.attribute:
                if a.type == onnx.AttributeProto.TENSOR:
                    total += _numel(a.t.dims)
                elif a.type == onnx.AttributeProto.TENSORS:
                    total += sum(_numel(t.dims) for t in a.tensors)
                elif a.type == onnx.AttributeProto.SPARSE_TENSOR:
                    total += _numel(a.sparse_tensor.values.dims)
                elif node.op_type == "Constant" and a.type in (
                    onnx.AttributeProto.FLOATS,
                    onnx.AttributeProto.INTS,
                ):
                    total += len(a.floats) + len(a.ints)
                elif node.op_type == "Constant" and a.type in (
                    onnx.AttributeProto.FLOAT,
                    onnx.AttributeProto.INT,
                ):
                    total += 1
    return total


def _external(model) -> bool:
    onnx = _onnx()
    for g in _subgraphs(model.graph):
        tensors = list(g.initializer) + [s.values for s in g.sparse_initializer]
        for node in g.node:
            for a in node.attribute:
                tensors += [a.t] if a.HasField("t") else []
                tensors += list(a.tensors)
        if any(
            t.data_location == onnx.TensorProto.EXTERNAL or len(t.external_data) for t in tensors
        ):
            return True
    return False


def inspect(path: str | os.PathLike, raw: bytes | None = None) -> ModelInfo:
    """Validate a model file against the contract (nothing is run); ``OnnxModelError`` in one
    line naming the file."""
    onnx = _onnx()
    raw = read_model_bytes(path) if raw is None else raw

    def fail(problem: str):
        raise OnnxModelError(f"{path}: {problem}")

    if raw.startswith(HDF5_SIGNATURE):
        fail(
            "an HDF5 file (a predictions file?), not an ONNX model: the ranked track runs "
            "ONNX models only; predictions are scored on the self-scored track "
            "(leaderboard submit)"
        )
    try:
        model = onnx.load_model_from_string(raw)
    except Exception:
        fail("not an ONNX model (it does not parse as an ONNX ModelProto)")
    if not model.HasField("graph") or not model.ir_version:
        fail("not an ONNX model (no graph or IR version)")
    _check_operators(model, fail)
    names, out = _check_io(model, fail)
    opset = max((o.version for o in model.opset_import if o.domain in STANDARD_DOMAINS), default=0)
    return ModelInfo(
        path=str(path),
        sha256=hashlib.sha256(raw).hexdigest(),
        n_bytes=len(raw),
        params=count_parameters(model),
        inputs=tuple(names),
        output=out.name,
        opset=int(opset),
        producer=f"{model.producer_name} {model.producer_version}".strip()[:80] or "unknown",
        metadata=tuple((p.key[:40], p.value[:80]) for p in model.metadata_props[:32]),
    )


def _check_operators(model, fail) -> None:
    """``inspect``: one self-contained file of standard ONNX operators that passes the checker."""
    onnx = _onnx()
    if _external(model):
        fail("refers to external data; store every tensor inside the one .onnx file")
    domains = sorted({o.domain for o in model.opset_import} - set(STANDARD_DOMAINS))
    if domains:
        fail(f"imports the operator domain {domains[0]!r}: only standard ONNX operators run here")
    if len(model.functions):
        fail("defines local functions: only standard ONNX operators run here")
    for g in _subgraphs(model.graph):
        for node in g.node:
            if node.domain not in STANDARD_DOMAINS:
                fail(
                    f"node {node.name or node.op_type!r} uses the custom operator "
                    f"{node.domain}.{node.op_type}: only standard ONNX operators run here"
                )
    try:
        onnx.checker.check_model(model)
    except Exception as exc:
        lines = str(exc).strip().splitlines()
        fail(f"fails the ONNX checker ({lines[0][:200] if lines else exc.__class__.__name__})")


def _check_io(model, fail) -> tuple[list[str], object]:
    """``inspect``: the inputs the contract defines (names, dtypes, ranks), one dB-grid output."""
    onnx = _onnx()
    from onnx import helper

    initializers = {t.name for t in model.graph.initializer}
    inputs = [i for i in model.graph.input if i.name not in initializers]
    names = []
    for i in inputs:
        if i.name not in INPUTS:
            fail(
                f"has the input {i.name[:40]!r}, which the contract does not define "
                f"(inputs: {', '.join(INPUTS)})"
            )
        dtype, rank = INPUTS[i.name]
        tt = i.type.tensor_type
        if not i.type.HasField("tensor_type") or helper.tensor_dtype_to_np_dtype(
            tt.elem_type
        ) != np.dtype(dtype):
            fail(f"input {i.name} must be a {dtype} tensor")
        if tt.HasField("shape") and len(tt.shape.dim) != rank:
            fail(f"input {i.name} must have rank {rank}, not {len(tt.shape.dim)}")
        names.append(i.name)
    if len(model.graph.output) != 1:
        fail(f"has {len(model.graph.output)} outputs; the contract has one (the dB grid)")
    out = model.graph.output[0]
    tt = out.type.tensor_type
    if not out.type.HasField("tensor_type") or tt.elem_type != onnx.TensorProto.FLOAT:
        fail("its output must be a float32 tensor (the dB grid)")
    if tt.HasField("shape") and len(tt.shape.dim) != 3:
        fail(f"its output must have rank 3 (aspect, roll, range), not {len(tt.shape.dim)}")
    return names, out


# --- inputs and running ------------------------------------------------------------------
def mesh_inputs(
    names,
    vertices: np.ndarray,
    faces: np.ndarray,
    scale_m: np.ndarray,
    scale_bins: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The inputs ``names`` of one mesh (normalized ``vertices``, ``faces``, the object's
    ``scale_m``), each computed only if asked for."""
    from benchmark.scoring import mesh_features as mf

    names = set(names)
    v = np.ascontiguousarray(vertices, np.float32)
    f = np.ascontiguousarray(faces, np.int64)
    out = {"vertices": v, "faces": f, "scale_m": np.asarray(scale_m, np.float64).reshape(3)}
    if "scale_bins" in names:
        if scale_bins is None:
            raise ValueError("the model asks for scale_bins: pass the dataset's")
        out["scale_bins"] = np.asarray(scale_bins, np.int64).reshape(3)
    if names & {"face_direct", "face_tokens"}:
        out["face_direct"], out["face_tokens"], _ = mf.face_features(v, f)
    if "face_edges" in names:
        out["face_edges"] = mf.face_adjacency(f)
    if "ray_probes" in names:
        out["ray_probes"] = mf.ray_probes(v, f)
    if names & {"surface_points", "surface_neighbours"}:
        out["surface_points"] = mf.surface_points(v, f)
    if "surface_neighbours" in names:
        out["surface_neighbours"] = mf.point_neighbours(out["surface_points"])
    if "normal_descriptor" in names:
        out["normal_descriptor"] = mf.normal_descriptor(v, f).astype(np.float32)
    return {k: out[k] for k in names}


def session(raw: bytes, threads: int = 1):
    """An onnxruntime CPU session of a model's bytes: ``threads`` intra- and inter-op threads,
    sequential execution, no thread spinning."""
    try:
        import onnxruntime as ort
    except ImportError as exc:
        raise OnnxModelError(
            f"running ONNX models needs onnxruntime ({exc}); install basic-shapes[board]"
        ) from None
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = threads
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.log_severity_level = 3
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.add_session_config_entry("session.inter_op.allow_spinning", "0")
    return ort.InferenceSession(raw, so, providers=["CPUExecutionProvider"])


def check_output(out, target_shape: tuple[int, ...], where: str) -> np.ndarray:
    """One run's output as float32 ``target_shape``; ``OnnxModelError`` if it is not that."""
    arr = np.asarray(out)
    if arr.shape != tuple(target_shape) or arr.dtype != np.float32:
        raise OnnxModelError(
            f"{where}: the model returned {arr.dtype}{list(arr.shape)}, expected "
            f"float32{list(target_shape)} (the dataset's aspect x roll x range grid)"
        )
    if not np.all(np.isfinite(arr)):
        raise OnnxModelError(f"{where}: the model returned non-finite values")
    return arr


class OnnxModel:
    """An ONNX model file behind the benchmark's model protocol (``predict(batch)``), one mesh
    per onnxruntime call, ``threads`` threads (1: as the board runs it)."""

    embedding, regime = None, None

    def __init__(self, path: str | os.PathLike, threads: int | str = 1, name: str | None = None):
        raw = read_model_bytes(path)
        self.info = inspect(path, raw)
        self.name = name or Path(path).stem
        self.params = self.info.params
        self.session = session(raw, int(threads))

    def predict(self, batch: dict) -> np.ndarray:
        out = []
        for i, (v, f) in enumerate(zip(batch["vertices"], batch["faces"])):
            feeds = mesh_inputs(
                self.info.inputs,
                v,
                f,
                batch["scale_m"][i],
                batch["scale_bins"][i] if "scale_bins" in batch else None,
            )
            (pred,) = self.session.run(None, feeds)
            out.append(np.asarray(pred, np.float32))
        return np.stack(out)
