"""The degrees of freedom of a Student-t reflectance prior, fitted to the measured reflectances the shipped basis and
Gaussian prior were built from (``tools/build_bases.py``): :data:`illumon.diagnosis.spectral.REFLECTANCE_PRIOR_DOF`.

Run: ``python tools/reflectance_prior_dof.py``. Prints the maximum-likelihood ν of a multivariate t with the shipped
prior's mean and covariance over the 1 835 spectra of ``../shared/data/reflectances`` (each set weighted equally, as
the prior was built), and how heavy the tails are under the Gaussian prior.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar
from scipy.special import gammaln
from scipy.stats import chi2


def squared_distances() -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Each measured reflectance's squared Mahalanobis distance under the shipped Gaussian prior (its coefficients on
    the shipped basis), its weight (each set summing to the same) and the basis size K."""
    from illumon.priors import reflectance_basis
    from illumon.simulation import datasets

    rb = reflectance_basis()
    spectra, weights = [], []
    for name in datasets.REFLECTANCE_SETS:
        _, r = datasets.load_reflectance_set(name)
        spectra.append(r)
        weights.append(np.full(r.shape[0], 1.0 / r.shape[0]))
    d = np.concatenate(spectra) @ rb.functions - rb.prior_mean
    d2 = np.einsum("pi,ij,pj->p", d, np.linalg.inv(rb.prior_covariance), d)
    w = np.concatenate(weights)
    return d2, w / w.sum(), rb.size


def t_log_likelihood(nu: float, d2: NDArray[np.float64], k: int) -> NDArray[np.float64]:
    """Log density (up to ν-free terms) of a K-variate t with ν > 2 degrees of freedom and covariance ``C`` at points
    whose squared Mahalanobis distance under ``C`` is ``d2`` (scale matrix ``C (ν − 2) / ν``)."""
    u = d2 * nu / (nu - 2.0)
    return (gammaln((nu + k) / 2) - gammaln(nu / 2) - k / 2 * np.log(nu * np.pi) + k / 2 * np.log(nu / (nu - 2.0))
            - (nu + k) / 2 * np.log1p(u / nu))


def prior_dof(d2: NDArray[np.float64], weights: NDArray[np.float64], k: int) -> float:
    """The maximum-likelihood ν (weighted) of :func:`t_log_likelihood` over (2, 1000]."""
    res = minimize_scalar(lambda nu: -float((weights * t_log_likelihood(nu, d2, k)).sum()), bounds=(2.01, 1000.0),
                          method="bounded")
    return float(res.x)


def main() -> None:
    d2, w, k = squared_distances()
    nu = prior_dof(d2, w, k)
    beyond = float((w * (d2 > chi2.ppf(0.99, k))).sum())
    print(f"{d2.size} measured reflectances, K = {k}: weighted mean d² {float((w * d2).sum()):.2f} (Gaussian: {k}), "
          f"{100 * beyond:.1f} % beyond the Gaussian's 99 % point; maximum-likelihood ν = {nu:.2f}")


if __name__ == "__main__":
    main()
