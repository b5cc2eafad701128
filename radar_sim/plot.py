"""One PNG per object: a range-aspect image and an RCS polar plot, at one roll angle.

The two views a radar engineer checks first: where along the line of sight the object
scatters (|range profile| in dB against aspect) and how strong it is (σ in dBsm against aspect
at the frequency sample nearest the band centre, named in the title).
dB = 20·log10|A| = 10·log10 σ.
"""

from __future__ import annotations

import os

import numpy as np

from basic_shapes.infra import save_png

DYNAMIC_RANGE_DB = 80.0


def _db(values: np.ndarray) -> np.ndarray:
    return 20 * np.log10(np.maximum(np.abs(values), 1e-12))


def nearest_roll(roll_deg: np.ndarray, roll: float) -> int:
    """Index of the grid roll closest to ``roll`` (degrees, modulo 360)."""
    gap = np.abs((np.asarray(roll_deg) - roll + 180.0) % 360.0 - 180.0)
    return int(np.argmin(gap))


def band_centre_sample(frequency_hz) -> tuple[int, str]:
    """(index, title text) of the frequency sample the RCS panel shows: the one nearest the band
    centre. With an even number of uniform samples (xband-v1: 128 over 8-12 GHz) the centre,
    10 GHz, lies midway between two samples, so the title names the sample actually shown."""
    frequency_hz = np.asarray(frequency_hz, dtype=np.float64)
    centre = (frequency_hz.min() + frequency_hz.max()) / 2
    f = int(np.argmin(np.abs(frequency_hz - centre)))
    shown = f"{frequency_hz[f] / 1e9:.4g} GHz"
    if np.isclose(frequency_hz[f], centre, rtol=1e-9, atol=0):
        return f, f"{shown} (band centre)"
    return f, f"{shown}\n(the sample nearest the {centre / 1e9:.4g} GHz band centre)"


def plot_signature(
    out: str | os.PathLike,
    *,
    aspect_deg,
    roll_deg,
    range_m,
    frequency_hz,
    range_profiles: np.ndarray,
    frequency_response: np.ndarray,
    roll: float = 0.0,
    title: str = "",
) -> None:
    """Write the PNG. Profiles (n_aspect, n_roll, n_range), responses (n_aspect, n_roll, n_freq)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    aspect_deg, range_m, frequency_hz = map(np.asarray, (aspect_deg, range_m, frequency_hz))
    r = nearest_roll(roll_deg, roll)
    f, shown = band_centre_sample(frequency_hz)
    image = _db(range_profiles[:, r, :])
    rcs = _db(frequency_response[:, r, f])
    top = max(image.max(), rcs.max())

    fig = plt.figure(figsize=(11, 4.8))
    ax = fig.add_subplot(1, 2, 1)
    mesh = ax.imshow(
        image,
        origin="lower",
        aspect="auto",
        cmap="viridis",
        vmin=top - DYNAMIC_RANGE_DB,
        vmax=top,
        extent=(range_m[0], range_m[-1], aspect_deg[0], aspect_deg[-1]),
    )
    ax.set_xlabel("range (m)")
    ax.set_ylabel("aspect (deg)")
    shown_roll = float(np.asarray(roll_deg)[r])
    asked = "" if shown_roll == roll else f" (the grid roll nearest {roll:g})"
    ax.set_title(f"range profile, roll {shown_roll:.4g} deg{asked}")
    fig.colorbar(mesh, ax=ax, label="|profile| (dB, 20 log10)")

    ax = fig.add_subplot(1, 2, 2, projection="polar")
    ax.plot(np.radians(aspect_deg), rcs, lw=1.2)
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_thetamin(float(aspect_deg.min()))
    ax.set_thetamax(float(aspect_deg.max()))
    ax.set_ylim(np.ceil(rcs.max() + 5) - DYNAMIC_RANGE_DB, np.ceil(rcs.max() + 5))
    ax.set_title(f"RCS (dBsm) vs aspect, roll {shown_roll:.4g} deg, at {shown}", pad=18)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    save_png(fig, out)
