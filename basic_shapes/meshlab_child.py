"""MeshLab's remeshing filters in a child process whose memory layout is always the same.

MeshLab's isotropic remeshing depends on where the process's memory lies (the same call gave
3,110 or 3,111 vertices in fresh processes; docs/GENERATOR.md, "Out-of-distribution meshes",
*Determinism*): on address randomization, on the interpreter's hash seed, on whatever ran
before. So the remeshers run here: one child per object, started with address randomization
off, a fixed environment, working directory and command line, importing only numpy and
pymeshlab, and given that object's calls in their deterministic order. Its results then depend
only on those calls (on one installation: another Python or pymeshlab build lays memory out
differently). The likely cause, an uninitialized default of ``checksurfdist``, is pinned by
the caller too (remesh._remesh); this child guards against others.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys

import numpy as np

ADDR_NO_RANDOMIZE = 0x0040000

CHILD = r"""
import ctypes, os, sys
libc = ctypes.CDLL(None)
persona = libc.personality(0xffffffff)
if not persona & 0x0040000:  # re-exec once without address randomization
    if libc.personality(persona | 0x0040000) != -1:
        os.execv(sys.executable, [sys.executable, "-s", "-c", sys.argv[-1], sys.argv[-1]])
import io, json
from pathlib import Path
import numpy as np
import pymeshlab as pm
gomp = Path(pm.__file__).parent / "lib" / "libgomp.so.1"
if gomp.exists():
    ctypes.CDLL(str(gomp)).omp_set_num_threads(1)
inp, out = sys.stdin.buffer, sys.stdout.buffer
def send(arr):
    b = io.BytesIO()
    np.save(b, arr, allow_pickle=False)
    out.write(len(b.getvalue()).to_bytes(8, "little") + b.getvalue())
def recv():
    return np.load(io.BytesIO(inp.read(int.from_bytes(inp.read(8), "little"))),
                   allow_pickle=False)
while True:
    line = inp.readline()
    if not line:
        break
    name, kw = json.loads(line)
    v, f = recv(), recv()
    ms = pm.MeshSet()
    ms.add_mesh(pm.Mesh(vertex_matrix=v, face_matrix=f))
    if "targetlen" in kw:
        kw["targetlen"] = pm.PureValue(kw["targetlen"])
    getattr(ms, name)(**kw)
    m = ms.current_mesh()
    send(m.vertex_matrix())
    send(m.face_matrix())
    out.flush()
"""

ENV = {"PATH": "/usr/bin:/bin", "PYTHONHASHSEED": "0", "OMP_NUM_THREADS": "1", "LC_ALL": "C"}
"""The child's whole environment: nothing of the caller's (its size moves the stack)."""


def _send(pipe, arr: np.ndarray) -> None:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    pipe.write(len(buf.getvalue()).to_bytes(8, "little") + buf.getvalue())


def _recv(pipe) -> np.ndarray:
    return np.load(io.BytesIO(pipe.read(int.from_bytes(pipe.read(8), "little"))),
                   allow_pickle=False)


class MeshLabChild:
    """A child process that applies MeshLab filters; use as a context manager."""

    def __enter__(self) -> MeshLabChild:
        self._proc = subprocess.Popen([sys.executable, "-s", "-c", CHILD, CHILD],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      env=ENV, cwd="/")
        return self

    def __exit__(self, *exc) -> None:
        self._proc.stdin.close()
        self._proc.wait()

    def apply(self, filter_name: str, vertices: np.ndarray, faces: np.ndarray,
              **kwargs) -> tuple[np.ndarray, np.ndarray]:
        """``MeshSet.<filter_name>(**kwargs)`` on one mesh; its result (vertices, faces).
        ``targetlen`` is an absolute length (MeshLab's PureValue)."""
        pipe = self._proc.stdin
        pipe.write(json.dumps([filter_name, kwargs]).encode() + b"\n")
        _send(pipe, np.asarray(vertices, np.float64))
        _send(pipe, np.asarray(faces, np.int32))
        pipe.flush()
        try:  # numpy's own array format both ways, length-prefixed: nothing is unpickled
            return _recv(self._proc.stdout), _recv(self._proc.stdout)
        except (ValueError, EOFError):
            raise RuntimeError(f"MeshLab child died during {filter_name} "
                               f"(exit code {self._proc.wait()})") from None
