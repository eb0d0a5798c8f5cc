"""The tone-curve extension of the bilinear stage (``nonlinear_response``): the history's values as an output
encoding of linear light, ``y = x^(1/γ)`` or one of the standard curves with a linear toe (sRGB, BT.709), each
hypothesis with its own Poissonian-Gaussian noise learned in its linear light, scored against the linear base.

:func:`tone_candidate` is used by :func:`.stages.bilinear_stage` and, alone, by :func:`.stages.tone_stage`.

References
----------
.. [IEC61966-2-1] IEC 61966-2-1:1999 (sRGB): the sRGB encoding and its inverse.
.. [ITU-BT709] ITU-R BT.709-6: the BT.709 opto-electronic transfer function.
.. [Foi2008] Foi et al., IEEE TIP 2008: the noise each hypothesis learns.
.. [Huber1964] Huber, 1964: the loss.
"""

from __future__ import annotations

import colour
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

from . import bilinear as bl
from . import noise as nz
from .candidate import Candidate

__all__ = [
    "GAMMA_NOISE_FLOOR", "TONE_HUBER", "ADAPTIVE_DARK", "DARK_STEP", "MIN_GAMMA", "MAX_DARK_LEVEL", "DECIDE_PROBE",
    "srgb_decode", "srgb_decode_slope", "bt709_decode", "bt709_decode_slope", "tone_candidate",
]

GAMMA_NOISE_FLOOR = 0.025
"""Read and rounding noise of the linear light, in units of the shot noise's signal (σ² ∝ x + 0.025), with which γ is
estimated once a tone curve is detected (it changes the reported γ, not the diagnosis). Re-chosen on
development data only (``benchmarks/diagnose.py --split dev`` histories, seeds 4000…4013: 14 γ curves of the project's
simulator and 5 of the raw pipeline, the other raw ones being sRGB): median |γ̂/γ − 1| 15.7 % with 0 (pure shot
noise), 5.1 % with 0.0125, 2.4 % with 0.025 (worst 12.7 %), 7.1 % with 0.05 (the value before, partly chosen looking
at score seeds; worst 18.3 %), 14.4 % with 0.1."""

TONE_HUBER = 2.5
"""Huber's constant (in units of the learned noise) of the tone-curve test's likelihood."""

ADAPTIVE_DARK = 3.0
"""The tone test's censoring level starts at :data:`.noise.DARK_LEVEL` and rises by :data:`DARK_STEP` while the
band of values just above it misfits the linear hypothesis's learned noise this many times more than the values above
the band (mean squared standardised residual, winsorised at 3σ): a camera whose output is rounded to 8 (or 10) bits
delivers dark regions whose pixel noise is below half a code, so the rounding does not average out and biases their
means by up to half a code — tens of σ of a region mean — which a γ of 1.2…1.4 otherwise fits (clean 8-bit
raw histories at ISO 100…200, ΔBIC −42 and −69 with the censoring fixed at 3 %). A tone curve lifts the whole range,
so the test keeps its power on the brighter values. Chosen on development histories of both simulators (ratio 2 left
a clean raw history at −17, 3 none below −4; no tone curve of either simulator moved); 0 disables."""

DARK_STEP = 1.5
"""Factor by which the tone test's censoring level rises (band width)."""

MIN_GAMMA = 1.0
"""Least exponent of the tone test's decoding ``x = y^γ``: an output encoding compresses (sRGB, BT.709, gammas
1.8…2.6, log curves: γ > 1 in this direction); none expands. An expanding fit (γ < 1) is the bilinear model's misfit
from something else: dark values rounded by 10-bit output, clipped highlights, lamp-lit frames. On the
score histories of the raw pipeline every false ``nonlinear_response`` (a clean 10-bit Canon 500D at ΔBIC −149 and
−33, a clipped history at −181, an off-locus one at −198, a fluorescent one at −75) had γ̂ = 0.46…0.80, every real
tone curve γ̂ ≥ 1.4. The sRGB and BT.709 hypotheses are compressive by construction."""

