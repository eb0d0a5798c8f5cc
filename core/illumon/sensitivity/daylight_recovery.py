"""Daylight spectrum from known camera sensitivities and a chart image (Han et al. 2012, §6.2).

With the sensitivities ``c`` known, a chart patch's value is linear in the coefficients of a daylight basis
(eqs. 17–19): ``R_q = Σ_j γ_j ∫ s_q c_R b_j``. The 3 × 24 equations give the coefficients by least squares. The
basis is either the CIE D-series S0, S1, S2 (Judd et al., the paper's choice) or illumon's measured-daylight basis
(mean and principal components of the Granada spectra).

References
----------
.. [Han2012] Han et al., CVPR 2012: §6.2, eqs. 17–19.
.. [CIE015] CIE 015:2018: the D-series basis S0, S1, S2.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import render
from ..daylight import CIE_D_BASIS
from ..priors import DaylightPrior, default_daylight_prior

__all__ = ["daylight_Han2012", "daylight_basis"]


def daylight_basis(name: str = "cie", prior: DaylightPrior | None = None, n: int = 3) -> NDArray[np.float64]:
    """Daylight basis (61 × n): ``"cie"`` (S0, S1, S2) or ``"measured"`` (Granada mean + n − 1 components)."""
    if name == "cie":
        return CIE_D_BASIS[:, :n]
    if name == "measured":
        dp = prior or default_daylight_prior()
        return dp.basis[:, :n]
    raise ValueError(f"unknown daylight basis {name!r}; use 'cie' or 'measured'")


def daylight_Han2012(
    chart_rgb: ArrayLike,
    chart_reflectances: ArrayLike,
    sensitivities: ArrayLike,
    *,
    basis: str | ArrayLike = "cie",
    n: int = 3,
) -> NDArray[np.float64]:
    """Recover the illuminant spectrum (61,) from a chart under it, Han et al. eqs. (17)–(19).

    Parameters
    ----------
    chart_rgb
        Linear camera values (P × 3).
    chart_reflectances
        Patch reflectances (P × 61).
    sensitivities
        Known (or estimated) camera sensitivities (61 × 3).
    basis
        ``"cie"``, ``"measured"`` or an explicit basis (61 × n).
    n
        Number of basis functions for named bases (the paper uses 3).

    Returns
    -------
    ndarray
        The spectrum scaled to unit mean (negative values clipped).

    References
    ----------
    .. [Han2012] Han et al., CVPR 2012: eqs. 17–19.
    """
    b = daylight_basis(basis, n=n) if isinstance(basis, str) else np.asarray(basis, dtype=float)
    x = np.asarray(chart_rgb, dtype=float)
    design = np.stack(
        [render(sensitivities, b[:, j], chart_reflectances).ravel() for j in range(b.shape[1])], 1
    )
    gamma = np.linalg.lstsq(design, x.ravel(), rcond=None)[0]  # eq. (19), least squares
    spd = np.clip(b @ gamma, 0.0, None)
    return spd / spd.mean()
