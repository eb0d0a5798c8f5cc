"""Shared pieces of the single-chart sensitivity estimators: result type, input checks, imaging operators,
metric."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..priors.camera import smooth_kernel
from ..spectra import WAVELENGTHS

__all__ = [
    "SensitivityResult",
    "check_chart",
    "chart_operator",
    "second_difference",
    "smooth_kernel",
    "rmse_per_channel",
    "finish",
]

N_WL = WAVELENGTHS.size


@dataclass
class SensitivityResult:
    """Camera sensitivities estimated from one chart image.

    Attributes
    ----------
    sensitivities
        Estimated sensitivities on :data:`~illumon.spectra.GRID` (61 × 3), non-negative, max-normalised over all
        channels.
    illuminant
        Recovered illuminant spectrum (61,), unit mean over the grid, or ``None`` when the method gives none.
    method
        Name of the method.
    info
        Diagnostics (cost, iterations, selected CCT…).
    """

    sensitivities: NDArray[np.float64]
    illuminant: NDArray[np.float64] | None
    method: str
    info: dict = field(default_factory=dict)


def check_chart(
    chart_rgb: ArrayLike, chart_reflectances: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Validate a chart's camera values (P × 3) and reflectances (P × 61); return them as float arrays.

    Raises :class:`ValueError` for mismatched shapes, non-finite or negative values, or an all-zero image.
    """
    x = np.asarray(chart_rgb, dtype=float)
    r = np.asarray(chart_reflectances, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError("chart values must be patches × 3 (r, g, b)")
    if r.ndim != 2 or r.shape != (x.shape[0], N_WL):
        raise ValueError(f"chart reflectances must be {x.shape[0]} × {N_WL} (patches × grid wavelengths)")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(r))):
        raise ValueError("chart values and reflectances must be finite")
    if np.any(x < 0):
        raise ValueError("chart values must be non-negative linear camera counts")
    if np.any(x.max(axis=0) <= 0):
        raise ValueError("a camera channel is zero on every patch")
    return x, r


def chart_operator(reflectances: NDArray[np.float64], illuminant: NDArray[np.float64]) -> NDArray[np.float64]:
    """Matrix ``A`` (3P × 183) with ``A @ c = vec(rgb)`` for stacked sensitivities ``c = [r; g; b]``.

    The rows of ``vec(rgb)`` are patch-major (``rgb.ravel()``), the model of Kinoshita & Kiya (2023) eq. (2) and
    Huynh & Robles-Kelly eq. (2) with the illuminant folded into the reflectances.
    """
    b = reflectances * illuminant
    p = b.shape[0]
    a = np.zeros((3 * p, 3 * N_WL))
    for c in range(3):
        a[c::3, c * N_WL : (c + 1) * N_WL] = b
    return a


def second_difference(n: int) -> NDArray[np.float64]:
    """The (n − 2) × n second-difference matrix ``D`` of Huynh & Robles-Kelly eq. (4)."""
    d = np.zeros((n - 2, n))
    for i in range(n - 2):
        d[i, i : i + 3] = (1.0, -2.0, 1.0)
    return d


def rmse_per_channel(estimate: ArrayLike, truth: ArrayLike) -> NDArray[np.float64]:
    """Per-channel RMSE (3,) between sensitivities after max-normalising each over all channels.

    This is the error measure of Jiang et al. (2013), Huynh & Robles-Kelly (Tables I–II) and Kinoshita & Kiya
    (Tables 1–2): both curve sets are scaled so that their largest value is 1; negative estimates are clipped.
    """
    e = np.clip(np.asarray(estimate, dtype=float), 0.0, None)
    t = np.asarray(truth, dtype=float)
    e = e / e.max()
    t = t / t.max()
    return np.sqrt(np.mean((e - t) ** 2, axis=0))


def finish(
    sensitivities: ArrayLike, illuminant: ArrayLike | None, method: str, **info: object
) -> SensitivityResult:
    """Clip, max-normalise and wrap an estimate; the illuminant is scaled to unit mean and clipped at zero."""
    c = np.clip(np.asarray(sensitivities, dtype=float), 0.0, None)
    if c.max() <= 0:
        raise ValueError(f"{method}: the estimate is zero everywhere")
    e = None
    if illuminant is not None:
        e = np.clip(np.asarray(illuminant, dtype=float), 0.0, None)
        e = e / e.mean() if e.mean() > 0 else e
    return SensitivityResult(c / c.max(), e, method, dict(info))
