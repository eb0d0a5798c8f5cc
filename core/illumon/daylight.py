"""Daylight models: the CIE D-series, (CCT, Duv) parameterisation and Marguier & Süsstrunk's θ curve.

A daylight spectrum in illumon is ``E(λ) = S0(λ) + M1·S1(λ) + M2·S2(λ)`` (CIE 015:2018, §4.1.2 and Appendix C) with the
weights M1, M2 given by the illuminant's chromaticity. The chromaticity itself is parameterised by the correlated colour
temperature (CCT, K) and the signed distance Duv from the Planckian locus in CIE 1960 UCS (Ohno 2013 convention:
positive above the locus). CIE D illuminants lie on the *daylight locus*, Duv ≈ +0.003 around 6500 K; measured daylight
scatters around it.

The module also carries the one-parameter curve of J. Marguier & S. Süsstrunk, "Illuminant retrieval for fixed location
cameras" (CIC 2007): the mean and first two principal components of CIE D40…D100, with each illuminant's normalised
3-coefficient vector on the unit sphere, and the elevation of those points fitted by a quadratic in the azimuth θ.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import colour
import numpy as np
from colour.colorimetry import SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES
from numpy.typing import ArrayLike, NDArray

from .spectra import GRID, WAVELENGTHS

__all__ = [
    "CIE_D_BASIS",
    "CMFS",
    "MIRED_RANGE",
    "cie_d_weights",
    "daylight_spectrum",
    "daylight_locus_xy",
    "cie_d_cct",
    "daylight_locus_duv",
    "xy_from_cct_duv",
    "cct_duv_from_xy",
    "spectrum_to_xy",
    "ThetaCurve",
    "theta_curve",
    "DaylightModel",
    "CIEDaylight",
]


def _grid_columns(msd_like: dict) -> NDArray[np.float64]:
    cols = []
    for key in ("S0", "S1", "S2"):
        sd = msd_like[key].copy()
        # CIE 015 recommends linear interpolation of the D-series basis functions.
        sd.interpolator = colour.LinearInterpolator
        sd = sd.interpolate(colour.SpectralShape(GRID.start, GRID.end, GRID.interval))
        cols.append(np.asarray(sd.values, dtype=float))
    return np.stack(cols, axis=1)


CIE_D_BASIS: NDArray[np.float64] = _grid_columns(SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES)
"""S0, S1, S2 on :data:`~illumon.spectra.GRID` (61 × 3)."""

CMFS: NDArray[np.float64] = np.asarray(
    colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    .copy()
    .align(colour.SpectralShape(GRID.start, GRID.end, GRID.interval))
    .values,
    dtype=float,
)
"""CIE 1931 2° colour matching functions on the grid (61 × 3), used for chromaticities of grid spectra."""

MIRED_RANGE = (1e6 / 25000.0, 1e6 / 2500.0)
"""Reciprocal-temperature range (MK⁻¹) that illumon's daylight estimates are allowed to span: 2500–25000 K."""


def cie_d_weights(xy: ArrayLike) -> NDArray[np.float64]:
    """CIE D-series weights ``(M1, M2)`` for chromaticities ``xy`` (…, 2), CIE 015:2018 eq. 4.8 (unrounded)."""
    xy = np.asarray(xy, dtype=float)
    x, y = xy[..., 0], xy[..., 1]
    m = 0.0241 + 0.2562 * x - 0.7341 * y
    m1 = (-1.3515 - 1.7703 * x + 5.9114 * y) / m
    m2 = (0.0300 - 31.4424 * x + 30.0717 * y) / m
    return np.stack([m1, m2], axis=-1)


def daylight_spectrum(xy: ArrayLike, normalise: bool = True) -> NDArray[np.float64]:
    """CIE D-series relative spectral power for chromaticities ``xy`` (…, 2) → (…, 61).

    With ``normalise`` the spectrum is scaled to 100 at 560 nm, the CIE convention.
    """
    w = cie_d_weights(xy)
    spd = CIE_D_BASIS[:, 0] + w[..., :1] * CIE_D_BASIS[:, 1] + w[..., 1:2] * CIE_D_BASIS[:, 2]
    if normalise:
        i560 = int(np.argmin(np.abs(WAVELENGTHS - 560)))
        spd = 100.0 * spd / spd[..., i560 : i560 + 1]
    return spd


