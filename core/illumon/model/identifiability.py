"""How well a history determines its illuminants: spread of its reciprocal temperatures, the condition of the
data-only Jacobian of the joint problem (Marguier & Süsstrunk's model with the reflectance basis; priors left out),
and how far the data narrow the frames' illuminants relative to each other in the model as fitted (its priors and,
with :data:`illumon.camera.formation.FLARE_SD` > 0, each frame's offset)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from ..daylight import CIEDaylight
from ..priors import ReflectanceBasis
from ..retrieval.common import imaging_operators

__all__ = ["IdentifiabilityWarning", "identifiability", "spread_subsample"]


class IdentifiabilityWarning(UserWarning):
    """The fitted history cannot determine the illuminants (too little illuminant variation or an ill-posed fit)."""


def spread_subsample(mired: NDArray[np.float64], n: int) -> NDArray[np.int64]:
    """``n`` frame indices spread evenly over the rank order of ``mired`` (covers the illuminant range)."""
    if mired.size <= n:
        return np.arange(mired.size)
    order = np.argsort(mired, kind="stable")
    pick = order[np.round(np.linspace(0, mired.size - 1, n)).astype(int)]
    return np.unique(pick)


def _whitened_prediction(css: NDArray[np.float64], dm: CIEDaylight, rb: ReflectanceBasis,
                         theta: NDArray[np.float64], coef: NDArray[np.float64], w2: NDArray[np.float64]
                         ) -> tuple[Callable[[NDArray[np.float64]], NDArray[np.float64]], NDArray[np.float64],
                                    NDArray[np.float64]]:
    """The joint model's whitened prediction of the frames ``theta`` (F × 3) and patches ``coef`` (P × K) as a
    function of their stacked parameters ``x`` (every frame's ``(mired, δ, log k)``, then every patch's
    coefficients), the parameters' current values and the step that scales each to a meaningful change."""
    k_ops, w_ops = imaging_operators(css, dm.basis, rb)
    f, p, nk = theta.shape[0], coef.shape[0], rb.size
    sqrt_w2 = np.sqrt(w2)

    def pred(x: NDArray[np.float64]) -> NDArray[np.float64]:
        fr = x[: 3 * f].reshape(f, 3)
        s = x[3 * f :].reshape(p, nk)
        a = np.asarray(dm.weights(fr[:, :2]))
        m = np.einsum("fk,kcj->fcj", a, k_ops) / (a @ w_ops)[:, 1, None, None]
        return (np.exp(fr[:, 2])[:, None, None] * np.einsum("fcj,pj->fpc", m, s) * sqrt_w2).ravel()

    x0 = np.concatenate([theta.ravel(), coef.ravel()])
    steps = np.concatenate([np.tile([10.0, dm.duv_sigma, 0.1], f), np.full(p * nk, 0.1)])
    return pred, x0, steps


def _information(jac: NDArray[np.float64], f: int, nk: int, offsets: NDArray[np.float64] | None
                 ) -> NDArray[np.float64]:
    """``Jᵀ J`` of the whitened Jacobian ``jac`` (rows: frame, patch, channel; columns: every frame's ``(mired, δ,
    log k)``, then every patch's ``nk`` coefficients) with, for ``offsets`` (F × P × 3: each value's whitened change
    per unit of its frame's offset amount in its channel), one more column per frame and channel, from the blocks
    that are not zero by construction: a frame's parameters move only its rows, a patch's coefficients only its rows,
    an offset only its frame's rows in its channel. The same sums as the dense product over every row (a 1 920 × 368
    one for 40 frames of 16 patches, 95 % zeros), to rounding."""
    n_p = (jac.shape[1] - 3 * f) // nk
    fr, pa = np.arange(f), np.arange(n_p)
    a_t = jac[:, : 3 * f].reshape(f, n_p, 3, f, 3)[fr, :, :, fr, :]  # f, p, c, m: frame f's own columns
    a_s = jac[:, 3 * f :].reshape(f, n_p, 3, n_p, nk)[:, pa, :, pa, :]  # p, f, c, j: patch p's own columns
    n_o = 0 if offsets is None else 3 * f
    info = np.zeros((3 * f + n_p * nk + n_o,) * 2)
    t_t = np.einsum("fpcm,fpcn->fmn", a_t, a_t)
    for m in range(3):
        info[(fr * 3 + m)[:, None], (fr * 3)[:, None] + np.arange(3)] = t_t[:, m, :]
    t_s = np.einsum("fpcm,pfcj->fmpj", a_t, a_s).reshape(3 * f, n_p * nk)
    info[: 3 * f, 3 * f : 3 * f + n_p * nk] = t_s
    info[3 * f : 3 * f + n_p * nk, : 3 * f] = t_s.T
    s_s = np.einsum("pfcj,pfck->pjk", a_s, a_s)
    i0 = 3 * f
    for q in range(n_p):
        info[i0 + q * nk : i0 + (q + 1) * nk, i0 + q * nk : i0 + (q + 1) * nk] = s_s[q]
    if offsets is not None:
        o0 = 3 * f + n_p * nk
        t_o = np.einsum("fpcm,fpc->fmc", a_t, offsets)  # frame f's parameter m, its offset in channel c
        for m in range(3):
            info[(fr * 3 + m)[:, None], o0 + (fr * 3)[:, None] + np.arange(3)] = t_o[:, m, :]
            info[o0 + (fr * 3)[:, None] + np.arange(3), (fr * 3 + m)[:, None]] = t_o[:, m, :]
        s_o = np.einsum("pfcj,fpc->pjfc", a_s, offsets).reshape(n_p * nk, 3 * f)
        info[i0 : i0 + n_p * nk, o0:] = s_o
        info[o0:, i0 : i0 + n_p * nk] = s_o.T
        info[np.arange(o0, o0 + 3 * f), np.arange(o0, o0 + 3 * f)] = (offsets**2).sum(axis=1).reshape(-1)
    return info


