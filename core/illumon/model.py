"""Learned scene models: fit a fixed camera's patch reflectances once, then estimate each new frame in well under 1 ms.

A :class:`SceneModel` holds what a history of a fixed camera teaches about its scene: the reflectance coefficients of
every static patch with their Gaussian posterior covariance (Y. Kinoshita & H. Kiya, "Bayesian spectral estimation",
eqs. 11–16: the reflectance posterior given illuminants and sensitivities), the camera sensitivities and wavelength
grid used, the daylight model and its prior, the noise level measured from the fit residuals, a summary of the data
it was fitted on (frames, time span, illuminant spread) and an identifiability report. It is saved as versioned,
human-readable JSON (``illumon fit``) and loaded back identically.

Fitting alternates two exact sub-problems of the joint model of :mod:`illumon.retrieval.joint` (block coordinate
descent): the reflectances given all illuminants and exposures (linear Gaussian posterior, Kinoshita & Kiya eq. 13–14
in basis coefficients), then every frame's daylight and exposure given the reflectances (the per-frame solver below).
Long histories are fitted on a subsample of frames spread over the illuminant range.

Per-frame estimation with a learned model (``illumon estimate --model``) is linear first: with reflectances fixed,
the response of patch ``p`` is ``y_p = Σ_k b_k G_k[p]`` with ``G_k = C^T diag(E_k) S σ_p`` for the three CIE D basis
spectra ``E_k`` and ``b = k/white_g · (1, M1, M2)``, so a 3 × 3 weighted least-squares solve gives ``b̂`` and its
precision ``A`` (the reflectance posterior covariance enters the per-patch noise covariance). The daylight parameters
(reciprocal CCT and offset from the daylight locus) and log exposure then follow from a 3-parameter Gauss–Newton on
``(b(θ) − b̂)ᵀ A (b(θ) − b̂)`` plus the Gaussian daylight prior, vectorised over frames. Its Laplace covariance is
propagated to 95 % intervals of CCT, Duv and the white-balance gains.

``confidence`` (0…1) is the posterior probability that the estimated camera white lies within 1° (angular error) of
the true one, from the Laplace covariance approximated as an isotropic Gaussian on the tangent plane (Rayleigh).
"""

from __future__ import annotations

import argparse
import json
import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._blas import single_blas_thread
from .camera.calibration import calibrate_scene_model
from .camera.formation import gains_from_white
from .camera.references import check_known_reflectances
from .daylight import MIRED_RANGE, CIEDaylight, _planck, cie_d_weights, daylight_locus_duv, xy_from_cct_duv
from .observations import Observations
from .reflectance import ReflectanceBasis, reflectance_basis
from .retrieval.common import RetrievalResult, imaging_operators
from .spectra import GRID

__all__ = [
    "MODEL_FORMAT",
    "MODEL_VERSION",
    "SceneModel",
    "FrameSolver",
    "IdentifiabilityWarning",
    "fit_scene_model",
    "estimate_with_model",
    "add_fit_command",
]

MODEL_FORMAT = "illumon-scene-model"
MODEL_VERSION = 1
Z95 = 1.959963984540054

MODEL_ERROR = {"mired": 0.8, "duv": 0.001, "log_gain": 0.002, "common_duv": 0.0015, "common_mired": 7.5}
"""Standard deviations of the CIE D-series' mismatch to measured daylight as a camera sees it, added in quadrature to
the Laplace intervals: for Granada spectra 1000–2599 and four measured cameras (Nikon D5100, D3X, Canon 5D Mark II,
600D), the CIE daylight with the same camera white differs from the measured spectrum by 0.6–0.9 MK⁻¹ (σ), −0.0006 ±
0.0007 in Duv and 0.16–0.20 % (RMS) in log gains. ``common_duv`` is the uncertainty of the offset from the daylight
locus shared by all frames of a history: static patches cannot separate it from a tint of every reflectance (it is set
by the prior, not the data), and a day of Granada skies departs from the locus by ~0.0015 on average.

``common_mired`` (MK⁻¹) is added in quadrature to the Laplace standard deviation of the reciprocal-temperature shift
shared by all frames. That shift is set by the Gaussian reflectance prior (static patches cannot see it), and the
Laplace curvature trusts the prior as if a scene's patches were drawn from it; a real patch set is a biased draw, and
that bias does not shrink with more frames. Calibrated on 80 histories (Granada runs, 10 patches the basis never saw,
fit on 40 or 80 frames, estimate as many) from eight cameras used nowhere else (Canon 20D, 40D, 5D Mark II, Nikon
D3X, D700, D80, D7000, Hasselblad H2; seeds 1000–1039, 2000–2039): the common error has RMS 6.8 MK⁻¹ (80-frame fits,
Laplace ≈ 1.9) and 8.8 MK⁻¹ (40-frame fits, Laplace ≈ 2.7), mean −1.6 and −0.6; pooled RMS 7.9 MK⁻¹ with Laplace
≈ 2.4 leaves 7.5 MK⁻¹ for the prior's bias."""


CENSORED = 2.0
"""A channel value below this many absolute noise levels (0.4 % of the history's median green) is taken as censored
at 0 — a dark channel clipped after the black level or a colour matrix — and carries no weight."""


class IdentifiabilityWarning(UserWarning):
    """The fitted history cannot determine the illuminants (too little illuminant variation or an ill-posed fit)."""


# --- fast daylight weights ----------------------------------------------------------------------------------------


