"""Intervals and confidence of the scene model's per-frame estimates.

The Laplace covariance of each frame's ``(mired, δ, log k)`` (:mod:`.solver`) is widened by what the model itself
leaves uncertain (:data:`MODEL_ERROR`): the CIE D-series' mismatch to measured daylight, the shift common to the whole
history that static patches cannot see, and an unmeasured camera's own uncertainty
(:data:`illumon.camera.calibration.CAMERA_WHITE_SD`, and for the CCT
:data:`illumon.camera.calibration.CAMERA_MIRED_SD`), then propagated to 95 % intervals of CCT, Duv and the gains.

``confidence`` (0…1) is the posterior probability that the estimated camera white lies within 1° (angular error) of
the true one, from that covariance approximated as an isotropic Gaussian on the tangent plane (Rayleigh).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr

from ..camera.formation import Z95, confidence_variance, gains_from_white, within_one_degree
from ..daylight import xy_from_cct_duv
from ..observations import Observations
from ..retrieval.common import RetrievalResult
from .solver import FrameSolver

__all__ = ["MODEL_ERROR", "Z95", "assemble_estimates", "interval_columns", "mired_sd_from_interval", "mixture_interval",
           "VERDICT_KEYS", "within_one_degree", "confidence_variance"]

VERDICT_KEYS = ("verdict_shift", "verdict_p")
"""The model-error keys of the history's lamp-lit-or-balanced verdict's other reading: the reciprocal-temperature
shift (MK⁻¹) it would move every frame by, and its probability (:func:`illumon.model.level.verdict_shift`, written by
the fit, read by :func:`assemble_estimates` through :func:`mixture_interval`)."""

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


def assemble_estimates(
    obs: Observations, noise: dict, camera: dict, theta: NDArray[np.float64], cov: NDArray[np.float64],
    few: NDArray[np.bool_], solver: FrameSolver, cost: NDArray[np.float64], n_shared: int,
    reflectances: NDArray[np.float64],
) -> tuple[RetrievalResult, dict]:
    """The per-frame result of :meth:`.SceneModel.estimate` (given its ``noise`` and ``camera``): illuminant, white
    and gains from ``θ``, and their 95 % intervals and ``confidence`` from the Laplace covariance plus the model
    errors (:data:`MODEL_ERROR`, the history's common shift, the camera's own uncertainty); frames with fewer than two
    patches (``few``) are NaN."""
    dm = solver.daylight
    mired, delta = theta[:, 0], theta[:, 1]
    # the light's temperature as reported (a rendered camera's reference moves T, not the light: see
    # illumon.camera.calibration.calibrate_scene_model); white and gains come from θ itself
    shown = theta[:, :2].copy()
    shown[:, 0] = mired + noise.get("mired_offset", 0.0)
    cct = 1e6 / shown[:, 0]
    locus_shown = solver.table.lookup(shown[:, 0])[:, 4]
    duv = locus_shown + delta
    xy = xy_from_cct_duv(cct, duv)
    a0 = solver.table.weights(mired, delta)
    white = a0 @ solver.w
    white = white / white[:, 1:2]
    res = RetrievalResult(
        frames=list(obs.frames), patches=list(obs.patches), spectra=dm.spectra(shown), xy=xy, cct=cct,
        duv=duv, white=white, gains=gains_from_white(white), exposures=np.exp(theta[:, 2]) / noise["scale"],
        reflectances=reflectances,
        method="model", times=list(obs.times),
    )
    me = noise.get("model_error", MODEL_ERROR)
    frame_cov = cov  # the frame's own uncertainty, without what is common to the history
    cov = cov.copy()
    cov[:, 0, 0] += me.get("common_mired", 0.0) ** 2  # shift common to the history (fit's Laplace posterior)
    cov[:, 1, 1] += me.get("common_duv", 0.0) ** 2  # the day's common offset from the locus (see MODEL_ERROR)
    # A reference of known reflectance (grey card, chart) pins the camera white of its frame: a shift common to every
    # frame's daylight then moves the camera transform with it, not the whites and gains (the CCT stays uncertain).
    white_cov = frame_cov if camera.get("calibration") in ("grey", "chart") else cov
    # an unmeasured camera's own reading of the light's temperature (a reference pins its white, not its CCT)
    sm = np.sqrt(np.clip(cov[:, 0, 0], 0, None) + me["mired"] ** 2 + me.get("camera_mired", 0.0) ** 2
                 + me.get("balanced_mired", 0.0) ** 2)
    # … and the history's lamp-lit-or-balanced verdict, whose other reading moves every frame (a two-point mixture)
    m_lo, m_hi = mixture_interval(shown[:, 0], sm, *(me.get(k, 0.0) for k in VERDICT_KEYS))
    cct_lo = 1e6 / np.clip(m_hi, 1e-3, None)
    cct_hi = np.where(m_lo > 0, 1e6 / np.clip(m_lo, 1e-3, None), np.inf)
    dlocus = (solver.table.lookup(shown[:, 0] + 0.5)[:, 4] - solver.table.lookup(shown[:, 0] - 0.5)[:, 4]) / 1.0
    g = np.stack([dlocus, np.ones_like(dlocus)], axis=1)
    sduv = np.sqrt(np.clip(np.einsum("fi,fij,fj->f", g, cov[:, :2, :2], g), 0, None) + me["duv"] ** 2)
    gain, sg, confidence = _gain_spread(solver, mired, delta, a0, white_cov, me)
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
        "gain_lo": gain - Z95 * sg,
        "gain_hi": gain + Z95 * sg,
        "theta": theta,
        "covariance": cov,
        "cost": cost,
        "shared_patches": n_shared,
        "too_few_patches": few,
    }
    return res, extra


def mixture_interval(mired: NDArray[np.float64], sd: NDArray[np.float64], shift: float, p: float
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The central 95 % interval of each frame's reciprocal temperature (MK⁻¹) when it is ``N(mired, sd²)`` with
    probability ``1 − p`` and ``N(mired + shift, sd²)`` with probability ``p`` (the other reading of the history's
    lamp-lit-or-balanced verdict, :func:`illumon.model.level.verdict_shift`); ``mired ± Z95·sd`` when ``p`` is 0.
    Found by bisection on the mixture's distribution function."""
    mired, sd = np.asarray(mired, dtype=float), np.asarray(sd, dtype=float)
    if not (p > 0 and math.isfinite(shift) and shift != 0):
        return mired - Z95 * sd, mired + Z95 * sd
    s = np.clip(sd, 1e-9, None)

    def cdf(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return (1 - p) * ndtr((x - mired) / s) + p * ndtr((x - mired - shift) / s)

    out = []
    for q in (0.025, 0.975):
        # the bracket holds both quantiles (its ends are 8 σ beyond both modes); 40 halvings leave ~1e-10 MK⁻¹
        lo = mired + min(shift, 0.0) - 8 * s
        hi = mired + max(shift, 0.0) + 8 * s
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            below = cdf(mid) < q
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        out.append(0.5 * (lo + hi))
    return out[0], out[1]


def _gain_spread(solver: FrameSolver, mired: NDArray[np.float64], delta: NDArray[np.float64], a0: NDArray[np.float64],
                 white_cov: NDArray[np.float64], me: dict) -> tuple[NDArray[np.float64], ...]:
    """Gains at ``(mired, δ)`` (basis weights ``a0``), their standard deviation and the ``confidence`` (probability
    that the white is within 1° of the truth) from the covariance ``white_cov`` of ``(mired, δ)``, by finite
    differences, plus the camera model's own log-gain uncertainty from the model errors ``me``."""
    # white, gains and their sensitivities to (mired, δ)
    h = np.array([0.5, 1e-4])
    a1 = solver.table.weights(mired + h[0], delta)
    a2 = solver.table.weights(mired, delta + h[1])
    wh = [a @ solver.w for a in (a0, a1, a2)]
    gains = [gains_from_white(w) for w in wh]
    jg = np.stack([(gains[1] - gains[0]) / h[0], (gains[2] - gains[0]) / h[1]], axis=-1)  # F × 3 × 2
    # the camera model's own uncertainty (an unmeasured camera's sensitivities; a reference pins most of it)
    log_gain = math.hypot(me["log_gain"], me.get("camera_log_gain", 0.0))
    # a camera nobody measured: the Laplace part scaled by what its calibration leaves out (STATED_WHITE_SPREAD)
    white_cov = white_cov * me.get("laplace_scale", 1.0) ** 2
    sg = np.sqrt(np.clip(np.einsum("fci,fij,fcj->fc", jg, white_cov[:, :2, :2], jg), 0, None) + (gains[0] * log_gain) ** 2)
    unit = [w / np.linalg.norm(w, axis=1, keepdims=True) for w in wh]
    ju = np.stack([(unit[1] - unit[0]) / h[0], (unit[2] - unit[0]) / h[1]], axis=-1)
    tr = np.einsum("fci,fij,fcj->f", ju, white_cov[:, :2, :2], ju) + 2 * log_gain**2  # angular variance (rad²)
    return gains[0], sg, within_one_degree(tr)


def mired_sd_from_interval(cct_lo: ArrayLike, cct_hi: ArrayLike) -> NDArray[np.float64]:
    """The reciprocal-temperature spread (MK⁻¹) a 95 % CCT interval states: its width in MK⁻¹ over ``2·Z95``, as if
    symmetric (an interval unbounded above, ``cct_hi`` infinite, reaches 0 MK⁻¹). What the benchmarks and the
    calibration tools compare a temperature's error with."""
    return (1e6 / np.asarray(cct_lo, dtype=float) - 1e6 / np.asarray(cct_hi, dtype=float)) / (2 * Z95)


def widen_cct_intervals(result: RetrievalResult, extra: dict, extra_sd: float) -> None:
    """Add ``extra_sd`` (MK⁻¹) in quadrature to the reciprocal-temperature spread of every frame's 95 % CCT interval,
    in place (an estimate made before the model learned it: ``model_error["balanced_mired"]``, which
    :func:`assemble_estimates` adds for later estimates). Each side of the interval is widened on its own (a
    verdict's mixture makes them differ, :func:`mixture_interval`)."""
    mired = 1e6 / np.asarray(result.cct, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        up = (1e6 / np.asarray(extra["cct_lo"], dtype=float) - mired) / Z95  # towards warmer light
        down = (mired - 1e6 / np.asarray(extra["cct_hi"], dtype=float)) / Z95  # towards bluer (1e6/inf = 0)
    up = np.sqrt(np.clip(up, 0, None) ** 2 + extra_sd**2)
    down = np.sqrt(np.clip(down, 0, None) ** 2 + extra_sd**2)
    lo = 1e6 / np.clip(mired + Z95 * up, 1e-3, None)
    hi = np.where(mired - Z95 * down > 0, 1e6 / np.clip(mired - Z95 * down, 1e-3, None), np.inf)
    ok = np.isfinite(extra["cct_lo"])
    extra["cct_lo"] = np.where(ok, lo, extra["cct_lo"])
    extra["cct_hi"] = np.where(ok, hi, extra["cct_hi"])


def widen_white_intervals(result: RetrievalResult, extra: dict, extra_log_sd: float) -> None:
    """Add ``extra_log_sd`` (log r/g and log b/g, each) to every frame's camera-white uncertainty, in place: as
    :func:`_gain_spread` adds the model error ``camera_log_gain`` — ``2·extra_log_sd²`` to the angle's variance behind
    ``confidence`` (:func:`within_one_degree`, inverted to find it) and ``(gain · extra_log_sd)²`` to each gain's —
    for an estimate made before the model learned it (:func:`widen_cct_intervals`' counterpart)."""
    c = np.clip(np.asarray(extra["confidence"], dtype=float), 0.0, 1.0)
    tr = confidence_variance(c)  # the variance :func:`within_one_degree` was given
    extra["confidence"] = np.where(np.isfinite(c) & (c > 0), within_one_degree(tr + 2 * extra_log_sd**2), c)
    g = np.asarray(result.gains, dtype=float)
    half = (np.asarray(result.info["gain_hi"], dtype=float) - np.asarray(result.info["gain_lo"], dtype=float)) / 2
    half = np.sqrt(half**2 + (Z95 * g * extra_log_sd) ** 2)
    result.info["gain_lo"] = g - half
    result.info["gain_hi"] = g + half


def interval_columns(result: RetrievalResult, extra: dict[str, NDArray[np.float64]]) -> dict[str, NDArray[np.float64]]:
    """The ESTIMATES.csv interval columns of :meth:`SceneModel.estimate`'s output: ``cct_lo, cct_hi, duv_lo, duv_hi,
    confidence`` then ``gain_r_lo, gain_r_hi, gain_b_lo, gain_b_hi`` (95 % intervals; the green gain is 1), then
    ``non_daylight`` when the model judged its frames (:mod:`illumon.model.lamps`)."""
    out = {k: v for k, v in extra.items() if k != "non_daylight"}
    for c, name in ((0, "r"), (2, "b")):
        out[f"gain_{name}_lo"] = result.info["gain_lo"][:, c]
        out[f"gain_{name}_hi"] = result.info["gain_hi"][:, c]
    if "non_daylight" in extra:  # last, after the older columns, whose order readers rely on (:mod:`illumon.model.lamps`)
        out["non_daylight"] = extra["non_daylight"]
    return out
