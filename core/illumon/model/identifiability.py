"""How well a history determines its illuminants: spread of its reciprocal temperatures and the condition of the
data-only Jacobian of the joint problem (Marguier & Süsstrunk's model with the reflectance basis; priors left out)."""

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
