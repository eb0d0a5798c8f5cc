"""The noise of a fixed camera's patch means and its auto-exposure, as simulated and as assumed by default.

A patch mean on a 0…1 scale has variance ``σ² = shot · y + read²`` (shot noise proportional to the signal, read noise
constant); the auto-exposure brings the brightest patch to ``target`` with log-normal jitter ``exposure_jitter`` (a
metering system never hits its target exactly). The default is the noise of a mean over ~100 pixels of an 8-bit
sensor. The simulator (:mod:`illumon.simulation.simulate`) renders with it; the diagnosis (:mod:`illumon.diagnosis`)
starts from it where a history's own residuals do not tell the noise. It lives with the camera, below both, so that
neither imports the other.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CameraNoise", "DEFAULT_NOISE"]


@dataclass(frozen=True)
class CameraNoise:
    """Noise of a patch mean on a 0…1 scale: ``σ² = shot · y + read²``; ``exposure_jitter`` is the log-normal σ."""

    shot: float = 2e-5
    read: float = 5e-4
    exposure_jitter: float = 0.15
    target: float = 0.75


DEFAULT_NOISE = CameraNoise()
"""The default camera noise and auto-exposure model."""
