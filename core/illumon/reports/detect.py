"""Physics-based detection of distortions that a daylight model lacks, by residual analysis.

Two kinds of departure are searched for in a set of measured spectra, each against the measured-daylight model of
:mod:`illumon.daylight.measured` (no classifier is trained):

* **Absorption bands.** Every spectrum is fitted freely with the model's smooth basis; an absorber multiplies the
  spectrum by ``1 − d·g(λ)`` with a band profile ``g`` (Beer–Lambert for a weak line), so its trace in the relative
  residual is the part of ``g`` that the basis cannot reproduce. A matched filter (Gaussian profiles, centres every
  1 nm, several widths) gives each spectrum a depth estimate and a significance against its own residual noise; the
  band is where the summed positive evidence over spectra peaks, and the affected spectra are the significant ones
  after a two-cluster split of the depths (Otsu's threshold, IEEE SMC 9, 1979).
* **Off-locus tints.** The model's learnt prior gives the expected offset ``δ̄(mired)`` of measured daylight from the
  CIE daylight locus and its spread ``σ_δ``; a tint moves a subset coherently off that line. The standardised
  offsets are split into two clusters (two-component Gaussian mixture by EM); a tint is reported when the clusters
  are separated by more than 3 σ and the mixture beats one Gaussian by BIC (Schwarz 1978).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..daylight import cct_duv_from_xy, daylight_locus_duv, xy_from_spectrum
from ..daylight.measured import MeasuredDaylightData, shipped_measured_daylight, unit_mean
from ..spectra import WAVELENGTHS

__all__ = ["detect_band", "detect_tint", "otsu_threshold"]

BAND_FWHM_NM = (8.0, 15.0, 25.0, 40.0)
"""Band widths (full width at half maximum) scanned by :func:`detect_band`."""


def otsu_threshold(values: NDArray[np.float64]) -> float:
    """Threshold maximising the between-class variance of a 1-D sample (Otsu 1979), on sorted midpoints."""
    v = np.sort(np.asarray(values, dtype=float))
    n = v.size
    if n < 2:
        return float(v[0]) if n else 0.0
    c = np.cumsum(v)
    k = np.arange(1, n)
    m0 = c[:-1] / k
    m1 = (c[-1] - c[:-1]) / (n - k)
    between = k * (n - k) * (m0 - m1) ** 2
    i = int(np.argmax(between))
    return float(0.5 * (v[i] + v[i + 1]))


def _profiles(centres: NDArray[np.float64], fwhm: float) -> NDArray[np.float64]:
    s = fwhm / 2.3548
    return np.exp(-0.5 * ((WAVELENGTHS[:, None] - centres[None, :]) / s) ** 2)


def detect_band(
    spectra: NDArray[np.float64],
    data: MeasuredDaylightData | None = None,
    *,
    min_significance: float = 5.0,
    min_fraction: float = 0.05,
) -> dict:
    """Find an absorption band hidden in some of ``spectra`` (N × 61, grid) and the spectra that carry it.

    Parameters
    ----------
    spectra
        Measured spectra on the grid, any scale.
    data
        Reference model; the shipped Granada model by default.
    min_significance
        Matched-filter significance (depth / standard error) a spectrum needs to count as affected.
    min_fraction
        Fewest affected spectra (as a fraction) for a band to be reported.

    Returns
    -------
    dict
        ``found``, ``centre_nm``, ``fwhm_nm``, ``affected`` (indices), ``depth_median``, ``profile`` (evidence per
        centre for the best width) and ``centres``.
    """
    data = data or shipped_measured_daylight()
    e = unit_mean(spectra)
    b = data.basis
    coef = np.linalg.lstsq(b, e.T, rcond=None)[0]
    fit = (b @ coef).T
    rho = e / fit - 1.0
    # Residual-space projector of the basis in relative units (basis divided by the mean spectrum).
    bt = b / data.mean[:, None]
    q = np.eye(b.shape[0]) - bt @ np.linalg.pinv(bt)
    noise = data.residual_rel_sd + 1e-4  # natural residual spread per wavelength, from the model's training data
    centres = np.arange(400.0, 700.0 + 0.5, 1.0)
    best = None
    for fwhm in BAND_FWHM_NM:
        h = q @ _profiles(centres, fwhm)  # 61 × T: what a unit-depth band leaves after the basis fit
        hw = h / noise[:, None] ** 2
        hh = (h * hw).sum(0)
        depth = -(rho @ hw) / hh  # N × T, positive for absorption
        # Residual noise of each spectrum once the band is taken out (weighted least squares, analytic).
        ss = ((rho / noise) ** 2).sum(1)[:, None]
        rss = np.clip(ss - depth**2 * hh, 1e-12, None)
        scale = np.sqrt(rss / max(b.shape[0] - b.shape[1] - 1, 1))
        t = depth * np.sqrt(hh) / scale
        evidence = np.clip(t, 0, None) ** 2
        evidence = np.where(t > min_significance, evidence, 0.0).sum(0)
        j = int(np.argmax(evidence))
        if best is None or evidence[j] > best[0]:
            best = (float(evidence[j]), fwhm, j, t[:, j], depth[:, j], evidence)
    assert best is not None
    _, fwhm, j, t, depth, evidence = best
    sig = t > min_significance
    affected = np.zeros(len(e), dtype=bool)
    if sig.sum() >= 2:
        thr = otsu_threshold(np.log(np.clip(depth[sig], 1e-6, None)))
        # Keep the deep cluster unless the significant depths form a single tight group.
        logd = np.log(np.clip(depth, 1e-6, None))
        spread = np.ptp(logd[sig])
        affected = sig & (logd >= thr) if spread > 1.0 else sig
    found = bool(affected.sum() >= max(2, min_fraction * len(e)))
    return {
        "found": found,
        "centre_nm": float(centres[j]) if found else None,
        "fwhm_nm": float(fwhm) if found else None,
        "affected": np.flatnonzero(affected).tolist() if found else [],
        "depth_median": float(np.median(depth[affected])) if found else 0.0,
        "centres": centres.tolist(),
        "profile": evidence.tolist(),
        "significance": t.tolist(),
    }


def _gmm2(x: NDArray[np.float64], iters: int = 200) -> tuple[NDArray[np.float64], dict]:
    """Two-component 1-D Gaussian mixture by EM, initialised at Otsu's split; posterior of the minor component."""
    thr = otsu_threshold(x)
    lo, hi = x[x < thr], x[x >= thr]
    if lo.size < 2 or hi.size < 2:
        return np.zeros_like(x), {"bic_gain": 0.0, "separation": 0.0}
    mu = np.array([lo.mean(), hi.mean()])
    sd = np.array([max(lo.std(), 0.3), max(hi.std(), 0.3)])
    w = np.array([lo.size, hi.size], dtype=float) / x.size
    for _ in range(iters):
        dens = w / (sd * np.sqrt(2 * np.pi)) * np.exp(-0.5 * ((x[:, None] - mu) / sd) ** 2)
        tot = dens.sum(1, keepdims=True) + 1e-300
        r = dens / tot
        nk = r.sum(0) + 1e-12
        w = nk / x.size
        mu = (r * x[:, None]).sum(0) / nk
        sd = np.sqrt((r * (x[:, None] - mu) ** 2).sum(0) / nk)
        sd = np.maximum(sd, 0.3)
    dens = w / (sd * np.sqrt(2 * np.pi)) * np.exp(-0.5 * ((x[:, None] - mu) / sd) ** 2)
    ll2 = float(np.log(dens.sum(1) + 1e-300).sum())
    m1, s1 = x.mean(), max(x.std(), 1e-9)
    ll1 = float((-0.5 * ((x - m1) / s1) ** 2 - np.log(s1 * np.sqrt(2 * np.pi))).sum())
    bic_gain = (ll2 - ll1) - 1.5 * np.log(x.size)  # 3 extra parameters
    # The distorted cluster is the one farther from the natural mean (z = 0), whatever its size.
    minor = int(np.argmax(np.abs(mu)))
    post = dens[:, minor] / (dens.sum(1) + 1e-300)
    separation = abs(mu[1] - mu[0]) / float(np.sqrt(sd[0] * sd[1]))
    return post, {"bic_gain": bic_gain, "separation": separation, "mu": mu.tolist(), "sd": sd.tolist(),
                  "weights": w.tolist(), "minor": minor}