class _WeightTable:
    """Tabulated Planckian locus, its normal and the daylight-locus Duv on a fine reciprocal-temperature grid, so the
    CIE D weights ``(1, M1, M2)`` of ``(mired, δ)`` cost a handful of array operations."""

    def __init__(self) -> None:
        p = _planck()
        self.m0 = float(MIRED_RANGE[0] - 5.0)
        self.dm = 0.25
        m = np.arange(self.m0, MIRED_RANGE[1] + 10.0, self.dm)
        cols = [np.interp(m, p.mired, p.uv[:, 0]), np.interp(m, p.mired, p.uv[:, 1])]
        cols += [np.interp(m, p.mired, p.normal[:, 0]), np.interp(m, p.mired, p.normal[:, 1])]
        cols.append(daylight_locus_duv(1e6 / m))
        self.table = np.stack(cols, axis=1)
        self.n = m.size

    def lookup(self, mired: NDArray[np.float64]) -> NDArray[np.float64]:
        """Interpolated table rows (…, 5): u0, v0, nu, nv, locus Duv."""
        x = (mired - self.m0) / self.dm
        i = np.minimum(np.maximum(x.astype(np.int64), 0), self.n - 2)
        t = (x - i)[..., None]
        return self.table[i] * (1.0 - t) + self.table[i + 1] * t

    def weights(self, mired: NDArray[np.float64], delta: NDArray[np.float64]) -> NDArray[np.float64]:
        """CIE D basis weights (…, 3) = (1, M1, M2) for reciprocal CCT ``mired`` and offset ``delta`` from the locus."""
        r = self.lookup(mired)
        duv = r[..., 4] + delta
        u = r[..., 0] + duv * r[..., 2]
        v = r[..., 1] + duv * r[..., 3]
        den = 2 * u - 8 * v + 4
        x, y = 3 * u / den, 2 * v / den
        m = 0.0241 + 0.2562 * x - 0.7341 * y
        out = np.empty(m.shape + (3,))
        out[..., 0] = 1.0
        out[..., 1] = (-1.3515 - 1.7703 * x + 5.9114 * y) / m
        out[..., 2] = (0.0300 - 31.4424 * x + 30.0717 * y) / m
        return out


_TABLE: _WeightTable | None = None


def _table() -> _WeightTable:
    global _TABLE
    if _TABLE is None:
        _TABLE = _WeightTable()
    return _TABLE


# --- per-frame solver ----------------------------------------------------------------------------------------------


_DIAG = np.arange(3)
_MAX_STEP = np.array([40.0, 0.01, np.inf])
_EPS3 = 1e-12 * np.eye(3)


