"""Fixed-camera histories simulated from measured spectra, with a real camera's noise and auto-exposure.

A frame is rendered with the linear model (:func:`illumon.camera.render`), then an auto-exposure factor brings the
brightest patch to a target level with log-normal jitter (a metering system never hits its target exactly), then
shot noise (variance proportional to the signal) and read noise are added, and values clip at the white level.
Patch means average many pixels, so the default noise is that of a mean over ~100 pixels of an 8-bit sensor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import DEFAULT_NOISE, CameraNoise, camera_white, render
from ..observations import Observations

__all__ = ["SimulatedHistory", "simulate_history"]


@dataclass
class SimulatedHistory:
    """Simulated observations with their ground truth."""

    observations: Observations
    illuminants: NDArray[np.float64]
    reflectances: NDArray[np.float64]
    exposures: NDArray[np.float64]
    sensitivities: NDArray[np.float64]

    @property
    def true_white(self) -> NDArray[np.float64]:
        """Camera white (F × 3) under each frame's true illuminant."""
        return camera_white(self.sensitivities, self.illuminants)


def simulate_history(
    sensitivities: ArrayLike,
    illuminants: ArrayLike,
    reflectances: ArrayLike,
    *,
    noise: CameraNoise | None = DEFAULT_NOISE,
    rng: np.random.Generator | int | None = None,
    missing_fraction: float = 0.0,
    times: list[str] | None = None,
) -> SimulatedHistory:
    """Render a history of static patches under a sequence of illuminants.

    Parameters
    ----------
    sensitivities
        Camera sensitivities (61 × 3).
    illuminants
        One spectrum per frame (F × 61), any scale.
    reflectances
        Patch reflectances (P × 61), 0…1.
    noise
        Noise and exposure model; ``None`` for exact values with each illuminant's own scale.
    rng
        Random generator or seed.
    missing_fraction
        Probability that a patch is occluded (missing) in a frame; every frame keeps at least two patches.
    times
        Optional ISO 8601 time per frame.
    """
    rng = np.random.default_rng(rng)
    c = np.asarray(sensitivities, dtype=float)
    e = np.atleast_2d(np.asarray(illuminants, dtype=float))
    r = np.asarray(reflectances, dtype=float)
    clean = render(c, e, r)  # F × P × 3
    f, p, _ = clean.shape
    if noise is None:
        exposures = np.ones(f)
        values = clean.copy()
    else:
        peak = clean.max(axis=(1, 2))
        exposures = noise.target / peak * np.exp(noise.exposure_jitter * rng.standard_normal(f))
        y = clean * exposures[:, None, None]
        sigma = np.sqrt(noise.shot * np.clip(y, 0, None) + noise.read**2)
        values = np.clip(y + sigma * rng.standard_normal(y.shape), 0.0, 1.0)
    if missing_fraction > 0:
        drop = rng.random((f, p)) < missing_fraction
        for i in range(f):
            keep = np.flatnonzero(~drop[i])
            if keep.size < 2:
                drop[i, rng.choice(p, 2, replace=False)] = False
        values[drop] = np.nan
    obs = Observations(
        frames=[f"f{i:05d}" for i in range(f)],
        patches=[f"p{j:02d}" for j in range(p)],
        values=values,
        times=list(times) if times is not None else [""] * f,
    )
    return SimulatedHistory(obs, e, r, exposures, c)
