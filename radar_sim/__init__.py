"""radar_sim: exact physical-optics monostatic radar simulator on triangle meshes (Embree).

Public API (docs/RADAR.md): ``monostatic_field``, ``polarimetric_field`` (channels
``CHANNELS``), ``detect_mode``, ``RadarConfig``, ``simulate``, ``RadarResult``, ``MeshError``,
``rcs``. Never imports bpy or torch.
"""

__version__ = "0.1.0"

from radar_sim.config import RadarConfig, RadarResult, simulate
from radar_sim.field import CHANNELS, monostatic_field, polarimetric_field
from radar_sim.rcs import rcs
from radar_sim.scene import MeshError, UnitsWarning, detect_mode

__all__ = [
    "CHANNELS",
    "MeshError",
    "RadarConfig",
    "RadarResult",
    "UnitsWarning",
    "__version__",
    "detect_mode",
    "monostatic_field",
    "polarimetric_field",
    "rcs",
    "simulate",
]
