"""Per-frame daylight and exposure for fixed (learned) patch reflectances, all frames at once in well under 1 ms each.

With reflectances fixed, the response of patch ``p`` is ``y_p = Σ_k b_k G_k[p]`` with ``G_k = Cᵀ diag(E_k) S σ_p`` for
the three CIE D basis spectra ``E_k`` and ``b = k/white_g · (1, M1, M2)``: a 3 × 3 weighted least-squares solve gives
``b̂`` and its precision ``A`` (the reflectance posterior covariance — Kinoshita & Kiya eqs. 13–14 — enters the
per-patch noise covariance). The daylight parameters (reciprocal CCT and offset from the daylight locus) and log
exposure then follow from a 3-parameter Gauss–Newton on ``(b(θ) − b̂)ᵀ A (b(θ) − b̂)`` plus the Gaussian daylight
prior, with its Laplace covariance.

With :data:`illumon.camera.formation.FLARE_SD` > 0 (the default) every frame also carries an additive offset
``o`` common to its patches (veiling glare): ``y_p = Σ_k b_k G_k[p] + o``, ``o`` Gaussian around 0, integrated out of
the linear solve in closed form (the Schur complement of its 3 × 3 block), so ``b̂`` and ``A`` are what the patches'
contrasts say, whatever the glare.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
from numpy.typing import NDArray

from ..camera import formation
from ..camera.formation import flare_scales
from ..daylight import CIEDaylight
from ..priors import ReflectanceBasis
from ..retrieval.common import CENSORED, NEAR_WHITE, censored, imaging_operators
from .weights import weight_table

__all__ = ["CENSORED", "NEAR_WHITE", "FrameSolver"]

_DIAG = np.arange(3)
_MAX_STEP = np.array([40.0, 0.01, np.inf])
_EPS3 = 1e-12 * np.eye(3)
_H = np.array([1e-3, 1e-6])  # finite-difference steps in (mired, δ)

_START_CHUNK = 64
"""Frames :meth:`FrameSolver.start` scores against its grid at once (64 × 1 089 grid points per temporary: 32 took
~5 % longer, the calls' own cost; the same θ)."""


SOLVE_CHUNK = 2048
"""Frames :meth:`FrameSolver.solve` solves at once (a 100k-frame history at once held ~550 MB of temporaries; with
8 192 a chunk's frames × patches × 9 temporaries, ~9 MB each, took a 100k-frame estimate ~0.1 s longer than 2 048's;
every frame is solved on its own, the same numbers)."""


def _inv3(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverses of 3 × 3 matrices (… × 3 × 3) by their adjugates: what ``np.linalg.inv`` gives to rounding, without
    a LAPACK call per matrix (a 100k-frame history's 1.6 million patch covariances took 1.5 s that way)."""
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    out = np.empty_like(m)
    out[..., 0, 0] = m11 * m22 - m12 * m21
    out[..., 1, 0] = m12 * m20 - m10 * m22
    out[..., 2, 0] = m10 * m21 - m11 * m20
    out[..., 0, 1] = m02 * m21 - m01 * m22
    out[..., 1, 1] = m00 * m22 - m02 * m20
    out[..., 2, 1] = m01 * m20 - m00 * m21
    out[..., 0, 2] = m01 * m12 - m02 * m11
    out[..., 1, 2] = m02 * m10 - m00 * m12
    out[..., 2, 2] = m00 * m11 - m01 * m10
    det = m00 * out[..., 0, 0] + m01 * out[..., 1, 0] + m02 * out[..., 2, 0]
    out /= det[..., None, None]
    return out


def _solve3(a: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a⁻¹ z`` for every frame (F × 3 × 3, F × 3): LAPACK's, and for a frame whose ``a`` is singular to the last bit
    (one patch seen with a channel censored: ``_EPS3`` is below its entries' rounding) the least-squares solution,
    where the batched solve raised for the whole batch. Such a frame has fewer than two patches or no signal in a
    channel: its estimate is reported as missing or carries no weight either way."""
    try:
        return np.linalg.solve(a, z[..., None])[..., 0]
    except np.linalg.LinAlgError:
        out = np.empty_like(z)
        for i in range(len(a)):
            try:
                out[i] = np.linalg.solve(a[i], z[i])
            except np.linalg.LinAlgError:
                out[i] = np.linalg.lstsq(a[i], z[i], rcond=None)[0]
        return out


def _without_offset(a: NDArray[np.float64], z: NDArray[np.float64], u: NDArray[np.float64],
                    cinv_sum: NDArray[np.float64], cinv_g: NDArray[np.float64], cinv_y: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``b``'s precision and information (F × 3 × 3, F × 3) with each frame's offset amounts ``φ`` (``o = u ⊙ φ``,
    ``u`` F × 3 of :func:`flare_scales`) integrated out: the Schur complement of their block
    ``diag(u) (Σ_p C_p⁻¹) diag(u) + I`` given the patches' summed precisions ``cinv_sum`` (F × 3 × 3), precision
    times operator ``cinv_g`` (Σ_p C_p⁻¹ G_p, F × 3(c) × 3(k)) and precision times value ``cinv_y`` (F × 3)."""
    s_oo = u[:, :, None] * cinv_sum * u[:, None, :] + np.eye(3)
    s_ob = u[:, :, None] * cinv_g
    t = np.swapaxes(s_ob, 1, 2) @ _inv3(s_oo)
    return a - t @ s_ob, z - (t @ (u * cinv_y)[..., None])[..., 0]


_SETUPS: OrderedDict[tuple, tuple[NDArray[np.float64], ...]] = OrderedDict()
_SETUPS_KEPT = 8
_SETUPS_LOCK = threading.Lock()


def _setup_key(sensitivities: NDArray[np.float64], daylight: CIEDaylight, reflectance: ReflectanceBasis
               ) -> tuple | None:
    """What a solver's coefficient-free parts depend on, for a CIE daylight model (else ``None``: not remembered)."""
    if type(daylight) is not CIEDaylight:
        return None
    css, fn = np.asarray(sensitivities, dtype=float), np.asarray(reflectance.functions, dtype=float)
    basis = np.asarray(daylight.basis, dtype=float)
    return (css.shape, css.tobytes(), fn.shape, fn.tobytes(), basis.shape, basis.tobytes(), daylight.duv_sigma,
            daylight.mired_mean, daylight.mired_sigma, daylight.n_params)


def _setup(sensitivities: NDArray[np.float64], daylight: CIEDaylight, reflectance: ReflectanceBasis
           ) -> tuple[NDArray[np.float64], ...] | None:
    """The imaging operators and start grid (``K``, ``w``, grid θ, grid ``b``, grid prior cost) an earlier
    :class:`FrameSolver` of the same camera, daylight model and reflectance basis computed, or ``None``. They do not
    depend on the reflectance coefficients, so the scene fit's alternation — a new solver each iteration — computes
    them once (issue 29: ~0.4 ms of each of its ~18 solvers); the same values, read-only."""
    key = _setup_key(sensitivities, daylight, reflectance)
    if key is None:
        return None
    with _SETUPS_LOCK:
        hit = _SETUPS.get(key)
        if hit is not None:
            _SETUPS.move_to_end(key)
        return hit


def _keep_setup(sensitivities: NDArray[np.float64], daylight: CIEDaylight, reflectance: ReflectanceBasis,
                parts: tuple[NDArray[np.float64], ...]) -> None:
    """Remember a solver's coefficient-free parts (:func:`_setup`), the last :data:`_SETUPS_KEPT`."""
    key = _setup_key(sensitivities, daylight, reflectance)
    if key is None:
        return
    for a in parts:
        a.flags.writeable = False
    with _SETUPS_LOCK:
        _SETUPS[key] = parts
        while len(_SETUPS) > _SETUPS_KEPT:
            _SETUPS.popitem(last=False)


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
    white
        The white level on the model's scale (``1 / scale`` for observations 0…1 of it); values at or above
        :data:`NEAR_WHITE` of it may be clipped and carry no weight. ``inf``: none are.
    gn_iterations
        Gauss–Newton iterations.
    flare_sd
        Prior spread of each frame's additive offset, integrated out of every frame's linear solve (``None``:
        :data:`illumon.camera.formation.FLARE_SD` as it is when the solver is built; 0: no offset).
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
        white: float = float("inf"),
        gn_iterations: int = 3,
        flare_sd: float | None = None,
    ) -> None:
        self.daylight = daylight
        setup = _setup(sensitivities, daylight, reflectance)
        k, w = setup[:2] if setup else imaging_operators(sensitivities, daylight.basis, reflectance)  # nb×3×K, nb×3
        self.w = w
        self.G = np.einsum("kcj,pj->pck", k, coefficients)  # P × 3(c) × 3(k)
        g, n_p = self.G, self.G.shape[0]
        # the sums over patches and channels of :meth:`linear` as matrix products with these tables:
        # GG[(p, c), (k, l)] = G[p, c, k] G[p, c, l]; GGE[(p, c, e), (k, l)] = G[p, e, k] G[p, c, l];
        # GE[(p, c, e), k] = G[p, e, k]
        self._gg = (g[:, :, :, None] * g[:, :, None, :]).reshape(n_p * 3, 9)
        self._gge = (g[:, None, :, :, None] * g[:, :, None, None, :]).reshape(n_p * 9, 9)
        self._ge = np.broadcast_to(g[:, None, :, :], (n_p, 3, 3, 3)).reshape(n_p * 9, 3)
        # GC[(p, c), (d, k)] = [c = d] G[p, c, k]: the offset's Σ_p C_p⁻¹ G_p for a diagonal C_p⁻¹
        self._gc = (np.eye(3)[None, :, :, None] * g[:, :, None, :]).reshape(n_p * 3, 9)
        if covariance is not None:
            # H[p, c, e, k, l] = (K_k Σ_p K_lᵀ)_{ce}: reflectance uncertainty of patch p for illuminant weights k, l
            self.H = np.einsum("kcj,pjm,lem->pcekl", k, covariance, k)
            self._h = self.H.reshape(n_p * 9, 9).T.copy()  # 9 (k, l) × (p, c, e)
            # the offset's sums over patches of :meth:`linear` as matrix products with these tables (the einsums they
            # replace took ~5 ms of a 2 000-frame estimate): GCE[(p, c, e), (d, k)] = [c = d] G[p, e, k];
            # CE[(p, c, e), d] = [c = d]
            same = np.eye(3)[None, :, None, :, None]  # p, c, e, d, k
            self._gce = (same * g[:, None, :, None, :]).reshape(n_p * 9, 9)
            self._ce = np.broadcast_to(np.eye(3)[None, :, None, :], (n_p, 3, 3, 3)).reshape(n_p * 9, 3)
        else:
            self.H = None
        self.rel = float(relative_error)
        self.abs = float(absolute_error)
        self.noise_scale = float(noise_scale)
        self.scale = float(scale)
        self.white = float(white)  # on the model's scale
        self.iters = int(gn_iterations)
        self.flare_sd = float(formation.FLARE_SD if flare_sd is None else flare_sd)
        self.table = weight_table()
        lo, hi = daylight.bounds()
        self.lo = np.append(lo, -np.inf)
        self.hi = np.append(hi, np.inf)
        self.prior_mean = np.array([daylight.mired_mean, 0.0])
        self.prior_prec = np.array([1.0 / daylight.mired_sigma**2, 1.0 / daylight.duv_sigma**2])
        if setup:  # the start grid of an earlier solver of this camera, daylight model and basis
            self.grid_theta, self.grid_u, self.grid_prior = setup[2:]
            return
        # Coarse start grid over (mired, δ): unit-exposure b vectors and their prior cost.
        gm, gd = np.meshgrid(
            np.arange(lo[0], hi[0] + 1e-9, 3.0), np.linspace(-3, 3, 9) * daylight.duv_sigma, indexing="ij"
        )
        self.grid_theta = np.stack([gm.ravel(), gd.ravel()], axis=1)
        self.grid_u = self._b(gm.ravel(), gd.ravel(), np.zeros(gm.size))
        self.grid_prior = self.prior_prec[0] * (gm.ravel() - daylight.mired_mean) ** 2 + self.prior_prec[1] * gd.ravel() ** 2
        _keep_setup(sensitivities, daylight, reflectance, (k, w, self.grid_theta, self.grid_u, self.grid_prior))

    # b(θ) = exp(logk) · a(θ) / white_g(a(θ))
    def _b(self, mired: NDArray[np.float64], delta: NDArray[np.float64], logk: NDArray[np.float64]) -> NDArray[np.float64]:
        a = self.table.weights(mired, delta)
        return np.exp(logk)[..., None] * a / (a @ self.w[:, 1])[..., None]

    def linear(
        self, y: NDArray[np.float64], present: NDArray[np.bool_], extra_var: NDArray[np.float64] | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Weighted linear least squares for ``b`` (F × 3) and its precision ``A`` (F × 3 × 3).

        ``y`` are observations on the model's scale (F × P × 3, NaN where missing). The per-patch noise covariance is
        the noise model plus ``extra_var`` (F × P × 3, the values' own measured variance on the model's scale, e.g.
        from their pixel spread) plus, after a first pass, the reflectance posterior mapped through the current ``b``.
        """
        yy = np.where(present[..., None], y, 0.0)
        var = (self.noise_scale**2) * ((self.rel * yy) ** 2 + self.abs**2)  # F × P × 3
        if extra_var is not None:
            var = var + np.where(present[..., None], extra_var, 0.0)
        var = np.where(censored(yy, self.abs, self.white), 1e12, var)  # censored at 0 or near white: no weight
        f, n_p = present.shape
        # the sums over patches and channels as matrix products (the einsums they replace took 5 × as long)
        cinv = np.where(present[..., None], 1.0 / var, 0.0).reshape(f, n_p * 3)  # diagonal
        a = (cinv @ self._gg).reshape(f, 3, 3) + _EPS3
        z = (cinv * yy.reshape(f, n_p * 3)) @ self.G.reshape(n_p * 3, 3)
        u = flare_scales(yy, cinv.reshape(f, n_p, 3) > 0, self.flare_sd, self.abs)
        if u is not None:
            ci = cinv.reshape(f, n_p, 3)
            diag = np.zeros((f, 3, 3))
            diag[:, _DIAG, _DIAG] = ci.sum(axis=1)
            a, z = _without_offset(a, z, u, diag, (cinv @ self._gc).reshape(f, 3, 3), (ci * yy).sum(axis=1))
        b = _solve3(a, z)
        if self.H is not None:
            # the reflectance posterior mapped through the current b joins each patch's noise covariance
            cov = ((b[:, :, None] * b[:, None, :]).reshape(f, 9) @ self._h).reshape(f, n_p, 9)
            cov[..., ::4] += var  # each 3 × 3's diagonal (entries 0, 4, 8: fancy indexing took twice as long)
            cinv = _inv3(cov.reshape(f, n_p, 3, 3))
            cinv[~present] = 0.0  # in place of np.where's copy of the inverses (issue 29: ~0.04 s of 100k frames)
            a = (cinv.reshape(f, n_p * 9) @ self._gge).reshape(f, 3, 3) + _EPS3
            z = (cinv * yy[..., None]).reshape(f, n_p * 9) @ self._ge
            if u is not None:
                flat = cinv.reshape(f, n_p * 9)
                a, z = _without_offset(a, z, u, cinv.sum(axis=1), (flat @ self._gce).reshape(f, 3, 3),
                                       (cinv * yy[:, :, None, :]).reshape(f, n_p * 9) @ self._ce)
            b = _solve3(a, z)
        return b, a

    def start(self, b: NDArray[np.float64], a: NDArray[np.float64]) -> NDArray[np.float64]:
        """Starting ``(mired, δ, logk)`` (F × 3): the best point of a coarse (mired, δ) grid with the exposure
        eliminated in closed form, ``k = uᵀAb̂ / uᵀAu`` for the unit-exposure ``u(θ)``."""
        out = np.empty((b.shape[0], 3))
        u = self.grid_u
        ut = np.ascontiguousarray(u.T)
        uu = (u[:, :, None] * u[:, None, :]).reshape(len(u), 9).T  # 9 × n: uᵀAu = vec(A)·vec(uuᵀ), one matmul
        step = _START_CHUNK
        for i in range(0, b.shape[0], step):
            ab = (a[i : i + step] @ b[i : i + step, :, None])[..., 0]  # F × 3
            num = ab @ ut  # F × n
            den = a[i : i + step].reshape(-1, 9) @ uu
            # k = clip(num / den, 1e-12), cost = den k² − 2 k num + prior, in place (the same operations in the same
            # order: the same bits as the expressions, in 32-frame pieces that stay in cache: 1.7 × faster)
            k = np.maximum(den, 1e-300)
            np.divide(num, k, out=k)
            np.maximum(k, 1e-12, out=k)
            cost = k * k
            cost *= den
            num *= k
            num *= 2.0
            cost -= num
            cost += self.grid_prior
            best = np.argmin(cost, axis=1)
            rows = np.arange(best.size)
            out[i : i + step, :2] = self.grid_theta[best]
            out[i : i + step, 2] = np.log(k[rows, best])
        return out

    def _jacobian(self, theta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``b(θ)`` (F × 3) and its Jacobian (F × 3(b) × 3(θ)): forward differences in (mired, δ), exact in log k;
        ``b`` at θ and at both steps in one table lookup."""
        f = theta.shape[0]
        mir, dl, lk = theta[:, 0], theta[:, 1], theta[:, 2]
        mm = np.concatenate([mir, mir + _H[0], mir])
        dd = np.concatenate([dl, dl, dl + _H[1]])
        bb = self._b(mm, dd, np.concatenate([lk, lk, lk])).reshape(3, f, 3)
        b = bb[0]
        return b, np.stack([(bb[1] - b) / _H[0], (bb[2] - b) / _H[1], b], axis=-1)

    def solve(
        self, y: NDArray[np.float64], present: NDArray[np.bool_], extra_var: NDArray[np.float64] | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Per-frame MAP ``θ = (mired, δ, log k)`` (F × 3), Laplace covariance (F × 3 × 3) and normalised cost (F,).

        Gauss–Newton with Levenberg damping on ``‖U(b(θ) − b̂)‖² + prior``, ``UᵀU = A``; all frames at once, at
        most :data:`SOLVE_CHUNK` at a time (every frame is solved on its own; the temporaries hold F × patches × 9
        values each). ``extra_var``: see :meth:`linear`.
        """
        parts = self._chunks(y, present, extra_var, laplace=True)
        if len(parts) == 1:
            return parts[0]  # type: ignore[return-value]
        return tuple(np.concatenate(v) for v in zip(*parts, strict=True))  # type: ignore[return-value]

    def solve_theta(
        self, y: NDArray[np.float64], present: NDArray[np.bool_], extra_var: NDArray[np.float64] | None = None
    ) -> NDArray[np.float64]:
        """:meth:`solve`'s ``θ`` alone (F × 3), without the Laplace covariance and cost it then works out: the scene
        fit's alternation reads ``θ`` only (issue 29: ~0.5 ms of each of its ~19 solves of 300 frames; the same ``θ``
        bit for bit)."""
        parts = self._chunks(y, present, extra_var, laplace=False)
        return parts[0][0] if len(parts) == 1 else np.concatenate([p[0] for p in parts])

    def _chunks(self, y: NDArray[np.float64], present: NDArray[np.bool_], extra_var: NDArray[np.float64] | None,
                laplace: bool) -> list[tuple]:
        """:meth:`_solve` of the frames at most :data:`SOLVE_CHUNK` at a time (each frame is solved on its own)."""
        return [self._solve(y[i:i + SOLVE_CHUNK], present[i:i + SOLVE_CHUNK],
                            None if extra_var is None else extra_var[i:i + SOLVE_CHUNK], laplace)
                for i in range(0, max(len(y), 1), SOLVE_CHUNK)]

    def _solve(
        self, y: NDArray[np.float64], present: NDArray[np.bool_], extra_var: NDArray[np.float64] | None = None,
        laplace: bool = True,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64] | None]:
        """:meth:`solve` of frames at once (``laplace`` false: ``θ`` alone, the covariance and cost ``None``)."""
        bhat, a = self.linear(y, present, extra_var)
        theta = self.start(bhat, a)
        pm, pp = self.prior_mean, self.prior_prec
        lam = 1e-3
        for _ in range(self.iters):
            b, jac = self._jacobian(theta)
            ja = np.swapaxes(jac, 1, 2) @ a  # Jᵀ A
            hess = ja @ jac
            grad = np.einsum("fjk,fk->fj", ja, b - bhat)
            hess[:, 0, 0] += pp[0]
            hess[:, 1, 1] += pp[1]
            grad[:, 0] += pp[0] * (theta[:, 0] - pm[0])
            grad[:, 1] += pp[1] * (theta[:, 1] - pm[1])
            hess[:, _DIAG, _DIAG] *= 1.0 + lam
            hess += _EPS3  # a frame whose light gives no signal (a channel at 0) has a zero exposure row
            step = np.linalg.solve(hess, -grad[..., None])[..., 0]
            step = np.minimum(np.maximum(step, -_MAX_STEP), _MAX_STEP)
            theta = np.minimum(np.maximum(theta + step, self.lo), self.hi)
        if not laplace:
            return theta, None, None
        b, jac = self._jacobian(theta)
        hess = np.swapaxes(jac, 1, 2) @ a @ jac
        hess[:, 0, 0] += pp[0]
        hess[:, 1, 1] += pp[1]
        cov = np.linalg.inv(hess + _EPS3)
        r = b - bhat
        cost = np.einsum("fi,fij,fj->f", r, a, r)
        return theta, cov, cost
