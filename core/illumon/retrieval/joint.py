"""illumon's joint multi-frame retrieval: all illuminants, exposures and patch reflectances in one bounded fit.

The model is Marguier & Süsstrunk's (CIC 2007): static patches with unknown reflectances ``R_p = S σ_p`` (8-component
basis) seen in every frame under a daylight ``E_f`` (CIE D-series) and an exposure ``k_f``::

    y_fpc = k_f · Σλ C_c(λ) E_f(λ) R_p(λ) + noise

Instead of matching pseudo-inverse reflectances under D65 (their eq. 3), all unknowns are fitted together by bounded
non-linear least squares with *variable projection*: for given illuminants and exposures the reflectance coefficients
are a linear, Gaussian-regularised least-squares solution (prior mean and covariance of 1835 measured reflectances,
as in Kinoshita & Kiya's Bayesian formulation), so the outer problem has only the illuminant parameters
(reciprocal CCT and Duv offset from the daylight locus, with a Gaussian prior) and log exposures of each frame.
Residuals are weighted by a noise model (relative model error plus a floor), missing patches simply drop out, and
several starts seeded from gray-world chromaticities guard against local minima. A final stage enforces physical
reflectances (0…1) where the unconstrained solution strays outside them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ..daylight import DaylightModel, daylight_locus_duv, daylight_model, xy_from_cct_duv
from ..observations import Observations
from ..reflectance import ReflectanceBasis, reflectance_basis
from .common import RetrievalResult, gray_world, imaging_operators, make_result

__all__ = ["illuminant_retrieval_joint", "JointProblem"]


class JointProblem:
    """The variable-projection least-squares problem behind :func:`illuminant_retrieval_joint`.

    Parameters
    ----------
    obs
        Observations (values on a 0…1 scale, NaN where missing).
    sensitivities
        Camera sensitivities on the grid (61 × 3).
    model
        Daylight model of each frame.
    reflectance
        Reflectance basis with its Gaussian prior.
    relative_error, absolute_error
        Noise model of a patch mean: σ = sqrt((relative·y)² + absolute²), ``y`` normalised to a median of 1. The
        relative part also absorbs model error (basis truncation of reflectances and daylight).
    """

    def __init__(
        self,
        obs: Observations,
        sensitivities: NDArray[np.float64],
        model: DaylightModel,
        reflectance: ReflectanceBasis,
        *,
        relative_error: float = 0.02,
        absolute_error: float = 0.002,
    ) -> None:
        self.model = model
        self.rb = reflectance
        self.K, self.w = imaging_operators(sensitivities, model.basis, reflectance)
        y = np.asarray(obs.values, dtype=float)
        present = np.all(np.isfinite(y), axis=-1)
        self.F, self.P = present.shape
        green = y[..., 1][present]
        self.scale = float(np.median(green)) if green.size else 1.0
        if not self.scale > 0:
            self.scale = float(np.nanmax(y)) or 1.0
        yn = np.where(present[..., None], y / self.scale, 0.0)
        wt = 1.0 / np.sqrt((relative_error * yn) ** 2 + absolute_error**2)
        wt = np.where(present[..., None], wt, 0.0)
        # Rows ordered frame-major: r = 3 f + c; arrays are P × 3F.
        self.Y = yn.transpose(1, 0, 2).reshape(self.P, 3 * self.F)
        self.W = wt.transpose(1, 0, 2).reshape(self.P, 3 * self.F)
        self.W2Y = self.W**2 * self.Y
        cov = reflectance.prior_covariance
        self.Lambda = np.linalg.inv(cov)
        self.R = np.linalg.cholesky(self.Lambda).T  # ‖R(σ−μ)‖² = (σ−μ)ᵀΛ(σ−μ)
        self.mu = reflectance.prior_mean
        self.Lmu = self.Lambda @ self.mu
        self.present = present
        self.np = model.n_params

    # parameters: per frame [model params..., log exposure]
    def unpack(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Split the parameter vector into daylight parameters (F × n) and log exposures (F,)."""
        x = x.reshape(self.F, self.np + 1)
        return x[:, : self.np], x[:, self.np]

    def operators(self, params: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per-frame response matrices (F × 3 × K) for unit exposure, with the illuminant scaled to white_g = 1."""
        a = self.model.weights(params)
        white = a @ self.w
        m = np.einsum("fk,kcj->fcj", a, self.K) / white[:, 1, None, None]
        return m, white

    def solve_reflectances(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Posterior-mean reflectance coefficients (P × K) and the stacked operator (3F × K) for parameters ``x``."""
        params, logk = self.unpack(x)
        m, _ = self.operators(params)
        a = (np.exp(logk)[:, None, None] * m).reshape(3 * self.F, -1)
        n = np.einsum("pr,ri,rj->pij", self.W**2, a, a) + self.Lambda
        b = self.W2Y @ a + self.Lmu
        sigma = np.linalg.solve(n, b[..., None])[..., 0]
        return sigma, a

    def residuals(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Whitened residuals: data, reflectance prior and daylight prior."""
        sigma, a = self.solve_reflectances(x)
        data = self.W * (self.Y - sigma @ a.T)
        prior = (sigma - self.mu) @ self.R.T
        params, _ = self.unpack(x)
        return np.concatenate([data.ravel(), prior.ravel(), self.model.prior_residuals(params).ravel()])

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Bounds of the full parameter vector."""
        lo, hi = self.model.bounds()
        lo = np.tile(np.append(lo, -np.inf), self.F)
        hi = np.tile(np.append(hi, np.inf), self.F)
        return lo, hi

    def start(self, mired: NDArray[np.float64]) -> NDArray[np.float64]:
        """Initial vector from per-frame reciprocal temperatures, exposures fitted to the frames' levels."""
        params = self.model.start(mired)
        m, _ = self.operators(params)
        typical = m @ self.mu  # F × 3 responses of the mean reflectance
        level = np.array(
            [np.mean(self.Y[self.present[f], 3 * f + 1]) if self.present[f].any() else 1.0 for f in range(self.F)]
        )
        logk = np.log(np.maximum(level, 1e-6) / np.maximum(typical[:, 1], 1e-9))
        return np.concatenate([params, logk[:, None]], axis=1).ravel()


def _gray_world_mired(obs: Observations, sensitivities: NDArray[np.float64], model: DaylightModel) -> NDArray[np.float64]:
    """Per-frame reciprocal temperature whose camera white is closest in chromaticity to the gray-world white."""
    grid = np.linspace(45.0, 380.0, 200)
    cct = 1e6 / grid
    xy = xy_from_cct_duv(cct, daylight_locus_duv(cct))
    from ..daylight import daylight_spectrum

    whites = daylight_spectrum(xy) @ sensitivities
    chrom = np.log(whites[:, [0, 2]] / whites[:, 1:2])
    gw = gray_world(obs)
    gchrom = np.log(np.clip(gw[:, [0, 2]], 1e-9, None))
    d = ((gchrom[:, None, :] - chrom[None, :, :]) ** 2).sum(-1)
    return grid[np.argmin(d, axis=1)]


def illuminant_retrieval_joint(
    obs: Observations,
    sensitivities: NDArray[np.float64],
    *,
    daylight: str | DaylightModel = "cie",
    reflectance: ReflectanceBasis | None = None,
    relative_error: float = 0.02,
    absolute_error: float = 0.002,
    start_offsets: tuple[float, ...] = (0.0, -40.0, 40.0),
    max_nfev: int = 200,
) -> RetrievalResult:
    """Retrieve every frame's illuminant and the patches' reflectances by a joint bounded least-squares fit.

    Implements the imaging model of J. Marguier & S. Süsstrunk, "Illuminant retrieval for fixed location cameras"
    (IS&T/SID CIC 2007) with illumon's own solver (see module docstring): variable projection over the reflectance
    coefficients with a Gaussian reflectance prior (Y. Kinoshita & H. Kiya, Bayesian spectral estimation), trust-region
    reflective least squares over per-frame daylight parameters and log exposures, several starts.

    Parameters
    ----------
    obs
        Observations of static patches (at least two frames).
    sensitivities
        Camera sensitivities on the grid (61 × 3).
    daylight
        Daylight model name or instance.
    reflectance
        Reflectance basis and prior; the shipped one by default.
    relative_error, absolute_error
        Noise model for the residual weights (see :class:`JointProblem`).
    start_offsets
        Offsets (MK⁻¹) added to the gray-world start; each is one start.
    max_nfev
        Function-evaluation cap of each least-squares run.

    Returns
    -------
    RetrievalResult
    """
    model = daylight_model(daylight)
    rb = reflectance or reflectance_basis()
    c = np.asarray(sensitivities, dtype=float)
    prob = JointProblem(obs, c, model, rb, relative_error=relative_error, absolute_error=absolute_error)
    lo, hi = prob.bounds()
    base = _gray_world_mired(obs, c, model)
    best = None
    runs = []
    for off in start_offsets:
        x0 = np.clip(prob.start(base + off), lo + 1e-9, hi - 1e-9)
        sol = least_squares(prob.residuals, x0, bounds=(lo, hi), x_scale="jac", max_nfev=max_nfev, method="trf")
        runs.append(float(sol.cost))
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    params, logk = prob.unpack(best.x)
    sigma, _ = prob.solve_reflectances(best.x)
    refl = rb.spectra(sigma)
    spectra = model.spectra(params)
    xy = None
    if hasattr(model, "_cct_duv"):
        cct, duv = model._cct_duv(params)
        xy = xy_from_cct_duv(cct, duv)
    jac = best.jac
    try:
        cond = float(np.linalg.cond(jac))
    except np.linalg.LinAlgError:
        cond = float("inf")
    info = {
        "cost": float(best.cost),
        "start_costs": runs,
        "nfev": int(best.nfev),
        "jacobian_condition": cond,
        "reflectance_out_of_range": float(np.mean((refl < -0.02) | (refl > 1.02))),
        "scale": prob.scale,
    }
    return make_result(
        obs,
        c,
        spectra,
        "joint",
        xy=xy,
        exposures=np.exp(logk) / prob.scale,
        reflectances=refl,
        info=info,
    )
