"""A measured-daylight model: a PCA basis of real daylight spectra with an off-locus chromaticity parameter.

The CIE D-series (CIE 015:2018 §4.1.2; Judd, MacAdam & Wyszecki, JOSA 54, 1964) ties the spectrum of daylight to its
chromaticity and puts that chromaticity on the daylight locus. Measured daylight departs from both assumptions:
Hernández-Andrés, Romero, Nieves & Lee ("Color and spectral analysis of daylight in southern Europe", JOSA A 18(6),
2001) show that Granada's global irradiance needs more than three basis functions for accurate spectral recovery and
that its chromaticities scatter above the locus at high correlated colour temperature (blue sky without direct sun).

:class:`MeasuredDaylight` keeps the CIE parameters a solver can find from camera data — reciprocal temperature
``mired = 10⁶/CCT`` and the offset ``δ = Duv − Duv_locus(CCT)`` from the CIE daylight locus — and replaces the CIE
spectrum at that chromaticity with what measured daylight looks like there:

``E = μ + V a``,  ``a = Π_xy(B · [1, M1(xy), M2(xy)] + U diag(s) z)``

* ``μ, V`` — mean and first ``k`` principal components of unit-mean training spectra (``k`` chosen by cross-validated
  reconstruction error within the training split);
* ``B`` — a linear regression of the PCA coefficients on the CIE D weights ``(1, M1, M2)`` of each training spectrum's own
  chromaticity (CIE 015:2018 eq. 4.8), so the expected spectrum follows chromaticity and extrapolates like CIE D;
* ``Π_xy`` — the smallest change of ``a`` that gives the spectrum exactly the chromaticity ``xy`` (two linear
  constraints on tristimulus values), so ``(mired, δ)`` is the spectrum's chromaticity and ``z`` only its shape;
* ``z`` — ``n_extra`` whitened coefficients along the principal directions ``U`` of the regression residual, prior
  N(0, I) (the part of measured spectral shape that chromaticity does not predict);
* ``δ`` — Gaussian prior N(δ̄(mired), σ_δ²) with a mean linear in mired learnt from the training spectra, because
  measured skies sit below the locus at 5000–6000 K and above it beyond 10000 K.

The shipped model (``illumon/data/measured_daylight_basis.csv`` and ``measured_daylight_model.json``) is derived by
``tools/build_daylight_basis.py`` from the training half of the Granada spectra as distributed in the
``neuralsignal/dreye`` repository.

References
----------
.. [HernandezAndres2001] Hernández-Andrés et al., JOSA A 2001.
.. [CIE015] CIE 015:2018: §4.1.2 and eq. 4.8, the CIE D weights the regression uses.
.. [Judd1964] Judd, MacAdam & Wyszecki, JOSA 1964.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..spectra import WAVELENGTHS, read_spectral_csv, resample_columns, write_spectral_csv
from .base import MIRED_RANGE, DaylightModel
from .cie import CMFS, cie_d_weights, daylight_locus_duv, xy_from_spectrum
from .ohno2013 import cct_duv_from_xy, xy_from_cct_duv

__all__ = [
    "MeasuredDaylightData",
    "MeasuredDaylight",
    "fit_measured_daylight",
    "select_components",
    "unit_mean",
    "shipped_measured_daylight",
    "split_indices",
]

DELTA_BOUND = 0.03
"""Bound on the off-locus parameter δ (Duv units), as for :class:`~illumon.daylight.cie.CIEDaylight`."""

Z_BOUND = 5.0
"""Bound on the whitened extra coefficients (prior standard deviations)."""


def unit_mean(spectra: ArrayLike) -> NDArray[np.float64]:
    """Spectra (…, 61) scaled to a mean of 1 over the grid (scale-free comparison of relative irradiance)."""
    e = np.asarray(spectra, dtype=float)
    return e / e.mean(axis=-1, keepdims=True)


def split_indices(n: int, split: str = "time", seed: int = 0) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Training and held-out indices of ``n`` spectra.

    ``"time"``: the first half in file order trains and the second half is held out (for the Granada file, file order
    follows acquisition, so this is a split by time and near-duplicate neighbours do not straddle it). ``"random"``:
    random halves with ``seed``.
    """
    if split == "time":
        half = n // 2
        return np.arange(half), np.arange(half, n)
    if split == "random":
        perm = np.random.default_rng(seed).permutation(n)
        half = n // 2
        return np.sort(perm[:half]), np.sort(perm[half:])
    raise ValueError(f"unknown split {split!r}; use 'time' or 'random'")