def daylight_locus_xy(cct: ArrayLike) -> NDArray[np.float64]:
    """Chromaticity of the CIE daylight locus at nominal temperature ``cct`` (K), valid 4000–25000 K (extrapolated below)."""
    t = np.asarray(cct, dtype=float)
    x = np.where(
        t <= 7000,
        -4.6070e9 / t**3 + 2.9678e6 / t**2 + 0.09911e3 / t + 0.244063,
        -2.0064e9 / t**3 + 1.9018e6 / t**2 + 0.24748e3 / t + 0.237040,
    )
    y = -3.000 * x**2 + 2.870 * x - 0.275
    return np.stack([x, y], axis=-1)


def cie_d_cct(nominal: ArrayLike) -> NDArray[np.float64]:
    """Correlated colour temperature (K) of the CIE illuminant named by a nominal temperature (D65: 6500 K → 6504 K):
    the nominal value × 1.4388/1.4380, the change of the radiation constant c₂ since the D series was defined."""
    return np.asarray(nominal, dtype=float) * 1.4388 / 1.4380


# --- Planckian locus table -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanckLocus:
    """The Planckian locus tabulated on reciprocal temperature (CIE 1960 uv, derivative and unit normal)."""

    mired: NDArray[np.float64]
    uv: NDArray[np.float64]
    duv_dm: NDArray[np.float64]  # derivative of uv with respect to mired
    normal: NDArray[np.float64]  # unit normal pointing "above" the locus (Ohno's positive Duv side)


@lru_cache(maxsize=1)
def planck_locus() -> PlanckLocus:
    """The tabulated Planckian locus (5–1000 MK⁻¹ at 0.25 MK⁻¹; CIE 1931 2° observer, c₂ = 1.4388e-2 m K)."""
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    wl = np.asarray(cmfs.wavelengths, dtype=float) * 1e-9
    xyz_bar = np.asarray(cmfs.values, dtype=float)
    mired = np.arange(5.0, 1000.0 + 1e-9, 0.25)
    t = 1e6 / mired
    c2 = 1.4388e-2
    spd = 1.0 / (wl[None, :] ** 5 * np.expm1(c2 / (wl[None, :] * t[:, None])))
    xyz = spd @ xyz_bar
    den = xyz[:, 0] + 15 * xyz[:, 1] + 3 * xyz[:, 2]
    uv = np.stack([4 * xyz[:, 0] / den, 6 * xyz[:, 1] / den], axis=1)
    d = np.gradient(uv, mired, axis=0)
    tangent = d / np.linalg.norm(d, axis=1, keepdims=True)
    # Rotate the tangent (direction of increasing mired, i.e. decreasing CCT) so that the normal points to +v.
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    normal *= np.sign(normal[:, 1:2])
    return PlanckLocus(mired, uv, d, normal)


def _uv_to_xy(uv: NDArray[np.float64]) -> NDArray[np.float64]:
    u, v = uv[..., 0], uv[..., 1]
    den = 2 * u - 8 * v + 4
    return np.stack([3 * u / den, 2 * v / den], axis=-1)


