"""basic_shapes.portable: stored numbers whose bits do not follow the CPU's BLAS kernel.

OpenBLAS picks its kernel by CPU model; ``OPENBLAS_CORETYPE`` picks it by name, so two
kernels can be compared on one machine: ``Haswell`` (an AVX2 host, AMD's EPYC among them)
and ``Prescott`` (SSE3, what any x86-64 runs). numpy's own BLAS calls give different bits
under the two; the portable functions must not.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from basic_shapes import portable

_PROBE = """
import hashlib, json
import numpy as np
from basic_shapes import portable
rng = np.random.default_rng(0)
v = rng.uniform(0.1, 2.0, size=(5000, 3))
a = rng.normal(size=(500, 4, 4)) + 4 * np.eye(4)
b = rng.normal(size=(500, 4))
h = lambda x: hashlib.sha256(np.ascontiguousarray(x, np.float64).tobytes()).hexdigest()
print(json.dumps({
    "portable": h(np.concatenate([
        [portable.norm(x) for x in v],
        portable.solve(a, b).ravel(),
        portable.matmul(v[:300], v[:300].T).ravel(),
    ])),
    "numpy": h([np.linalg.norm(x) for x in v]),
}))
"""


def _probe(kernel: str) -> dict:
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, "-c", _PROBE], capture_output=True, text=True, env=env, check=True
    )
    return json.loads(proc.stdout)


def test_same_bits_under_two_blas_kernels():
    """numpy's vector norm differs between the kernels (so the emulation is real); the
    portable norm, solve and matmul do not."""
    haswell, prescott = _probe("Haswell"), _probe("Prescott")
    assert haswell["numpy"] != prescott["numpy"]
    assert haswell["portable"] == prescott["portable"]


def test_norm_adds_the_squares_in_index_order():
    """The sum the Haswell kernel forms for a 3-vector (the recorded versions' bytes): each
    square rounded, then added left to right; on some vectors that is not the exactly
    rounded sum (math.fsum), so the order matters."""
    v = np.random.default_rng(2).uniform(0.1, 2.0, size=(2000, 3))
    in_order = [math.sqrt((x * x + y * y) + z * z) for x, y, z in v.tolist()]
    exact = [math.sqrt(math.fsum(c * c for c in row)) for row in v.tolist()]
    assert [portable.norm(row) for row in v] == in_order
    assert in_order != exact
    assert portable.norm([3.0, 4.0]) == 5.0 and portable.norm([]) == 0.0


def test_solve_agrees_with_lapack_and_marks_singular_systems():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(200, 4, 4)) + 4 * np.eye(4)
    b = rng.normal(size=(200, 4))
    x = portable.solve(a, b)
    np.testing.assert_allclose(x, np.linalg.solve(a, b[..., None])[..., 0], rtol=1e-10)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", a, x), b, atol=1e-12)
    a[0] = 0.0
    a[1, :, 2] = 0.0
    x = portable.solve(a, b)
    assert np.isnan(x[:2]).all() and np.isfinite(x[2:]).all()
    with pytest.raises(ValueError, match="do not match"):
        portable.solve(a[:, :3], b)