def _pca(e: NDArray[np.float64], k: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    mu = e.mean(0)
    _, s, vt = np.linalg.svd(e - mu, full_matrices=False)
    v = vt[:k].T.copy()
    for j in range(v.shape[1]):  # deterministic orientation: largest excursion positive
        if v[np.argmax(np.abs(v[:, j])), j] < 0:
            v[:, j] *= -1
    return mu, v, s


def free_fit(basis: NDArray[np.float64], spectra: ArrayLike) -> NDArray[np.float64]:
    """Least-squares fit of spectra (N × 61) with free weights on ``basis`` (61 × m); returns the fitted spectra."""
    e = np.asarray(spectra, dtype=float)
    coef = np.linalg.lstsq(basis, e.T, rcond=None)[0]
    return (basis @ coef).T


def _rel_rmse(fit: NDArray[np.float64], e: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.sqrt(np.mean((fit - e) ** 2, axis=-1)) / e.mean(axis=-1)


def select_components(
    spectra: ArrayLike, max_components: int = 12, folds: int = 5, tolerance: float = 0.05
) -> tuple[int, NDArray[np.float64]]:
    """Number of PCA components chosen by ``folds``-fold cross-validated reconstruction error.

    Each fold builds the mean and components from the other folds and fits the held-out fold's spectra freely with
    ``[mean, V_1…V_k]``; the error is the relative RMSE (RMSE / mean level) averaged over spectra. Measured daylight is
    smooth and low-noise, so that error keeps falling slowly with every component; the chosen ``k`` is the smallest
    that achieves all but ``tolerance`` of the attainable reduction, ``err_k − err_min ≤ tolerance·(err_1 − err_min)``
    (a parsimony rule in the spirit of the one-standard-error rule of Hastie, Tibshirani & Friedman, *The Elements of
    Statistical Learning*, §7.10).

    Returns
    -------
    k, errors
        The choice and the cross-validated error for k = 1…``max_components``.
    """
    e = unit_mean(spectra)
    n = e.shape[0]
    fold = np.arange(n) % folds  # contiguous interleave: each fold spans the whole training period
    errs = np.zeros(max_components)
    for f in range(folds):
        tr, te = e[fold != f], e[fold == f]
        mu, v, _ = _pca(tr, max_components)
        for k in range(1, max_components + 1):
            fit = free_fit(np.column_stack([mu, v[:, :k]]), te)
            errs[k - 1] += _rel_rmse(fit, te).sum()
    errs /= n
    best = errs.min()
    k = int(np.flatnonzero(errs - best <= tolerance * (errs[0] - best))[0]) + 1
    return k, errs


def _features(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    m = cie_d_weights(xy)
    return np.concatenate([np.ones(m.shape[:-1] + (1,)), m], axis=-1)


@dataclass
class MeasuredDaylightData:
    """Everything that defines a :class:`MeasuredDaylight` model (what the shipped files hold).

    Attributes
    ----------
    mean, components
        Mean (61,) and principal components (61 × k) of unit-mean training spectra.
    regression
        ``B`` (k × 3): PCA coefficients as a linear function of the CIE D weights ``[1, M1, M2]``.
    residual_directions, residual_sd
        Principal directions (k × k) and standard deviations (k,) of the regression residual.
    delta_coef, delta_sd
        Prior on the off-locus offset: mean ``delta_coef[0] + delta_coef[1]·mired`` (mired clipped to
        ``mired_range``), standard deviation ``delta_sd``.
    mired_range
        Range (0.5–99.5 %) of the training spectra's reciprocal temperatures.
    mired_mean, mired_sd
        Mean and standard deviation of the training spectra's reciprocal temperatures (MK⁻¹).
    residual_rel_sd
        Per-wavelength standard deviation (61,) of the training spectra's relative residual after a free fit with
        ``[μ, V]``: the natural spectral detail the basis leaves out (absorption lines, noise).
    cv_errors
        Cross-validated relative RMSE for k = 1…12 that chose ``k``.
    provenance
        Source, split and counts.
    """

    mean: NDArray[np.float64]
    components: NDArray[np.float64]
    regression: NDArray[np.float64]
    residual_directions: NDArray[np.float64]
    residual_sd: NDArray[np.float64]
    delta_coef: NDArray[np.float64]
    delta_sd: float
    mired_range: tuple[float, float]
    mired_mean: float
    mired_sd: float
    residual_rel_sd: NDArray[np.float64]
    cv_errors: NDArray[np.float64]
    provenance: dict = field(default_factory=dict)

    @property
    def k(self) -> int:
        """Number of principal components."""
        return self.components.shape[1]

    @property
    def basis(self) -> NDArray[np.float64]:
        """``[μ, V_1…V_k]`` (61 × (k+1))."""
        return np.column_stack([self.mean, self.components])

    def delta_mean(self, mired: ArrayLike) -> NDArray[np.float64]:
        """Prior mean of δ at reciprocal temperature ``mired``."""
        m = np.clip(np.asarray(mired, dtype=float), *self.mired_range)
        return self.delta_coef[0] + self.delta_coef[1] * m

    def coefficients(self, xy: ArrayLike, extra: ArrayLike | None = None) -> NDArray[np.float64]:
        """PCA coefficients (…, k) at chromaticity ``xy``: regression (+ ``extra``), then the smallest change that
        gives the spectrum exactly that chromaticity (two linear constraints on X, Y, Z)."""
        xy = np.asarray(xy, dtype=float)
        a = _features(xy) @ self.regression.T
        if extra is not None:
            a = a + extra
        x, y = xy[..., :1], xy[..., 1:2]
        s = CMFS.sum(1)
        gx = CMFS[:, 0][None] - x * s[None]  # (…, 61): x·(X+Y+Z) − X = 0
        gy = CMFS[:, 1][None] - y * s[None]
        g = np.stack([gx, gy], axis=-2)  # (…, 2, 61)
        c = g @ self.components  # (…, 2, k)
        r = -(g @ self.mean) - np.einsum("...ij,...j->...i", c, a)  # (…, 2)
        cct = c @ np.swapaxes(c, -1, -2)
        lam = np.linalg.solve(cct, r[..., None])[..., 0]
        return a + np.einsum("...ij,...i->...j", c, lam)

    def predict(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Expected unit-mean-scale spectrum (…, 61) of measured daylight at chromaticity ``xy`` (exact xy)."""
        return self.mean + self.coefficients(xy) @ self.components.T

    def to_json(self) -> dict:
        """The non-spectral parts as a JSON-ready dict (the basis goes to CSV)."""
        return {
            "version": 1,
            "n_components": self.k,
            "regression": self.regression.tolist(),
            "residual_directions": self.residual_directions.tolist(),
            "residual_sd": self.residual_sd.tolist(),
            "delta_coef": self.delta_coef.tolist(),
            "delta_sd": self.delta_sd,
            "mired_range": list(self.mired_range),
            "mired_mean": self.mired_mean,
            "mired_sd": self.mired_sd,
            "residual_rel_sd": self.residual_rel_sd.tolist(),
            "cv_errors": self.cv_errors.tolist(),
            "provenance": self.provenance,
        }

    def save(self, csv_path: str, json_path: str, comments: tuple[str, ...] = ()) -> None:
        """Write the basis CSV (``wavelength_nm,mean,pc1…``) and the JSON of the rest."""
        cols = {"mean": self.mean} | {f"pc{j + 1}": self.components[:, j] for j in range(self.k)}
        write_spectral_csv(csv_path, WAVELENGTHS, cols, comments=comments)
        with open(json_path, "w") as fh:
            json.dump(self.to_json(), fh, indent=1)


def fit_measured_daylight(
    spectra: ArrayLike,
    *,
    n_components: int | None = None,
    max_components: int = 12,
    provenance: dict | None = None,
) -> MeasuredDaylightData:
    """Build a measured-daylight model from training spectra on the grid (N × 61, any scale).

    Parameters
    ----------
    spectra
        Training spectra; never pass the spectra the model will be evaluated on.
    n_components
        Fixed number of principal components; chosen by :func:`select_components` when ``None``.
    max_components
        Largest ``k`` considered by the selection.
    provenance
        Stored with the model.
    """
    e = unit_mean(spectra)
    k_cv, cv = select_components(e, max_components=max_components)
    k = int(n_components or k_cv)
    mu, v, _ = _pca(e, k)
    a = (e - mu) @ v  # N × k (orthonormal components)
    xy = xy_from_spectrum(e)
    feats = _features(xy)
    b = np.linalg.lstsq(feats, a, rcond=None)[0].T  # k × 3
    resid = a - feats @ b.T
    cov = np.cov(resid.T).reshape(k, k)
    sd2, u = np.linalg.eigh(cov)
    order = np.argsort(sd2)[::-1]
    sd = np.sqrt(np.clip(sd2[order], 0, None))
    u = u[:, order]
    cct, duv = cct_duv_from_xy(xy)
    mired = 1e6 / cct
    delta = duv - daylight_locus_duv(cct)
    # Robust (Huber-like, two passes) line δ ~ mired: a few twilight spectra must not tilt it.
    design = np.column_stack([np.ones_like(mired), mired])
    coef = np.linalg.lstsq(design, delta, rcond=None)[0]
    for _ in range(3):
        r = delta - design @ coef
        s = 1.4826 * np.median(np.abs(r - np.median(r)))
        w = np.minimum(1.0, 2.5 * s / np.maximum(np.abs(r), 1e-12))
        coef = np.linalg.lstsq(design * np.sqrt(w)[:, None], delta * np.sqrt(w), rcond=None)[0]
    dsd = float(np.std(delta - design @ coef))
    prov = dict(provenance or {})
    prov.setdefault("n_training_spectra", int(e.shape[0]))
    prov["n_components_cv"] = k_cv
    return MeasuredDaylightData(
        mean=mu,
        components=v,
        regression=b,
        residual_directions=u,
        residual_sd=sd,
        delta_coef=coef,
        delta_sd=dsd,
        mired_range=(float(np.percentile(mired, 0.5)), float(np.percentile(mired, 99.5))),
        mired_mean=float(mired.mean()),
        mired_sd=float(mired.std()),
        residual_rel_sd=(e / free_fit(np.column_stack([mu, v]), e) - 1.0).std(0),
        cv_errors=cv,
        provenance=prov,
    )


@lru_cache(maxsize=1)
def shipped_measured_daylight() -> MeasuredDaylightData:
    """The model shipped in ``illumon/data`` (``measured_daylight_basis.csv`` + ``measured_daylight_model.json``)."""
    root = resources.files("illumon") / "data"
    wl, values, names = read_spectral_csv("measured_daylight_basis.csv", text=(root / "measured_daylight_basis.csv").read_text())
    cols = resample_columns(wl, values)
    meta = json.loads((root / "measured_daylight_model.json").read_text())
    return MeasuredDaylightData(
        mean=cols[:, 0],
        components=cols[:, 1:],
        regression=np.asarray(meta["regression"], dtype=float),
        residual_directions=np.asarray(meta["residual_directions"], dtype=float),
        residual_sd=np.asarray(meta["residual_sd"], dtype=float),
        delta_coef=np.asarray(meta["delta_coef"], dtype=float),
        delta_sd=float(meta["delta_sd"]),
        mired_range=(float(meta["mired_range"][0]), float(meta["mired_range"][1])),
        mired_mean=float(meta["mired_mean"]),
        mired_sd=float(meta["mired_sd"]),
        residual_rel_sd=np.asarray(meta["residual_rel_sd"], dtype=float),
        cv_errors=np.asarray(meta["cv_errors"], dtype=float),
        provenance=meta["provenance"],
    )


class MeasuredDaylight(DaylightModel):
    """Measured daylight for the retrieval solvers: ``[mired, δ, z_1…z_n]`` per frame.

    Parameters
    ----------
    data
        Model data; the shipped Granada model by default (:func:`shipped_measured_daylight`).
    n_extra
        Number of whitened shape coefficients ``z`` beyond chromaticity (0…k). Each costs one parameter per frame; a
        camera's three channels see little of them, so the default is 1 and the prior N(0, 1) keeps them honest.
    mired_mean, mired_sigma
        Weak Gaussian prior on the reciprocal temperature, which static patches alone cannot pin down (a common
        colour-temperature shift of all frames is nearly unobservable). The mean defaults to the training spectra's
        mean; the width defaults to 45 MK⁻¹, the same as :class:`~illumon.daylight.cie.CIEDaylight`'s, so comparisons
        between the two models measure the spectral model, not a tighter prior.

    Notes
    -----
    ``weights(params)`` returns ``[1, a]`` on ``basis = [μ, V]`` with ``a`` as in the module docstring; the spectrum is
    linear in the basis, as the solvers require. ``prior_residuals`` are ``(mired − m̄)/σ_m``,
    ``(δ − δ̄(mired))/σ_δ`` and ``z``.
    """

    name = "measured"

    def __init__(
        self,
        data: MeasuredDaylightData | None = None,
        n_extra: int = 1,
        mired_mean: float | None = None,
        mired_sigma: float = 45.0,
    ) -> None:
        self.data = data if data is not None else shipped_measured_daylight()
        self.mired_mean = float(self.data.mired_mean if mired_mean is None else mired_mean)
        self.mired_sigma = float(mired_sigma)
        self.n_extra = int(min(max(n_extra, 0), self.data.k))
        self.n_params = 2 + self.n_extra
        self.basis = self.data.basis
        self._shape = self.data.residual_directions[:, : self.n_extra] * self.data.residual_sd[: self.n_extra]

    def _cct_duv(self, params: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        p = np.atleast_2d(params)
        cct = 1e6 / p[:, 0]
        return cct, daylight_locus_duv(cct) + p[:, 1]

    def weights(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        p = np.atleast_2d(np.asarray(params, dtype=float))
        cct, duv = self._cct_duv(p)
        extra = p[:, 2:] @ self._shape.T if self.n_extra else None
        a = self.data.coefficients(xy_from_cct_duv(cct, duv), extra)
        return np.concatenate([np.ones((p.shape[0], 1)), a], axis=1)

    def prior_residuals(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        p = np.atleast_2d(np.asarray(params, dtype=float))
        m = (p[:, 0] - self.mired_mean) / self.mired_sigma
        d = (p[:, 1] - self.data.delta_mean(p[:, 0])) / self.data.delta_sd
        return np.column_stack([m, d, p[:, 2:]])

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        lo = np.array([MIRED_RANGE[0], -DELTA_BOUND] + [-Z_BOUND] * self.n_extra)
        hi = np.array([MIRED_RANGE[1], DELTA_BOUND] + [Z_BOUND] * self.n_extra)
        return lo, hi

    def scale(self) -> NDArray[np.float64]:
        """Characteristic change of each parameter: 10 MK⁻¹, σ_δ and one prior σ of each ``z``."""
        return np.array([10.0, self.data.delta_sd] + [1.0] * self.n_extra)

    def start(self, mired: NDArray[np.float64]) -> NDArray[np.float64]:
        m = np.clip(np.asarray(mired, dtype=float).ravel(), *MIRED_RANGE)
        d = np.clip(self.data.delta_mean(m), -DELTA_BOUND, DELTA_BOUND)
        return np.column_stack([m, d, np.zeros((m.size, self.n_extra))])
