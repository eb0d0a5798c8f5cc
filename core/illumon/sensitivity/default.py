"""illumon's own single-chart estimator: everything measured, marginalised properly.

The camera's stacked sensitivities ``c`` (183-vector) get a Gaussian prior from measured cameras
(:class:`~illumon.priors.CameraPrior`: joint principal components with their sample variances, plus a
smooth squared-exponential floor so that curves may leave the span of the training cameras only smoothly). The
unknown daylight is ``E = mean + V y`` with the Gaussian prior of the measured Granada spectra
(:class:`~illumon.priors.DaylightPrior`). Given ``E`` and an exposure ``a``, the chart values
``x = a A(E) c + n`` are linear-Gaussian in ``c``, so ``c`` is integrated out analytically and the few daylight and
exposure parameters are chosen by maximising the marginal likelihood (type-II maximum likelihood) plus the daylight
prior. The sensitivities are then the non-negative MAP given that daylight (bounded least squares on the whitened
posterior), which enforces the physical constraints: non-negative, smooth, close to measured cameras in shape.

Compared with iterating the illumination and sensitivity posteriors of Kinoshita & Kiya (2023), marginalising ``c``
avoids the bias of fitting the daylight to one point estimate of the sensitivities.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import lsq_linear, minimize

from ..priors import CameraPrior, DaylightPrior, default_camera_prior, default_daylight_prior
from ..priors.camera import SMOOTH_FLOOR, camera_prior_covariance
from .common import SensitivityResult, chart_operator, check_chart, finish

__all__ = ["sensitivities_illumon", "camera_prior_covariance", "SMOOTH_FLOOR", "NEAR_CLIP"]


NEAR_CLIP = 0.95
"""Chart values at or above this fraction of the chart's largest value may be clipped (a raw channel saturates at one
level for every channel, and a patch's mean whose brightest pixels reach it is already biased low): they are treated
as censored — left out of the fit, and taken back only when the fitted sensitivities predict them below what was
measured (a clipped value can only be lower than the truth). Found on raw-pipeline charts (``benchmarks/rawsim.py``)
of a camera whose blue channel saturates on the white patch while the exposure is metered on green (Point Grey
Grasshopper2); the 5 % margin covers the ~2σ of a patch's pixel spread (texture and noise) of the
development charts."""


def sensitivities_illumon(
    chart_rgb: ArrayLike,
    chart_reflectances: ArrayLike,
    *,
    camera_prior: CameraPrior | None = None,
    daylight_prior: DaylightPrior | None = None,
    noise: float = 0.003,
    floor: float = SMOOTH_FLOOR,
    length_nm: float = 30.0,
    n_daylight: int = 3,
    near_clip: float | None = NEAR_CLIP,
) -> SensitivityResult:
    """Estimate sensitivities and daylight from one chart image (illumon's default method).

    Parameters
    ----------
    chart_rgb
        Linear camera values of the chart patches (P × 3), any scale.
    chart_reflectances
        Reflectances of the same patches on the grid (P × 61).
    camera_prior
        Prior from measured cameras (default: the shipped prior of all 24 cameras). Leave-one-out evaluation passes
        a prior built without the camera under test.
    daylight_prior
        Prior of measured daylight (default: shipped Granada prior).
    noise
        Standard deviation of the chart values relative to the brightest value (noise plus model error).
    floor, length_nm
        Variance and length scale (nm) of the smooth prior floor outside the PCA span (:data:`SMOOTH_FLOOR`).
    n_daylight
        Daylight components used (≤ those in the prior).
    near_clip
        Values at or above this fraction of the largest are taken as possibly clipped (:data:`NEAR_CLIP`); ``None``
        trusts every value.

    Returns
    -------
    SensitivityResult
        Max-normalised sensitivities and the recovered daylight (unit mean).
    """
    x, r = check_chart(chart_rgb, chart_reflectances)
    cp = camera_prior or default_camera_prior()
    dp = daylight_prior or default_daylight_prior()
    j = min(n_daylight, dp.size)
    v = dp.components[:, :j]
    y_mean = dp.coefficient_mean[:j]
    y_prec = np.linalg.inv(dp.coefficient_covariance[:j, :j])
    xv = (x / x.max()).ravel()
    mu = cp.mean.T.ravel()
    cov = camera_prior_covariance(cp, floor, length_nm)
    s2 = noise**2

    def illuminant(y: NDArray[np.float64]) -> NDArray[np.float64]:
        return dp.mean + v @ y

    lc = np.linalg.cholesky(np.linalg.inv(cov))  # Σ⁻¹ = L Lᵀ

    def solve(use: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64], float, object]:
        """Type-II ML daylight and exposure, then the non-negative MAP sensitivities, from the rows ``use``."""
        xu = xv[use]

        def neg_log_evidence(p: NDArray[np.float64]) -> float:
            a = np.exp(p[0])
            y = p[1:]
            op = a * chart_operator(r, illuminant(y))[use]
            k = op @ cov @ op.T + s2 * np.eye(xu.size)
            try:
                fac = cho_factor(k)
            except np.linalg.LinAlgError:
                return 1e12
            res = xu - op @ mu
            d = y - y_mean
            return float(0.5 * res @ cho_solve(fac, res) + np.log(np.diag(fac[0])).sum() + 0.5 * d @ y_prec @ d)

        m0 = chart_operator(r, illuminant(y_mean))[use] @ mu
        p0 = np.concatenate([[np.log(max(xu @ m0, 1e-12) / (m0 @ m0))], y_mean])
        sol = minimize(neg_log_evidence, p0, method="L-BFGS-B")
        a = float(np.exp(sol.x[0]))
        e = illuminant(sol.x[1:])
        op = a * chart_operator(r, e)
        # Non-negative MAP: minimise |x − A c|²/σ² + (c − μ)ᵀ Σ⁻¹ (c − μ) subject to c ≥ 0.
        design = np.vstack([op[use] / noise, lc.T])
        target = np.concatenate([xu / noise, lc.T @ mu])
        c = lsq_linear(design, target, bounds=(0.0, np.inf), method="bvls").x
        return c, e, a, sol

    near = xv >= near_clip if near_clip is not None else np.zeros(xv.size, dtype=bool)
    use = np.ones(xv.size, dtype=bool)
    if near.any():
        c, e, a, _ = solve(~near)
        use = ~near | (a * chart_operator(r, e) @ c <= xv)  # clipped values can only be below the truth
    c, e, a, sol = solve(use)
    return finish(
        c.reshape(3, -1).T,
        e,
        "default",
        exposure=a,
        daylight_coefficients=sol.x[1:].tolist(),
        neg_log_evidence=float(sol.fun),
        censored=int((~use).sum()),
    )
