"""Jiang, Liu, Gu & Süsstrunk (WACV 2013) baseline: camera PCA basis and a CIE daylight search.

J. Jiang, D. Liu, J. Gu, S. Süsstrunk, "What is the space of spectral sensitivity functions for digital color
cameras?", WACV 2013. Each channel's sensitivity is a combination of the first two eigenvectors of measured cameras'
curves; for a *known* illuminant the coefficients follow by least squares — this step is colour-science's
:func:`colour.recovery.RGB_to_msds_camera_sensitivities_Jiang2013`, used unchanged. For the unknown daylight the
method searches CIE D-series illuminants over correlated colour temperature and keeps the one whose recovered
sensitivities reproduce the chart best (smallest relative residual).

References
----------
.. [Jiang2013] Jiang et al., WACV 2013: the PCA basis and the daylight search.
"""

from __future__ import annotations

import warnings

import colour
import numpy as np
from colour.recovery import RGB_to_msds_camera_sensitivities_Jiang2013
from numpy.typing import ArrayLike

from ..camera import render
from ..daylight import daylight_locus_xy, daylight_spectrum
from ..priors import CameraPrior, default_camera_prior
from ..spectra import GRID, WAVELENGTHS
from .common import SensitivityResult, check_chart, finish

__all__ = ["sensitivities_Jiang2013"]


def sensitivities_Jiang2013(
    chart_rgb: ArrayLike,
    chart_reflectances: ArrayLike,
    *,
    camera_prior: CameraPrior | None = None,
    n_basis: int = 2,
    cct_range: tuple[float, float] = (3000.0, 25000.0),
    n_cct: int = 60,
    **_: object,
) -> SensitivityResult:
    """Estimate sensitivities with Jiang et al. (2013): eigenvector basis and a CIE-D illuminant search.

    Parameters
    ----------
    chart_rgb
        Linear camera values of the chart patches (P × 3).
    chart_reflectances
        Patch reflectances on the grid (P × 61).
    camera_prior
        Supplies the per-channel eigenvectors (``channel_bases``, from :func:`colour.recovery.PCA_Jiang2013`);
        default: the shipped prior of all measured cameras.
    n_basis
        Eigenvectors per channel (Jiang et al. use 2).
    cct_range, n_cct
        CIE daylight candidates, uniformly spaced in reciprocal temperature.

    Returns
    -------
    SensitivityResult
        Sensitivities, the selected CIE daylight (unit mean) and its nominal CCT in ``info``.

    References
    ----------
    .. [Jiang2013] Jiang et al., WACV 2013.
    .. [CIE015] CIE 015:2018: the D-series searched.
    """
    x, r = check_chart(chart_rgb, chart_reflectances)
    cp = camera_prior or default_camera_prior()
    basis = np.moveaxis(cp.channel_bases[:, :, :n_basis], 0, 2)  # 61 × k × 3
    basis = np.moveaxis(basis, 1, 0)  # k × 61 × 3, colour-science's layout
    shape = colour.SpectralShape(GRID.start, GRID.end, GRID.interval)
    reflectances = colour.MultiSpectralDistributions(r.T, WAVELENGTHS)
    xn = x / x.max()
    best = None
    for mired in np.linspace(1e6 / cct_range[1], 1e6 / cct_range[0], n_cct):
        spd = daylight_spectrum(daylight_locus_xy(1e6 / mired))
        illuminant = colour.SpectralDistribution(spd, WAVELENGTHS)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            msds = RGB_to_msds_camera_sensitivities_Jiang2013(xn, illuminant, reflectances, basis, shape)
        c = np.asarray(msds.values, dtype=float)
        pred = render(c, spd, r)
        scale = (pred * xn).sum() / max((pred * pred).sum(), 1e-30)
        err = float(np.linalg.norm(xn - scale * pred) / np.linalg.norm(xn))
        if best is None or err < best[0]:
            best = (err, 1e6 / mired, c, spd)
    err, cct, c, spd = best
    return finish(c, spd, "jiang2013", cct=float(cct), relative_residual=err)
