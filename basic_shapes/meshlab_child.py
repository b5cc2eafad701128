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
import tempfile

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


class MeshLabError(OSError):
    """The MeshLab child ended without answering (killed, out of memory, crashed)."""


class MeshLabChild:
    """A child process that applies MeshLab filters; use as a context manager.

    The child's stderr is a file of its own, read only to explain its death: a child whose
    parent died (a killed worker, an interrupted job) fails writing to the pipe, and its
    traceback must not reach the user's terminal (its program text, part of its fixed memory
    layout, stays as it is)."""

    def __enter__(self) -> MeshLabChild:
        self._stderr = tempfile.TemporaryFile()
        self._proc = subprocess.Popen([sys.executable, "-s", "-c", CHILD, CHILD],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=self._stderr, env=ENV, cwd="/")
        return self

    def __exit__(self, *exc) -> None:
        for pipe in (self._proc.stdin, self._proc.stdout):  # a child still writing stops too
            try:
                pipe.close()
            except OSError:  # BrokenPipeError flushing to a child that is gone
                pass
        self._proc.wait()
        self._stderr.close()

    def apply(self, filter_name: str, vertices: np.ndarray, faces: np.ndarray,
              **kwargs) -> tuple[np.ndarray, np.ndarray]:
        """``MeshSet.<filter_name>(**kwargs)`` on one mesh; its result (vertices, faces).
        ``targetlen`` is an absolute length (MeshLab's PureValue). ``MeshLabError`` if the
        child dies."""
        try:  # numpy's own array format both ways, length-prefixed: nothing is unpickled
            pipe = self._proc.stdin
            pipe.write(json.dumps([filter_name, kwargs]).encode() + b"\n")
            _send(pipe, np.asarray(vertices, np.float64))
            _send(pipe, np.asarray(faces, np.int32))
            pipe.flush()
            return _recv(self._proc.stdout), _recv(self._proc.stdout)
        except (OSError, ValueError, EOFError):
            try:
                code = self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:  # alive but talking nonsense
                self._proc.kill()
                code = self._proc.wait()
            raise MeshLabError(f"MeshLab child died during {filter_name} (exit code "
                               f"{code}{self._last_words()})") from None

    def _last_words(self) -> str:
        """The last line the child wrote to stderr (its exception), as ``: <line>``."""
        self._stderr.seek(0, 2)
        self._stderr.seek(max(0, self._stderr.tell() - 4096))
        lines = self._stderr.read().decode(errors="replace").strip().splitlines()
        return f": {lines[-1][:200]}" if lines else ""
