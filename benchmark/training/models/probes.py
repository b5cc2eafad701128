"""Ray probes: the surface seen along fixed rays from the bounding-box centre (numpy only).

Defined in ``benchmark.scoring.mesh_features`` (torch-free: the board computes them for ONNX
models that ask for them); kept here under their old names, the features of the invariant
model (``benchmark.training.models.invariant``).
"""

from __future__ import annotations

from benchmark.scoring.mesh_features import N_RAYS, PROBE_DIM, ray_probes

__all__ = ["N_RAYS", "PROBE_DIM", "ray_probes"]