def _relative_posterior_sd(jac: NDArray[np.float64], f: int, dm: CIEDaylight, rb: ReflectanceBasis,
                           steps: NDArray[np.float64], sqrt_w2: NDArray[np.float64],
                           flare: NDArray[np.float64] | None) -> tuple[float, float]:
    """Posterior standard deviations (MK⁻¹, Duv) of the frames' illuminants relative to each other, in the direction
    the model as fitted determines worst: the data's Gauss–Newton information (``jac``, whitened, columns in
    ``steps``) plus the fit's priors — the history prior of the reciprocal temperatures and Duv (its within-history
    part: a level common to the frames does not enter), the reflectance prior, and each frame's additive offset with
    its prior scale ``flare`` (F × 3) where the model has one; the common level of every parameter projected out."""
    info = _information(jac, f, rb.size, None if flare is None else sqrt_w2 * flare[:, None, :])
    centre = np.eye(f) - 1.0 / f  # takes away the frames' mean
    for k, (sigma, between) in enumerate(((dm.mired_sigma, dm.mired_between), (dm.duv_sigma, dm.duv_between))):
        idx = np.arange(f) * 3 + k
        # −2 log prior of N(m·1, σ_w² I + σ_b² 11ᵀ): σ_w⁻² on the frames' departures from their mean (the
        # common level, weaker, is projected out below anyway), in the columns' units
        info[idx[:, None], idx[None, :]] += centre * (steps[idx[0]] ** 2 / (sigma**2 - between**2))
    n_p = (jac.shape[1] - 3 * f) // rb.size
    lam = np.linalg.inv(rb.prior_covariance) * 0.1**2
    for q in range(n_p):
        i0 = 3 * f + q * rb.size
        info[i0 : i0 + rb.size, i0 : i0 + rb.size] += lam
    i0 = 3 * f + n_p * rb.size  # the offsets' columns (if any) are in units of their prior scale
    info[np.arange(i0, info.shape[0]), np.arange(i0, info.shape[0])] += 1.0
    # a level common to the frames (each parameter's) is the gauge and the prior's business: pin it
    for k in range(3):
        idx = np.arange(f) * 3 + k
        info[idx[:, None], idx[None, :]] += 1.0 / f
    try:
        cov = np.linalg.solve(info, np.eye(len(info))[:, : 3 * f])[: 3 * f]  # the frames' block of the inverse
    except np.linalg.LinAlgError:
        return math.inf, math.inf
    out = []
    for k in range(2):
        c = centre @ cov[k::3, k::3] @ centre
        out.append(float(steps[k] * math.sqrt(max(np.linalg.eigvalsh(c)[-1], 0.0))))
    return out[0], out[1]


