"""The interface every per-frame daylight model offers the solvers, and the range of temperatures they may span.

A model maps a small parameter vector per frame to weights on a fixed set of basis spectra, so the image formation
stays linear in the basis: ``E = basis @ weights(params)``. :class:`~illumon.daylight.cie.CIEDaylight` and
:class:`~illumon.daylight.measured.MeasuredDaylight` implement it; the registry in :mod:`illumon.daylight` names them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..spectra import WAVELENGTHS

__all__ = ["MIRED_RANGE", "DaylightModel"]

MIRED_RANGE = (1e6 / 25000.0, 1e6 / 2500.0)
"""Reciprocal-temperature range (MK⁻¹) that illumon's daylight estimates are allowed to span: 2500–25000 K."""


class DaylightModel:
    """Interface of a per-frame daylight model used by the retrieval solvers.

    A model maps a small parameter vector per frame to weights on a fixed set of basis spectra, so the image
    formation stays linear in the basis: ``E = basis @ weights(params)``. It also supplies a Gaussian prior on its
    parameters (as residuals for least squares), bounds, and a start from a reciprocal temperature.
    """

    name: str = "base"
    n_params: int = 0
    basis: NDArray[np.float64]

    def weights(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        """Basis weights (F × nb) for parameters (F × n_params)."""
        raise NotImplementedError

    def prior_residuals(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        """Whitened prior residuals (F × k) of the parameters."""
        raise NotImplementedError

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Lower and upper bounds of one frame's parameters."""
        raise NotImplementedError

    def start(self, mired: NDArray[np.float64]) -> NDArray[np.float64]:
        """Initial parameters (F × n_params) for reciprocal temperatures ``mired`` (MK⁻¹)."""
        raise NotImplementedError

    def scale(self) -> NDArray[np.float64]:
        """Characteristic size of each parameter's meaningful change (trust-region scaling)."""
        raise NotImplementedError

    def spectra(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        """Illuminant spectra (F × 61), CIE-normalised to 100 at 560 nm."""
        spd = self.weights(params) @ self.basis.T
        i560 = int(np.argmin(np.abs(WAVELENGTHS - 560)))
        return 100.0 * spd / spd[:, i560 : i560 + 1]
