"""Tests that need the spectral model: off-locus light and fluorescence.

Both effects leave the camera-agnostic bilinear model intact (:mod:`.bilinear`): a lamp-lit frame is still some
combination of patch responses, and a fluorophore's emission ``(Σλ' a(λ') E(λ')) e(λ)`` is linear in the illuminant,
so a fluorescent patch behaves like a patch with another (non-physical) reflectance. They show only against what is
known of daylight, cameras and surfaces, i.e. against the joint spectral fit of :mod:`illumon.retrieval.joint`:

* **off-locus light**: with the reflectances of the joint fit held, each frame is re-fitted with measured daylight
  (a Gaussian mixture of Granada skies, :func:`daylight_mixture`) and with a free illuminant (a smooth 10-function
  basis, no prior). A daylight frame gains little from the freedom; a lamp-lit frame gains much.
* **fluorescence** (Han, Matsushita, Sato, Okabe & Sato, CVPR 2012, eqs. 1–2): with the frames' illuminants
  re-fitted as measured daylight (above) and held, each patch is re-fitted with its reflectance (Gaussian prior)
  plus an emission ``k_f (Σλ a(λ) E_f(λ)) w``: :func:`generic_fluorescence_gains` (used by the diagnosis) with ``w``
  any camera response to light above a generic short-wave absorption band ``a`` (the Stokes shift), so the
  fluorophore need not be known;
  :func:`fluorescence_gains` with ``w = s Cᵀe``, ``s ≥ 0``, for each of the 21 fluorophores shipped in
  ``illumon/data/fluorophores.csv`` (reported as the closest shipped one).

Both gains are in the whitened units of the joint fit, whose noise scale is profiled from its data residuals.

References
----------
.. [Han2012] Han et al., CVPR 2012: eqs. 1–2, the emission model.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from importlib import resources

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares, nnls

from ..daylight import CIEDaylight, daylight_model
from ..model.general import cie_lamp_spectra
from ..observations import Observations
from ..priors import default_daylight_prior, reflectance_basis
from ..retrieval.common import grey_world_mired, imaging_operators
from ..retrieval.joint import JointProblem
from ..spectra import WAVELENGTHS, read_spectral_csv
from .noise import dark_level as current_dark_level

__all__ = [
    "SpectralBase", "fit_spectral_base", "refine_with_measured_daylight", "off_locus_gains", "fluorescence_gains",
    "generic_fluorescence_gains", "excitation_bands", "EXCITATION_CENTRES_NM", "daylight_mixture",
    "LOCAL_REFLECTANCE_SD", "local_reflectance_functions", "spectral_pedestal", "without_patches",
    "studentised_fluorescence_ratio", "REFLECTANCE_PRIOR_DOF", "FLUORESCENCE_CANDIDATES", "STOKES_SHIFT_NM",
    "emission_cone",
]


@dataclass
class SpectralBase:
    """The joint spectral fit of a history (one start, projected reflectances), with its residuals."""

    prob: JointProblem
    params: NDArray[np.float64]
    logk: NDArray[np.float64]
    sigma: NDArray[np.float64]
    data_res: NDArray[np.float64]  # F × P × 3 whitened
    prior_res: NDArray[np.float64]  # F × nd whitened daylight prior
    phi: float  # noise scale of the whitened data residuals
    sensitivities: NDArray[np.float64]
    day_spectra: NDArray[np.float64] | None = None  # F × 61 measured-daylight re-fit per frame, exposure included


def fit_spectral_base(obs: Observations, sensitivities: NDArray[np.float64], max_nfev: int = 100,
                      daylight: str = "cie", dark_level: float | None = None) -> SpectralBase:
    """Fit the joint model (CIE daylight with its prior, reflectance basis with its prior) from a gray-world start;
    values at or below ``dark_level`` (default: the diagnosed history's, :func:`.noise.dark_level`) censored."""
    if dark_level is None:
        dark_level = current_dark_level()
    model = daylight_model(daylight)
    rb = reflectance_basis()
    c = np.asarray(sensitivities, dtype=float)
    prob = JointProblem(obs, c, model, rb)
    # values within a few codes of black are censored (clipping at 0 after black subtraction, rounding of undithered
    # dark pixels; :data:`.noise.DARK_LEVEL`): they carry no Gaussian residual
    prob.W = np.where(np.nan_to_num(np.asarray(obs.values, dtype=float)) <= dark_level, 0.0, prob.W)
    lo, hi = prob.bounds()
    nfr = prob.F * prob.nf
    x0 = np.clip(prob.start(grey_world_mired(obs, c)), lo + 1e-9, hi - 1e-9)
    sol = least_squares(prob.projected_residuals, x0[:nfr], bounds=(lo[:nfr], hi[:nfr]), x_scale=prob.frame_scale(),
                        max_nfev=max_nfev, method="trf")
    fr = sol.x.reshape(prob.F, prob.nf)
    params, logk = fr[:, : prob.np], fr[:, prob.np]
    sigma = prob.solve_reflectances(params, logk)
    m, _ = prob.operators(params)
    pred = np.exp(logk)[:, None, None] * np.einsum("fcj,pj->fpc", m, sigma)
    data = prob.W * (prob.Y - pred)
    prior = model.prior_residuals(params)
    n = int(prob.present.sum()) * 3
    k = prob.F * prob.nf + prob.P * prob.nk
    phi = float((data**2).sum() / max(n - k, 1))
    return SpectralBase(prob, params, logk, sigma, data, prior, phi, c)


def _generic_basis(n: int = 10, width_nm: float = 30.0) -> NDArray[np.float64]:
    centres = np.linspace(400.0, 700.0, n)
    return np.exp(-0.5 * ((WAVELENGTHS[:, None] - centres[None, :]) / width_nm) ** 2)


def _daylight_basis() -> NDArray[np.float64]:
    """The shipped measured-daylight mean and components (61 × (1 + J)), the basis of :func:`daylight_mixture`."""
    dp = default_daylight_prior()
    return np.column_stack([dp.mean, dp.components])


@lru_cache(maxsize=1)
def daylight_mixture() -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The Gaussian mixture of measured daylight coefficients (``illumon/data/daylight_mixture.json``): weights (K,),
    means (K × 4) and covariances (K × 4 × 4) of the coefficients on the shipped daylight components, fitted by EM to
    the training half of the Granada spectra (``tools/build_daylight_mixture.py``; K = 6 by BIC). Measured skies are
    far from Gaussian (a long blue tail, a thin warm end): one Gaussian, symmetric about its mean, would give warm lamp
    light the probability of blue sky."""
    import json
    meta = json.loads((resources.files("illumon") / "data" / "daylight_mixture.json").read_text())
    return (np.asarray(meta["weights"], dtype=float), np.asarray(meta["means"], dtype=float),
            np.asarray(meta["covariances"], dtype=float))


def _daylight_frames(base: SpectralBase, sigma: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                                              NDArray[np.float64]]:
    """Each frame fitted as measured daylight with the reflectances held: ``E = k (μ + Pc)``, ``c`` under the mixture
    of measured skies (:func:`daylight_mixture`; the component of lowest cost). Returns the weights ``x = [k, k·c]``
    (F × (1+J)), the cost (data / φ + the component's χ² + ln det Σ_k − 2 ln w_k, relative to the smallest such
    constant) and the data misfit."""
    prob = base.prob
    day_basis = _daylight_basis()
    weights, means, covs = daylight_mixture()
    j = day_basis.shape[1] - 1
    cov_inv = np.linalg.inv(covs)
    const = np.linalg.slogdet(covs)[1] - 2.0 * np.log(weights)
    const = const - const.min()
    kd, _ = imaging_operators(base.sensitivities, day_basis, prob.rb)
    design_d = np.einsum("bcj,pj->pcb", kd, sigma)  # P × 3 × (1 + J)
    xs = np.zeros((prob.F, j + 1))
    cost = np.full(prob.F, np.inf)
    data = np.zeros(prob.F)
    for f in range(prob.F):
        w = prob.W[f]
        b = (w * prob.Y[f]).ravel()
        ad = (w[..., None] * design_d).reshape(-1, j + 1)
        k0 = max(float(ad[:, 0] @ b / max(ad[:, 0] @ ad[:, 0], 1e-300)), 1e-12)
        ata, atb = ad.T @ ad / base.phi, ad.T @ b / base.phi
        for q in range(weights.size):
            # minimise |b − ad x|²/φ + (x₁ − k₀m)ᵀ (k₀²Σ)⁻¹ (x₁ − k₀m),  x = [k, k·c]
            lam = np.zeros((j + 1, j + 1))
            lam[1:, 1:] = cov_inv[q] / k0**2
            rhs = np.zeros(j + 1)
            rhs[1:] = lam[1:, 1:] @ (k0 * means[q])
            try:
                x = np.linalg.solve(ata + lam, atb + rhs)
            except np.linalg.LinAlgError:  # a frame the patches cannot light-read (a dark or clipped channel)
                x = np.linalg.lstsq(ata + lam, atb + rhs, rcond=None)[0]
            d = x[1:] - k0 * means[q]
            dat = float(((b - ad @ x) ** 2).sum())
            c = dat / base.phi + float(d @ lam[1:, 1:] @ d) + float(const[q])
            if c < cost[f]:
                cost[f], data[f], xs[f] = c, dat, x
    return xs, cost, data


def refine_with_measured_daylight(base: SpectralBase, iters: int = 3) -> SpectralBase:
    """Alternate frames (measured daylight, :func:`_daylight_frames`) and reflectances (linear under their prior) from the
    joint CIE fit, so the tests below see less daylight-model error; updates ``base`` in place (``sigma``, ``phi``,
    ``day_spectra``)."""
    prob = base.prob
    day_basis = _daylight_basis()
    sigma = base.sigma
    for _ in range(iters):
        xs, _, data = _daylight_frames(base, sigma)
        spectra = xs @ day_basis.T
        a, _ = imaging_operators(base.sensitivities, spectra.T, prob.rb)  # F × 3 × K
        w2 = (prob.W**2).transpose(1, 0, 2)  # P × F × 3
        n = np.einsum("pfc,fci,fcj->pij", w2, a, a) + prob.Lambda
        b = np.einsum("pfc,fci->pi", w2 * prob.Y.transpose(1, 0, 2), a) + prob.Lambda @ prob.mu
        sigma = np.linalg.solve(n, b[..., None])[..., 0]
        nobs = int(prob.present.sum()) * 3
        base.phi = float(data.sum() / max(nobs - prob.F * (day_basis.shape[1]) - prob.P * prob.nk, 1))
    base.sigma = sigma
    xs, _, _ = _daylight_frames(base, sigma)  # iters = 0: the frames only, reflectances of the joint fit
    base.day_spectra = xs @ day_basis.T
    return base


def spectral_pedestal(base: SpectralBase, iters: int = 25, tol: float = 1e-4) -> tuple[NDArray[np.float64], float]:
    """A black offset fitted within the spectral model: ``y = k·Cᵀ(E·R) + β`` with one pedestal ``β`` per channel.

    The camera-agnostic bilinear model cannot see a pedestal when the exposure keeps the scene's brightness steady (an
    auto-exposure metering the mean): one combination of its frame factors is then constant and carries the pedestal
    as a column (a patch-independent "reflectance"). The spectral model cannot: a reflectance that adds the same
    signal under every frame's light exists only if the light's colour does not change. Frames (measured daylight,
    :func:`_daylight_frames`) alternate with the reflectances and ``β`` (linear, jointly: the reflectance step's
    normal equations with the shared ``β`` eliminated by its Schur complement), from the refined fit ``base``
    (:func:`refine_with_measured_daylight`; not changed), until ``β`` moves by less than ``tol`` (on the values'
    scale) or after ``iters`` rounds: exposure and pedestal trade off, so the alternation is slow (a 5 % pedestal
    reached 65 % of itself after 3 rounds, 95 % after 12).

    Returns
    -------
    tuple
        ``β`` (3,, on the values' scale) and the drop of the frames' cost (whitened misfit in units of ``base.phi``
        plus the daylight mixture's, :func:`_daylight_frames`) against no pedestal.
    """
    prob = base.prob
    day_basis = _daylight_basis()
    y0 = prob.Y
    sigma = base.sigma
    beta = np.zeros(3)
    _, cost0, _ = _daylight_frames(base, sigma)
    w2 = (prob.W**2).transpose(1, 0, 2)  # P × F × 3
    yt = y0.transpose(1, 0, 2)  # P × F × 3
    try:
        for _ in range(iters):
            prob.Y = y0 - beta
            xs, _, _ = _daylight_frames(base, sigma)
            a, _ = imaging_operators(base.sensitivities, (xs @ day_basis.T).T, prob.rb)  # F × 3 × K
            n = np.einsum("pfc,fci,fcj->pij", w2, a, a) + prob.Lambda  # P × K × K
            r = np.einsum("pfc,fci->pi", w2 * yt, a) + prob.Lambda @ prob.mu  # P × K
            g = np.einsum("pfc,fci->pic", w2, a)  # P × K × 3: the pedestal's columns
            n_r = np.linalg.solve(n, r[..., None])[..., 0]
            n_g = np.linalg.solve(n, g)
            schur = np.diag(w2.sum(axis=(0, 1))) - np.einsum("pic,pid->cd", g, n_g)
            rhs = np.einsum("pfc,pfc->c", w2, yt) - np.einsum("pic,pi->c", g, n_r)
            step = np.linalg.solve(schur, rhs) - beta
            beta = beta + step
            sigma = n_r - np.einsum("pic,c->pi", n_g, beta)
            if float(np.max(np.abs(step))) * prob.scale < tol:
                break
        prob.Y = y0 - beta
        _, cost1, _ = _daylight_frames(base, sigma)
    finally:
        prob.Y = y0
    return beta * prob.scale, float(cost0.sum() - cost1.sum())


def off_locus_gains(base: SpectralBase) -> tuple[NDArray[np.float64], int]:
    """Per frame, how much better a free illuminant explains it than measured daylight (reflectances held).

    The daylight alternative is the Gaussian mixture of measured Granada skies on the shipped daylight components
    (:func:`daylight_mixture`), so rare but natural skies (twilight, haze, well off the CIE locus) keep their
    probability while warm light where no measured sky lies (below ~5000 K off the locus) does not borrow the blue
    skies' spread; the free alternative is a smooth 10-function basis without prior. Returns the gains (F,) in units
    of the noise variance ``phi`` (data misfit over ``phi`` plus the mixture component's χ² and log-normaliser) and the
    number of extra parameters per frame.
    """
    prob = base.prob
    g = _generic_basis()
    kb, _ = imaging_operators(base.sensitivities, g, prob.rb)  # nb × 3 × K
    design = np.einsum("bcj,pj->pcb", kb, base.sigma)  # P × 3 × nb
    xs, day, _ = _daylight_frames(base, base.sigma)
    gains = np.zeros(prob.F)
    for f in range(prob.F):
        w = prob.W[f]  # P × 3
        b = (w * prob.Y[f]).ravel()
        a = (w[..., None] * design).reshape(-1, g.shape[1])
        coef, *_ = np.linalg.lstsq(a, b, rcond=None)
        gains[f] = day[f] - float(((b - a @ coef) ** 2).sum()) / base.phi
    if base.day_spectra is None:
        base.day_spectra = xs @ _daylight_basis().T
    return gains, g.shape[1] - xs.shape[1]


def lamp_shares(base: SpectralBase, frames: list[int], steps: int = 21,
                sigma: NDArray[np.float64] | None = None) -> list[float | None]:
    """The share of lamp light in each of ``frames`` (0…1 of the light at 560 nm), where it can be estimated.

    Each frame's light is re-fitted, reflectances held, as ``(1 − m)·D + m·L`` — ``D`` a CIE daylight (reciprocal
    temperature on a grid over the daylight range: the frame's own daylight re-fit has absorbed part of the lamp),
    ``L`` any lamp of the CIE tables (:mod:`illumon.model.lamps`), both 100 at 560 nm, ``m`` on a grid — with a free
    exposure. ``None`` where the best lamp mixture does not explain the frame better than the best daylight alone by
    more than the noise (χ² gain < 4): the light is off the locus, but not like any tabulated lamp. ``sigma``: the
    reflectance coefficients to hold (default the base's; better those fitted without the lamp-lit frames, which
    otherwise absorb part of the lamp).
    """
    prob = base.prob
    lamps = cie_lamp_spectra()
    dm = CIEDaylight()
    lo, hi = dm.bounds()
    days = dm.spectra(np.stack([np.linspace(lo[0], hi[0], 24), np.zeros(24)], axis=1))
    days = days / days[:, 32:33] * 100.0
    kl, _ = imaging_operators(base.sensitivities, lamps.T, prob.rb)  # N × 3 × J
    kd, _ = imaging_operators(base.sensitivities, days.T, prob.rb)  # D × 3 × J
    sig = base.sigma if sigma is None else sigma
    pred_l = np.einsum("ncj,pj->npc", kl, sig)  # N × P × 3
    pred_d = np.einsum("ncj,pj->npc", kd, sig)  # D × P × 3
    share = np.linspace(0.0, 1.0, steps)
    out: list[float | None] = []
    for f in frames:
        w2 = prob.W[f] ** 2
        y = prob.Y[f]
        best_chi = np.full(steps, np.inf)
        best_arg = [None] * steps
        for i, m in enumerate(share):
            pred = (1 - m) * pred_d[:, None] + m * pred_l[None]  # D × N × P × 3
            num = np.einsum("pc,dnpc->dn", w2 * y, pred)
            den = np.einsum("pc,dnpc->dn", w2, pred**2)
            k = np.clip(num / np.maximum(den, 1e-300), 0, None)
            chi = (np.einsum("pc,pc->", w2, y**2) - 2 * k * num + k**2 * den) / base.phi
            best_chi[i] = float(chi.min())
            best_arg[i] = np.unravel_index(int(np.argmin(chi)), chi.shape)
        i = int(np.argmin(best_chi))
        out.append(float(share[i]) if best_chi[0] - best_chi[i] >= 4.0 else None)
    return out


def shipped_fluorophores() -> tuple[list[str], NDArray[np.float64], NDArray[np.float64]]:
    """The 21 fluorophores shipped with illumon: names, excitation (21 × 61) and emission (21 × 61), peak-normalised."""
    text = (resources.files("illumon") / "data" / "fluorophores.csv").read_text()
    wl, values, names = read_spectral_csv("fluorophores.csv", text=text)
    cols = {n: values[:, i] for i, n in enumerate(names)}
    ids = sorted({n[2:] for n in names if n.startswith("ex")})
    labels = {}
    for line in text.splitlines():
        if line.startswith("# f") and ":" in line:
            key, rest = line[2:].split(":", 1)
            labels[key.strip()[1:]] = rest.strip().split(",")[0]
    ex = np.asarray([cols[f"ex{i}"] for i in ids])
    em = np.asarray([cols[f"em{i}"] for i in ids])
    return [labels.get(i, f"f{i}") for i in ids], ex, em


def fluorescence_gains(base: SpectralBase) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], list[str]]:
    """Per patch, the best drop of whitened misfit (units of ``phi``) when the patch fluoresces, over the shipped
    fluorophores; with the index of the best fluorophore, its strength (relative to the patch's reflected green) and
    the fluorophore names.

    References
    ----------
    .. [Han2012] Han et al., CVPR 2012: eqs. 1–2, the emission model.
    """
    prob = base.prob
    names, ex, em = shipped_fluorophores()
    if base.day_spectra is not None:  # frames re-fitted with measured daylight (off_locus_gains), exposure included
        spectra = base.day_spectra
        k = np.ones(prob.F)
        kf, _ = imaging_operators(base.sensitivities, spectra.T, prob.rb)  # F × 3 × K
        m = kf
    else:
        m, white = prob.operators(base.params)
        spectra = prob.model.weights(base.params) @ prob.model.basis.T / white[:, 1:2]  # F × 61, camera white_g = 1
        k = np.exp(base.logk)
    q = spectra @ ex.T  # F × J: absorbed light (Han et al. eq. 1)
    wcol = em @ base.sensitivities  # J × 3: camera response to each emission spectrum (eq. 2)
    a_all = k[:, None, None] * m  # F × 3 × K
    lam, mu = prob.Lambda, prob.mu
    P = prob.P
    J = len(names)
    gains = np.zeros(P)
    best = np.zeros(P, dtype=np.int64)
    strength = np.zeros(P)
    for p in range(P):
        w = prob.W[:, p]  # F × 3
        d = (w[..., None] * a_all).reshape(-1, a_all.shape[-1])  # 3F × K
        y = (w * prob.Y[:, p]).ravel()
        nmat = d.T @ d + lam
        rhs = d.T @ y + lam @ mu
        sig = np.linalg.solve(nmat, rhs)
        g = (w[:, None, :] * (k[:, None, None] * q[:, :, None] * wcol[None, :, :])).transpose(1, 0, 2).reshape(J, -1)
        # eliminate σ: the gain of one extra column g is (gᵀ r)² / (gᵀ g − gᵀ D N⁻¹ Dᵀ g) with r the base residual
        res = y - d @ sig
        ninv_dg = np.linalg.solve(nmat, d.T @ g.T)  # K × J
        denom = (g**2).sum(1) - np.einsum("jk,kj->j", g @ d, ninv_dg)
        num = g @ res
        s = num / np.maximum(denom, 1e-300)
        gain = np.where(s > 0, num**2 / np.maximum(denom, 1e-300), 0.0)
        j = int(np.argmax(gain))
        gains[p] = gain[j] / base.phi
        best[p] = j
        green = np.median(prob.Y[:, p, 1]) if prob.present[:, p].any() else 1.0
        strength[p] = float(s[j] * np.median(k * q[:, j] * wcol[j, 1]) / max(green, 1e-9)) if s[j] > 0 else 0.0
    return gains, best, strength, names


EXCITATION_CENTRES_NM: tuple[float, ...] = (400.0, 430.0, 460.0, 490.0, 520.0, 550.0)
"""Centres of the generic excitation bands (:func:`excitation_bands`)."""


def excitation_bands(centres: tuple[float, ...] = EXCITATION_CENTRES_NM, width_nm: float = 30.0) -> NDArray[np.float64]:
    """Generic short-wave excitation spectra (B × 61): Gaussian absorption bands, peak 1, for fluorophores not shipped."""
    return np.exp(-0.5 * ((WAVELENGTHS[None, :] - np.asarray(centres)[:, None]) / width_nm) ** 2)


STOKES_SHIFT_NM = 40.0
"""How far above an excitation band's centre the emission of the fluorescence test may start
(:func:`emission_cone`): a fluorophore re-emits what it absorbs at longer wavelengths (the Stokes shift, as in the
fluorophores' spectra Han et al. 2012 work with). Before 2026-11-28 the emission was any non-negative RGB, so a
surface's misfit of the spectral model in any colour — blue under a green band included — could pass for an
emission, and every patch's gain, which sets the test's scale, grew with it. With 40 nm the emission's bumps (σ 15
nm) begin about 15 nm above the band's centre, inside its own 30 nm width, so a fluorophore of small Stokes shift is
still reached through a bluer band. Chosen on the development histories (``python benchmarks/diagnose.py --split dev
--sims illumon,rawsim,imgsim --effects fluorescence --seeds 20``, and ``--effects none --seeds 60``), 30 and 40 nm
tried: fluorescent patches named 17 / 14 / 10 of 20 (``illumon`` / ``rawsim`` / ``imgsim``, margin 3.0) → 18 / 15 /
14 (30 nm, margin 4.0, clean maxima 2.68 / 3.98 / 3.92) and 18 / 15 / 13 (40 nm, margin 5.0, clean maxima 2.93 /
4.08 / 4.44, the weakest named 5.41 / 5.87 / 5.47): 40 nm kept, whose margin sits in a gap rather than at its edge."""


def emission_cone(sensitivities: NDArray[np.float64], centre_nm: float, shift_nm: float = STOKES_SHIFT_NM,
                  step_nm: float = 15.0, width_nm: float = 15.0) -> NDArray[np.float64]:
    """Generators of the camera responses an emission above ``centre_nm + shift_nm`` can give (3 × n, unit columns):
    Gaussian bumps every ``step_nm`` from there to 700 nm seen through ``sensitivities`` (61 × 3); the emission's RGB
    is a non-negative combination of them (:data:`STOKES_SHIFT_NM`).

    References
    ----------
    .. [Han2012] Han et al., CVPR 2012: eqs. 1–2, the emission ``e(λ)`` a fluorophore gives for the light it absorbs.
    """
    first = min(centre_nm + shift_nm, 700.0)
    centres = np.arange(first, 700.0 + 1e-9, step_nm)
    bumps = np.exp(-0.5 * ((WAVELENGTHS[:, None] - centres[None, :]) / width_nm) ** 2)
    g = np.asarray(sensitivities, dtype=float).T @ bumps
    return g / np.maximum(np.linalg.norm(g, axis=0, keepdims=True), 1e-300)


def _cone_quadratic_gain(h: NDArray[np.float64], b: NDArray[np.float64],
                         cone: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """``max 2 bᵀx − xᵀHx`` over ``x = G c``, ``c ≥ 0`` (``G`` = ``cone``, 3 × n), with its maximiser ``x``.

    With ``H = UᵀU`` and ``b = Uᵀz`` the objective is ``|z|² − |z − U G c|²``: a non-negative least-squares
    problem (:func:`scipy.optimize.nnls`)."""
    lv, vv = np.linalg.eigh(0.5 * (h + h.T))
    lv = np.maximum(lv, max(float(lv.max()), 1e-300) * 1e-10)
    u = np.sqrt(lv)[:, None] * vv.T
    z = (vv.T @ b) / np.sqrt(lv)
    c, rn = nnls(u @ cone, z)
    return float(z @ z - rn**2), cone @ c


LOCAL_REFLECTANCE_SD = 0.05
"""Prior standard deviation of each local reflectance function (:func:`local_reflectance_functions`) in the fluorescence
test. Unusual surfaces depart from the 8-function basis by up to ~0.03 RMS (measured reflectances outside the basis's
training set); without this freedom such a patch's misfit, which changes with the sky like an emission does, was the
main source of false fluorescence on clean development histories (0.02 and 0.05 tried; 0.05 kept)."""


def local_reflectance_functions(spacing_nm: float = 15.0, width_nm: float = 10.0) -> NDArray[np.float64]:
    """Gaussian bumps (61 × 21; σ 10 nm every 15 nm over 400–700 nm): local departures of a reflectance from the basis."""
    centres = np.arange(400.0, 700.0 + 1e-9, spacing_nm)
    return np.exp(-0.5 * ((WAVELENGTHS[:, None] - centres[None, :]) / width_nm) ** 2)


REFLECTANCE_PRIOR_DOF = 5.4
"""Degrees of freedom of the Student-t reflectance prior in the fluorescence test (:func:`generic_fluorescence_gains`):
the maximum-likelihood ν of a multivariate t with the shipped prior's mean and covariance over the 1 835 measured
reflectances the basis and prior were built from (each set weighted equally, as in ``tools/build_bases.py``;
``tools/reflectance_prior_dof.py``). Measured surfaces are heavy-tailed under the Gaussian prior — 6.7 % of them lie
beyond its 99 % point of χ²₈ — so a Gaussian prior shrinks an unusual surface towards the mean much harder than the
population warrants, and an emission of free colour, which has no prior, took up the misfit that shrinkage left."""

REFLECTANCE_PRIOR_ROUNDS = 3
"""Re-weighting rounds of the Student-t prior (each patch's prior precision × ``(ν + K) / (ν + d²)``, ``d²`` its
coefficients' squared Mahalanobis distance under the Gaussian prior: the EM steps towards the t prior's posterior
mode)."""


def generic_fluorescence_gains(base: SpectralBase, bands: NDArray[np.float64] | None = None,
                               local_sd: float = LOCAL_REFLECTANCE_SD,
                               patches: Sequence[int] | None = None,
                               prior_dof: float | None = REFLECTANCE_PRIOR_DOF,
                               shift_nm: float | None = STOKES_SHIFT_NM) -> tuple[NDArray[np.float64],
                                                                                       NDArray[np.int64],
                                                                                       NDArray[np.float64]]:
    """Per patch, the drop of whitened misfit (units of ``phi``) when the patch adds an emission of unknown colour.

    Han et al. (CVPR 2012, eqs. 1–2): the emitted light is a fixed spectrum scaled by the light the fluorophore
    absorbs, ``(Σλ' a(λ') E_f(λ')) e(λ)``, so the camera sees ``q_f · w`` with ``q_f`` the frame's absorbed light
    and ``w = Cᵀe`` a fixed RGB. The fluorophore is not assumed known: the excitation ``a`` is one of a few generic
    short-wave bands (:func:`excitation_bands`) and ``w`` any camera response to an emission at longer wavelengths
    than the band's (``shift_nm`` above its centre: :func:`emission_cone`, :data:`STOKES_SHIFT_NM`; before 2026-11-28
    any non-negative RGB). A reflectance cannot follow
    ``q_f`` because the ratio of absorbed short-wave light to the light a surface reflects changes with the sky's
    colour temperature: the evidence grows with the history's range of skies. Frames are the measured-daylight re-fit
    (``base.day_spectra``, exposure included), the patch's reflectance is re-fitted (Gaussian prior on the basis
    coefficients, plus local departures :func:`local_reflectance_functions` with prior σ ``local_sd``) with and
    without the emission. With ``prior_dof`` the basis coefficients' prior is a Student t of that many degrees of
    freedom (:data:`REFLECTANCE_PRIOR_DOF`) with the Gaussian prior's mean and covariance: each patch's prior
    precision is scaled by ``(ν + K) / (ν + d²)`` at its reflectance without the emission (:data:`REFLECTANCE_PRIOR_ROUNDS`
    re-weightings), and the same prior serves the fit with the emission; ``None``: the Gaussian prior.
    ``shift_nm`` ``None`` frees the emission's colour (any non-negative RGB, as before 2026-11-28).
    Returns the best gain over bands per patch, the band index and the emission's share of the patch's signal per
    channel (median over frames, P × 3); with ``patches`` given, only those patches are tested (the others' entries
    are 0).

    References
    ----------
    .. [Han2012] Han et al., CVPR 2012: eqs. 1–2, the emission model.
    """
    prob = base.prob
    if base.day_spectra is None:
        raise ValueError("generic_fluorescence_gains needs the measured-daylight frames (refine_with_measured_daylight)")
    bands = excitation_bands() if bands is None else bands
    spectra = base.day_spectra
    m, _ = imaging_operators(base.sensitivities, spectra.T, prob.rb)  # F × 3 × K
    q = spectra @ bands.T  # F × B absorbed light per band (eq. 1)
    lam, mu = prob.Lambda, prob.mu
    kb = lam.shape[0]  # the basis coefficients come first
    if local_sd > 0:  # local departures from the basis, N(0, local_sd²) each, in the null and the alternative alike
        bumps = local_reflectance_functions()
        m = np.concatenate([m, np.einsum("lc,fl,lj->fcj", base.sensitivities, spectra, bumps)], axis=-1)
        nb = bumps.shape[1]
        lam = np.block([[lam, np.zeros((kb, nb))], [np.zeros((nb, kb)), np.eye(nb) / local_sd**2]])
        mu = np.concatenate([mu, np.zeros(nb)])
    basis_block = np.zeros_like(lam)  # the Student-t re-weighting scales the basis coefficients' prior only
    basis_block[:kb, :kb] = prob.Lambda
    cones = [np.eye(3) if shift_nm is None else
             emission_cone(base.sensitivities, float(WAVELENGTHS[int(np.argmax(band))]), shift_nm) for band in bands]
    gains = np.zeros(prob.P)
    best = np.zeros(prob.P, dtype=np.int64)
    share = np.zeros((prob.P, 3))
    eye = np.eye(3)
    for p in range(prob.P) if patches is None else patches:
        w = prob.W[:, p]  # F × 3
        d = (w[..., None] * m).reshape(-1, m.shape[-1])  # 3F × K
        y = (w * prob.Y[:, p]).ravel()
        lam_p = lam
        for _ in range(REFLECTANCE_PRIOR_ROUNDS if prior_dof else 0):
            sig = np.linalg.solve(d.T @ d + lam_p, d.T @ y + lam_p @ mu)
            dev = sig[:kb] - mu[:kb]
            scale = (prior_dof + kb) / (prior_dof + float(dev @ prob.Lambda @ dev))
            lam_p = lam + (scale - 1.0) * basis_block
        nmat = d.T @ d + lam_p
        sig = np.linalg.solve(nmat, d.T @ y + lam_p @ mu)
        res = y - d @ sig
        for bi in range(bands.shape[0]):
            g = (w[:, :, None] * q[:, bi, None, None] * eye[None]).reshape(-1, 3)  # 3F × 3, one column per channel
            dg = d.T @ g
            h = g.T @ g - dg.T @ np.linalg.solve(nmat, dg)
            gain, x = _cone_quadratic_gain(h, g.T @ res, cones[bi])
            if gain / base.phi > gains[p]:
                gains[p], best[p] = gain / base.phi, bi
                ok = prob.present[:, p]
                level = np.median(prob.Y[ok, p], axis=0) if ok.any() else np.ones(3)
                share[p] = np.median(q[ok, bi, None], axis=0) * x / np.maximum(level, 1e-9)
    return gains, best, share


def without_patches(base: SpectralBase, patches: Sequence[int], iters: int = 3) -> SpectralBase:
    """``base`` with the frames' measured-daylight lights, the reflectances and the noise scale ``phi`` re-fitted
    without ``patches`` (:func:`refine_with_measured_daylight`, ``iters`` rounds from ``base``'s reflectances); the
    values and weights of every patch are kept, so the left-out patches can be tested against the re-fit. ``base`` is
    not changed."""
    prob = copy.copy(base.prob)
    w = base.prob.W.copy()
    w[:, list(patches)] = 0.0
    prob.W = w
    out = replace(base, prob=prob)
    refine_with_measured_daylight(out, iters=iters)
    out.prob = base.prob
    return out


FLUORESCENCE_CANDIDATES = 3
"""Patches :func:`studentised_fluorescence_ratio` measures against the fit without them before it picks the fluorescent
one: the three largest in-sample gains. A fluorescent patch bends the lights fitted with it, which lowers its own
in-sample gain and raises the others', so it need not rank first in sample: on the development histories
(``python benchmarks/diagnose.py --split dev --seeds 20``) two of the 20 fluorescent ``rawsim`` patches ranked second
(in-sample gains 139.5 against 149.8, 148.2 against 149.0) and stood out only against the fit without them (1 676 and
1 052 against 293 and 213 for the in-sample best). Measuring every patch so picks the same patch in all 60
development fluorescent histories of the three simulators (the four whose patch ranked lower in sample, fourth to
ninth, do not stand out against the fit without it either) and, in 7 of 67 clean ones, a patch whose only effect is
a larger clean statistic; the three best cost two re-fits more per history."""


def studentised_fluorescence_ratio(base: SpectralBase, gains: NDArray[np.float64], floor: float,
                                   iters: int = 3, candidates: int | None = None,
                                   shift_nm: float | None = STOKES_SHIFT_NM) -> tuple[float, int, float, float]:
    """The fluorescence test's statistic with externally studentised gains: the best patch's gain over the largest
    gain any other patch shows under the same test.

    The in-sample gains ``gains`` (:func:`generic_fluorescence_gains` on ``base``) name the candidates, the
    ``candidates`` largest (:data:`FLUORESCENCE_CANDIDATES`); each candidate's gain is then measured against the
    frames' lights, reflectances and noise scale re-fitted without it (:func:`without_patches`) — a fluorescent patch
    bends the lights fitted with it, which lowers its own gain and raises every other patch's, so it need not rank
    first in sample — and the largest is the patch ``p``. Each other patch ``q`` is tested the same way against the
    fit without ``p`` and ``q``: under the alternative "``p`` fluoresces" ``p`` says nothing about the lights or the
    noise, and every patch is judged by a fit it took no part in (as externally studentised residuals are, so a
    surface the lights happen to fit badly is no more likely to be the largest than any other). The scale is the
    largest such ``q`` gain (at least ``floor``): one patch fluoresces, the others show what the spectral model's
    misfit alone gives.

    Parameters
    ----------
    base
        The refined spectral fit (:func:`refine_with_measured_daylight`).
    gains
        Its in-sample fluorescence gains (P,).
    floor
        The smallest scale (the gain of 3 non-negative parameters on noise alone).
    iters
        Rounds of the re-fits.
    candidates
        How many of the largest in-sample gains are measured against the fit without their patch (default
        :data:`FLUORESCENCE_CANDIDATES`; 1: the in-sample best alone, as before 2026-11-28).
    shift_nm
        The emission's start above its band (:func:`generic_fluorescence_gains`; ``None``: any colour).

    Returns
    -------
    tuple
        The ratio, the patch ``p``, its gain (units of the re-fit's ``phi``) and the scale.
    """
    k = FLUORESCENCE_CANDIDATES if candidates is None else candidates
    best = [int(c) for c in np.argsort(-gains, kind="stable")[:max(1, k)] if gains[c] > 0] or [int(np.argmax(gains))]
    held = {c: _held_out_gain(base, c, (), iters, shift_nm) for c in best}
    p = max(best, key=held.__getitem__)
    gain_p = held[p]
    scale = floor
    for q in range(gains.size):
        if q != p and base.prob.present[:, q].any():
            scale = max(scale, _held_out_gain(base, q, (p,), iters, shift_nm))
    return gain_p / scale, p, gain_p, scale


def _held_out_gain(base: SpectralBase, patch: int, also: tuple[int, ...], iters: int,
                   shift_nm: float | None = STOKES_SHIFT_NM) -> float:
    """``patch``'s fluorescence gain against the lights, reflectances and noise scale re-fitted without it and the
    patches ``also`` (:func:`without_patches`)."""
    return float(generic_fluorescence_gains(without_patches(base, [*also, patch], iters), patches=[patch],
                                            shift_nm=shift_nm)[0][patch])
