"""Bayesian spectral estimation after Y. Kinoshita & H. Kiya (eqs. 6–19): Gaussian posteriors of illumination,
reflectance or camera sensitivity given the other two, on the spectral grid and in basis coefficients, with
sequential updating.

Pixel values follow eq. (7): ``x_ijk = Σ_n e_i[n] r_j[n] c_k[n] + ε``, ``ε ~ N(0, β⁻¹)``, i.e. for the unknown
spectrum ``v`` (one of ``e_i``, ``r_j``, ``c_k``) the observations are linear, ``x = D v + ε`` with design rows
``r_j ⊙ c_k`` (illumination), ``c_k ⊙ e_i`` (reflectance) or ``e_i ⊙ r_j`` (sensitivity). With the Gaussian prior of
eq. (6), ``N(μ, Λ⁻¹)``, the posterior is Gaussian (eq. 10) with

    Λ̂ = Λ + β Dᵀ D,        μ̂ = Λ̂⁻¹ (Λ μ + β Dᵀ x)          (eqs. 11–16)

Errata in the paper as printed: eqs. (11), (13), (15) show ``Λ − β Σ …`` and eqs. (12), (14), (16) ``Λ̂ (…)``; the
derivation in eq. (10) gives the ``+`` sign and the inverse ``Λ̂⁻¹`` used here (the printed forms are not a
precision and not a mean). The sums ``Σ_{j,k} diag(r_j) c_k c_kᵀ diag(r_j)`` are exactly ``DᵀD``.

In basis coefficients, ``v = B a`` with a prior ``N(m, P⁻¹)`` on ``a``: the same formulas with ``D B`` in place of
``D``. Because the posterior is conjugate, feeding observations in batches and using each posterior as the next prior
(the paper's §3.3 remark) gives exactly the batch posterior; :class:`SequentialPosterior` does this.

Priors from measured data (eqs. 17–18 use a mean; we also use the measured covariance, regularised): daylight spectra
(Granada) for illumination, camera sensitivities (other cameras) for sensitivity, reflectance sets for reflectance.

References
----------
.. [Kinoshita2023] Kinoshita & Kiya, 2023: eqs. 6–19.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "GaussianPrior",
    "gaussian_posterior",
    "illuminant_design",
    "reflectance_design",
    "sensitivity_design",
    "posterior_illuminant",
    "posterior_reflectance",
    "posterior_sensitivity",
    "posterior_in_basis",
    "least_squares_estimate",
    "prior_from_samples",
    "SequentialPosterior",
    "normalise_max",
]


@dataclass(frozen=True)
class GaussianPrior:
    """A Gaussian ``N(mean, precision⁻¹)`` (Kinoshita & Kiya eq. 6)."""

    mean: NDArray[np.float64]
    precision: NDArray[np.float64]

    @property
    def covariance(self) -> NDArray[np.float64]:
        """``precision⁻¹``."""
        return np.linalg.inv(self.precision)


def prior_from_samples(samples: ArrayLike, ridge: float = 1e-3) -> GaussianPrior:
    """Gaussian prior from measured spectra (n × N): sample mean and the inverse of the sample covariance plus
    ``ridge × mean variance`` on the diagonal (measured sets have fewer effective dimensions than grid points)."""
    x = np.asarray(samples, dtype=float)
    mean = x.mean(0)
    cov = np.cov(x, rowvar=False) if x.shape[0] > 1 else np.zeros((x.shape[1], x.shape[1]))
    floor = ridge * max(float(np.trace(cov)) / cov.shape[0], 1e-12)
    cov = cov + floor * np.eye(cov.shape[0])
    return GaussianPrior(mean, np.linalg.inv(cov))


def gaussian_posterior(
    design: ArrayLike, x: ArrayLike, prior: GaussianPrior, beta: float
) -> GaussianPrior:
    """Posterior of ``v`` for ``x = D v + ε``, ``ε ~ N(0, β⁻¹ I)``, prior ``N(μ, Λ⁻¹)`` (Kinoshita & Kiya eq. 10):
    precision ``Λ + β DᵀD`` and mean ``Λ̂⁻¹ (Λμ + β Dᵀx)`` (eqs. 11–16 with the errata of the module docstring)."""
    d = np.asarray(design, dtype=float)
    xv = np.asarray(x, dtype=float).ravel()
    ok = np.isfinite(xv)
    d, xv = d[ok], xv[ok]
    prec = prior.precision + beta * d.T @ d
    rhs = prior.precision @ prior.mean + beta * d.T @ xv
    return GaussianPrior(np.linalg.solve(prec, rhs), prec)


def illuminant_design(reflectances: ArrayLike, sensitivities: ArrayLike) -> NDArray[np.float64]:
    """Design matrix (J·K × N) of illumination: rows ``r_j ⊙ c_k`` (eq. 5's ``M_{r,c}``), ordered j-major."""
    r = np.asarray(reflectances, dtype=float)
    c = np.asarray(sensitivities, dtype=float)
    return (r[:, None, :] * c.T[None, :, :]).reshape(-1, r.shape[1])


def reflectance_design(illuminants: ArrayLike, sensitivities: ArrayLike) -> NDArray[np.float64]:
    """Design matrix (I·K × N) of one reflectance: rows ``c_k ⊙ e_i`` (eqs. 13–14), ordered i-major."""
    e = np.atleast_2d(np.asarray(illuminants, dtype=float))
    c = np.asarray(sensitivities, dtype=float)
    return (e[:, None, :] * c.T[None, :, :]).reshape(-1, e.shape[1])


def sensitivity_design(illuminants: ArrayLike, reflectances: ArrayLike) -> NDArray[np.float64]:
    """Design matrix (I·J × N) of one channel's sensitivity: rows ``e_i ⊙ r_j`` (eqs. 15–16), ordered i-major."""
    e = np.atleast_2d(np.asarray(illuminants, dtype=float))
    r = np.asarray(reflectances, dtype=float)
    return (e[:, None, :] * r[None, :, :]).reshape(-1, e.shape[1])


def posterior_illuminant(
    x: ArrayLike, reflectances: ArrayLike, sensitivities: ArrayLike, prior: GaussianPrior, beta: float
) -> GaussianPrior:
    """``p(e_i | X, R, C)``, eqs. (11)–(12): ``x`` are frame ``i``'s pixel values (J × K), NaN where missing."""
    return gaussian_posterior(illuminant_design(reflectances, sensitivities), x, prior, beta)


def posterior_reflectance(
    x: ArrayLike, illuminants: ArrayLike, sensitivities: ArrayLike, prior: GaussianPrior, beta: float
) -> GaussianPrior:
    """``p(r_j | X, E, C)``, eqs. (13)–(14): ``x`` are patch ``j``'s pixel values (I × K) under illuminants (I × N)."""
    return gaussian_posterior(reflectance_design(illuminants, sensitivities), x, prior, beta)


def posterior_sensitivity(
    x: ArrayLike, illuminants: ArrayLike, reflectances: ArrayLike, prior: GaussianPrior, beta: float
) -> GaussianPrior:
    """``p(c_k | X, E, R)``, eqs. (15)–(16): ``x`` are channel ``k``'s pixel values (I × J)."""
    return gaussian_posterior(sensitivity_design(illuminants, reflectances), x, prior, beta)


def posterior_in_basis(
    design: ArrayLike, x: ArrayLike, basis: ArrayLike, prior: GaussianPrior, beta: float, offset: ArrayLike | None = None
) -> tuple[GaussianPrior, NDArray[np.float64], NDArray[np.float64]]:
    """Eqs. (11)–(16) in basis coefficients: ``v = offset + B a`` with prior ``N(m, P⁻¹)`` on ``a``.

    Returns the coefficient posterior and the spectrum's posterior mean ``offset + B μ̂`` and covariance
    ``B Λ̂⁻¹ Bᵀ``.
    """
    d = np.asarray(design, dtype=float)
    b = np.asarray(basis, dtype=float)
    xv = np.asarray(x, dtype=float).ravel()
    off = np.zeros(b.shape[0]) if offset is None else np.asarray(offset, dtype=float)
    post = gaussian_posterior(d @ b, xv - d @ off, prior, beta)
    return post, off + b @ post.mean, b @ np.linalg.solve(post.precision, b.T)


def least_squares_estimate(design: ArrayLike, x: ArrayLike) -> NDArray[np.float64]:
    """Kinoshita & Kiya eq. (3)–(4): the (minimum-norm) least-squares solution ``D⁺ x``, the baseline."""
    d = np.asarray(design, dtype=float)
    xv = np.asarray(x, dtype=float).ravel()
    ok = np.isfinite(xv)
    return np.linalg.lstsq(d[ok], xv[ok], rcond=None)[0]


def normalise_max(v: ArrayLike) -> NDArray[np.float64]:
    """Eq. (19): ``v / max_n v_n`` (last axis)."""
    a = np.asarray(v, dtype=float)
    return a / np.max(a, axis=-1, keepdims=True)


class SequentialPosterior:
    """Sequential Bayesian updating (Kinoshita & Kiya §3.3): each posterior becomes the prior of the next batch.

    Works on the natural parameters (precision ``Λ`` and information vector ``Λμ``), so an update costs one rank-``n``
    update and the result after any split of the data equals the batch posterior up to round-off.
    """

    def __init__(self, prior: GaussianPrior) -> None:
        self.precision = np.array(prior.precision, dtype=float)
        self.information = self.precision @ prior.mean
        self.count = 0

    def update(self, design: ArrayLike, x: ArrayLike, beta: float) -> GaussianPrior:
        """Absorb observations ``x = D v + ε`` (ε ~ N(0, β⁻¹)); return the new posterior."""
        d = np.asarray(design, dtype=float)
        xv = np.asarray(x, dtype=float).ravel()
        ok = np.isfinite(xv)
        d, xv = d[ok], xv[ok]
        self.precision = self.precision + beta * d.T @ d
        self.information = self.information + beta * d.T @ xv
        self.count += int(ok.sum())
        return self.posterior

    @property
    def posterior(self) -> GaussianPrior:
        """Current posterior ``N(Λ⁻¹ h, Λ⁻¹)``."""
        return GaussianPrior(np.linalg.solve(self.precision, self.information), self.precision.copy())
