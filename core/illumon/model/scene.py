"""The learned scene model: what a fixed camera's history teaches about its scene, saved as versioned JSON.

A :class:`SceneModel` holds the reflectance coefficients of every static patch with their Gaussian posterior
covariance (Y. Kinoshita & H. Kiya, "Bayesian spectral estimation", eqs. 11–16: the reflectance posterior given
illuminants and sensitivities), the camera (effective) sensitivities and how they were calibrated, the wavelength grid,
the daylight model and its prior, the noise level measured from the fit residuals, a summary of the data it was fitted
on and an identifiability report. It is saved as human-readable JSON (``illumon fit``) and loaded back identically.

References
----------
.. [Kinoshita2023] Kinoshita & Kiya, 2023: eqs. 11–16, the reflectance posterior.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._blas import single_blas_thread
from ..daylight import CIEDaylight
from ..observations import Observations, observed, sd_variance
from ..priors import ReflectanceBasis, reflectance_basis
from ..retrieval.common import RetrievalResult
from ..spectra import GRID
from .intervals import assemble_estimates, interval_columns
from .lamps import apply_lamps
from .solver import FrameSolver

__all__ = ["ESTIMATE_CHUNK", "MODEL_FORMAT", "MODEL_VERSION", "SceneModel", "estimate_with_model"]

MODEL_FORMAT = "illumon-scene-model"
MODEL_VERSION = 1


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
    lamps
        The history's posterior of its scene-average colour (:func:`illumon.model.lamps.history_lamps`), with which
        every estimate adds ``non_daylight`` and follows a lamp's light (:func:`illumon.model.lamps.apply_lamps`);
        ``None`` for a model saved before it.
    fit_frames
        After a fixed-camera fit: the frames its reflectances were fitted on, as indices of ``history_estimate``'s
        frames (the subsample of long histories); not saved, ``None`` on a loaded model.
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
    lamps: dict | None = None
    fit_frames: NDArray[np.intp] | None = field(default=None, repr=False, compare=False)

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
            **({"lamps": self.lamps} if self.lamps else {}),
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
                lamps=dict(d["lamps"]) if d.get("lamps") else None,
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
            white=(n.get("white_level", 1.0) or float("inf")) / n["scale"],  # models before it: 0…1 observations
            flare_sd=float(n.get("flare_sd", 0.0)),  # the history's glare spread; models before it had no offset
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
        scale = self.noise["scale"]
        values = np.asarray(obs.values, dtype=float)
        n = len(obs.frames)
        chunks = [slice(i, i + ESTIMATE_CHUNK) for i in range(0, n, ESTIMATE_CHUNK)] or [slice(0, 0)]
        ys = [values[c][:, oj] / scale for c in chunks]  # made once (issue 29: twice was ~0.04 s of 100k frames)
        present = np.concatenate([observed(y) for y in ys])
        few = present.sum(axis=1) < 2
        if few.all():
            raise ValueError("no frame has two or more of the model's patches")
        reflectances = _patch_reflectances(self, obs.patches)
        out = _Estimates(n)
        ys.reverse()
        for c in chunks:  # every frame is estimated on its own: chunks bound the temporaries, not the numbers
            y = ys.pop()  # each chunk's values let go once solved
            extra = None if obs.sd is None else sd_variance(obs.sd[c][:, oj]) / scale**2
            theta, cov, cost = solver.solve(y, present[c], extra)
            part = obs if len(chunks) == 1 else Observations(obs.frames[c], obs.patches, values[c], obs.times[c])
            out.add(c, *assemble_estimates(part, self.noise, self.camera, theta, cov, few[c], solver, cost,
                                           len(shared), reflectances))
        res, cols = out.result(obs)
        if self.lamps:
            apply_lamps(self, obs, res, cols, solver)  # its frame means need only this solver's operators
        return res, cols


ESTIMATE_CHUNK = 8192
"""Frames :meth:`SceneModel.estimate` solves and assembles at once (the temporaries of 100k frames' intervals and
spectra at once were ~180 MB; the same numbers either way)."""

_FRAME_INFO = ("gain_lo", "gain_hi", "theta", "covariance", "cost", "too_few_patches")
"""The per-frame arrays of an estimate's ``info`` (:func:`.intervals.assemble_estimates`)."""


class _Estimates:
    """The chunks of :meth:`SceneModel.estimate` written into arrays of every frame as they come (no list of chunks
    then a concatenation: one copy of the estimate at a time)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.res: RetrievalResult | None = None
        self.cols: dict = {}
        self.fields: dict = {}  # the result's per-frame arrays, filled chunk by chunk
        self.info: dict = {}  # its info's per-frame arrays (_FRAME_INFO)

    def _into(self, store: dict, key: str, chunk: slice, value: NDArray) -> None:
        if key not in store:
            store[key] = np.empty((self.n, *np.shape(value)[1:]), dtype=np.asarray(value).dtype)
        store[key][chunk] = value

    def add(self, chunk: slice, res: RetrievalResult, cols: dict) -> None:
        if self.res is None and chunk.stop >= self.n and chunk.start == 0:  # one chunk: taken as it is
            self.res, self.cols = res, cols
            return
        if self.res is None:
            self.res = res
        for k in ("spectra", "xy", "cct", "duv", "white", "gains", "exposures"):
            self._into(self.fields, k, chunk, getattr(res, k))
        for k in _FRAME_INFO:
            self._into(self.info, k, chunk, res.info[k])
        for k, v in cols.items():
            self._into(self.cols, k, chunk, v)

    def result(self, obs: Observations) -> tuple[RetrievalResult, dict]:
        res = self.res
        assert res is not None
        if len(res.frames) == self.n:
            return res, self.cols
        for k, v in self.fields.items():
            setattr(res, k, v)
        res.info.update(self.info)
        res.frames, res.times = list(obs.frames), list(obs.times)
        return res, self.cols


def _patch_reflectances(model: SceneModel, patches: list[str]) -> NDArray[np.float64]:
    """Learned reflectance spectra (0…1) of ``patches``; NaN rows for patches the model does not know."""
    spectra = np.clip(model.coefficients @ model.basis.T, 0.0, 1.0)
    index = {p: i for i, p in enumerate(model.patches)}
    out = np.full((len(patches), spectra.shape[1]), np.nan)
    for j, p in enumerate(patches):
        if p in index:
            out[j] = spectra[index[p]]
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