def _xy_to_uv(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    x, y = xy[..., 0], xy[..., 1]
    den = -2 * x + 12 * y + 3
    return np.stack([4 * x / den, 6 * y / den], axis=-1)


def xy_from_cct_duv(cct: ArrayLike, duv: ArrayLike) -> NDArray[np.float64]:
    """Chromaticity ``xy`` of the point at ``cct`` (K) and ``duv`` from the Planckian locus (Ohno 2013 convention).

    Vectorised through a dense tabulated locus (0.25 MK⁻¹ steps, linearly interpolated), so it is cheap enough for
    per-frame solves; agrees with :func:`colour.temperature.CCT_to_uv_Ohno2013` to < 1e-5 in uv.
    """
    p = planck_locus()
    m = 1e6 / np.asarray(cct, dtype=float)
    duv = np.asarray(duv, dtype=float)
    u0 = np.interp(m, p.mired, p.uv[:, 0])
    v0 = np.interp(m, p.mired, p.uv[:, 1])
    nu = np.interp(m, p.mired, p.normal[:, 0])
    nv = np.interp(m, p.mired, p.normal[:, 1])
    uv = np.stack([u0 + duv * nu, v0 + duv * nv], axis=-1)
    return _uv_to_xy(uv)


def cct_duv_from_xy(xy: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """CCT (K) and Duv of chromaticities ``xy`` (…, 2) by nearest point on the tabulated Planckian locus.

    The nearest table point is refined by projecting onto the local tangent, which makes the result accurate to well
    under 1 K around daylight temperatures.
    """
    p = planck_locus()
    uv = _xy_to_uv(np.asarray(xy, dtype=float))
    flat = uv.reshape(-1, 2)
    cct = np.empty(flat.shape[0])
    duv = np.empty(flat.shape[0])
    for start in range(0, flat.shape[0], 2048):
        chunk = flat[start : start + 2048]
        d2 = ((chunk[:, None, :] - p.uv[None, :, :]) ** 2).sum(-1)
        k = np.argmin(d2, axis=1)
        base = p.uv[k]
        deriv = p.duv_dm[k]
        dm = ((chunk - base) * deriv).sum(1) / (deriv * deriv).sum(1)
        m = np.clip(p.mired[k] + dm, p.mired[0], p.mired[-1])
        u0 = np.interp(m, p.mired, p.uv[:, 0])
        v0 = np.interp(m, p.mired, p.uv[:, 1])
        nu = np.interp(m, p.mired, p.normal[:, 0])
        nv = np.interp(m, p.mired, p.normal[:, 1])
        cct[start : start + 2048] = 1e6 / m
        duv[start : start + 2048] = (chunk[:, 0] - u0) * nu + (chunk[:, 1] - v0) * nv
    return cct.reshape(uv.shape[:-1]), duv.reshape(uv.shape[:-1])


@lru_cache(maxsize=1)
def _locus_duv_table() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    nominal = np.geomspace(2000.0, 50000.0, 4000)
    cct, duv = cct_duv_from_xy(daylight_locus_xy(nominal))
    mired = 1e6 / cct
    order = np.argsort(mired)
    return mired[order], duv[order]


def daylight_locus_duv(cct: ArrayLike) -> NDArray[np.float64]:
    """Duv of the CIE daylight locus at (Planckian) correlated colour temperature ``cct`` (K).

    Tabulated once from :func:`daylight_locus_xy` and interpolated in reciprocal temperature.
    """
    mired, duv = _locus_duv_table()
    return np.interp(1e6 / np.asarray(cct, dtype=float), mired, duv)


def spectrum_to_xy(spd: ArrayLike) -> NDArray[np.float64]:
    """CIE 1931 chromaticity of grid spectra (…, 61)."""
    xyz = np.asarray(spd, dtype=float) @ CMFS
    return xyz[..., :2] / xyz.sum(-1, keepdims=True)


# --- Marguier & Süsstrunk θ curve ---------------------------------------------------------------------------------


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
    """Build the θ curve from CIE D40, D45, …, D100 (13 illuminants, nominal temperatures × 1.4388/1.438)."""
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


# --- Daylight models used by the estimators ------------------------------------------------------------------------


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


class CIEDaylight(DaylightModel):
    """CIE D-series daylight parameterised by reciprocal CCT and an offset from the daylight locus.

    Parameters per frame: ``mired = 10⁶ / CCT`` and ``δ = Duv − Duv_locus(CCT)``. ``δ`` carries a Gaussian prior
    N(0, ``duv_sigma``²); the 2600 Granada spectra scatter around the CIE daylight locus with σ ≈ 0.0025, so the default
    0.003 lets measured skies leave the locus while keeping the estimate daylight-like. ``duv_sigma=0`` pins frames on
    the locus (one parameter per frame, like the θ curve). A weak Gaussian prior on the reciprocal temperature,
    N(150, 45²) MK⁻¹ (Granada: mean 149, σ 34, 1–99 % 55–186 MK⁻¹, widened for other sites), keeps the common
    colour-temperature shift that static patches cannot determine (see :mod:`illumon.retrieval.joint`) near daylight.

    For a history (:meth:`history_prior_cost`, the scene model's fit) the frames are independent by default. With
    ``mired_between``/``duv_between`` > 0 they share a level that varies between histories with that sd (every frame's
    marginal prior unchanged), a hierarchical prior; Granada runs of 40 spectra vary by 8.4 MK⁻¹ and 0.00068 between
    runs. It is off by default because it measured worse on the development scenes (``tools/common_level_study.py``):
    the reflectance prior then moves the common level further from the truth.
    """

    name = "cie"

    def __init__(
        self, duv_sigma: float = 0.003, mired_mean: float = 150.0, mired_sigma: float = 45.0,
        mired_between: float = 0.0, duv_between: float = 0.0,
    ) -> None:
        self.duv_sigma = float(duv_sigma)
        self.mired_mean = float(mired_mean)
        self.mired_sigma = float(mired_sigma)
        self.mired_between = float(mired_between)
        self.duv_between = float(duv_between)
        if not (0 <= self.mired_between < self.mired_sigma and (self.duv_between == 0 or self.duv_between < self.duv_sigma)):
            raise ValueError("the spread between histories must be non-negative and below the per-frame spread")
        self.n_params = 2 if self.duv_sigma > 0 else 1
        self.basis = CIE_D_BASIS

    def _cct_duv(self, params: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        p = np.atleast_2d(params)
        cct = 1e6 / p[:, 0]
        offset = p[:, 1] if self.n_params == 2 else 0.0
        return cct, daylight_locus_duv(cct) + offset

    def weights(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        cct, duv = self._cct_duv(params)
        m = cie_d_weights(xy_from_cct_duv(cct, duv))
        return np.concatenate([np.ones((m.shape[0], 1)), m], axis=1)

    def prior_residuals(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        p = np.atleast_2d(params)
        out = [(p[:, :1] - self.mired_mean) / self.mired_sigma]
        if self.n_params == 2:
            out.append(p[:, 1:2] / self.duv_sigma)
        return np.concatenate(out, axis=1)

    def history_prior_cost(self, params: NDArray[np.float64]) -> float:
        """−2 log prior density (up to a constant) of a history's parameters (F × n_params)."""
        p = np.atleast_2d(params)
        cost = _hierarchical_cost(p[:, 0], self.mired_mean, self.mired_sigma, self.mired_between)
        if self.n_params == 2:
            cost += _hierarchical_cost(p[:, 1], 0.0, self.duv_sigma, self.duv_between)
        return cost

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if self.n_params == 1:
            return np.array([MIRED_RANGE[0]]), np.array([MIRED_RANGE[1]])
        return np.array([MIRED_RANGE[0], -0.03]), np.array([MIRED_RANGE[1], 0.03])

    def scale(self) -> NDArray[np.float64]:
        return np.array([10.0, self.duv_sigma][: self.n_params])

    def start(self, mired: NDArray[np.float64]) -> NDArray[np.float64]:
        m = np.clip(np.asarray(mired, dtype=float), *MIRED_RANGE)[:, None]
        if self.n_params == 1:
            return m
        return np.concatenate([m, np.zeros_like(m)], axis=1)


def _hierarchical_cost(x: NDArray[np.float64], mean: float, sigma: float, between: float) -> float:
    """−2 log N(x; mean·1, σ_w² I + σ_b² 11ᵀ) up to a constant, σ_w² = sigma² − between², σ_b = ``between``: every
    frame's marginal is N(mean, sigma²), and the frames of one history share a level that varies between histories
    with sd ``between`` (``between = 0``: independent frames)."""
    if between == 0:
        return float((((x - mean) / sigma) ** 2).sum())
    within2 = sigma**2 - between**2
    xbar = float(np.mean(x))
    return float(((x - xbar) ** 2).sum() / within2 + len(x) * (xbar - mean) ** 2 / (within2 + len(x) * between**2))
