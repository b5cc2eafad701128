"""``rcs``: a mesh's monostatic field at given aspects and frequencies, without building
lines of sight by hand.

The directions follow the documented convention (docs/RADAR.md): aspect θ and roll φ give the
line of sight (sin θ cos φ, sin θ sin φ, cos θ), object frame, exactly axis-aligned at
multiples of 90° as in ``RadarConfig.directions``, so ``rcs`` on a config's grid gives the
same numbers as ``simulate``.
"""

from __future__ import annotations

import numpy as np

from basic_shapes.geometry import line_of_sight
from radar_sim.field import DEFAULT_TOL, monostatic_field


def rcs(
    vertices,
    faces,
    freq_hz,
    aspect_deg,
    roll_deg=0.0,
    mode: str = "auto",
    *,
    tol: float = DEFAULT_TOL,
) -> np.ndarray:
    """Complex field amplitude A, shape (n_aspect, n_freq); σ = |A|² in m², dBsm = 20 log10|A|.

    ``vertices`` in metres; ``freq_hz`` one or more frequencies; ``aspect_deg`` one or more
    aspects θ; ``roll_deg`` one roll φ or one per aspect; ``mode`` and ``tol`` as in
    ``monostatic_field``.
    """
    return monostatic_field(
        vertices, faces, freq_hz, line_of_sight(aspect_deg, roll_deg), mode=mode, tol=tol
    )
