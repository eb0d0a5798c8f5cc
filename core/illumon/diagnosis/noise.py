"""The noise of a history's values, learned from its own residuals, and what counts as censored.

A patch mean's variance is ``σ² = shot · y + read²`` (Foi, Trimeche, Katkovnik & Egiazarian, "Practical
Poissonian-Gaussian noise modeling and fitting for single-image raw-data", IEEE TIP 17(10), 2008), with ``shot`` and
``read`` fitted to the residuals of the history's low-rank factorisation (:func:`.bilinear.wals`), at least the
quantisation noise of values on a grid, and values within a few codes of black censored. Values measured from images
(:data:`CODEC_NOISE`) may also carry noise of the output domain, ``σ² += c·(dy/dx)²`` with ``0 ≤ c ≤`` the cap.
"""

from __future__ import annotations

import contextvars
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

from ..camera.noise import DEFAULT_NOISE
from .bilinear import LowRankFit, wals

__all__ = ["noise_weights", "NoiseLevel", "quantisation_step", "estimate_noise", "DARK_LEVEL", "DARK_CODES",
           "DIM_BRIGHTEST", "dark_level", "dark_level_set", "history_dark_level", "SHOT_SHARE",
           "CODEC_NOISE", "LearnedNoise", "fit_learned_noise"]


def noise_weights(
    y: NDArray[np.float64], shot: float = DEFAULT_NOISE.shot, read: float = DEFAULT_NOISE.read,
    extra: NDArray[np.float64] | float = 0.0,
) -> NDArray[np.float64]:
    """Inverse noise variance ``1 / (shot · y + read² + extra)`` of values on a 0…1 scale (``extra``: a known
    variance, scalar or per value, such as the output's rounding); 0 where missing."""
    w = 1.0 / (shot * np.clip(np.nan_to_num(y), 0, None) + read**2 + extra)
    return np.where(np.isfinite(y), w, 0.0)


