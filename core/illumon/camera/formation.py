"""Image formation: the linear model ``rgb = k · Σλ C(λ) E(λ) R(λ)``.

``C`` are the camera's spectral sensitivities on the grid (61 × 3), ``E`` the illuminant's spectral power, ``R`` a
surface reflectance and ``k`` an exposure factor (shutter, aperture, gain). Sums over the 5-nm grid stand for the
integrals, as in Marguier & Süsstrunk (2007) and Kinoshita & Kiya (2023) eq. (1).

References
----------
.. [Marguier2007] Marguier & Süsstrunk, CIC 2007.
.. [Kinoshita2023] Kinoshita & Kiya, 2023: eq. 1.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..observations import count_over_patches

__all__ = [
    "FLARE_SD",
    "flare_scales",
    "render",
    "camera_white",
    "gains_from_white",
    "angular_error_deg",
    "Z95",
    "within_one_degree",
    "confidence_variance",
]


FLARE_SD = 0.05
"""Prior standard deviation of a frame's additive offset (veiling glare, flare), as a fraction of the frame's mean
patch value in each channel (:func:`flare_scales`); 0: the model has no offset. The development
photographs (``benchmarks/real.py``'s ``sony-raw``) show offsets of 3–19 % of the frame's mean patch value, changing
from frame to frame (spread about their mean 0.047–0.058; ``python benchmarks/flare.py``); with 0.05 every real set
gains (``docs/methods.md``, *Veiling glare*). On glare-free simulated histories it costs a little (a few tenths of a
degree on single frames); ``confidence`` (``STATED_WHITE_SPREAD``) is calibrated with it, on histories with and
without glare. Benchmarks set it to compare (``benchmarks/unmeasured.py --flare-sd 0``: the model without it)."""


def flare_scales(values: NDArray[np.float64], weighted: NDArray[np.bool_], flare_sd: float, floor: float
                 ) -> NDArray[np.float64] | None:
    """Each frame's prior standard deviation of its additive offset in each channel (F × 3), or ``None`` when
    ``flare_sd`` is 0: the offset is ``o_c = u_c φ_c`` with ``φ`` standard normal a priori.

    The offset of frame ``f`` in channel ``c`` is Gaussian around 0 with standard deviation ``flare_sd`` times the
    frame's mean weighted value in that channel (at least ``floor``): light scattered in the lens adds a fraction of
    the scene's mean radiance to every patch, and that fraction changes with what surrounds the patches. One amount
    per channel (the glare's colour is its surroundings', which the patches need not share): a single amount along
    the patches' mean colour read the development photographs' ``sony-raw`` 3.9° off without a reference, where
    one per channel read 1.9° (both with ``flare_sd`` 0.12, in a state of the fit before its noise level took the
    offsets out)."""
    if flare_sd <= 0:
        return None
    n = np.maximum(count_over_patches(weighted), 1)
    return np.maximum(np.where(weighted, values, 0.0).sum(axis=1) / n, floor) * flare_sd


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


Z95 = 1.959963984540054
"""The standard normal's 97.5 % point: a 95 % interval is ``± Z95`` standard deviations."""

_RHO2 = math.radians(1.0) ** 2
"""1° in radians, squared: the radius of ``confidence``."""


def within_one_degree(tr: ArrayLike) -> NDArray[np.float64]:
    """``confidence``: the probability that a white whose angular error has variance ``tr`` (rad², the trace of its
    2-D covariance) is within 1° of the truth — Rayleigh with σ² = tr/2."""
    return 1.0 - np.exp(-_RHO2 / np.clip(tr, 1e-30, None))


def confidence_variance(confidence: ArrayLike) -> NDArray[np.float64]:
    """The angular variance ``tr`` (rad²) a ``confidence`` below 1 was stated with: :func:`within_one_degree`
    inverted (0 for a confidence of 1)."""
    c = np.asarray(confidence, dtype=float)
    with np.errstate(divide="ignore"):
        return np.where(c < 1.0, -_RHO2 / np.log1p(-c), 0.0)
