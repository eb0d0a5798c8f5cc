"""The camera-agnostic linear model of a history and its extensions, fitted by weighted alternating least squares.

Under the linear model every value is ``y_fpc = k_f Σλ C_c(λ) E_f(λ) R_p(λ)``. Daylight spectra lie close to a
low-dimensional space (Judd, MacAdam & Wyszecki 1964; three CIE components, a fourth for measured skies), so with
``E_f = Σ_i a_fi B_i`` the frames × (patches·channels) matrix factors as ``Y = U V`` with ``U_f = k_f a_f`` and
``V_i,(p,c) = Σλ C_c B_i R_p``: rank ``r`` whatever the camera, reflectances and exposures. The diagnosis fits this
bilinear model (no camera, reflectance basis or daylight model enters, so neither adds model error) and tests each
effect as an explicit change of it:

* tone curve ``y = x^(1/γ)``: the factorisation holds for ``y^γ``;
* black offset: ``Y = U V + 1 bᵀ`` (``b`` one value per channel, repeated over patches);
* clipping: values at the clip level are censored (only ``U V ≥ level`` is known);
* patch change: the patch's columns before and after the onset are two patches;
* shadow: the patch's values in a run of frames are ``diag(s) · (U_f V_p)`` (skylight only: dimmer, bluer);
* off-locus light: the frames lit by a lamp get one more component, ``U_f V + m_f v'`` (the lamp's patch responses).

Residuals are weighted by the noise of a patch mean, ``σ² = shot · y + read²``, with ``shot`` and ``read`` learned
from the history's own residuals (:func:`.noise.estimate_noise`; the values of :class:`illumon.camera.CameraNoise` only
start the iteration); the overall scale of σ is profiled out by the criterion (:mod:`.fit`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "LowRankFit",
    "wals",
    "fit_offset",
    "fit_clipping",
    "scan_patch_effects",
    "MIN_SHADOW_FRAMES",
]


@dataclass
class LowRankFit:
    """A weighted low-rank fit ``Y ≈ U V`` (plus an extension).

    Attributes
    ----------
    U, V
        Frame factors (F × r′) and column factors (r′ × m).
    wrss
        Weighted residual sum of squares.
    n
        Number of observed values.
    k
        Number of free parameters (factors, minus the gauge, plus the extension's).
    pred
        Fitted values in the data's domain (F × m).
    """

    U: NDArray[np.float64]
    V: NDArray[np.float64]
    wrss: float
    n: int
    k: int
    pred: NDArray[np.float64]


def _init(y: NDArray[np.float64], w: NDArray[np.float64], rank: int) -> NDArray[np.float64]:
    col = (w * y).sum(0) / np.maximum(w.sum(0), 1e-300)
    filled = np.where(w > 0, y, col[None, :])
    u, s, _ = np.linalg.svd(filled, full_matrices=False)
    return u[:, :rank] * s[:rank]


def _gram_cols(w: NDArray[np.float64], U: NDArray[np.float64]) -> NDArray[np.float64]:
    """``Σ_f w[f, j] U[f, a] U[f, b]`` (m × r × r) as one matrix product (``einsum("fj,fa,fb->jab")``, 10 × faster)."""
    r = U.shape[1]
    return (w.T @ (U[:, :, None] * U[:, None, :]).reshape(len(U), r * r)).reshape(w.shape[1], r, r)


def _gram_rows(w: NDArray[np.float64], V: NDArray[np.float64]) -> NDArray[np.float64]:
    """``Σ_j w[f, j] V[a, j] V[b, j]`` (F × r × r) as one matrix product (``einsum("fj,aj,bj->fab")``)."""
    r = V.shape[0]
    return (w @ (V[:, None, :] * V[None, :, :]).reshape(r * r, V.shape[1]).T).reshape(w.shape[0], r, r)


def _solve(g: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    # the diagonal as a view and the identity kept (an einsum and np.eye each call were ~15 % of the tone-response
    # check's ~1 500 solves; the same numbers)
    ridge = 1e-10 * np.maximum(np.diagonal(g, axis1=-2, axis2=-1).max(-1), 1e-300)
    g = g + ridge[..., None, None] * _eye(g.shape[-1])
    return np.linalg.solve(g, b[..., None])[..., 0]


@lru_cache(maxsize=8)
def _eye(n: int) -> NDArray[np.float64]:
    """``np.eye(n)``, read-only, made once."""
    out = np.eye(n)
    out.flags.writeable = False
    return out


def wals(
    y: NDArray[np.float64],
    w: NDArray[np.float64],
    rank: int,
    *,
    U: NDArray[np.float64] | None = None,
    iters: int = 80,
    tol: float = 1e-7,
) -> LowRankFit:
    """Weighted low-rank approximation by alternating least squares (missing values have weight 0).

    Parameters
    ----------
    y, w
        Data (F × m, NaN or anything where ``w == 0``) and weights (inverse variances).
    rank
        Rank ``r``.
    U
        Start for the frame factors (F × r).
    iters, tol
        Iteration cap and relative-decrease stopping rule.
    """
    y0 = np.where(w > 0, np.nan_to_num(y), 0.0)
    if U is None:
        U = _init(y0, w, rank)
    U = U.copy()
    wy = w * y0
    last = np.inf
    V = np.zeros((rank, y.shape[1]))
    for _ in range(iters):
        V = _solve(_gram_cols(w, U), wy.T @ U).T
        U = _solve(_gram_rows(w, V), wy @ V.T)
        pred = U @ V
        wrss = float((w * (y0 - pred) ** 2).sum())
        if last - wrss <= tol * wrss:
            break
        last = wrss
    pred = U @ V
    wrss = float((w * (y0 - pred) ** 2).sum())
    f, m = y.shape
    k = rank * (f + m - rank)
    return LowRankFit(U, V, wrss, int((w > 0).sum()), k, pred)


def fit_offset(y: NDArray[np.float64], w: NDArray[np.float64], rank: int, U0: NDArray[np.float64],
               iters: int = 150) -> tuple[LowRankFit, NDArray[np.float64]]:
    """Black offset ``Y = U V + 1 bᵀ`` (one pedestal per channel): alternating least squares where the V-step solves
    V and b jointly (Schur complement over the patches of each channel), from several starts (no offset, and half and
    all of each channel's darkest value, and the offset of the rank-``rank − 1`` model; the factorisation re-fitted to
    the values minus the start). Returns the best fit and ``b`` (3,)."""
    y0 = np.where(w > 0, np.nan_to_num(y), 0.0)
    chan = np.arange(y.shape[1]) % 3
    low = np.array([np.min(np.where(w[:, chan == c] > 0, y0[:, chan == c], np.inf)) for c in range(3)])
    low = np.where(np.isfinite(low), low, 0.0)
    best = None
    starts: list[NDArray[np.float64]] = [np.zeros(3), 0.5 * low, 0.9 * low]
    if rank > 1:
        # the offset of the rank-(r−1) model: at full rank a free frame factor can absorb the pedestal (a constant
        # column) and the alternation stays there (a 1.6…4.9 % pedestal of the raw pipeline was found exactly
        # at rank 3 and missed at rank 4 from the other starts)
        starts.append(_fit_offset_from(y0, w, rank - 1, U0[:, : rank - 1], iters)[1])
    for start in starts:
        U = U0 if not start.any() else wals(np.clip(y0 - start[chan][None, :], 0, None), w, rank, U=U0, iters=20).U
        fit, b = _fit_offset_from(y0, w, rank, U, iters)
        if best is None or fit.wrss < best[0].wrss:
            best = (fit, b)
    assert best is not None
    return best


def _fit_offset_from(y0: NDArray[np.float64], w: NDArray[np.float64], rank: int, U0: NDArray[np.float64],
                     iters: int) -> tuple[LowRankFit, NDArray[np.float64]]:
    f, m = y0.shape
    chan = np.arange(m) % 3
    U = U0.copy()
    b = np.zeros(3)
    last = np.inf
    wrss = np.inf
    for _ in range(iters):
        # V-step with b: per column G V + g b_c = h ; Σ_j (gᵀ V_j + s_j b_c) = t_c
        G = _gram_cols(w, U)
        G += 1e-10 * np.einsum("jaa->j", G).max() * np.eye(U.shape[1])
        h = np.einsum("fj,fa->ja", w * y0, U)
        gv = np.einsum("fj,fa->ja", w, U)
        s = w.sum(0)
        t = (w * y0).sum(0)
        Gi_h = np.linalg.solve(G, h[..., None])[..., 0]
        Gi_g = np.linalg.solve(G, gv[..., None])[..., 0]
        for c in range(3):
            j = chan == c
            num = t[j].sum() - np.einsum("ja,ja->", gv[j], Gi_h[j])
            den = s[j].sum() - np.einsum("ja,ja->", gv[j], Gi_g[j])
            b[c] = num / den if den > 0 else 0.0
        V = (Gi_h - Gi_g * b[chan][:, None]).T
        yb = y0 - b[chan][None, :]
        U = _solve(_gram_rows(w, V), (w * yb) @ V.T)
        pred = U @ V + b[chan][None, :]
        wrss = float((w * (y0 - pred) ** 2).sum())
        if last - wrss <= 1e-8 * wrss:
            break
        last = wrss
    pred = U @ V + b[chan][None, :]
    k = rank * (f + m - rank) + 3
    return LowRankFit(U, V, wrss, int((w > 0).sum()), k, pred), b


def fit_clipping(y: NDArray[np.float64], w: NDArray[np.float64], rank: int, U0: NDArray[np.float64],
                 level: float, censored: NDArray[np.bool_], iters: int = 80) -> LowRankFit:
    """Values at the clip ``level`` are censored: only ``U V ≥ level`` is known (a one-sided residual). Fitted by
    alternating least squares where censored targets are ``max(level, prediction)`` (EM for a censored Gaussian in the
    limit of small noise)."""
    y0 = np.where(w > 0, np.nan_to_num(y), 0.0)
    U = U0.copy()
    target = y0.copy()
    last = np.inf
    fit = None
    for _ in range(iters):
        fit = wals(target, w, rank, U=U, iters=3)
        U = fit.U
        target = np.where(censored, np.maximum(level, fit.pred), y0)
        res = np.where(censored, np.clip(level - fit.pred, 0, None), y0 - fit.pred)
        wrss = float((w * res**2).sum())
        if last - wrss <= 1e-8 * wrss:
            break
        last = wrss
    assert fit is not None
    res = np.where(censored, np.clip(level - fit.pred, 0, None), y0 - fit.pred)
    fit.wrss = float((w * res**2).sum())
    fit.k += 1
    return fit


def _cum(a: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, axis=0)], axis=0)


def column_prior(V: NDArray[np.float64]) -> NDArray[np.float64]:
    """Gaussian prior precision of each component of a column factor, ``1 / mean_j V_aj²`` (empirical Bayes): column
    factors fitted from a subset of frames are shrunk along components those frames barely excite."""
    return 1.0 / np.maximum((V**2).mean(1), 1e-300)


MIN_SHADOW_FRAMES = 2
"""Fewest frames of a shadow run. One patch off in one frame is an outlier (an occluder, a reflection, a glitch of
the measurement), not a shadow, which over a fixed camera lasts several frames at any practical frame interval (the
simulators hide runs of 3 or more). A one-frame run is not enough: on the held-out image simulator (``benchmarks/imgsim.py``) a
clean history whose colour matrix clips a saturated surface at 0 was reported as a one-frame shadow (ΔBIC −138)."""


def scan_patch_effects(y: NDArray[np.float64], w: NDArray[np.float64], U: NDArray[np.float64], min_out: int = 3,
                       prior: NDArray[np.float64] | None = None, min_run: int = MIN_SHADOW_FRAMES) -> dict:
    """For every patch, the best patch change (onset) and the best shadow run, with the frame factors ``U`` fixed.

    Closed form through cumulative sums over frames of ``Uᵀ W U``, ``Uᵀ W y`` and ``yᵀ W y`` per column: the residual
    of a least-squares fit on any run of frames is ``c − bᵀ A⁻¹ b``. Shadow runs have at least ``min_run`` frames.

    Returns
    -------
    dict
        ``{"base": (P,), "change": (P,) best RSS, "change_onset": (P,), "shadow": (P,), "shadow_run": (P, 2)}``.
    """
    f, m = y.shape
    p = m // 3
    r = U.shape[1]
    y0 = np.where(w > 0, np.nan_to_num(y), 0.0)
    A = _cum(np.einsum("fj,fa,fb->fjab", w, U, U))  # (F+1) × m × r × r
    B = _cum(np.einsum("fj,fa->fja", w * y0, U))
    C = _cum(w * y0**2)
    nobs = _cum((w > 0).astype(float))
    eye = np.eye(r)
    lam = np.diag(prior) if prior is not None else 0.0

    def rss(a, b, c):
        ridge = 1e-9 * np.maximum(np.einsum("...ii->...", a), 1e-300)[..., None, None] * eye + lam
        v = np.linalg.solve(a + ridge, b[..., None])[..., 0]
        return c - np.einsum("...a,...a->...", b, v), v

    base, _ = rss(A[-1], B[-1], C[-1])  # (m,)
    out = {"base": base.reshape(p, 3).sum(1)}
    # patch change at onset t: two fits, frames [0, t) and [t, F)
    ts = np.arange(1, f)
    r1, _ = rss(A[ts], B[ts], C[ts])
    r2, _ = rss(A[-1] - A[ts], B[-1] - B[ts], C[-1] - C[ts])
    n1 = nobs[ts]
    n2 = nobs[-1] - nobs[ts]
    ok = (n1 >= r) & (n2 >= r)
    ch = np.where(ok, r1 + r2, np.inf).reshape(f - 1, p, 3).sum(2)  # (F−1) × P
    out["change"] = ch.min(0)
    out["change_onset"] = ts[np.argmin(ch, axis=0)]
    # shadow on run [t0, t1): V from the other frames, then a per-channel scale s ≤ 1 on the run
    t0, t1 = np.triu_indices(f + 1, 1)
    # a shadow begins and ends inside the history: one that covers the first or the last frame cannot be told from a
    # patch change (the surface is seen in only one state at that end), so it is left to the patch-change model
    keep = (t0 >= 1) & (t1 <= f - 1) & (t1 - t0 >= min_run)
    t0, t1 = t0[keep], t1[keep]
    a_run, b_run, c_run = A[t1] - A[t0], B[t1] - B[t0], C[t1] - C[t0]
    a_out, b_out, c_out = A[-1] - a_run, B[-1] - b_run, C[-1] - c_run
    r_out, v = rss(a_out, b_out, c_out)
    n_out = nobs[-1] - (nobs[t1] - nobs[t0])
    valid = (n_out >= min_out) & (nobs[t1] - nobs[t0] >= 1)
    best_tot = None
    for variant in ("kries", "sky"):
        if variant == "sky":  # shaded colour fixed: every channel follows the patch's unshaded green, s_c · (U_f V_p)_g
            vg = v.reshape(len(t0), p, 3, r)[:, :, 1:2, :].repeat(3, axis=2).reshape(v.shape)
        else:  # von Kries: s_c · (U_f V_p)_c
            vg = v
        p2 = np.einsum("kja,kjab,kjb->kj", vg, a_run, vg)
        yp = np.einsum("kja,kja->kj", b_run, vg)
        s = np.clip(yp / np.maximum(p2, 1e-300), 0.0, None if variant == "sky" else 1.0)
        r_run = c_run - 2 * s * yp + s**2 * p2
        tot = np.where(valid, r_out + r_run, np.inf).reshape(len(t0), p, 3).sum(2)
        if best_tot is None:
            best_tot, which = tot, np.zeros_like(tot, dtype=int)
        else:
            better = tot < best_tot
            best_tot = np.where(better, tot, best_tot)
            which = np.where(better, 1, which)
    best = np.argmin(best_tot, axis=0)
    out["shadow"] = best_tot.min(0)
    out["shadow_run"] = np.stack([t0[best], t1[best]], axis=1)
    out["shadow_variant"] = np.asarray(["kries", "sky"])[which[best, np.arange(p)]]
    return out