MAX_DARK_LEVEL = 0.2
"""Highest censoring level of the tone test (a fifth of white; 8-bit pixels are dithered above it at any ISO)."""

DECIDE_PROBE = 0.02
"""log γ of the one pure γ (≈ 1.02) :func:`tone_candidate` evaluates beside its search when deciding, once the
search's first point has not settled the verdict: with γ = 1 (the linear hypothesis's own fit) and that point it draws
a convex floor that settles a linear history after one search point, where the search's own points near γ = 1 came
after five or six (issue 29). On the refit benchmark's 48-frame checks of five 2k-frame histories, noise-learning fits
per linear check: 6 with 0.005, 0.01, 0.02 or 0.05, 8–9 with 0.1 (10 without a probe, 15–18 for the whole test)."""


def _convex_floor(t: NDArray[np.float64], h: NDArray[np.float64], lo: float, hi: float) -> float:
    """The least value on ``[lo, hi]`` of any function convex there that takes the values ``h`` at the sorted points
    ``t`` (within ``[lo, hi]``), or −∞ when there is no such bound: fewer than three points, or points that are not
    convex themselves (their secant slopes decrease somewhere).

    A convex function lies above the extension of every chord beyond the chord's ends, so between two neighbouring
    points it is above the chords on either side extended into the gap (and before the first, after the last point
    above the nearest chord extended); the least of the larger of those lines over each gap is at a gap's end or where
    the lines cross."""
    t, h = np.asarray(t, dtype=float), np.asarray(h, dtype=float)
    if t.size < 3:
        return -np.inf
    slope = np.diff(h) / np.diff(t)
    if np.any(np.diff(slope) < 0):
        return -np.inf
    knots = np.concatenate([[lo], t, [hi]])
    least = np.inf
    for i in range(len(knots) - 1):  # the gap (knots[i], knots[i + 1]); chord j joins t[j] and t[j + 1]
        lines = [(slope[j], t[j], h[j]) for j in (i - 2, i) if 0 <= j < len(slope)]
        if not lines:
            return -np.inf
        a, b = knots[i], knots[i + 1]
        cands = [a, b]
        if len(lines) == 2 and lines[0][0] != lines[1][0]:
            (s1, t1, h1), (s2, t2, h2) = lines
            cross = (h2 - h1 + s1 * t1 - s2 * t2) / (s1 - s2)
            if a < cross < b:
                cands.append(cross)
        least = min(least, min(max(h0 + s0 * (x - t0) for s0, t0, h0 in lines) for x in cands))
    return float(least)


