"""Radar configurations ("xband-v1") and ``simulate``: frequency response and range profiles.

Conventions (docs/RADAR.md): line of sight (sin θ cos φ, sin θ sin φ, cos θ) for aspect θ and
roll φ; field amplitude A with σ = |A|²; range profile
    p(r_m) = Σ_n w_n A(f_n) exp(+j 2 k_n r_m) / Σ_n w_n,   r_m = m·c/(2 N Δf),
so a point scatterer of σ = 1 m² at the origin peaks at exactly 1 (window gain divided out),
and positive range points away from the radar (down-range): a scatterer at p appears at −r̂·p.
"""

from __future__ import annotations

import functools
import json
import math
import re
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from basic_shapes import portable
from basic_shapes.analytic import SIMULATION_RULES
from basic_shapes.geometry import line_of_sight
from basic_shapes.infra import load_json
from radar_sim.field import (
    C0,
    CHANNELS,
    DEFAULT_TOL,
    EDGES,
    channel_field,
    resolve_mode,
    wavenumbers,
)
from radar_sim.scene import MILLIMETRE_RADIUS, MeshError, check_units, prepare

WINDOWS = ("hann", "none")
TRANSFORMS = ("numpy-fft", "portable-dft")
# fields added after xband-v1: absent from the config JSON when at these defaults
LATER_FIELDS = {"channels": "VV", "edges": "none", "simulation_rule": 1, "transform": "numpy-fft"}
# Size bounds (docs/RADAR.md, "Config bounds"): simulate holds the frequency response and two
# FFT temporaries, about 48 bytes per grid sample (complex128 x 3), so MAX_GRID_SAMPLES keeps a
# worker under ~0.8 GB whatever the mesh; per-axis bounds keep each list sane on its own.
MAX_GRID_SAMPLES = 1 << 24  # n_aspect * n_roll * n_freq
MAX_AXIS = {"n_aspect": 3601, "n_roll": 7200, "n_freq": 65536}
MAX_FREQUENCY_HZ = 1e12
CONFIG_MAX_BYTES = 1 << 16
GRID_SUFFIX = re.compile(r"(.+)-([1-9]\d{0,5})x([1-9]\d{0,5})x([1-9]\d{0,5})")  # with_grid


