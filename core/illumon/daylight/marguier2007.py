"""The one-parameter daylight curve of Marguier & Süsstrunk: CIE D40…D100 as a θ curve on the unit sphere.

The mean and first two principal components of the 13 unit-norm CIE D40, D45, …, D100 spectra form a 3-function
basis; each illuminant's normalised 3-coefficient vector is a point on the unit sphere, and the elevation φ of those
points is fitted by a quadratic in their azimuth θ. One number θ per frame then names a daylight spectrum, the model
of :func:`illumon.retrieval.marguier2007.illuminant_retrieval_Marguier2007`.

References
----------
.. [Marguier2007] Marguier & Süsstrunk, CIC 2007: Fig. 1 and the text around it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .cie import cie_d_cct, daylight_locus_xy, daylight_spectrum

__all__ = ["ThetaCurve", "theta_curve"]


@dataclass(frozen=True)
class ThetaCurve:
    """One-parameter daylight model of Marguier & Süsstrunk (CIC 2007, Fig. 1).

    Attributes
    ----------
    basis
        Mean and first two principal components of the CIE D40…D100 spectra (61 × 3).
    quadratic
        Coefficients ``(a, b, c)`` of the elevation ``φ(θ) = aθ² + bθ + c`` of the normalised coefficient vectors.
    theta_range
        Azimuths of D40 and D100 on the curve (radians); the search is bounded to a slightly wider interval.

    References
    ----------
    .. [Marguier2007] Marguier & Süsstrunk, CIC 2007.
    """

    basis: NDArray[np.float64]
    quadratic: NDArray[np.float64]
    theta_range: tuple[float, float]

    def coefficients(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Unit 3-vectors on the sphere for azimuths ``theta``."""
        th = np.asarray(theta, dtype=float)
        phi = np.polyval(self.quadratic, th)
        return np.stack([np.cos(phi) * np.cos(th), np.cos(phi) * np.sin(th), np.sin(phi)], axis=-1)

    def spectrum(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Spectra (…, 61) for azimuths ``theta``; ε1 normalised to 1 as in the paper."""
        c = self.coefficients(theta)
        c = c / c[..., :1]
        return c @ self.basis.T

    def theta_of(self, spd: ArrayLike) -> NDArray[np.float64]:
        """Azimuth of spectra projected on the basis (least squares)."""
        c = np.linalg.lstsq(self.basis, np.asarray(spd, dtype=float).T, rcond=None)[0].T
        return np.arctan2(c[..., 1], c[..., 0])


@lru_cache(maxsize=1)
def theta_curve() -> ThetaCurve:
    """Build the θ curve from CIE D40, D45, …, D100 (13 illuminants, nominal temperatures × 1.4388/1.438).

    Returns
    -------
    ThetaCurve
        The basis, the fitted quadratic and the azimuths of D40 and D100.

    References
    ----------
    .. [Marguier2007] Marguier & Süsstrunk, CIC 2007.
    """
    temps = cie_d_cct(np.arange(4000, 10001, 500))
    spds = daylight_spectrum(daylight_locus_xy(temps))
    spds = spds / np.linalg.norm(spds, axis=1, keepdims=True)
    mean = spds.mean(0)
    _, _, vt = np.linalg.svd(spds - mean, full_matrices=False)
    basis = np.stack([mean, vt[0], vt[1]], axis=1)
    coef = np.linalg.lstsq(basis, spds.T, rcond=None)[0].T
    coef /= np.linalg.norm(coef, axis=1, keepdims=True)
    theta = np.arctan2(coef[:, 1], coef[:, 0])
    phi = np.arcsin(np.clip(coef[:, 2], -1, 1))
    quad = np.polyfit(theta, phi, 2)
    return ThetaCurve(basis=basis, quadratic=quad, theta_range=(float(theta.min()), float(theta.max())))
