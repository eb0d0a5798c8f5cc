"""Huynh & Robles-Kelly: sensitivities and a smooth illuminant from one colour-chart image.

C. P. Huynh, A. Robles-Kelly, "Recovery of spectral sensitivity functions from a colour chart image under unknown
spectrally smooth illumination" (ICPR 2014). Two stages:

1. Non-negative least squares for ``P_c = s_c L ⊙ Q_c`` per channel from the chart (eq. 3), lightly smoothed
because
   a 24-patch chart is under-determined (see ``nnls_smoothness``).
2. Coordinate descent (Algorithm 1) on eq. (8): the spectral angle between ``P_c`` and ``Q_c ⊙ L``,
second-derivative
   smoothness of ``L`` and ``Q_c`` (eqs. 4–6), the distance of ``Q_c`` to a linear subspace (``‖T_c Q_c‖``, Luther /
   camera basis) and a penalty on low-SNR bands (eq. 7), with ``‖Q_c‖ = ‖L‖ = 1``.

The paper's parameters are used (α_L = 50, α_Q = 0.5, β_Q = 1, γ_Q = 1, ε = 0.05). They were set for 10-nm sampling,
so the solve runs on 400–700 nm at 10 nm and the result is interpolated onto the 5-nm grid. The subspace ``B_c`` is
the first three per-channel eigenvectors of measured cameras (Jiang et al. 2013). Unit-norm constraints are handled
by optimising an unnormalised non-negative vector ``u`` with ``Q = u / ‖u‖`` (every term is then scale-free), each
step by L-BFGS-B with analytic gradients instead of the paper's interior-point solver. Per-channel scales lost to
the normalisation are restored by least squares against the chart values (the ``s_c`` of eq. 1).

References
----------
.. [Huynh2014] Huynh & Robles-Kelly, ICPR 2014: eqs. 3–8 and Algorithm 1.
.. [Jiang2013] Jiang et al., WACV 2013: the camera subspace.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize, nnls

from ..priors import CameraPrior, default_camera_prior
from ..spectra import WAVELENGTHS
from .common import SensitivityResult, check_chart, finish, second_difference

__all__ = ["sensitivities_Huynh2014", "decompose_Huynh2014"]

SUB = slice(None, None, 2)  # 10-nm sub-grid of the 5-nm grid
OPTS = {"ftol": 1e-12, "gtol": 1e-9, "maxiter": 500}


def _angle_and_grad(p: NDArray[np.float64], v: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """Spectral angle θ(p, v) and dθ/dv."""
    np_, nv = np.linalg.norm(p), np.linalg.norm(v)
    if nv == 0 or np_ == 0:
        return float(np.pi / 2), np.zeros_like(v)
    cos = float(p @ v / (np_ * nv))
    cos = min(max(cos, -1.0 + 1e-12), 1.0 - 1e-12)
    dcos = p / (np_ * nv) - cos * v / nv**2
    return float(np.arccos(cos)), -dcos / np.sqrt(1.0 - cos**2)


def _rayleigh(m: NDArray[np.float64], u: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """``qᵀ M q`` with ``q = u / ‖u‖`` and its gradient with respect to ``u``."""
    uu = float(u @ u)
    mu = m @ u
    rho = float(u @ mu) / uu
    return rho, 2.0 * (mu - rho * u) / uu


def decompose_Huynh2014(
    p: NDArray[np.float64],
    bases: NDArray[np.float64],
    *,
    alpha_l: float = 50.0,
    alpha_q: float = 0.5,
    beta_q: float = 1.0,
    gamma_q: float = 1.0,
    epsilon: float = 0.05,
    max_iter: int = 20,
    tol: float = 1e-5,
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Algorithm 1: split ``P_c`` (n × 3) into a unit-norm illuminant ``L`` (n,) and unit-norm ``Q_c`` (n × 3).

    ``bases`` are the per-channel subspaces ``B_c`` (3 × n × d). Returns ``(L, Q, iterations)``.

    References
    ----------
    .. [Huynh2014] Huynh & Robles-Kelly, ICPR 2014: eq. 8 by coordinate descent, Algorithm 1.
    """
    n = p.shape[0]
    d = second_difference(n)
    dtd = d.T @ d
    mq = []
    for c in range(3):
        b = bases[c]
        t = np.eye(n) - b @ np.linalg.pinv(b)  # T_c = J − B_c B_c†
        w = (p[:, c] >= epsilon * p[:, c].max()).astype(float)  # eq. (7)
        mq.append(alpha_q * dtd + beta_q * t.T @ t + gamma_q * np.diag((1.0 - w) ** 2))
    bounds = [(1e-9, None)] * n
    lum = np.ones(n) / np.sqrt(n)  # L⁽⁰⁾ = 1 (normalised)
    q = np.empty((n, 3))
    for c in range(3):
        # Start from P_c's projection on the subspace: starting at P_c itself puts the spectral angle at its
        # kink
        # (θ = 0, where arccos is not differentiable) and the line search cannot leave it.
        proj = bases[c] @ (np.linalg.pinv(bases[c]) @ p[:, c])
        q[:, c] = np.maximum(proj, 1e-3 * proj.max() + 1e-12)
        q[:, c] /= np.linalg.norm(q[:, c])
    iterations = 0
    for it in range(1, max_iter + 1):
        iterations = it
        q_old, l_old = q.copy(), lum.copy()
        for c in range(3):

            def fq(
                u: NDArray[np.float64], c: int = c, lum: NDArray[np.float64] = lum
            ) -> tuple[float, NDArray[np.float64]]:
                th, g = _angle_and_grad(p[:, c], u * lum)
                pen, gp = _rayleigh(mq[c], u)
                return th + pen, g * lum + gp

            u = minimize(fq, q[:, c], jac=True, method="L-BFGS-B", bounds=bounds, options=OPTS).x
            q[:, c] = u / np.linalg.norm(u)

        def fl(u: NDArray[np.float64], q: NDArray[np.float64] = q) -> tuple[float, NDArray[np.float64]]:
            total, grad = 0.0, np.zeros(n)
            for c in range(3):
                th, g = _angle_and_grad(p[:, c], q[:, c] * u)
                total += th
                grad += g * q[:, c]
            pen, gp = _rayleigh(alpha_l * dtd, u)
            return total + pen, grad + gp

        u = minimize(fl, lum, jac=True, method="L-BFGS-B", bounds=bounds, options=OPTS).x
        lum = u / np.linalg.norm(u)
        if max(np.abs(q - q_old).max(), np.abs(lum - l_old).max()) < tol:
            break
    return lum, q, iterations


