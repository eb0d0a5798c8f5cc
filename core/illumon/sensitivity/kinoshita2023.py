"""Kinoshita & Kiya: Gaussian posteriors for sensitivity and illumination, iterated for an unknown daylight.

Y. Kinoshita, H. Kiya, "Separated-spectral-distribution estimation based on Bayesian inference with single RGB
camera". With Gaussian priors (eq. 6) and Gaussian pixel noise of precision β (eq. 7), the posterior of one
spectral factor given the other two is Gaussian: for the sensitivity, eqs. (15)–(16); for the illumination, eqs.
(11)–(12). (The extracted text prints ``Λ − β Σ …`` for the posterior precision; the derivation of eq. (10) gives
``Λ + β Σ …``, used here, and ``μ̂ = Λ̂⁻¹ (…)``.)

The paper estimates one factor with the others known. Here the daylight is unknown too, so the two posteriors are
alternated: sensitivity posterior given the current illuminant mean, then illumination posterior given the
sensitivity mean, until the estimates settle. The priors are measured: the camera prior of
:class:`~illumon.priors.CameraPrior` (eq. 18 uses the mean of measured cameras; the covariance is theirs
too) and the Granada daylight prior (eq. 17 uses a mean daylight). The final estimate is max-normalised (eq. 19).

References
----------
.. [Kinoshita2023] Kinoshita & Kiya, 2023: eqs. 6–19.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..bayes import GaussianPrior, gaussian_posterior
from ..priors import CameraPrior, DaylightPrior, default_camera_prior, default_daylight_prior
from .common import SensitivityResult, chart_operator, check_chart, finish

__all__ = ["sensitivities_Kinoshita2023"]


def sensitivities_Kinoshita2023(
    chart_rgb: ArrayLike,
    chart_reflectances: ArrayLike,
    *,
    camera_prior: CameraPrior | None = None,
    daylight_prior: DaylightPrior | None = None,
    noise: float = 0.005,
    daylight_floor: float = 1e-3,
    max_iter: int = 50,
    tol: float = 1e-6,
    **_: object,
) -> SensitivityResult:
    """Estimate sensitivities and daylight by alternating Kinoshita & Kiya's Gaussian posteriors.

    Parameters
    ----------
    chart_rgb
        Linear camera values of the chart patches (P × 3).
    chart_reflectances
        Patch reflectances on the grid (P × 61).
    camera_prior
        Sensitivity prior (mean, covariance) from measured cameras; default: the shipped prior.
    daylight_prior
        Illumination prior from measured daylight; default: the shipped Granada prior.
    noise
        Pixel-noise standard deviation relative to the brightest value; β = 1 / noise² (eq. 7).
    daylight_floor
        Variance added to the daylight prior covariance on the diagonal (relative to unit-mean spectra).
    max_iter, tol
        Alternations at most, and the relative change that stops them.

    Returns
    -------
    SensitivityResult
        Posterior-mean sensitivities (max-normalised, eq. 19) and illuminant; the posterior precision of the
        sensitivities is in ``info["precision"]``.

    References
    ----------
    .. [Kinoshita2023] Kinoshita & Kiya, 2023: eqs. 11–12 and 15–16, alternated.
    """
    x, r = check_chart(chart_rgb, chart_reflectances)
    cp = camera_prior or default_camera_prior()
    dp = daylight_prior or default_daylight_prior()
    xv = (x / x.max()).ravel()
    beta = 1.0 / noise**2
    mu_c = cp.mean.T.ravel()
    prec_c = np.linalg.inv(cp.covariance())
    cov_e = dp.components @ dp.coefficient_covariance @ dp.components.T + daylight_floor * np.eye(
        dp.mean.size
    )
    mean_e = dp.mean + dp.components @ dp.coefficient_mean
    # The exposure is unknown: put it in the illuminant's scale, fitted once to the prior means.
    pred = chart_operator(r, mean_e) @ mu_c
    a = float(xv @ pred / (pred @ pred))
    mu_e, prec_e = a * mean_e, np.linalg.inv(a**2 * cov_e)
    e = mu_e.copy()
    c = mu_c.copy()
    n = mu_e.size
    prec = prec_c
    iterations = 0
    for it in range(1, max_iter + 1):
        iterations = it
        c_old, e_old = c, e
        post_c = gaussian_posterior(chart_operator(r, e), xv, GaussianPrior(mu_c, prec_c), beta)  # eqs. (15)–(16)
        c, prec = post_c.mean, post_c.precision
        cm = c.reshape(3, n)
        # rows must follow rgb.ravel() (patch-major): build them patch by patch
        design_e = np.stack([r * cm[k] for k in range(3)], axis=1).reshape(-1, n)
        e = gaussian_posterior(design_e, xv, GaussianPrior(mu_e, prec_e), beta).mean  # eqs. (11)–(12)
        change = max(np.abs(c - c_old).max() / np.abs(c).max(), np.abs(e - e_old).max() / np.abs(e).max())
        if change < tol:
            break
    return finish(c.reshape(3, n).T, e, "kinoshita2023", iterations=iterations, precision=prec)