def srgb_decode(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Linear values of sRGB-encoded ``v`` (IEC 61966-2-1 EOTF, via colour-science)."""
    return np.asarray(colour.models.eotf_sRGB(v), dtype=float)


def srgb_decode_slope(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Derivative of :func:`srgb_decode` (IEC 61966-2-1: 1/12.92 on the linear toe, the 2.4 power above)."""
    return np.where(v <= 0.04045, 1.0 / 12.92, 2.4 / 1.055 * ((v + 0.055) / 1.055) ** 1.4)


def bt709_decode(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Linear values of BT.709-encoded ``v`` (inverse of the ITU-R BT.709-6 OETF, via colour-science)."""
    return np.asarray(colour.models.oetf_inverse_BT709(np.clip(v, 0.0, 1.0)), dtype=float)


def bt709_decode_slope(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Derivative of :func:`bt709_decode` (ITU-R BT.709-6: 1/4.5 on the linear toe below 0.081, the 1/0.45 power of
    ``(v + 0.099)/1.099`` above)."""
    power = (1.0 / 0.45) / 1.099 * ((np.clip(v, 0.081, None) + 0.099) / 1.099) ** (1.0 / 0.45 - 1.0)
    return np.where(v < 0.081, 1.0 / 4.5, power)


def tone_candidate(y: NDArray[np.float64], noise: nz.NoiseLevel, present: NDArray[np.bool_], base: bl.LowRankFit,
                    rank: int, n: int, fits: dict, decide: float | None = None) -> Candidate:
    """The bilinear stage's tone-curve extension (``nonlinear_response``) against the linear base ``base``; records
    ``fits["dark_level"]`` and ``fits["nonlinear_response"]``.

    Parameters
    ----------
    y
        Values, frames × (patches·channels), NaN where missing.
    noise
        The noise learned (or assumed) for the linear base; its rounding step enters every hypothesis.
    present
        Where ``y`` has a value with weight.
    base
        The rank-``rank`` linear fit the extension is scored against.
    rank, n
        Rank of the bilinear model and number of values of the base fit.
    fits
        Record of the stage's fits, updated in place.
    decide
        A ΔBIC margin, or ``None`` (the diagnosis: the whole test). Given, only the verdict ``score < −decide`` and,
        when it holds, γ are wanted (the service's tone-response check): the standard curves are scored first and the
        search for the best pure γ stops as soon as the verdict is settled (Notes). The verdict and γ are
        then the whole test's. The score is the best of the hypotheses evaluated: for a supported curve no lower than
        the whole test's; for none, among them γ = 1 (ΔBIC ``log n``) and :data:`DECIDE_PROBE`, so within what the
        whole test's search could still find below it. A verdict of no tone curve carries no γ (NaN: its estimate is
        skipped).

    Notes
    -----
    How ``decide`` settles the verdict early (issue 29: the service's tone-response check was 0.24 s of a 2k-frame
    refit, 18 noise-learning fits of which 14 for the pure γ's bounded search, and γ's own estimate). *The curve is
    supported* once a standard curve or a point of the search scores below ``−decide``: exact — the whole test's
    score is the least over the same standard curves and the same search's points (the bounded search is
    deterministic and evaluates the same points until it stops), so it is no higher. *It is not* once neither standard
    curve scores below ``−decide`` and the least value a function convex in log γ through the pure γs evaluated — the
    search's, γ = 1 (the linear hypothesis: ``x = y``, slope 1, the same fit and nll) and :data:`DECIDE_PROBE` — can
    take on the whole range (:func:`_convex_floor`) scores no lower: the whole test's score is a value of that
    function. The bound is used only where the points are themselves convex (secant slopes increasing), else the
    search runs on as the whole test's does. On the refit benchmark's 48-frame checks of five 2k-frame histories: 6
    noise-learning fits per linear check and 4–5 per tone-encoded one, against 15–18 and 11–15 for the whole test.

    Returns
    -------
    Candidate
        ``nonlinear_response`` with its ΔBIC-like score (negative favours the curve), the curve (``gamma``, ``srgb``
        or ``bt709``) and the best pure γ.

    References
    ----------
    .. [IEC61966-2-1] IEC 61966-2-1:1999 (sRGB): a standard curve tried beside a pure γ.
    .. [ITU-BT709] ITU-R BT.709-6: a standard curve tried beside a pure γ.
    .. [Foi2008] Foi et al., IEEE TIP 2008: the Poissonian-Gaussian noise each hypothesis learns.
    """
    # tone curve: y = x^(1/γ) (γ fitted) or the sRGB encoding (IEC 61966-2-1, the usual camera output curve, whose
    # linear toe a pure gamma does not follow); the factorisation holds for the linearised x = T(y). Each hypothesis
    # learns its own Poissonian-Gaussian noise (σ² = a·x + b in its linear light, a and b free) from its residuals,
    # and the likelihood carries the Jacobian of the curve: the tone curve shows in the structure of the values and
    # in how their spread grows with the signal, without assuming how large the noise is
    # values delivered on a grid (rounded in the output, after the curve) carry the rounding's variance step²/12 in
    # the output domain, which each hypothesis carries into its own linear light through the curve's slope: constant
    # output noise is otherwise exactly what a γ = 2 curve makes of shot noise (as region means rounded to
    # 8-bit codes showed); for values measured from images (noise.codec_cap > 0) every hypothesis also learns an
    # output-domain variance up to that cap (a codec's error: nz.CODEC_NOISE), carried into its light the same way
    q = noise.step**2 / 12.0
    yv = np.nan_to_num(y)
    dark = nz.dark_level()
    while True:
        yc = np.clip(yv, dark, None)
        lit = present & (yv > dark)  # values near black are censored here
        fit_lin, a_lin, b_lin, nll_lin, c_lin = nz.fit_learned_noise(yc, lit, rank, base.U, updates=3, iters=30,
                                                                     floor=noise.read**2 * 1e-3, huber=TONE_HUBER,
                                                                     extra=q, codec_cap=noise.codec_cap)
        band = lit & (yv <= DARK_STEP * dark)
        if not ADAPTIVE_DARK or dark * DARK_STEP > MAX_DARK_LEVEL or band.sum() < 10:
            break
        z2 = np.minimum((yc - fit_lin.pred) ** 2 / (a_lin * yc + b_lin + q + c_lin), 9.0)
        above = lit & (yv > DARK_STEP * dark)
        if float(z2[band].mean()) <= ADAPTIVE_DARK * float(z2[above].mean()):
            break
        dark *= DARK_STEP
    fits["dark_level"] = dark
    if int(lit.sum()) <= rank + 1:  # (almost) every value censored as dark: no curve can be read from them
        fits["nonlinear_response"] = {"curve": "gamma", "gamma": 1.0}
        return Candidate("nonlinear_response", float("inf"), {"curve": "gamma", "gamma": 1.0})

    def curve_nll(x: NDArray[np.float64], slope: NDArray[np.float64]) -> tuple[float, bl.LowRankFit]:
        learned = nz.fit_learned_noise(x, lit, rank, base.U, updates=3, iters=30, huber=TONE_HUBER,
                                       floor=noise.read**2 * 1e-3 * float(np.median(slope[lit])) ** 2,
                                       extra=q * slope**2, slope2=slope**2, codec_cap=noise.codec_cap)
        return learned.nll - float(np.log(slope[lit]).sum()), learned.fit

    def gamma_nll(g: float) -> tuple[float, bl.LowRankFit]:
        return curve_nll(yc**g, g * yc ** (g - 1.0))

    def standard_curves() -> tuple[float, str, bl.LowRankFit]:
        # the two standard output encodings, each with its linear toe: sRGB (IEC 61966-2-1) and BT.709 (ITU-R
        # BT.709-6, a 0.45 power with an offset, which neither a pure gamma nor sRGB follows and a black offset fits
        # in part)
        std = []
        for curve, decode, slope in (("srgb", srgb_decode, srgb_decode_slope),
                                     ("bt709", bt709_decode, bt709_decode_slope)):
            nll_c, fit_c = curve_nll(decode(yc), slope(yc))
            std.append((2.0 * (nll_c - nll_lin), curve, fit_c))
        return min(std, key=lambda t: t[0])

    def score_of(nll: float) -> float:
        return 2.0 * (nll - nll_lin) + np.log(n)

    settled = standard_curves() if decide is not None else None  # deciding: the standard curves first
    bounds = (np.log(MIN_GAMMA), np.log(3.5))
    searched: dict[float, tuple[float, bl.LowRankFit]] = {}  # log γ → (nll, fit) of every γ the search evaluated
    # deciding, the points the convex floor is drawn through (log γ → (nll, fit)): the search's, and γ = 1 — the
    # linear hypothesis itself (x = y, slope 1: the same fit, the same nll) — with one γ near it (DECIDE_PROBE)
    known: dict[float, tuple[float, bl.LowRankFit]] = {0.0: (nll_lin, fit_lin)} if MIN_GAMMA == 1.0 else {}

    def search_nll(lg: float) -> float:
        lg = float(lg)
        if lg not in searched:
            searched[lg] = gamma_nll(float(np.exp(lg)))
        if decide is not None:
            known[lg] = searched[lg]
            if score_of(min(v[0] for v in searched.values())) < -decide:
                raise _Settled  # supported
            if MIN_GAMMA == 1.0 and DECIDE_PROBE not in known:  # not settled by the first point: the probe
                known[DECIDE_PROBE] = gamma_nll(float(np.exp(DECIDE_PROBE)))
            t = np.array(sorted(known))
            if score_of(_convex_floor(t, np.array([known[k][0] for k in t]), *bounds)) >= -decide:
                raise _Settled  # not supported
        return searched[lg][0]

    verdict_by_curves = settled is not None and settled[0] < -decide
    if not verdict_by_curves:
        try:
            x = float(minimize_scalar(search_nll, bounds=bounds, method="bounded", options={"xatol": 1e-2}).x)
        except _Settled:
            x = min(searched, key=lambda k: searched[k][0])
        # the search's best γ again (the bounded search returns a point it evaluated: the same numbers)
        nll_g, fit_g = searched[x] if x in searched else gamma_nll(float(np.exp(x)))
        score_g = score_of(nll_g)
    else:
        score_g, fit_g = np.inf, None
    score_s, curve_s, fit_s = settled if settled is not None else standard_curves()
    if decide is not None and min(score_g, score_s) >= -decide:
        # no tone curve: the best of every pure γ evaluated (γ = 1 among them) or standard curve
        nll_k, fit_k = min(known.values(), key=lambda v: v[0])  # the search's points among them
        best_g = score_of(nll_k) <= score_s
        fit = fit_k if best_g else fit_s
        fits["nonlinear_response"] = {"curve": "gamma" if best_g else curve_s, "gamma": float("nan")}
        return Candidate("nonlinear_response", float(min(score_of(nll_k), score_s)),
                         {"curve": "gamma" if best_g else curve_s, "gamma": float("nan")},
                         residual=float(np.sqrt(fit.wrss / max(n - fit.k, 1))))
    # γ itself by maximum likelihood with shot noise and a floor in linear light (σ² = φ·(x + GAMMA_NOISE_FLOOR),
    # φ profiled; the curve's Jacobian included; values near black censored): re-learning a and b at every γ lets
    # them absorb part of the curve and biases γ upwards (tone curves 2.2…2.4 read as 2.6…3.3)

    def gamma_nll_held(lg: float) -> float:
        gg = float(np.exp(lg))
        x = yc**gg
        wx = np.where(lit, 1.0 / (x + GAMMA_NOISE_FLOOR), 0.0)
        fit = bl.wals(x, wx, rank, U=base.U, iters=30)
        m = int(lit.sum())
        return (0.5 * m * np.log(fit.wrss / m) + 0.5 * float(np.log(1.0 / wx[lit]).sum())
                - float(np.log(gg * yc[lit] ** (gg - 1.0)).sum()))

    g = float(np.exp(minimize_scalar(gamma_nll_held, bounds=bounds, method="bounded",
                                     options={"xatol": 3e-3}).x))
    if score_s < score_g:
        # the best pure gamma is reported too (the service's tone-response hint reads it)
        fits["nonlinear_response"] = {"curve": curve_s, "gamma": g}
        return Candidate("nonlinear_response", score_s, {"curve": curve_s, "gamma": round(g, 4)},
                         residual=float(np.sqrt(fit_s.wrss / max(n - fit_s.k, 1))))
    fits["nonlinear_response"] = {"curve": "gamma", "gamma": g}
    return Candidate("nonlinear_response", score_g, {"curve": "gamma", "gamma": round(g, 4)},
                     residual=float(np.sqrt(fit_g.wrss / max(n - fit_g.k, 1))))


class _Settled(Exception):
    """Raised inside the γ search of :func:`tone_candidate` once its verdict is settled (``decide``)."""