@dataclass(frozen=True)
class NoiseLevel:
    """Noise of a value learned from a history: ``σ² = shot · y + read² + codec`` (Poissonian-Gaussian, Foi et al.
    2008, plus the output domain's), ``step`` the quantisation step of the values (0 when they are not on a grid),
    ``censored`` the values at 0, ``codec`` the output-domain variance learned (at most ``codec_cap``, the cap every
    extension's own noise may use: :data:`CODEC_NOISE` for values measured from images, else 0)."""

    shot: float
    read: float
    step: float
    censored: NDArray[np.bool_]
    codec: float = 0.0
    codec_cap: float = 0.0

    def weights(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        """Inverse variances of ``y`` under this noise; 0 where missing or censored at 0."""
        return np.where(self.censored, 0.0, noise_weights(y, self.shot, self.read, self.codec))


def quantisation_step(y: NDArray[np.float64],
                      levels: tuple[int, ...] = (255, 256, 1023, 1024, 4095, 4096, 16383, 16384, 65535, 65536)) -> float:
    """The rounding step of values delivered as codes: on the coarsest grid ``1/L`` of ``levels`` that every finite
    value lies on (within 1e-6 of a code), the greatest common divisor of the codes over ``L`` (12-bit values in a
    16-bit container: 16/65535); 0 when the values are not on a grid (e.g. means of many coded pixels)."""
    v = y[np.isfinite(y)]
    if v.size == 0:
        return 0.0
    for lv in levels:
        if np.all(np.abs(v * lv - np.round(v * lv)) < 1e-6 * max(lv, 1)):
            codes = np.abs(np.round(v * lv)).astype(np.int64)
            g = int(np.gcd.reduce(codes[codes > 0])) if np.any(codes > 0) else 1
            return max(g, 1) / lv
    return 0.0


SHOT_SHARE = 0.9
"""Least share of the noise variance at the median signal that photon shot noise carries in linear light (raw
values: a few e⁻ of read noise against thousands of photo-electrons). Chosen on development histories of both
simulators: with 0.5 the weakest tone curves of :mod:`illumon.simulation.effects` scored −0.8…+1.7 (ΔBIC), with 0.9
all six below −29, clean histories at −16 and above but one raw-pipeline history at −42."""


def _noise_step(x: NDArray[np.float64], pred: NDArray[np.float64], present: NDArray[np.bool_], k: int, shot: float,
                read2: float, floor: float, extra: NDArray[np.float64] | float = 0.0) -> tuple[float, float]:
    """One reweighted least-squares update of ``σ² = a·x + b`` (+ ``extra``, a known variance such as the output's
    rounding) from the residuals of a fit with ``k`` parameters,
    with the physical constraint of linear light that shot noise carries at least :data:`SHOT_SHARE` of the variance
    at the median signal (in a camera's raw values read noise is a few e⁻ against thousands of photo-electrons,
    EMVA 1288). Without it a tone-encoded history, whose spread hardly grows with the value (σ² ∝ y^(2−γ)), would be
    described as linear with constant noise as well as it is as encoded light with shot noise."""
    n = int(present.sum())
    if n - k < 10:
        return shot, read2
    xp = np.clip(pred[present], 0.0, None)
    ex = np.broadcast_to(np.asarray(extra, dtype=float), x.shape)[present]
    res2 = (np.nan_to_num(x)[present] - pred[present]) ** 2 * n / (n - k)
    var = shot * xp + read2 + ex
    res2 = np.minimum(res2, 9.0 * var) - ex
    coef, *_ = np.linalg.lstsq(np.column_stack([xp, np.ones_like(xp)]) / var[:, None], res2 / var, rcond=None)
    x_med = float(np.median(xp)) * (1.0 - SHOT_SHARE) / SHOT_SHARE
    if coef[0] <= 0 or coef[1] > coef[0] * x_med:
        # linear light: photon shot noise carries at least half the variance at the median signal (read and
        # quantisation noise only dominate the dark values), b = a·x_med at most
        u = (xp + x_med) / var
        a = float(np.sum(u * res2 / var) / np.sum(u**2))
        coef = np.array([a, a * x_med])
    shot = max(float(coef[0]), 1e-14)
    return shot, max(float(coef[1]), floor, 1e-6 * shot)


def _joint_step(x: NDArray[np.float64], pred: NDArray[np.float64], present: NDArray[np.bool_], k: int, shot: float,
                read2: float, floor: float, extra: NDArray[np.float64] | float, slope2: NDArray[np.float64] | float,
                cap: float, current: float) -> tuple[float, float, float]:
    """:func:`_noise_step` with an output-domain variance: one reweighted non-negative least-squares update of
    ``σ² = a·x + b + extra + c·slope²`` (``slope`` the derivative of ``x`` by the output value), the shot-share
    constraint on ``a`` and ``b`` (linear light) and ``0 ≤ c ≤ cap`` (the output domain: :data:`CODEC_NOISE`);
    ``a``, ``b`` and ``c`` jointly (alternating them let ``a`` take the output noise first and keep it)."""

    n = int(present.sum())
    if n - k < 10:
        return shot, read2, current
    xp = np.clip(pred[present], 0.0, None)
    ex = np.broadcast_to(np.asarray(extra, dtype=float), x.shape)[present]
    s2 = np.broadcast_to(np.asarray(slope2, dtype=float), x.shape)[present]
    res2 = (np.nan_to_num(x)[present] - pred[present]) ** 2 * n / (n - k)
    var = shot * xp + read2 + ex + current * s2
    res2 = np.minimum(res2, 9.0 * var) - ex
    x_med = float(np.median(xp)) * (1.0 - SHOT_SHARE) / SHOT_SHARE
    best = None
    for free, cols, unpack in (
        (True, np.column_stack([xp, np.ones_like(xp), s2]), lambda v: (v[0], v[1], v[2])),
        (False, np.column_stack([xp + x_med, s2]), lambda v: (v[0], v[0] * x_med, v[1])),
    ):
        coef, _ = nnls(cols / var[:, None], res2 / var)
        a, b, c = unpack(coef)
        if c > cap:  # c at its cap, a and b refitted
            r = res2 - cap * s2
            coef2, _ = nnls(cols[:, :-1] / var[:, None], r / var)
            a, b, c = unpack(np.append(coef2, cap))
        if free and b > a * x_med * (1 + 1e-9):
            continue
        cost = float(np.sum(((res2 - a * xp - b - c * s2) / var) ** 2))
        if best is None or cost < best[0]:
            best = (cost, a, b, c)
    if best is None:
        return shot, read2, current
    _, a, b, c = best
    shot = max(float(a), 1e-14)
    return shot, max(float(b), floor, 1e-6 * shot), float(c)


class LearnedNoise(NamedTuple):
    """What :func:`fit_learned_noise` returns: the fit, the noise ``σ² = shot·x + read2 (+ extra) + codec·slope²`` and
    the negative log-likelihood."""

    fit: LowRankFit
    shot: float
    read2: float
    nll: float
    codec: float = 0.0


def fit_learned_noise(x: NDArray[np.float64], present: NDArray[np.bool_], rank: int, U: NDArray[np.float64] | None,
                      *, shot: float = DEFAULT_NOISE.shot, read: float = DEFAULT_NOISE.read, floor: float = 1e-14,
                      updates: int = 3, iters: int = 40, huber: float | None = None,
                      extra: NDArray[np.float64] | float = 0.0, slope2: NDArray[np.float64] | float = 1.0,
                      codec_cap: float = 0.0) -> LearnedNoise:
    """Rank-``rank`` fit of ``x`` with its noise ``σ² = a·x + b`` learned from its own residuals (alternating the fit
    and :func:`_noise_step`; Foi et al. 2008). Returns the fit, ``a``, ``b`` and the negative log-likelihood
    ``Σ ρ(r/σ) + ½ Σ ln σ²`` of the present values (the noise is a fitted part of the model), ``ρ(z) = z²/2`` or, with
    ``huber`` = c, Huber's loss (Huber, "Robust estimation of a location parameter", Ann. Math. Stat. 35, 1964;
    fitted by iteratively reweighted least squares): a few values off the noise model (rounding of dark pixels that
    the pixel noise does not dither, black clipping) then count linearly, not quadratically. ``extra`` is a known
    variance added to every value's (scalar or per value): the output's rounding, carried into ``x``'s light. With
    ``codec_cap`` > 0 an output-domain variance ``c ≤ codec_cap`` is learned too, carried into ``x``'s light by
    ``slope2`` (the squared derivative of ``x`` by the output value; 1 when ``x`` is the output): a codec's error,
    returned as ``codec``."""
    starts = [(shot, read**2, 0.0)]
    if codec_cap > 0 and OUTPUT_NOISE_START:
        starts.append((1e-14, 1e-14, codec_cap))
    runs = [_learn_noise(x, present, rank, U, *start, floor=floor, updates=updates, iters=iters, huber=huber,
                         extra=extra, slope2=slope2, codec_cap=codec_cap) for start in starts]
    return min(runs, key=lambda r: r.nll)


OUTPUT_NOISE_START = True
"""Whether :func:`fit_learned_noise` with an output-domain variance (``codec_cap`` > 0: values measured from images)
also starts from that variance alone, at its cap, beside linear light's noise (:data:`illumon.camera.DEFAULT_NOISE`),
and keeps the start of higher likelihood. The reweighted updates are a fixed-point iteration, not a maximiser: they
stay in the basin they start in. *Hidden assumption* (issue 28, branch ``diag-clean``): that one start finds the
noise of every hypothesis. From linear light's start the linear hypothesis of clean linear 8-bit histories (JPEG
or PNG, development seeds of the image-based simulator) kept shot noise while the tone hypotheses, whose values the
curve's slope reweights, reached the output-domain noise: tone curves at ΔBIC −60…−85 that are the same noise
described twice (the linear hypothesis from the second start: −12…+7)."""


def _learn_noise(x: NDArray[np.float64], present: NDArray[np.bool_], rank: int, U: NDArray[np.float64] | None,
                 shot: float, read2: float, c_out: float, *, floor: float, updates: int, iters: int,
                 huber: float | None, extra: NDArray[np.float64] | float, slope2: NDArray[np.float64] | float,
                 codec_cap: float) -> LearnedNoise:
    """:func:`fit_learned_noise` from one start (``shot``, ``read2``, output-domain variance ``c_out``)."""

    def weights() -> NDArray[np.float64]:
        return np.where(present, noise_weights(x, shot, np.sqrt(read2), extra + c_out * slope2), 0.0)

    fit = None
    rw = np.ones(x.shape)
    for _ in range(updates):
        w = weights()
        fit = wals(x, w * rw, rank, U=U, iters=iters)
        U = fit.U
        if codec_cap > 0:
            shot, read2, c_out = _joint_step(x, fit.pred, present, fit.k, shot, read2, floor, extra, slope2,
                                             codec_cap, c_out)
        else:
            shot, read2 = _noise_step(x, fit.pred, present, fit.k, shot, read2, floor, extra)
        if huber is not None:
            z = np.abs(np.where(present, np.nan_to_num(x) - fit.pred, 0.0)) * np.sqrt(weights())
            rw = np.minimum(1.0, huber / np.maximum(z, 1e-12))
    assert fit is not None
    w = weights()
    fit = wals(x, w * rw, rank, U=U, iters=iters)
    z = np.abs(np.where(present, np.nan_to_num(x) - fit.pred, 0.0)) * np.sqrt(w)
    rho = 0.5 * z**2 if huber is None else np.where(z < huber, 0.5 * z**2, huber * z - 0.5 * huber**2)
    nll = float(rho[present].sum()) + 0.5 * float(np.log(1.0 / w[present]).sum())
    return LearnedNoise(fit, shot, read2, nll, c_out)


CLIP_TOLERANCE = 2e-3
"""Values within this share of a clip level (at least 1e-6) sit at it (:func:`at_clip_level`)."""


def at_clip_level(values: ArrayLike, level: float) -> NDArray[np.bool_]:
    """Which ``values`` sit at the clip ``level`` (within :data:`CLIP_TOLERANCE` of it; NaN: not): what the clipping
    test censors (:func:`.stages.bilinear_stage`), the correction drops (:func:`.correction.corrected_observations`)
    and, with ``level`` 1, the white level of the 0…1 scale (:func:`.stages.held_at_white`)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(values, dtype=float) >= level - max(CLIP_TOLERANCE * level, 1e-6)


DARK_LEVEL = 0.03
"""The tone-curve test treats values at or below this fraction of the white level as censored (known only to be
dark): in a camera's output they sit within a few codes of the black clipping (the first 8 codes of 8-bit output),
where rounding of pixels that the pixel noise does not dither and the clipping at 0 after black subtraction bias a
region's mean by up to half a code, far beyond a shot-noise model, and a tone curve is fitted to that bias. Chosen on
the development cameras (a clean 8-bit history: ΔBIC −180 with all values, +6 with values above 3 %)."""

DARK_CODES = DARK_LEVEL * 255.0
""":data:`DARK_LEVEL` in codes of 8-bit output (7.65): the fewest codes above black a value needs to count as lit,
whatever the data's bit depth (:func:`history_dark_level`)."""

DIM_BRIGHTEST = 0.2
"""A history whose brightest values (99th percentile) lie below this fraction of the white level is *dim*: its
censoring level is :data:`DARK_LEVEL` of ``brightest / DIM_BRIGHTEST``, not of the white level
(:func:`history_dark_level`). The simulators' histories are exposed well above it (their levels are unchanged)."""

_DARK = contextvars.ContextVar("illumon_diagnosis_dark_level", default=DARK_LEVEL)


def dark_level() -> float:
    """The censoring level of the history being diagnosed (:func:`history_dark_level`; :data:`DARK_LEVEL` outside a
    diagnosis): the tone test, the offset test and the spectral fit read values above it only."""
    return _DARK.get()


@contextmanager
def dark_level_set(level: float) -> Iterator[None]:
    """Diagnose with the censoring level ``level`` (restored on exit; per thread and task)."""
    token = _DARK.set(float(level))
    try:
        yield
    finally:
        _DARK.reset(token)


def history_dark_level(values: NDArray[np.float64], white_level: float | None = None) -> float:
    """The censoring level for a history's values (0…1 of ``white_level``): :data:`DARK_LEVEL`, or for a dim history
    (brightest values, the 99th percentile, below :data:`DIM_BRIGHTEST`) the same share of its own range,
    ``DARK_LEVEL · brightest / DIM_BRIGHTEST`` — but never below :data:`DARK_CODES` codes of the data's bit depth
    (``white_level``; unknown: 16-bit).

    The censoring protects against the bias of a region's mean within a few codes of black (rounding of pixels the
    noise does not dither, clipping at 0 after black subtraction). On 8-bit output (``white_level`` 255) the level stays
    3 % of white whatever the brightness, and a history near black is refused as before. A real 16-bit linear camera
    (the MIMO lamp-lit scenes: regions at 1…10 % of white, i.e. 650…6 500 codes) had every value below 3 % of white:
    the diagnosis censored nearly all of them (or the CLI refused the history) although they are hundreds of codes
    above black and far above the noise."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    if v.size == 0:
        return DARK_LEVEL
    brightest = float(np.percentile(v, 99))
    floor = DARK_CODES / float(white_level if white_level and white_level > 0 else 65535.0)
    return float(min(DARK_LEVEL, max(DARK_LEVEL * brightest / DIM_BRIGHTEST, floor)))



CODEC_NOISE = (1.0 / 255.0) ** 2 / 12.0
"""Cap of the output-domain variance of a value measured from an image (the rounding variance of one 8-bit code; in
the values' own domain, so carried into a tone hypothesis's linear light through the curve's slope).

Region means measured from images carry errors made *after* the linear light: JPEG's quantisation of each 8 × 8
block's transform coefficients (in the encoded output, at any quality) and the rounding of pixels the noise does not
dither. Their variance does not grow with the value, so on a camera that outputs linear values it breaks the
Poissonian-Gaussian noise of linear light that :data:`SHOT_SHARE` assumes — and constant output noise is exactly
what a γ ≈ 2 curve makes of photon noise: clean linear JPEG histories of the image-based simulator
(``benchmarks/imgsim.py``, development seeds) read as tone curves at ΔBIC −160 with the region means' error, about
0.2…0.35 codes whatever the value, taken for shot noise. Allowed up to one code's rounding variance, the error is
what it is. Only for values measured from images (:class:`illumon.observations.Observations` with measured standard
errors, i.e. by the service): region means given at full precision (a raw pipeline's, the project's simulator's)
keep the linear-light noise alone, where the noise's growth with the value still tells a tone curve."""


def estimate_noise(y: NDArray[np.float64], rank: int, *, updates: int = 3, dark: float = 0.0,
                   codec_cap: float = 0.0) -> NoiseLevel:
    """Learn the noise of a history from its own residuals: ``σ² = a·y + b`` (Foi, Trimeche, Katkovnik & Egiazarian,
    "Practical Poissonian-Gaussian noise modeling and fitting for single-image raw-data", IEEE TIP 17(10), 2008),
    fitted by iteratively reweighted least squares to the squared residuals of the rank-``rank`` factorisation,
    scaled by ``n / (n − k)`` for its ``k`` parameters (squared residuals of a Gaussian have variance ``2σ⁴``;
    residuals beyond 3σ are winsorised). What the linear model does not explain of a clean history, its own misfit
    included, counts as noise. ``b`` is at least the quantisation noise ``step²/12`` of values on a grid (Widrow &
    Kollár, *Quantization Noise*, 2008). Values at 0 (at most half a step, or ``dark``) are censored: such a value
    says only that the signal is at most there, so it carries no Gaussian residual (clipping at 0 after black
    subtraction). ``codec_cap`` > 0 learns an output-domain variance too, at most that (:data:`CODEC_NOISE`).
    """
    step = quantisation_step(y)
    censored = np.isfinite(y) & (y <= max(0.5 * step, dark))
    present = np.isfinite(y) & ~censored
    floor = max(step**2 / 12.0, 1e-14)
    learned = fit_learned_noise(y, present, rank, None, floor=floor, updates=updates, codec_cap=codec_cap)
    return NoiseLevel(learned.shot, float(np.sqrt(learned.read2)), step, censored, learned.codec, codec_cap)