def identifiability(
    y: NDArray[np.float64], present: NDArray[np.bool_], css: NDArray[np.float64], dm: CIEDaylight,
    rb: ReflectanceBasis, theta: NDArray[np.float64], coef: NDArray[np.float64], w2: NDArray[np.float64],
    mired_all: NDArray[np.float64], *, max_frames: int = 40, min_mired_spread: float = 4.0,
    flare: NDArray[np.float64] | None = None, max_relative_share: float = 0.5,
) -> dict:
    """How well a history determines its illuminants.

    Reports the spread (standard deviation, 5–95 % range) of the history's reciprocal temperatures, the condition
    number of the *data-only* Jacobian of the joint problem (priors left out) on up to ``max_frames`` frames spread
    over the illuminant range, columns scaled to meaningful changes (10 MK⁻¹, 0.003 Duv, 0.1 log exposure, 0.1
    coefficient), and the posterior standard deviations of the frames' reciprocal temperatures and Duv relative to
    each other in the model as fitted (its priors, and each frame's offset of scale ``flare``, F × 3, where it has
    one), in their worst-determined direction.

    Two warnings: constant illuminants (spread < ``min_mired_spread``), where reflectance and illuminant colour
    trade off so the illuminants are the prior's; and data that narrow the frames' reciprocal temperatures relative
    to each other to no better than ``max_relative_share`` of the prior's within-history spread (Duv, whose prior is
    itself narrow, ±0.003, is reported). The data-only condition is
    reported but does not warn: its smallest singular values belong to reflectance directions the camera barely
    sees (a README history: 99 % of the 4th-smallest direction's weight on reflectance coefficients), which the
    reflectance prior holds and which do not move the illuminants.
    """
    sel = spread_subsample(theta[:, 0], max_frames)
    f, p, nk = sel.size, coef.shape[0], rb.size
    pred, x0, steps = _whitened_prediction(css, dm, rb, theta[sel], coef, w2[sel])
    r0 = pred(x0)
    # Forward differences, one column per parameter. A frame's parameters move only that frame's rows and a patch's
    # coefficients only that patch's rows, so one evaluation steps a parameter of every frame (of every patch) at
    # once: 1 + 3 + K evaluations instead of one per column, with the same columns (every row is computed on its own).
    jac = np.zeros((r0.size, x0.size))
    rows = np.arange(r0.size).reshape(f, p, 3)
    for cols, owner in ((np.arange(3 * f).reshape(f, 3), rows.reshape(f, -1)),
                        (3 * f + np.arange(p * nk).reshape(p, nk), rows.transpose(1, 0, 2).reshape(p, -1))):
        for k in range(cols.shape[1]):
            col = cols[:, k]
            h = 1e-4 * steps[col]
            xp = x0.copy()
            xp[col] += h
            d = pred(xp) - r0
            jac[owner, col[:, None]] = d[owner] / h[:, None] * steps[col][:, None]
    sv = np.linalg.svd(jac, compute_uv=False)
    # Three directions are not fixed by the data of any history (the exposure/reflectance scale and reflectance
    # directions the camera cannot see); the condition of the rest is reported. It does not say whether the
    # illuminants are determined (its smallest directions are mostly reflectance coefficients): the posterior
    # spread below does.
    cond = float(sv[0] / max(sv[-4], 1e-300)) if sv.size > 4 else math.inf
    sv_tail = [float(v / sv[0]) for v in sv[-4:]]
    rel_mired, rel_duv = _relative_posterior_sd(jac, f, dm, rb, steps, np.sqrt(w2[sel]),
                                                None if flare is None else flare[sel])
    prior_mired = math.sqrt(dm.mired_sigma**2 - dm.mired_between**2)
    spread = float(np.std(mired_all)) if mired_all.size else 0.0
    p5, p95 = (np.percentile(mired_all, [5, 95]) if mired_all.size else (np.nan, np.nan))
    warn = []
    if theta.shape[0] == 1:
        warn.append(
            "a single frame: its light and its patches' colours trade off, so the light is the priors' reading of one "
            "view (a Bayesian gray-world; a reference in it gives its white); post frames of the same view over a day "
            "for the scene to be learned"
        )
    elif spread < min_mired_spread:
        warn.append(
            f"illuminants barely vary in this history (σ = {spread:.1f} MK⁻¹ < {min_mired_spread}): reflectances and "
            "illuminant colour trade off, so illuminants are set by the daylight prior, not by the data"
        )
    if not rel_mired <= max_relative_share * prior_mired:
        warn.append(
            f"joint problem ill-conditioned: the data hardly narrow the frames' reciprocal temperatures relative to "
            f"each other (±{rel_mired:.3g} MK⁻¹ where the prior alone gives ±{prior_mired:.3g}): illuminants not "
            "determined"
        )
    return {
        "mired_std": spread,
        "mired_p05": float(p5),
        "mired_p95": float(p95),
        "condition": cond,
        "condition_frames": int(f),
        "smallest_singular_values_relative": sv_tail,
        "relative_mired_sd": rel_mired,
        "relative_duv_sd": rel_duv,
        "determined": not warn,
        "warnings": warn,
    }