def sensitivities_Huynh2014(
    chart_rgb: ArrayLike,
    chart_reflectances: ArrayLike,
    *,
    camera_prior: CameraPrior | None = None,
    n_basis: int = 3,
    alpha_l: float = 50.0,
    alpha_q: float = 0.5,
    beta_q: float = 1.0,
    gamma_q: float = 1.0,
    epsilon: float = 0.05,
    max_iter: int = 20,
    nnls_smoothness: float = 0.05,
    **_: object,
) -> SensitivityResult:
    """Estimate sensitivities and illuminant with Huynh & Robles-Kelly (eqs. 3 and 8, Algorithm 1).

    Parameters
    ----------
    chart_rgb
        Linear camera values of the chart patches (P × 3).
    chart_reflectances
        Patch reflectances on the grid (P × 61).
    camera_prior
        Supplies the per-channel subspace ``B_c`` (first ``n_basis`` eigenvectors); default: shipped prior.
    alpha_l, alpha_q, beta_q, gamma_q, epsilon
        Weights of eq. (8) and the band threshold of eq. (7); defaults are the paper's.
    max_iter
        Coordinate-descent iterations at most.
    nnls_smoothness
        Weight of a second-difference term added to the NNLS of eq. (3). The paper's images have m ≥ n pixels of
        distinct reflectance; a 24-patch chart gives 24 equations for 31 unknowns, and with 0.2–1 % noise the plain
        NNLS solution is spiky. ``0`` gives the literal eq. (3).

    Returns
    -------
    SensitivityResult
        Sensitivities and the recovered smooth illuminant (unit mean).

    References
    ----------
    .. [Huynh2014] Huynh & Robles-Kelly, ICPR 2014: eqs. 3–8 and Algorithm 1.
    """
    x, r = check_chart(chart_rgb, chart_reflectances)
    xn = x / x.max()
    rs = r[:, SUB]
    wl = WAVELENGTHS[SUB]
    # eq. (3); with a 24-patch chart m < n, so a light second-difference term keeps P_c from being spiky.
    n = rs.shape[1]
    design = np.vstack([rs, nnls_smoothness * second_difference(n)])
    pad = np.zeros(n - 2)
    p = np.column_stack([nnls(design, np.concatenate([xn[:, c], pad]), maxiter=50 * n)[0] for c in range(3)])
    if np.any(p.max(axis=0) <= 0):
        raise ValueError("huynh2014: NNLS gave an all-zero channel")
    cp = camera_prior or default_camera_prior()
    bases = cp.channel_bases[:, SUB, :n_basis]
    lum, q, it = decompose_Huynh2014(
        p,
        bases,
        alpha_l=alpha_l,
        alpha_q=alpha_q,
        beta_q=beta_q,
        gamma_q=gamma_q,
        epsilon=epsilon,
        max_iter=max_iter,
    )
    # Restore the per-channel scales s_c of eq. (1) from the chart values.
    scales = np.empty(3)
    for c in range(3):
        pred = rs @ (lum * q[:, c])
        scales[c] = max(pred @ xn[:, c], 0.0) / max(pred @ pred, 1e-30)
    q_full = np.column_stack([np.interp(WAVELENGTHS, wl, q[:, c] * scales[c]) for c in range(3)])
    l_full = np.interp(WAVELENGTHS, wl, lum)
    return finish(q_full, l_full, "huynh2014", iterations=it)