@dataclass(frozen=True)
class RadarConfig:
    """A monostatic measurement grid: aspects x rolls x frequencies, and the range window."""

    name: str = "xband-v1"
    aspect_start_deg: float = 0.0
    aspect_stop_deg: float = 180.0
    n_aspect: int = 61
    n_roll: int = 21  # rolls 0 .. 360° in n_roll equal steps, endpoint excluded
    f_start_hz: float = 8e9
    f_stop_hz: float = 12e9
    n_freq: int = 128
    window: str = "hann"  # symmetric Hann (numpy.hanning), or "none"
    n_range: int = 107  # range bins kept, centred on the origin
    channels: str = "VV"  # polarization channels stored, from HH,VV,HV; VV is the task's target
    edges: str = "none"  # edge diffraction: "none" (PO) or "mec" (equivalent edge currents)
    simulation_rule: int = 1  # basic_shapes.analytic.SIMULATION_RULES: an object's label mesh
    # frequencies to range: "numpy-fft" (np.fft, as labels through xband-v2 were made) or
    # "portable-dft" (a fixed-order DFT whose bytes do not depend on numpy or the CPU)
    transform: str = "numpy-fft"

    def __post_init__(self):
        problems = []
        if not (self.n_aspect >= 1 and self.n_roll >= 1 and self.n_freq >= 2):
            problems.append("n_aspect, n_roll >= 1 and n_freq >= 2")
        too_big = [f"{k} <= {v}" for k, v in MAX_AXIS.items() if getattr(self, k) > v]
        problems += too_big
        if not too_big and self.n_aspect * self.n_roll * self.n_freq > MAX_GRID_SAMPLES:
            problems.append(f"n_aspect * n_roll * n_freq <= {MAX_GRID_SAMPLES} (memory)")
        if not (0.0 <= self.aspect_start_deg <= self.aspect_stop_deg <= 180.0):
            problems.append("0 <= aspect_start_deg <= aspect_stop_deg <= 180")
        if not (0.0 < self.f_start_hz < self.f_stop_hz <= MAX_FREQUENCY_HZ):
            problems.append(f"0 < f_start_hz < f_stop_hz <= {MAX_FREQUENCY_HZ:g} (finite)")
        if self.window not in WINDOWS:
            problems.append(f"window in {WINDOWS}")
        if not (1 <= self.n_range <= self.n_freq and self.n_range % 2 == 1):
            problems.append("n_range odd and between 1 and n_freq")
        listed = self.channels.split(",")
        if "VV" not in listed or len(set(listed)) != len(listed) or set(listed) - set(CHANNELS):
            problems.append(f"channels a comma list from {','.join(CHANNELS)} including VV")
        if self.edges not in EDGES:
            problems.append(f"edges in {EDGES}")
        if self.simulation_rule not in SIMULATION_RULES:
            problems.append(f"simulation_rule in {sorted(SIMULATION_RULES)}")
        if self.transform not in TRANSFORMS:
            problems.append(f"transform in {TRANSFORMS}")
        reserved = globals().get("NAMED", {}).get(self.name)
        if reserved is not None and self != reserved:
            problems.append(f"a name other than {self.name!r} (reserved for a named config)")
        if problems:
            raise ValueError(f"invalid radar config {self.name!r}: need " + "; ".join(problems))

    @classmethod
    def named(cls, name: str) -> RadarConfig:
        """A named config, or one ``with_grid`` made from it: the name stored with the labels
        (``xband-v2-31x7x107``) loads the config that labelled them."""
        if name in NAMED:
            return NAMED[name]
        grid = GRID_SUFFIX.fullmatch(name)
        if grid is None or not (grid.group(1) in NAMED or GRID_SUFFIX.fullmatch(grid.group(1))):
            raise ValueError(
                f"unknown radar config {name!r}; known: {sorted(NAMED)}, "
                "each optionally with a grid suffix -<aspects>x<rolls>x<range bins>"
            )
        axes = dict(zip(("n_aspect", "n_roll", "n_range"), map(int, grid.group(2, 3, 4))))
        return cls.named(grid.group(1)).with_grid(**axes)

    def with_grid(self, **axes: int) -> RadarConfig:
        """This config with grid axes changed (``n_aspect``, ``n_roll``, ``n_range``), named
        ``<name>-<aspects>x<rolls>x<range bins>`` (a dataset version's radar config)."""
        if not axes:
            return self
        grid = "x".join(
            str(axes.get(k, getattr(self, k))) for k in ("n_aspect", "n_roll", "n_range")
        )
        return replace(self, name=f"{self.name}-{grid}", **axes)

    @classmethod
    def from_file(cls, path) -> RadarConfig:
        """A JSON object with the fields of RadarConfig (missing fields take the defaults)."""
        path = Path(path)
        data = load_json(
            path, max_bytes=CONFIG_MAX_BYTES, max_depth=2, what=f"{path}: radar config"
        )
        if not isinstance(data, dict):
            raise ValueError(f"{path}: radar config must be a JSON object")
        known = {f.name: f.type for f in fields(cls)}
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ValueError(f"{path}: unknown radar config field(s) {unknown}")
        if "name" not in data:
            raise ValueError(f'{path}: radar config must have a "name"')
        try:
            if any(isinstance(v, (bool, list, dict)) or v is None for v in data.values()):
                raise ValueError("fields must be numbers or strings")
            cast = {"str": str, "int": int, "float": float}
            kwargs = {k: cast[known[k]](v) for k, v in data.items()}
            if any(known[k] == "int" and v != data[k] for k, v in kwargs.items()):
                raise ValueError("counts and versions must be integers")
            return cls(**kwargs)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}: {exc}") from None

    def to_dict(self) -> dict:
        """Fields added after xband-v1 appear only where set, so older versions keep their
        config text (and with it their label fingerprints)."""
        data = asdict(self)
        for name, default in LATER_FIELDS.items():
            if data[name] == default:
                del data[name]
        return data

    def to_json(self) -> str:
        """The config text that labels are stamped and fingerprinted with."""
        return json.dumps(self.to_dict(), sort_keys=True)

    @property
    def channel_list(self) -> tuple[str, ...]:
        """The stored channels in ``CHANNELS`` order."""
        return tuple(c for c in CHANNELS if c in self.channels.split(","))

    # coordinates ------------------------------------------------------------------------
    @property
    def aspect_deg(self) -> np.ndarray:
        return np.linspace(self.aspect_start_deg, self.aspect_stop_deg, self.n_aspect)

    @property
    def roll_deg(self) -> np.ndarray:
        return np.arange(self.n_roll) * (360.0 / self.n_roll)

    @property
    def frequency_hz(self) -> np.ndarray:
        return np.linspace(self.f_start_hz, self.f_stop_hz, self.n_freq)

    @property
    def range_resolution_m(self) -> float:
        """Bin spacing c/(2 N Δf) of the inverse FFT."""
        df = (self.f_stop_hz - self.f_start_hz) / (self.n_freq - 1)
        return C0 / (2.0 * self.n_freq * df)

    @property
    def range_m(self) -> np.ndarray:
        half = self.n_range // 2
        return np.arange(-half, half + 1) * self.range_resolution_m

    @property
    def max_radius_m(self) -> float:
        """Objects must lie within this distance of the origin (the last kept bin)."""
        return (self.n_range // 2) * self.range_resolution_m

    def directions(self) -> np.ndarray:
        """(n_aspect*n_roll, 3) unit lines of sight, aspect-major (roll varies fastest)."""
        t, p = np.meshgrid(self.aspect_deg, self.roll_deg, indexing="ij")
        return line_of_sight(t.reshape(-1), p.reshape(-1))

    def window_weights(self) -> np.ndarray:
        return np.hanning(self.n_freq) if self.window == "hann" else np.ones(self.n_freq)

    def range_profiles(self, response: np.ndarray) -> np.ndarray:
        """(..., n_freq) frequency response -> (..., n_range) complex range profiles."""
        if self.transform == "portable-dft":
            flat = np.asarray(response, np.complex128).reshape(-1, self.n_freq)
            out = portable.matmul_parts(flat, _dft_parts(self))
            return out.reshape(*np.shape(response)[:-1], self.n_range)
        w = self.window_weights()
        n = self.n_freq
        spectrum = np.fft.ifft(response * w, axis=-1) * (n / w.sum())
        half = self.n_range // 2
        bins = np.arange(-half, half + 1)
        carrier = np.exp(2j * wavenumbers(self.f_start_hz)[0] * self.range_m)
        return spectrum[..., bins % n] * carrier


@functools.cache
def _dft_parts(config: RadarConfig) -> tuple[np.ndarray, np.ndarray]:
    """The (n_freq, n_range) matrix of the portable transform, split for ``matmul_parts``:
    T[n, m] = w_n exp(j(2π n m / N + 2 k_0 r_m)) / Σ w, the same sum as the inverse FFT's kept
    bins times the carrier, built from Python floats and ``math`` (IEEE operations and one
    glibc: the same bits everywhere), the window summed by ``math.fsum``."""
    n, half = config.n_freq, config.n_range // 2
    if config.window == "hann":
        w = [0.5 - 0.5 * math.cos(2.0 * math.pi * i / (n - 1)) for i in range(n)]
    else:
        w = [1.0] * n
    total = math.fsum(w)
    turn = [(math.cos(2.0 * math.pi * i / n), math.sin(2.0 * math.pi * i / n)) for i in range(n)]
    k0 = 2.0 * math.pi * config.f_start_hz / C0
    re = np.empty((n, 2 * half + 1))
    im = np.empty_like(re)
    for col, m in enumerate(range(-half, half + 1)):
        phase = 2.0 * k0 * (m * config.range_resolution_m)
        cr, ci = math.cos(phase), math.sin(phase)
        for i in range(n):
            tr, ti = turn[(i * m) % n]
            g = w[i] / total
            re[i, col] = g * (tr * cr - ti * ci)
            im[i, col] = g * (tr * ci + ti * cr)
    return re, im


NAMED = {
    "xband-v1": RadarConfig(),
    # xband-v1's grid with all three channels and edge diffraction (docs/RADAR.md)
    "xband-v2": RadarConfig(name="xband-v2", channels="HH,VV,HV", edges="mec"),
    # xband-v2's physics, its rims cut finer (simulation rule 2: HH converged) and range
    # profiles from the portable DFT (labels independent of numpy's version)
    "xband-v3": RadarConfig(
        name="xband-v3",
        channels="HH,VV,HV",
        edges="mec",
        simulation_rule=2,
        transform="portable-dft",
    ),
}
NEWEST = "xband-v3"
"""The default of ``simulate`` and of ``radar-sim label`` / ``plot``: the physics of the current
dataset versions (older names stay, for the versions recorded with them)."""


@dataclass
class RadarResult:
    """Frequency response and range profiles on a config's grid, with coordinates."""

    frequency_response: np.ndarray  # (n_aspect, n_roll, n_freq) complex, σ = |A|² m²
    range_profiles: np.ndarray  # (n_aspect, n_roll, n_range) complex
    aspect_deg: np.ndarray
    roll_deg: np.ndarray
    frequency_hz: np.ndarray
    range_m: np.ndarray
    mode: str  # the physics used: "convex", "shadowed" or "bounce2"
    config: RadarConfig
    # every channel of config.channel_list, (n_channel, n_aspect, n_roll, n_freq | n_range);
    # frequency_response and range_profiles above are its VV channel
    channel_response: np.ndarray | None = None
    channel_profiles: np.ndarray | None = None


def simulate(
    vertices,
    faces,
    config: RadarConfig | None = None,
    mode: str = "auto",
    *,
    tol: float = DEFAULT_TOL,
) -> RadarResult:
    """Simulate a mesh (metres) on the grid of ``config`` (default NEWEST).

    Raises MeshError if the mesh is invalid or extends beyond the range window, saying
    "millimetres" when its radius exceeds 100 m and a factor 1000 would make it fit.
    """
    config = config or RadarConfig.named(NEWEST)
    mesh = prepare(vertices, faces)
    limit = config.max_radius_m
    if mesh.radius > limit:
        plainly_mm = mesh.radius > MILLIMETRE_RADIUS and mesh.radius / 1000.0 <= limit
        hint = (
            f"; it looks like millimetres ({mesh.radius:.4g} mm = "
            f"{mesh.radius / 1000:.4g} m): mesh units must be metres"
            if plainly_mm
            else ""
        )
        raise MeshError(
            f"object extends {mesh.radius:.4g} m from the origin, beyond the "
            f"±{limit:.4g} m range window of {config.name!r}{hint}"
        )
    check_units(mesh)
    used = resolve_mode(mode, mesh)
    channels = config.channel_list
    k = wavenumbers(config.frequency_hz)
    field = channel_field(mesh, k, config.directions(), used, tol, channels, config.edges)
    field = np.moveaxis(field.reshape(config.n_aspect, config.n_roll, len(channels), -1), 2, 0)
    profiles = config.range_profiles(field)
    vv = channels.index("VV")
    several = len(channels) > 1
    return RadarResult(
        field[vv],
        profiles[vv],
        config.aspect_deg,
        config.roll_deg,
        config.frequency_hz,
        config.range_m,
        used,
        config,
        field if several else None,
        profiles if several else None,
    )
