"""Camera model: the linear image formation ``rgb = k · Σλ C(λ) E(λ) R(λ)`` and non-linear response curves.

``C`` are the camera's spectral sensitivities on the grid (61 × 3), ``E`` the illuminant's spectral power, ``R`` a
surface reflectance and ``k`` an exposure factor (shutter, aperture, gain). Sums over the 5-nm grid stand for the
integrals, as in Marguier & Süsstrunk (2007) and Kinoshita & Kiya (2023) eq. (1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "render",
    "camera_white",
    "gains_from_white",
    "angular_error_deg",
    "ResponseCurve",
]


def render(sensitivities: ArrayLike, illuminant: ArrayLike, reflectances: ArrayLike) -> NDArray[np.float64]:
    """Camera responses of surfaces under illuminants (linear model, unit exposure).

    Parameters
    ----------
    sensitivities
        Camera sensitivities (61 × 3).
    illuminant
        Illuminant spectra (61,) or (F × 61).
    reflectances
        Reflectances (P × 61).

    Returns
    -------
    ndarray
        (P × 3) for one illuminant, (F × P × 3) for several.
    """
    c = np.asarray(sensitivities, dtype=float)
    e = np.asarray(illuminant, dtype=float)
    r = np.asarray(reflectances, dtype=float)
    if e.ndim == 1:
        return (r * e) @ c
    return np.einsum("pl,fl,lc->fpc", r, e, c)


def camera_white(sensitivities: ArrayLike, illuminant: ArrayLike) -> NDArray[np.float64]:
    """Response of a perfect white diffuser (…, 3) under illuminants (…, 61)."""
    return np.asarray(illuminant, dtype=float) @ np.asarray(sensitivities, dtype=float)


def gains_from_white(white: ArrayLike) -> NDArray[np.float64]:
    """Per-channel white-balance gains (…, 3) that map ``white`` to neutral, normalised so ``gain_g = 1``."""
    w = np.asarray(white, dtype=float)
    return w[..., 1:2] / w


def angular_error_deg(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Angle in degrees between RGB vectors (…, 3), the usual colour-constancy error (Hordley 2006)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    cos = (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@dataclass(frozen=True)
class ResponseCurve:
    """A camera's tone response: ``encoded = clip(black + (white − black) · f(linear))``.

    ``encoding`` is ``"linear"``, ``"srgb"`` (IEC 61966-2-1) or ``"gamma"`` (power 1/``gamma``); values are on a
    0…``white_level`` scale with a ``black_level`` pedestal.
    """

    encoding: str = "linear"
    gamma: float = 2.2
    black_level: float = 0.0
    white_level: float = 255.0

    def __post_init__(self) -> None:
        if self.encoding not in ("linear", "srgb", "gamma"):
            raise ValueError(f"unknown encoding {self.encoding!r}; use linear, srgb or gamma")
        if not self.white_level > self.black_level:
            raise ValueError("white_level must exceed black_level")
        if self.encoding == "gamma" and not self.gamma > 0:
            raise ValueError("gamma must be positive")

    def linearise(self, values: ArrayLike) -> NDArray[np.float64]:
        """Encoded values → linear light on a 0…1 scale."""
        v = (np.asarray(values, dtype=float) - self.black_level) / (self.white_level - self.black_level)
        v = np.clip(v, 0.0, None)
        if self.encoding == "srgb":
            return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
        if self.encoding == "gamma":
            return v**self.gamma
        return v

    def encode(self, linear: ArrayLike) -> NDArray[np.float64]:
        """Linear light (0…1) → encoded values, clipped at the white level."""
        v = np.clip(np.asarray(linear, dtype=float), 0.0, 1.0)
        if self.encoding == "srgb":
            v = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
        elif self.encoding == "gamma":
            v = v ** (1.0 / self.gamma)
        return self.black_level + (self.white_level - self.black_level) * v
