"""Arithmetic whose bytes do not depend on the CPU, for every number a dataset stores.

Two things in the scientific stack round differently from one machine to the next:

- numpy's float64 ``exp``, ``log``, ``tan``, ``power``, ``arctan2`` and most other
  transcendental loops switch to SVML kernels on AVX-512 hosts (numpy 1.26), so
  ``np.exp(x)`` on an AVX-512 EPYC differs in the last bit from the same call on a Zen 3;
- BLAS (``@``, ``np.dot``, ``np.linalg``) picks its kernel, and with it the summation order
  and the use of FMA, by CPU model and by thread count (OpenBLAS ``SkylakeX`` vs ``Haswell``
  kernels, 1 vs 2 threads: different bits).

Code that computes stored numbers (scales, meshes, labels) calls these instead: the C
library's functions element by element (``math``: one glibc, the same bits on every x86-64
host), vector lengths and small linear systems in plain elementwise arithmetic, and matrix
products summed in one fixed order (compiled, no fast-math, so the compiler may vectorize
across outputs but never reorders a sum). ``tests/test_rebuild.py`` builds a slice of a
dataset under an emulated foreign CPU and compares every hash; ``tests/test_layout.py`` keeps
BLAS and SVML-switching calls out of the code that stores numbers.
"""

from __future__ import annotations

import functools
import math

import numpy as np


def _elementwise(fn):
    ufunc = np.frompyfunc(fn, 1, 1)

    def apply(x):
        x = np.asarray(x, dtype=np.float64)
        if x.ndim == 0:
            return np.float64(fn(float(x)))
        # each distinct value once: grids and lattices repeat a few coordinates many times
        values, inverse = np.unique(x, return_inverse=True)
        return ufunc(values).astype(np.float64)[inverse].reshape(x.shape)

    apply.__name__ = fn.__name__
    apply.__doc__ = f"``math.{fn.__name__}`` element by element (float64, same shape)."
    return apply


exp = _elementwise(math.exp)
log = _elementwise(math.log)
tan = _elementwise(math.tan)
cos = _elementwise(math.cos)


def norm(x) -> float:
    """Euclidean length of a 1-D vector: squares added in index order in float64, no FMA.
    ``np.linalg.norm`` of a vector is a BLAS dot product, whose bits follow the CPU's kernel
    (OpenBLAS ``SkylakeX`` and ``Prescott`` differ from ``Haswell``); for 3-vectors this sum
    is the ``Haswell`` kernel's, bit for bit, so the versions recorded on such a host keep
    their bytes."""
    total = 0.0
    for v in np.ravel(np.asarray(x, dtype=np.float64)):
        total += float(v) * float(v)
    return math.sqrt(total)


def matmul(a, b) -> np.ndarray:
    """``a @ b`` for 2-D float64 or complex128 arrays (a 1-D ``b`` is a column), each output
    summed over the inner index in increasing order."""
    a, b = np.asarray(a), np.asarray(b)
    vector = b.ndim == 1
    b2 = b[:, None] if vector else b
    if a.ndim != 2 or b2.ndim != 2 or a.shape[1] != b2.shape[0]:
        raise ValueError(f"matmul: shapes {a.shape} and {b.shape} do not chain")
    if np.iscomplexobj(a) or np.iscomplexobj(b2):
        out = matmul_parts(a, complex_parts(b2))
    else:
        out = np.zeros((a.shape[0], b2.shape[1]))
        _compiled()[0](
            np.ascontiguousarray(a, np.float64), np.ascontiguousarray(b2, np.float64), out
        )
    return out[:, 0] if vector else out


def solve(a, b) -> np.ndarray:
    """x with ``a[i] @ x[i] = b[i]`` for stacked square systems, a (n, m, m) and b (n, m),
    float64: Gaussian elimination with partial pivoting in elementwise arithmetic (LAPACK's
    ``np.linalg.solve`` runs on BLAS kernels). A singular system's row of x is NaN."""
    a = np.array(a, dtype=np.float64)
    x = np.array(b, dtype=np.float64)
    n, m = x.shape
    if a.shape != (n, m, m):
        raise ValueError(f"solve: shapes {a.shape} and {x.shape} do not match")
    rows = np.arange(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        for col in range(m):
            pivot = col + np.argmax(np.abs(a[:, col:, col]), axis=1)
            for arr in (a, x):
                top = arr[rows, col].copy()
                arr[rows, col] = arr[rows, pivot]
                arr[rows, pivot] = top
            for r in range(col + 1, m):
                f = a[:, r, col] / a[:, col, col]
                a[:, r, col:] -= f[:, None] * a[:, col, col:]
                x[:, r] -= f * x[:, col]
        for col in range(m - 1, -1, -1):
            for c in range(col + 1, m):
                x[:, col] -= a[:, col, c] * x[:, c]
            x[:, col] /= a[:, col, col]
    return x


def complex_parts(b) -> tuple[np.ndarray, np.ndarray]:
    """The right factor of ``matmul_parts``: a 2-D matrix's real and imaginary parts (float64,
    C-contiguous). A matrix used in many products is split once."""
    b = np.asarray(b, dtype=np.complex128)
    if b.ndim != 2:
        raise ValueError(f"complex_parts: a 2-D matrix, got shape {b.shape}")
    return np.ascontiguousarray(b.real), np.ascontiguousarray(b.imag)


def matmul_parts(a, parts: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``matmul(a, b)`` for ``parts = complex_parts(b)``, bit for bit: complex128 (n, m) times
    (m, k), each output summed over the inner index in increasing order."""
    b_re, b_im = parts
    a = np.ascontiguousarray(a, dtype=np.complex128)
    if a.ndim != 2 or a.shape[1] != b_re.shape[0] or b_re.shape != b_im.shape:
        raise ValueError(f"matmul: shapes {a.shape} and {b_re.shape} do not chain")
    re = np.zeros((a.shape[0], b_re.shape[1]))
    im = np.zeros_like(re)
    if a.size and re.size:
        _compiled()[1](a.view(np.float64), b_re, b_im, re, im)
    return re + 1j * im


@functools.cache
def _compiled():
    """The two loops, compiled on first use (numba is not needed to read or score data)."""
    from numba import njit

    return njit(cache=True)(_matmul_real), njit(cache=True)(_matmul_complex)


def _matmul_real(a, b, out):  # pragma: no cover - compiled
    n, m = a.shape
    k = b.shape[1]
    for i in range(n):
        for p in range(m):
            x = a[i, p]
            if x == 0.0:
                continue  # adds +0 or -0 to a sum that is never -0: nothing changes
            for j in range(k):
                out[i, j] += x * b[p, j]


def _matmul_complex(a, b_re, b_im, re, im):  # pragma: no cover - compiled
    """a: (n, 2m) float64, the complex left factor's real and imaginary parts interleaved (its
    float view). Rows of a are taken 8 at a time, so each row of b, read from memory once for
    them, serves 8 rows of outputs; every output still sums over p in increasing order."""
    n = a.shape[0]
    m, k = b_re.shape
    rows = 8
    for i0 in range(0, n, rows):
        i1 = min(i0 + rows, n)
        for p in range(m):
            for i in range(i0, i1):
                xr = a[i, 2 * p]
                xi = a[i, 2 * p + 1]
                if xr == 0.0 and xi == 0.0:
                    continue
                for j in range(k):
                    re[i, j] += xr * b_re[p, j] - xi * b_im[p, j]
                    im[i, j] += xr * b_im[p, j] + xi * b_re[p, j]