def detect_tint(
    spectra: NDArray[np.float64],
    data: MeasuredDaylightData | None = None,
    *,
    min_separation: float = 3.0,
    min_fraction: float = 0.01,
) -> dict:
    """Find a coherent off-locus tint in a subset of ``spectra`` (N × 61).

    Returns
    -------
    dict
        ``found``, ``shift_duv`` (mean offset of the tinted cluster from the rest), ``affected`` (indices),
        ``z`` (standardised offsets) and the mixture diagnostics.
    """
    data = data or shipped_measured_daylight()
    cct, duv = cct_duv_from_xy(xy_from_spectrum(np.asarray(spectra, dtype=float)))
    delta = duv - daylight_locus_duv(cct)
    z = (delta - data.delta_mean(1e6 / cct)) / data.delta_sd
    post, info = _gmm2(z)
    affected = post > 0.5
    n_aff = int(affected.sum())
    found = bool(
        info["separation"] >= min_separation
        and info["bic_gain"] > 10.0
        and n_aff >= max(2, min_fraction * len(z))
        and n_aff <= 0.9 * len(z)
    )
    shift = float(np.median(delta[affected]) - np.median(delta[~affected])) if found else 0.0
    return {
        "found": found,
        "shift_duv": shift,
        "affected": np.flatnonzero(affected).tolist() if found else [],
        "z": z.tolist(),
        "separation": float(info["separation"]),
        "bic_gain": float(info["bic_gain"]),
    }
