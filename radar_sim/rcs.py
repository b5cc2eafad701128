"""``rcs``: a mesh's monostatic field at given aspects and frequencies, without building
lines of sight by hand.

The directions follow the documented convention (docs/RADAR.md): aspect θ and roll φ give the
line of sight (sin θ cos φ, sin θ sin φ, cos θ), object frame, exactly axis-aligned at
multiples of 90° as in ``RadarConfig.directions``, so ``rcs`` on a config's grid gives the
same numbers as ``simulate``.
"""

from __future__ import annotations

import numpy as np

from radar_sim.config import _cosd, _sind
from radar_sim.field import DEFAULT_TOL, monostatic_field


def line_of_sight(aspect_deg, roll_deg=0.0) -> np.ndarray:
    """(n, 3) unit lines of sight for aspects θ (degrees) at roll φ (scalar or one per aspect)."""
    theta = np.atleast_1d(np.asarray(aspect_deg, dtype=np.float64))
    if theta.ndim != 1 or len(theta) == 0 or not np.isfinite(theta).all():
        raise ValueError(
            f"aspect_deg must be a non-empty 1-D array of finite degrees, "
            f"got shape {np.shape(aspect_deg)}"
        )
    phi = np.asarray(roll_deg, dtype=np.float64)
    if phi.ndim > 1 or phi.size not in (1, len(theta)) or not np.isfinite(phi).all():
        raise ValueError(
            f"roll_deg must be one finite angle or one per aspect, "
            f"got shape {np.shape(roll_deg)} for {len(theta)} aspects"
        )
    phi = np.broadcast_to(phi.reshape(-1), theta.shape)
    st = _sind(theta)
    return np.stack([st * _cosd(phi), st * _sind(phi), _cosd(theta)], axis=-1)


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
