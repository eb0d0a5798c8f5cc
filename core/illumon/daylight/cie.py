"""The CIE D-series: daylight spectra from chromaticity, the daylight locus, and the CIE daylight model of the solvers.

A daylight spectrum in illumon is ``E(λ) = S0(λ) + M1·S1(λ) + M2·S2(λ)`` with the weights M1, M2 given by the
illuminant's chromaticity. The chromaticity itself is parameterised by the correlated colour temperature (CCT, K) and
the signed distance Duv from the Planckian locus in CIE 1960 UCS (:mod:`.ohno2013`: positive above the locus). CIE D
illuminants lie on the *daylight locus*, Duv ≈ +0.003 around 6500 K; measured daylight scatters around it, which
:class:`CIEDaylight` allows with a prior on the offset from the locus.

References
----------
.. [CIE015] CIE 015:2018: §4.1.2 and Appendix C (the D-series basis S0, S1, S2, eq. 4.8 for M1, M2 and the daylight
   locus).
"""

from __future__ import annotations

from functools import lru_cache

import colour
import numpy as np
from colour.colorimetry import SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES
from numpy.typing import ArrayLike, NDArray

from .._tables import cached_arrays
from ..spectra import GRID, WAVELENGTHS
from .base import MIRED_RANGE, DaylightModel
from .ohno2013 import cct_duv_from_xy, xy_from_cct_duv

__all__ = [
    "CIE_D_BASIS",
    "CMFS",
    "cie_d_weights",
    "daylight_spectrum",
    "daylight_locus_xy",
    "cie_d_cct",
    "daylight_locus_duv",
    "xy_from_spectrum",
    "CIEDaylight",
]


def _grid_columns(msd_like: dict) -> NDArray[np.float64]:
    """S0, S1, S2 of colour-science's D-series basis on the grid (61 × 3), linearly interpolated."""
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


def cie_d_weights(xy: ArrayLike) -> NDArray[np.float64]:
    """CIE D-series weights ``(M1, M2)`` for chromaticities ``xy`` (…, 2), CIE 015:2018 eq. 4.8 (unrounded).

    References
    ----------
    .. [CIE015] CIE 015:2018: eq. 4.8.
    """
    xy = np.asarray(xy, dtype=float)
    x, y = xy[..., 0], xy[..., 1]
    m = 0.0241 + 0.2562 * x - 0.7341 * y
    m1 = (-1.3515 - 1.7703 * x + 5.9114 * y) / m
    m2 = (0.0300 - 31.4424 * x + 30.0717 * y) / m
    return np.stack([m1, m2], axis=-1)


def daylight_spectrum(xy: ArrayLike, normalise: bool = True) -> NDArray[np.float64]:
    """CIE D-series relative spectral power for chromaticities ``xy`` (…, 2) → (…, 61).

    With ``normalise`` the spectrum is scaled to 100 at 560 nm, the CIE convention.

    References
    ----------
    .. [CIE015] CIE 015:2018: §4.1.2 and Appendix C.
    """
    w = cie_d_weights(xy)
    spd = CIE_D_BASIS[:, 0] + w[..., :1] * CIE_D_BASIS[:, 1] + w[..., 1:2] * CIE_D_BASIS[:, 2]
    if normalise:
        i560 = int(np.argmin(np.abs(WAVELENGTHS - 560)))
        spd = 100.0 * spd / spd[..., i560 : i560 + 1]
    return spd


def daylight_locus_xy(cct: ArrayLike) -> NDArray[np.float64]:
    """Chromaticity of the CIE daylight locus at nominal temperature ``cct`` (K), valid 4000–25000 K (extrapolated below).

    References
    ----------
    .. [CIE015] CIE 015:2018: §4.1.2 (x_D as a cubic in 1/T, y_D as a quadratic in x_D).
    """
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
    the nominal value × 1.4388/1.4380, the change of the radiation constant c₂ since the D series was defined.

    References
    ----------
    .. [CIE015] CIE 015:2018: §4.1.2 (the D illuminants' nominal and correlated colour temperatures).
    """
    return np.asarray(nominal, dtype=float) * 1.4388 / 1.4380


@lru_cache(maxsize=1)
def _locus_duv_table() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Reciprocal temperature (ascending) and Duv of the CIE daylight locus at 4000 nominal temperatures, 2–50 kK:
    computed once a machine, then read from the disk cache bit for bit (:mod:`illumon._tables`)."""
    from . import ohno2013

    return cached_arrays("daylight-locus-duv", (), (__file__, ohno2013.__file__), _locus_duv_computed)


def _locus_duv_computed() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`_locus_duv_table`, computed."""
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


def xy_from_spectrum(spd: ArrayLike) -> NDArray[np.float64]:
    """CIE 1931 chromaticity of grid spectra (…, 61)."""
    xyz = np.asarray(spd, dtype=float) @ CMFS
    return xyz[..., :2] / xyz.sum(-1, keepdims=True)


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

    References
    ----------
    .. [CIE015] CIE 015:2018: §4.1.2 (the spectrum at a chromaticity).
    .. [Ohno2013] Ohno, LEUKOS 2014: CCT and Duv.
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