class FrameSolver:
    """Per-frame daylight, exposure and Laplace covariance for fixed (learned) patch reflectances.

    Parameters
    ----------
    sensitivities
        Camera sensitivities (61 × 3).
    coefficients
        Reflectance coefficients (P × K) of the patches.
    covariance
        Their posterior covariance (P × K × K), or ``None`` to treat reflectances as exact.
    daylight
        The CIE daylight model with its Gaussian prior on ``(mired, δ)``.
    reflectance
        Reflectance basis (functions used to build the operators).
    relative_error, absolute_error, noise_scale
        Noise model of a patch mean on the model's scale: ``σ = noise_scale · sqrt((relative·y)² + absolute²)``.
    scale
        Observation scale of the model (values are divided by it; the training median green).
    gn_iterations
        Gauss–Newton iterations.
    """

    def __init__(
        self,
        sensitivities: NDArray[np.float64],
        coefficients: NDArray[np.float64],
        covariance: NDArray[np.float64] | None,
        daylight: CIEDaylight,
        reflectance: ReflectanceBasis,
        *,
        relative_error: float = 0.02,
        absolute_error: float = 0.002,
        noise_scale: float = 1.0,
        scale: float = 1.0,
        gn_iterations: int = 3,
    ) -> None:
        self.daylight = daylight
        k, w = imaging_operators(sensitivities, daylight.basis, reflectance)  # nb×3×K, nb×3
        self.w = w
        self.G = np.einsum("kcj,pj->pck", k, coefficients)  # P × 3(c) × 3(k)
        if covariance is not None:
            # H[p, c, e, k, l] = (K_k Σ_p K_lᵀ)_{ce}: reflectance uncertainty of patch p for illuminant weights k, l
            self.H = np.einsum("kcj,pjm,lem->pcekl", k, covariance, k)
        else:
            self.H = None
        self.rel = float(relative_error)
        self.abs = float(absolute_error)
        self.noise_scale = float(noise_scale)
        self.scale = float(scale)
        self.iters = int(gn_iterations)
        self.table = _table()
        lo, hi = daylight.bounds()
        self.lo = np.append(lo, -np.inf)
        self.hi = np.append(hi, np.inf)
        self.prior_mean = np.array([daylight.mired_mean, 0.0])
        self.prior_prec = np.array([1.0 / daylight.mired_sigma**2, 1.0 / daylight.duv_sigma**2])
        # Coarse start grid over (mired, δ): unit-exposure b vectors and their prior cost.
        gm, gd = np.meshgrid(
            np.arange(lo[0], hi[0] + 1e-9, 3.0), np.linspace(-3, 3, 9) * daylight.duv_sigma, indexing="ij"
        )
        self.grid_theta = np.stack([gm.ravel(), gd.ravel()], axis=1)
        self.grid_u = self._b(gm.ravel(), gd.ravel(), np.zeros(gm.size))
        self.grid_prior = self.prior_prec[0] * (gm.ravel() - daylight.mired_mean) ** 2 + self.prior_prec[1] * gd.ravel() ** 2

    # b(θ) = exp(logk) · a(θ) / white_g(a(θ))
    def _b(self, mired: NDArray[np.float64], delta: NDArray[np.float64], logk: NDArray[np.float64]) -> NDArray[np.float64]:
        a = self.table.weights(mired, delta)
        return np.exp(logk)[..., None] * a / (a @ self.w[:, 1])[..., None]

    def linear(self, y: NDArray[np.float64], present: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Weighted linear least squares for ``b`` (F × 3) and its precision ``A`` (F × 3 × 3).

        ``y`` are observations on the model's scale (F × P × 3, NaN where missing). The per-patch noise covariance is
        the noise model plus, after a first pass, the reflectance posterior mapped through the current ``b``.
        """
        yy = np.where(present[..., None], y, 0.0)
        var = (self.noise_scale**2) * ((self.rel * yy) ** 2 + self.abs**2)  # F × P × 3
        var = np.where(yy < CENSORED * self.abs, 1e12, var)  # censored at 0: no weight
        b = None
        for it in range(2 if self.H is not None else 1):
            if it == 0:
                cinv = np.where(present[..., None], 1.0 / var, 0.0)  # diagonal
                gw = self.G[None] * cinv[..., None]  # F × P × 3 × 3
                a = np.einsum("fpck,pcl->fkl", gw, self.G)
                z = np.einsum("fpck,fpc->fk", gw, yy)
            else:
                cov = np.einsum("pcekl,fk,fl->fpce", self.H, b, b)
                cov[..., [0, 1, 2], [0, 1, 2]] += var
                cinv = np.linalg.inv(cov)
                cinv = np.where(present[..., None, None], cinv, 0.0)
                gw = np.einsum("fpce,pek->fpck", cinv, self.G)
                a = np.einsum("fpck,pcl->fkl", gw, self.G)
                z = np.einsum("fpck,fpc->fk", gw, yy)
            a = a + _EPS3
            b = np.linalg.solve(a, z[..., None])[..., 0]
        return b, a

    def start(self, b: NDArray[np.float64], a: NDArray[np.float64]) -> NDArray[np.float64]:
        """Starting ``(mired, δ, logk)`` (F × 3): the best point of a coarse (mired, δ) grid with the exposure
        eliminated in closed form, ``k = uᵀAb̂ / uᵀAu`` for the unit-exposure ``u(θ)``."""
        out = np.empty((b.shape[0], 3))
        u = self.grid_u
        uu = (u[:, :, None] * u[:, None, :]).reshape(len(u), 9).T  # 9 × n: uᵀAu = vec(A)·vec(uuᵀ), one matmul
        for i in range(0, b.shape[0], 256):
            ab = (a[i : i + 256] @ b[i : i + 256, :, None])[..., 0]  # F × 3
            num = ab @ u.T  # F × n
            den = a[i : i + 256].reshape(-1, 9) @ uu
            k = np.clip(num / np.maximum(den, 1e-300), 1e-12, None)
            cost = den * k**2 - 2 * k * num + self.grid_prior
            best = np.argmin(cost, axis=1)
            rows = np.arange(best.size)
            out[i : i + 256, :2] = self.grid_theta[best]
            out[i : i + 256, 2] = np.log(k[rows, best])
        return out

    def solve(
        self, y: NDArray[np.float64], present: NDArray[np.bool_]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Per-frame MAP ``θ = (mired, δ, log k)`` (F × 3), Laplace covariance (F × 3 × 3) and normalised cost (F,).

        Gauss–Newton with Levenberg damping on ``‖U(b(θ) − b̂)‖² + prior``, ``UᵀU = A``; all frames at once.
        """
        bhat, a = self.linear(y, present)
        theta = self.start(bhat, a)
        f = theta.shape[0]
        h = np.array([1e-3, 1e-6])
        pm, pp = self.prior_mean, self.prior_prec
        lam = 1e-3
        for _ in range(self.iters):
            mir, dl, lk = theta[:, 0], theta[:, 1], theta[:, 2]
            # b at θ and at the two finite-difference steps, in one table lookup
            mm = np.concatenate([mir, mir + h[0], mir])
            dd = np.concatenate([dl, dl, dl + h[1]])
            bb = self._b(mm, dd, np.concatenate([lk, lk, lk])).reshape(3, f, 3)
            b = bb[0]
            jac = np.stack([(bb[1] - b) / h[0], (bb[2] - b) / h[1], b], axis=-1)  # F × 3(b) × 3(θ)
            r = b - bhat
            ja = np.einsum("fij,fik->fjk", jac, a)  # Jᵀ A
            hess = ja @ jac
            grad = np.einsum("fjk,fk->fj", ja, r)
            hess[:, 0, 0] += pp[0]
            hess[:, 1, 1] += pp[1]
            grad[:, 0] += pp[0] * (mir - pm[0])
            grad[:, 1] += pp[1] * (dl - pm[1])
            hess[:, _DIAG, _DIAG] *= 1.0 + lam
            step = np.linalg.solve(hess, -grad[..., None])[..., 0]
            step = np.minimum(np.maximum(step, -_MAX_STEP), _MAX_STEP)
            theta = np.minimum(np.maximum(theta + step, self.lo), self.hi)
        mir, dl, lk = theta[:, 0], theta[:, 1], theta[:, 2]
        mm = np.concatenate([mir, mir + h[0], mir])
        dd = np.concatenate([dl, dl, dl + h[1]])
        bb = self._b(mm, dd, np.concatenate([lk, lk, lk])).reshape(3, f, 3)
        b = bb[0]
        jac = np.stack([(bb[1] - b) / h[0], (bb[2] - b) / h[1], b], axis=-1)
        hess = np.einsum("fij,fik,fkl->fjl", jac, a, jac)
        hess[:, 0, 0] += pp[0]
        hess[:, 1, 1] += pp[1]
        cov = np.linalg.inv(hess + _EPS3)
        r = b - bhat
        cost = np.einsum("fi,fij,fj->f", r, a, r)
        return theta, cov, cost


# --- the model ------------------------------------------------------------------------------------------------------


def _arr(x: Any) -> NDArray[np.float64]:
    return np.asarray(x, dtype=float)


@dataclass
class SceneModel:
    """What a fixed camera's history teaches about its scene (see module docstring).

    Attributes
    ----------
    patches
        Patch identifiers (P).
    coefficients, covariance
        Reflectance coefficients (P × K) in the shipped basis and their posterior covariance (P × K × K)
        (Kinoshita & Kiya eqs. 13–14 in basis coefficients, noise precision from the fit residuals).
    sensitivities
        Camera sensitivities used (61 × 3).
    grid
        Wavelength grid ``(start, end, interval)`` in nm.
    basis
        Reflectance basis functions (61 × K) the coefficients refer to.
    daylight
        Daylight model name and prior: ``{"name": "cie", "duv_sigma", "mired_mean", "mired_sigma"}``.
    noise
        ``{"relative_error", "absolute_error", "noise_scale", "scale"}``: the noise model of a patch mean, the factor
        on it measured from the fit residuals (√(χ²/dof)) and the observation scale (training median green).
    training
        Data it was fitted on: frame count, frames used for the reflectance fit, time span, illuminant spread.
    identifiability
        Spread of the history's reciprocal temperatures, condition of the joint problem, ``determined`` and warnings.
    camera
        How the camera was calibrated (:class:`illumon.camera.calibration.CameraCalibration`): ``"measured"``,
        ``"grey"``, ``"chart"`` or ``"none"``, the transform ``T`` of the effective sensitivities
        ``sensitivities = C0 T`` and its uncertainty.
    version
        Format version (:data:`MODEL_VERSION`).
    history_estimate
        After :func:`fit_scene_model`: :meth:`estimate` of the whole history it was fitted on (computed anyway for
        ``training``), so a refit need not estimate the same frames twice; not saved, ``None`` on a loaded model.
    """

    patches: list[str]
    coefficients: NDArray[np.float64]
    covariance: NDArray[np.float64]
    sensitivities: NDArray[np.float64]
    grid: tuple[float, float, float]
    basis: NDArray[np.float64]
    daylight: dict
    noise: dict
    training: dict = field(default_factory=dict)
    identifiability: dict = field(default_factory=dict)
    version: int = MODEL_VERSION
    camera: dict = field(default_factory=lambda: {"calibration": "measured"})
    history_estimate: tuple[RetrievalResult, dict] | None = field(default=None, repr=False, compare=False)

    # -- serialisation --
    def to_dict(self) -> dict:
        """A JSON-ready dictionary (plain lists and numbers)."""
        return {
            "format": MODEL_FORMAT,
            "version": self.version,
            "grid_nm": list(self.grid),
            "daylight": self.daylight,
            "noise": self.noise,
            "training": self.training,
            "identifiability": self.identifiability,
            "camera": self.camera,
            "patches": list(self.patches),
            "reflectance_coefficients": {p: self.coefficients[i].tolist() for i, p in enumerate(self.patches)},
            "reflectance_covariance": {p: self.covariance[i].tolist() for i, p in enumerate(self.patches)},
            "sensitivities_rgb": self.sensitivities.tolist(),
            "reflectance_basis": self.basis.tolist(),
        }

    def save(self, path: str | Path) -> None:
        """Write the model as indented JSON (floats round-trip exactly)."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def from_dict(cls, d: dict, source: str = "model") -> SceneModel:
        """Build a model from :meth:`to_dict` output; ValueError naming ``source`` for anything else."""
        if not isinstance(d, dict) or d.get("format") != MODEL_FORMAT:
            raise ValueError(f"{source}: not an illumon scene model (format {MODEL_FORMAT!r} expected)")
        if d.get("version") != MODEL_VERSION:
            raise ValueError(f"{source}: unsupported model version {d.get('version')!r} (this illumon reads {MODEL_VERSION})")
        try:
            patches = list(d["patches"])
            coef = _arr([d["reflectance_coefficients"][p] for p in patches])
            cov = _arr([d["reflectance_covariance"][p] for p in patches])
            css = _arr(d["sensitivities_rgb"])
            basis = _arr(d["reflectance_basis"])
            grid = tuple(float(v) for v in d["grid_nm"])
            model = cls(
                patches=patches, coefficients=coef, covariance=cov, sensitivities=css, grid=grid,  # type: ignore[arg-type]
                basis=basis, daylight=dict(d["daylight"]), noise=dict(d["noise"]), training=dict(d.get("training", {})),
                identifiability=dict(d.get("identifiability", {})), version=int(d["version"]),
                camera=dict(d.get("camera", {"calibration": "measured"})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: malformed scene model ({exc})") from None
        nl = int(round((grid[1] - grid[0]) / grid[2])) + 1
        if css.shape != (nl, 3) or basis.shape[0] != nl or coef.shape != (len(patches), basis.shape[1]):
            raise ValueError(f"{source}: array shapes do not match the grid and patches")
        if (grid[0], grid[1], grid[2]) != (float(GRID.start), float(GRID.end), float(GRID.interval)):
            raise ValueError(f"{source}: grid {grid} differs from illumon's {GRID.start}–{GRID.end} nm at {GRID.interval}")
        return model

    @classmethod
    def load(cls, path: str | Path) -> SceneModel:
        """Read a model written by :meth:`save`."""
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise ValueError(f"{path}: cannot read model ({exc.strerror or exc})") from None
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
        return cls.from_dict(d, str(path))

    # -- estimation --
    def daylight_model(self) -> CIEDaylight:
        """The daylight model with the stored prior."""
        d = self.daylight
        return CIEDaylight(duv_sigma=d["duv_sigma"], mired_mean=d["mired_mean"], mired_sigma=d["mired_sigma"])

    def reflectance_basis(self) -> ReflectanceBasis:
        """The reflectance basis the coefficients refer to (prior of the shipped basis)."""
        rb = reflectance_basis()
        return ReflectanceBasis(self.basis, rb.prior_mean, rb.prior_covariance, rb.provenance)

    def solver(self, patches: list[int] | None = None) -> FrameSolver:
        """A :class:`FrameSolver` over the selected patches (all by default); build once, call per frame."""
        idx = np.arange(len(self.patches)) if patches is None else np.asarray(patches)
        n = self.noise
        return FrameSolver(
            self.sensitivities, self.coefficients[idx], self.covariance[idx], self.daylight_model(),
            self.reflectance_basis(), relative_error=n["relative_error"], absolute_error=n["absolute_error"],
            noise_scale=n["noise_scale"], scale=n["scale"],
        )

    @single_blas_thread
    def estimate(self, obs: Observations, solver: FrameSolver | None = None) -> tuple[RetrievalResult, dict]:
        """Per-frame estimates with 95 % intervals for ``obs`` (patches matched by name; at least two shared).

        Returns the result and the extra per-frame columns ``cct_lo, cct_hi, duv_lo, duv_hi, confidence``; the
        result's ``info`` also holds ``gain_lo``/``gain_hi`` (F × 3), the covariance of ``(mired, δ, log k)`` and
        the patches used.
        """
        index = {p: i for i, p in enumerate(self.patches)}
        shared = [(j, index[p]) for j, p in enumerate(obs.patches) if p in index]
        if not shared:
            raise ValueError(
                f"observations' patches ({', '.join(obs.patches[:5])}{'…' if len(obs.patches) > 5 else ''}) share none "
                f"with the model's ({', '.join(self.patches[:5])}{'…' if len(self.patches) > 5 else ''})"
            )
        oj = [s[0] for s in shared]
        mi = [s[1] for s in shared]
        solver = solver or self.solver(mi)
        y = np.asarray(obs.values, dtype=float)[:, oj] / self.noise["scale"]
        present = np.all(np.isfinite(y), axis=-1)
        few = present.sum(axis=1) < 2
        if few.all():
            raise ValueError("no frame has two or more of the model's patches")
        theta, cov, cost = solver.solve(y, present)
        return _assemble(obs, self, theta, cov, few, solver, cost, len(shared))


def _patch_reflectances(model: SceneModel, patches: list[str]) -> NDArray[np.float64]:
    """Learned reflectance spectra (0…1) of ``patches``; NaN rows for patches the model does not know."""
    spectra = np.clip(model.coefficients @ model.basis.T, 0.0, 1.0)
    index = {p: i for i, p in enumerate(model.patches)}
    out = np.full((len(patches), spectra.shape[1]), np.nan)
    for j, p in enumerate(patches):
        if p in index:
            out[j] = spectra[index[p]]
    return out


def _assemble(
    obs: Observations, model: SceneModel, theta: NDArray[np.float64], cov: NDArray[np.float64],
    few: NDArray[np.bool_], solver: FrameSolver, cost: NDArray[np.float64], n_shared: int,
) -> tuple[RetrievalResult, dict]:
    dm = solver.daylight
    mired, delta = theta[:, 0], theta[:, 1]
    cct = 1e6 / mired
    locus = solver.table.lookup(mired)[:, 4]
    duv = locus + delta
    xy = xy_from_cct_duv(cct, duv)
    a0 = solver.table.weights(mired, delta)
    white = a0 @ solver.w
    white = white / white[:, 1:2]
    res = RetrievalResult(
        frames=list(obs.frames), patches=list(obs.patches), spectra=dm.spectra(theta[:, :2]), xy=xy, cct=cct,
        duv=duv, white=white, gains=gains_from_white(white), exposures=np.exp(theta[:, 2]) / model.noise["scale"],
        reflectances=_patch_reflectances(model, obs.patches),
        method="model", times=list(obs.times),
    )
    me = model.noise.get("model_error", MODEL_ERROR)
    frame_cov = cov  # the frame's own uncertainty, without what is common to the history
    cov = cov.copy()
    cov[:, 0, 0] += me.get("common_mired", 0.0) ** 2  # shift common to the history (fit's Laplace posterior)
    cov[:, 1, 1] += me.get("common_duv", 0.0) ** 2  # the day's common offset from the locus (see MODEL_ERROR)
    # A reference of known reflectance (grey card, chart) pins the camera white of its frame: a shift common to every
    # frame's daylight then moves the camera transform with it, not the whites and gains (the CCT stays uncertain).
    white_cov = frame_cov if model.camera.get("calibration") in ("grey", "chart") else cov
    sm = np.sqrt(np.clip(cov[:, 0, 0], 0, None) + me["mired"] ** 2)
    cct_lo = 1e6 / np.clip(mired + Z95 * sm, 1e-3, None)
    cct_hi = 1e6 / np.clip(mired - Z95 * sm, 1e-3, None)
    cct_hi = np.where(mired - Z95 * sm > 0, cct_hi, np.inf)
    dlocus = (solver.table.lookup(mired + 0.5)[:, 4] - solver.table.lookup(mired - 0.5)[:, 4]) / 1.0
    g = np.stack([dlocus, np.ones_like(dlocus)], axis=1)
    sduv = np.sqrt(np.clip(np.einsum("fi,fij,fj->f", g, cov[:, :2, :2], g), 0, None) + me["duv"] ** 2)
    # white, gains and their sensitivities to (mired, δ)
    h = np.array([0.5, 1e-4])
    a1 = solver.table.weights(mired + h[0], delta)
    a2 = solver.table.weights(mired, delta + h[1])
    wh = [a @ solver.w for a in (a0, a1, a2)]
    gains = [gains_from_white(w) for w in wh]
    jg = np.stack([(gains[1] - gains[0]) / h[0], (gains[2] - gains[0]) / h[1]], axis=-1)  # F × 3 × 2
    # the camera model's own uncertainty (an unmeasured camera's sensitivities; a reference pins most of it)
    log_gain = math.hypot(me["log_gain"], me.get("camera_log_gain", 0.0))
    sg = np.sqrt(np.clip(np.einsum("fci,fij,fcj->fc", jg, white_cov[:, :2, :2], jg), 0, None) + (gains[0] * log_gain) ** 2)
    unit = [w / np.linalg.norm(w, axis=1, keepdims=True) for w in wh]
    ju = np.stack([(unit[1] - unit[0]) / h[0], (unit[2] - unit[0]) / h[1]], axis=-1)
    tr = np.einsum("fci,fij,fcj->f", ju, white_cov[:, :2, :2], ju) + 2 * log_gain**2  # angular variance (rad²)
    rho = math.radians(1.0)
    confidence = 1.0 - np.exp(-(rho**2) / np.clip(tr, 1e-30, None))  # Rayleigh with σ² = tr/2
    nan = np.full(len(mired), np.nan)
    extra = {
        "cct_lo": np.where(few, nan, cct_lo),
        "cct_hi": np.where(few, nan, cct_hi),
        "duv_lo": np.where(few, nan, duv - Z95 * sduv),
        "duv_hi": np.where(few, nan, duv + Z95 * sduv),
        "confidence": np.where(few, 0.0, confidence),
    }
    if few.any():
        for arr in (res.cct, res.duv):
            arr[few] = np.nan
        res.xy[few] = np.nan
        res.white[few] = np.nan
        res.gains[few] = np.nan
    res.info = {
        "gain_lo": gains[0] - Z95 * sg,
        "gain_hi": gains[0] + Z95 * sg,
        "theta": theta,
        "covariance": cov,
        "cost": cost,
        "shared_patches": n_shared,
        "too_few_patches": few,
    }
    return res, extra


# --- fitting --------------------------------------------------------------------------------------------------------


def _spread_subsample(mired: NDArray[np.float64], n: int) -> NDArray[np.int64]:
    """``n`` frame indices spread evenly over the rank order of ``mired`` (covers the illuminant range)."""
    if mired.size <= n:
        return np.arange(mired.size)
    order = np.argsort(mired, kind="stable")
    pick = order[np.round(np.linspace(0, mired.size - 1, n)).astype(int)]
    return np.unique(pick)


def _reflectance_posterior(
    a: NDArray[np.float64], y: NDArray[np.float64], w2: NDArray[np.float64], lam: NDArray[np.float64],
    mu: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Kinoshita & Kiya eqs. 13–14 in basis coefficients, for every patch at once.

    ``a`` (F × 3 × K) maps coefficients to each frame's responses, ``w2`` (F × P × 3) are noise precisions (0 where
    missing), ``lam``/``mu`` the prior precision and mean. Returns means (P × K) and precisions (P × K × K).
    """
    prec = np.einsum("fpc,fci,fcj->pij", w2, a, a) + lam
    rhs = np.einsum("fpc,fpc,fci->pi", w2, y, a) + lam @ mu
    return np.linalg.solve(prec, rhs[..., None])[..., 0], prec


def fit_scene_model(
    obs: Observations,
    sensitivities: NDArray[np.float64] | None,
    *,
    known_reflectances: Mapping[str, NDArray[np.float64]] | None = None,
    camera_prior_mean: NDArray[np.float64] | None = None,
    daylight: CIEDaylight | None = None,
    relative_error: float = 0.02,
    absolute_error: float = 0.002,
    max_fit_frames: int = 300,
    iterations: int = 40,
    tol: float = 0.01,
) -> SceneModel:
    """Learn a :class:`SceneModel` from a history (see module docstring for the method).

    Parameters
    ----------
    obs
        Observations of static patches (at least two frames, each patch seen in at least one frame), linear, in the
        camera's output space.
    sensitivities
        Measured camera sensitivities on the grid (61 × 3), or ``None`` for a camera nobody measured: then the prior
        from the measured cameras is used and refined from the data (:mod:`illumon.camera.calibration`).
    known_reflectances
        References of known reflectance (patch id → spectrum on the grid, 0…1) that appear in some frames of ``obs``,
        typically one: a grey card pins each channel's scale, a chart also a 3 × 3 colour matrix. Their patches are
        not part of the learned scene.
    camera_prior_mean
        With ``sensitivities=None``: the unmeasured camera's prior sensitivities (default: the mean of the measured
        cameras shipped with illumon).
    daylight
        CIE daylight model with its prior; the default :class:`~illumon.daylight.CIEDaylight`.
    relative_error, absolute_error
        Noise model before the residual-based scale factor.
    max_fit_frames
        Histories longer than this fit reflectances on that many frames spread over the gray-world illuminant range.
    iterations, tol
        Alternation cap and convergence tolerance (MK⁻¹, largest change of any frame's reciprocal temperature).

    Returns
    -------
    SceneModel
        Its ``camera`` says how the camera was calibrated; estimates and gains are in the observations' RGB space.
    """
    kwargs = dict(daylight=daylight, relative_error=relative_error, absolute_error=absolute_error,
                  max_fit_frames=max_fit_frames, iterations=iterations, tol=tol)
    known = check_known_reflectances(known_reflectances, "known reflectances") if known_reflectances else {}
    missing = [p for p in known if p not in obs.patches]
    if missing:
        raise ValueError(f"known patch(es) never observed: {', '.join(missing)}")
    if sensitivities is None or known:
        return calibrate_scene_model(obs, sensitivities, known, lambda o, c: _fit_fixed_camera(o, c, **kwargs),
                                     prior_mean=camera_prior_mean)
    model, _ = _fit_fixed_camera(obs, np.asarray(sensitivities, dtype=float), **kwargs)
    model.camera = {"calibration": "measured"}
    return model


@single_blas_thread
def _fit_fixed_camera(
    obs: Observations,
    sensitivities: NDArray[np.float64],
    *,
    daylight: CIEDaylight | None = None,
    relative_error: float = 0.02,
    absolute_error: float = 0.002,
    max_fit_frames: int = 300,
    iterations: int = 40,
    tol: float = 0.01,
) -> tuple[SceneModel, NDArray[np.float64]]:
    """:func:`fit_scene_model` for given (effective) sensitivities. Returns the model and every frame's
    ``(mired, δ, log k)`` (F × 3) from the learned reflectances."""
    from .retrieval.joint import _gray_world_mired

    t0 = time.perf_counter()
    dm = daylight or CIEDaylight()
    rb = reflectance_basis()
    css = np.asarray(sensitivities, dtype=float)
    y_all = np.asarray(obs.values, dtype=float)
    if y_all.shape[0] < 2:
        raise ValueError("fitting a scene model needs at least two frames")
    present_all = np.all(np.isfinite(y_all), axis=-1)
    if present_all.any(axis=0).sum() < 2:
        raise ValueError("fitting a scene model needs at least two patches")
    unseen = [p for p, s in zip(obs.patches, present_all.any(axis=0), strict=True) if not s]
    if unseen:
        raise ValueError(f"patch(es) never observed: {', '.join(unseen)}")
    green = y_all[..., 1][present_all]
    scale = float(np.median(green)) if green.size else 1.0
    if not scale > 0:
        raise ValueError("observations are all black (median green is 0)")
    gw_mired = _gray_world_mired(obs, css, dm)
    sub = _spread_subsample(gw_mired, max_fit_frames)
    y = y_all[sub] / scale
    present = present_all[sub]
    yz = np.where(present[..., None], y, 0.0)
    base_w2 = np.where(present[..., None], 1.0 / ((relative_error * yz) ** 2 + absolute_error**2), 0.0)
    base_w2[yz < CENSORED * absolute_error] = 0.0  # censored at 0 (dark channels after the black level): no weight
    k_ops, w_ops = imaging_operators(css, dm.basis, rb)
    lam = np.linalg.inv(rb.prior_covariance)
    mu = rb.prior_mean
    # Start: gray-world temperatures on the locus, exposures from the frames' levels.
    mired0 = gw_mired[sub]
    daylight_prec = np.array([1.0 / dm.mired_sigma**2, 1.0 / dm.duv_sigma**2])

    def operators(th: NDArray[np.float64]) -> NDArray[np.float64]:
        a = np.asarray(dm.weights(th[:, :2]))
        m = np.einsum("fk,kcj->fcj", a, k_ops) / (a @ w_ops)[:, 1, None, None]
        return np.exp(th[:, 2])[:, None, None] * m

    def cost(th: NDArray[np.float64], noise: float = 1.0) -> tuple[float, NDArray[np.float64]]:
        """Joint MAP objective (−2 log posterior) with the reflectances eliminated (exact conditional mean)."""
        am = operators(th)
        w2 = base_w2 / noise**2
        s, _ = _reflectance_posterior(am, yz, w2, lam, mu)
        r = yz - np.einsum("fcj,pj->fpc", am, s)
        d = s - mu
        c = (w2 * r**2).sum() + np.einsum("pi,ij,pj->", d, lam, d)
        c += (daylight_prec[0] * (th[:, 0] - dm.mired_mean) ** 2 + daylight_prec[1] * th[:, 1] ** 2).sum()
        return float(c), s

    typical = np.einsum("fcj,j->fc", operators(np.stack([mired0, np.zeros_like(mired0), np.zeros_like(mired0)], 1)), mu)
    level = np.array([np.mean(y[f, present[f], 1]) if present[f].any() else 1.0 for f in range(len(sub))])
    theta = np.stack([mired0, np.zeros_like(mired0), np.log(np.maximum(level, 1e-6) / np.maximum(typical[:, 1], 1e-9))], 1)
    best, coef = cost(theta)
    lo_b, hi_b = dm.bounds()
    n_iter = 0
    for n_iter in range(1, iterations + 1):  # noqa: B007
        solver = FrameSolver(css, coef, None, dm, rb, relative_error=relative_error, absolute_error=absolute_error)
        new, _, _ = solver.solve(y, present)
        c_new, s_new = cost(new)
        step = new - theta
        cands: list[NDArray[np.float64]] = []
        # Over-relaxation along the alternation step and a common shift of every frame's reciprocal temperature:
        # the directions in which block coordinate descent crawls (the common shift is only weakly determined).
        for alpha in (2.0, 4.0, 8.0):
            cands.append(theta + alpha * step)
        for shift in (-16.0, -4.0, -1.0, 1.0, 4.0, 16.0):
            cands.append(new + np.array([shift, 0.0, 0.0]))
        prev = theta
        theta, best_new, coef = new, c_new, s_new
        for cand in cands:
            cand = cand.copy()
            cand[:, 0] = np.clip(cand[:, 0], lo_b[0], hi_b[0])
            cand[:, 1] = np.clip(cand[:, 1], lo_b[1], hi_b[1])
            c_c, s_c = cost(cand)
            if c_c < best_new:
                theta, best_new, coef = cand, c_c, s_c
        change = float(np.max(np.abs(theta[:, 0] - prev[:, 0])))
        improvement = best - best_new
        best = best_new
        if change < tol or improvement < 1e-6 * abs(best):
            break
    assert theta is not None
    am = operators(theta)
    coef, prec = _reflectance_posterior(am, yz, base_w2, lam, mu)
    pred = np.einsum("fcj,pj->fpc", am, coef)
    resid2 = base_w2 * (yz - pred) ** 2
    n_obs = int(present.sum()) * 3
    dof = max(n_obs - 3 * len(sub) - rb.size * len(obs.patches), 1)
    noise_scale = float(max(math.sqrt(resid2.sum() / dof), 0.5))
    # Posterior precision with the measured noise level (β scaled by 1/noise_scale²).
    coef, prec = _reflectance_posterior(am, yz, base_w2 / noise_scale**2, lam, mu)
    cov = np.linalg.inv(prec)
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    # Laplace uncertainty of a shift common to every frame (reciprocal temperature, Duv offset): the direction static
    # patches determine worst (profile curvature, reflectances re-solved; −2 log p → covariance 2 H⁻¹).
    steps = np.array([1.0, 3e-4])
    hc = np.empty((2, 2))
    c0 = cost(theta, noise_scale)[0]
    for i in range(2):
        for j in range(2):
            def shifted(si: float, sj: float, i: int = i, j: int = j) -> float:
                d = np.zeros(3)
                d[i] += si * steps[i]
                d[j] += sj * steps[j]
                return cost(theta + d, noise_scale)[0]

            if i == j:
                hc[i, i] = (shifted(1, 0) - 2 * c0 + shifted(-1, 0)) / steps[i] ** 2
            else:
                hc[i, j] = (shifted(1, 1) - shifted(1, -1) - shifted(-1, 1) + shifted(-1, -1)) / (
                    4 * steps[i] * steps[j]
                )
    try:
        common_cov = 2 * np.linalg.inv(0.5 * (hc + hc.T))
        common = np.sqrt(np.clip(np.diag(common_cov), 0, None))
    except np.linalg.LinAlgError:
        common = np.array([dm.mired_sigma, dm.duv_sigma])
    fit_seconds = time.perf_counter() - t0

    model = SceneModel(
        patches=list(obs.patches), coefficients=coef, covariance=cov, sensitivities=css,
        grid=(float(GRID.start), float(GRID.end), float(GRID.interval)), basis=rb.functions,
        daylight={"name": "cie", "duv_sigma": dm.duv_sigma, "mired_mean": dm.mired_mean, "mired_sigma": dm.mired_sigma},
        noise={"relative_error": relative_error, "absolute_error": absolute_error, "noise_scale": noise_scale,
               "scale": scale,
               "model_error": dict(MODEL_ERROR, common_mired=float(math.hypot(common[0], MODEL_ERROR["common_mired"])),
                                   common_duv=float(max(common[1], MODEL_ERROR["common_duv"])))},
    )
    # Illuminants of every frame with the learned reflectances (the fast solver), for the training summary.
    res, extra = model.estimate(obs)
    model.history_estimate = (res, extra)
    mired_all = 1e6 / res.cct
    ok = np.isfinite(mired_all)
    times = [t for t in obs.times if t]
    model.training = {
        "frames": len(obs.frames),
        "frames_used_for_reflectances": int(len(sub)),
        "patches": len(obs.patches),
        "observed_fraction": float(present_all.mean()),
        "time_first": min(times) if times else "",
        "time_last": max(times) if times else "",
        "mired_min": float(np.min(mired_all[ok])),
        "mired_max": float(np.max(mired_all[ok])),
        "mired_std": float(np.std(mired_all[ok])),
        "cct_p05": float(np.percentile(res.cct[ok], 5)),
        "cct_p95": float(np.percentile(res.cct[ok], 95)),
        "iterations": n_iter,
        "fit_seconds": round(fit_seconds, 3),
    }
    model.identifiability = identifiability(
        y, present, css, dm, rb, theta, coef, base_w2 / noise_scale**2, mired_all[ok]
    )
    for msg in model.identifiability["warnings"]:
        warnings.warn(msg, IdentifiabilityWarning, stacklevel=3)
    return model, res.info["theta"]


def identifiability(
    y: NDArray[np.float64], present: NDArray[np.bool_], css: NDArray[np.float64], dm: CIEDaylight,
    rb: ReflectanceBasis, theta: NDArray[np.float64], coef: NDArray[np.float64], w2: NDArray[np.float64],
    mired_all: NDArray[np.float64], *, max_frames: int = 40, min_mired_spread: float = 4.0,
    max_condition: float = 1e8,
) -> dict:
    """How well a history determines its illuminants.

    Reports the spread (standard deviation, 5–95 % range) of the history's reciprocal temperatures and the condition
    number of the *data-only* Jacobian of the joint problem (priors left out) on up to ``max_frames`` frames spread
    over the illuminant range, columns scaled to meaningful changes (10 MK⁻¹, 0.003 Duv, 0.1 log exposure, 0.1
    coefficient), the exact exposure/reflectance scale gauge removed. Constant illuminants make reflectance and
    illuminant trade off (condition → ∞); the spread then says the same in physical units.
    """
    sel = _spread_subsample(theta[:, 0], max_frames)
    k_ops, w_ops = imaging_operators(css, dm.basis, rb)
    f, p, nk = sel.size, coef.shape[0], rb.size

    def pred(x: NDArray[np.float64]) -> NDArray[np.float64]:
        fr = x[: 3 * f].reshape(f, 3)
        s = x[3 * f :].reshape(p, nk)
        a = np.asarray(dm.weights(fr[:, :2]))
        m = np.einsum("fk,kcj->fcj", a, k_ops) / (a @ w_ops)[:, 1, None, None]
        return (np.exp(fr[:, 2])[:, None, None] * np.einsum("fcj,pj->fpc", m, s) * np.sqrt(w2[sel])).ravel()

    x0 = np.concatenate([theta[sel].ravel(), coef.ravel()])
    steps = np.concatenate([np.tile([10.0, dm.duv_sigma, 0.1], f), np.full(p * nk, 0.1)])
    r0 = pred(x0)
    jac = np.empty((r0.size, x0.size))
    for j in range(x0.size):
        h = 1e-4 * steps[j]
        xp = x0.copy()
        xp[j] += h
        jac[:, j] = (pred(xp) - r0) / h * steps[j]
    sv = np.linalg.svd(jac, compute_uv=False)
    # Three directions are not fixed by the data of any history: the exposure/reflectance scale (exact gauge) and a
    # common shift of every frame's temperature and Duv (absorbed by reflectance changes, set by the priors).
    # The condition of the rest says whether the data determine the illuminants relative to each other.
    cond = float(sv[0] / max(sv[-4], 1e-300)) if sv.size > 4 else math.inf
    sv_tail = [float(v / sv[0]) for v in sv[-4:]]
    spread = float(np.std(mired_all)) if mired_all.size else 0.0
    p5, p95 = (np.percentile(mired_all, [5, 95]) if mired_all.size else (np.nan, np.nan))
    warn = []
    if spread < min_mired_spread:
        warn.append(
            f"illuminants barely vary in this history (σ = {spread:.1f} MK⁻¹ < {min_mired_spread}): reflectances and "
            "illuminant colour trade off, so illuminants are set by the daylight prior, not by the data"
        )
    if not cond < max_condition:
        warn.append(f"joint problem ill-conditioned (condition {cond:.3g} ≥ {max_condition:.0e}): illuminants not determined")
    return {
        "mired_std": spread,
        "mired_p05": float(p5),
        "mired_p95": float(p95),
        "condition": cond,
        "condition_frames": int(f),
        "smallest_singular_values_relative": sv_tail,
        "determined": not warn,
        "warnings": warn,
    }


# --- CLI glue -------------------------------------------------------------------------------------------------------


def interval_columns(result: RetrievalResult, extra: dict[str, NDArray[np.float64]]) -> dict[str, NDArray[np.float64]]:
    """The ESTIMATES.csv interval columns of :meth:`SceneModel.estimate`'s output: ``cct_lo, cct_hi, duv_lo, duv_hi,
    confidence`` then ``gain_r_lo, gain_r_hi, gain_b_lo, gain_b_hi`` (95 % intervals; the green gain is 1)."""
    out = dict(extra)
    for c, name in ((0, "r"), (2, "b")):
        out[f"gain_{name}_lo"] = result.info["gain_lo"][:, c]
        out[f"gain_{name}_hi"] = result.info["gain_hi"][:, c]
    return out


def estimate_with_model(obs: Observations, model_path: str | Path) -> tuple[RetrievalResult, dict[str, NDArray[np.float64]]]:
    """Per-frame estimates of ``obs`` with the model in ``model_path`` (``illumon estimate --model``).

    Returns the result and the extra columns of :func:`interval_columns` (see the module docstring for
    ``confidence``).
    """
    model = SceneModel.load(model_path)
    try:
        res, extra = model.estimate(obs)
    except ValueError as exc:
        raise ValueError(f"{model_path}: {exc}") from None
    return res, interval_columns(res, extra)


def _cmd_fit(args: argparse.Namespace) -> int:
    from .cli import fit_camera_and_scene, read_known
    from .observations import read_observations

    obs = read_observations(args.observations, white_level=args.white_level)
    model = fit_camera_and_scene(args, obs, read_known(args, obs), max_fit_frames=args.max_fit_frames)
    model.save(args.model)
    ident = model.identifiability
    tr = model.training
    cam = model.camera.get("calibration", "measured")
    print(
        f"fitted {len(model.patches)} patches on {tr['frames_used_for_reflectances']} of {tr['frames']} frames; "
        f"CCT {tr['cct_p05']:.0f}–{tr['cct_p95']:.0f} K (5–95 %); noise ×{model.noise['noise_scale']:.2f}; "
        f"condition {ident['condition']:.3g}; camera: {CAMERA_WORDS[cam]} → {args.model}"
    )
    for msg in ident["warnings"]:
        print(f"illumon: warning: {msg}")
    if ident["warnings"]:
        print(
            "illumon: what this means: the frames' colour *differences* are still estimated, but the colour common to "
            "the whole history (how warm or cool every frame is) comes from typical daylight and typical surfaces, not "
            "from this scene; intervals and confidence already include that. Fix: fit on a longer history that spans "
            "clear and overcast days, sunrise to noon (≥ 50 frames over several days), or add a grey card or chart "
            "frame with --known-reflectances."
        )
    return 0


CAMERA_WORDS = {
    "measured": "measured sensitivities",
    "grey": "calibrated by a grey card (channel scales)",
    "chart": "calibrated by a chart (3 × 3 matrix)",
    "none": "nobody measured it and no reference: prior of the measured cameras, wide intervals",
}


def add_fit_command(subparsers: Any) -> None:
    """Register ``illumon fit OBSERVATIONS.csv [--sensitivities S.csv] [--known-reflectances KNOWN.csv] --model M``."""
    from .cli import white_level_arg

    p = subparsers.add_parser("fit", help="learn a scene model (patch reflectances) from a history")
    p.add_argument("observations", help="OBSERVATIONS.csv with columns frame,time,patch,r,g,b")
    p.add_argument("--sensitivities", help="camera sensitivities CSV wavelength_nm,r,g,b (none: a camera nobody measured)")
    p.add_argument("--known-reflectances", help="KNOWN.csv wavelength_nm,<patch id>,…: references of known reflectance")
    p.add_argument("--model", required=True, help="MODEL.json to write")
    p.add_argument("--white-level", type=white_level_arg, default=255.0, help="value of a saturated pixel (255)")
    p.add_argument("--max-fit-frames", type=int, default=300, help="frames used for the reflectance fit (300)")
    p.set_defaults(func=_cmd_fit)


_ = cie_d_weights  # re-exported helper used in docs
