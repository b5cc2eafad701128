"""Compiled Newton iteration for the closest point on an ellipse or ellipsoid.

The same arithmetic, operation for operation, as ``analytic._closest_on_implicit`` with
``analytic._ellipsoid_implicit`` (numpy sums over an axis of length 2 or 3 add left to right,
and elementwise IEEE operations do not depend on vectorisation), but one point at a time
instead of numpy passes over the still active points: the stored distances stay bit for bit
the same (tests/test_analytic.py compares both on random points) at a fraction of the cost.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def closest(p, starts, inv, tol, steps):
    """Newton on x - p + lam grad F = 0, F = sum(x^2 inv) - 1 = 0, from ``starts``; each point
    stops once every |dx| <= tol (a NaN step never does). Returns x and F(x) per point."""
    n, dim = p.shape
    x = starts.copy()
    value = np.empty(n)
    g, r, w = np.empty(dim), np.empty(dim), np.empty(dim)
    for i in range(n):
        num, den = 0.0, 0.0
        for k in range(dim):
            g[k] = 2.0 * x[i, k] * inv[k]
            num = (p[i, k] - x[i, k]) * g[k] if k == 0 else num + (p[i, k] - x[i, k]) * g[k]
            den = g[k] * g[k] if k == 0 else den + g[k] * g[k]
        lam = num / den
        for _ in range(steps):
            f = 0.0
            for k in range(dim):
                f = x[i, k] * x[i, k] * inv[k] if k == 0 else f + x[i, k] * x[i, k] * inv[k]
            f = f - 1.0
            a, b = 0.0, 0.0
            for k in range(dim):
                g[k] = 2.0 * x[i, k] * inv[k]
                r[k] = x[i, k] - p[i, k] + lam * g[k]
                w[k] = 1.0 / (1.0 + lam * (2.0 * inv[k]))
                a = g[k] * w[k] * r[k] if k == 0 else a + g[k] * w[k] * r[k]
                b = g[k] * w[k] * g[k] if k == 0 else b + g[k] * w[k] * g[k]
            dlam = (f - a) / b
            done = True
            for k in range(dim):
                dx = -w[k] * (r[k] + g[k] * dlam)
                x[i, k] += dx
                done = done and abs(dx) <= tol
            lam += dlam
            if done:
                break
        f = 0.0
        for k in range(dim):
            f = x[i, k] * x[i, k] * inv[k] if k == 0 else f + x[i, k] * x[i, k] * inv[k]
        value[i] = f - 1.0
    return x, value
