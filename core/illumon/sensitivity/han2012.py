"""Han, Matsushita, Sato, Okabe & Sato (CVPR 2012): sensitivities from a fluorescent chart under unknown light.

S. Han et al., "Camera spectral sensitivity estimation from a single image under unknown illumination by using
fluorescence", CVPR 2012. The fluorescence emitted by a material has a fixed spectral shape whatever the light
(eqs. 1–2), so its camera chromaticity does not depend on the illuminant (eqs. 3–5). Steps:

1. Separate each fluorescent patch into reflective and fluorescent parts with a reference chart of known,
   non-fluorescent reflectances in the same frame (eqs. 6–11): the reference gives the integrals
   ``∫ b_n c l`` of an 8-function reflectance basis (illumon's measured basis), which predict the reflective part.
2. The fluorescent parts' chromaticities give the homogeneous system of eqs. (13)–(15) in the coefficients of
a
   Fourier basis for the sensitivities (eq. 12, 9 functions), stabilised with second-derivative smoothness
   (eq. 16, weights (8, 8, 3)); the solution is the eigenvector of the smallest eigenvalue, max-normalised.

:func:`render_fluorescent_chart` simulates such a chart from measured excitation / emission spectra (the 12
fluorophores shipped in ``illumon/data/fluorophores.csv``).

References
----------
.. [Han2012] Han et al., CVPR 2012: eqs. 1–16, the fluorescent-chart method.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..priors import reflectance_basis
from ..spectra import GRID, WAVELENGTHS, read_spectral_csv, resample_columns
from .common import SensitivityResult, check_chart, finish

__all__ = [
    "sensitivities_Han2012",
    "fourier_basis",
    "separate_fluorescence_Han2012",
    "shipped_fluorophores",
    "fluorescent_reflectances",
    "render_fluorescent_chart",
]


def fourier_basis(m: int = 9, order: int = 0) -> NDArray[np.float64]:
    """Fourier basis (61 × m) over 400–700 nm (Han et al. footnote 2), or its ``order``-th derivative.

    Wavelength is measured in units of the range (u = (λ − 400) / 300), so derivatives are per range.
    """
    u = (WAVELENGTHS - WAVELENGTHS[0]) / (WAVELENGTHS[-1] - WAVELENGTHS[0])
    cols = [np.ones_like(u) if order == 0 else np.zeros_like(u)]
    k = 1
    while len(cols) < m:
        w = 2 * np.pi * k
        # d^n/du^n sin(wu) = w^n sin(wu + nπ/2)
        cols.append(w**order * np.sin(w * u + order * np.pi / 2))
        if len(cols) < m:
            cols.append(w**order * np.cos(w * u + order * np.pi / 2))
        k += 1
    return np.column_stack(cols)


@lru_cache(maxsize=1)
def shipped_fluorophores() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Excitation and emission spectra (61 × 12 each, peak-normalised) of the shipped fluorophores."""
    text = (resources.files("illumon") / "data" / "fluorophores.csv").read_text()
    wl, values, names = read_spectral_csv("fluorophores.csv", text=text)
    v = resample_columns(wl, values, GRID)
    ex = v[:, [i for i, n in enumerate(names) if n.startswith("ex")]]
    em = v[:, [i for i, n in enumerate(names) if n.startswith("em")]]
    return ex, em


def fluorescent_reflectances(excitation: ArrayLike) -> NDArray[np.float64]:
    """Reflective part of fluorescent paints (P × 61): bright, but absorbing where the dye is excited.

    A simulation assumption standing in for the diagonal of a measured Donaldson matrix (Han et al. §6):
    ``s = 0.85 − 0.6 · a / max(a)``.
    """
    a = np.asarray(excitation, dtype=float).T
    return np.clip(0.85 - 0.6 * a / a.max(axis=1, keepdims=True), 0.05, 1.0)


def render_fluorescent_chart(
    sensitivities: ArrayLike,
    illuminant: ArrayLike,
    excitation: ArrayLike | None = None,
    emission: ArrayLike | None = None,
    quantum_yield: float = 1.0,
) -> NDArray[np.float64]:
    """Camera values (P × 3) of a fluorescent chart: reflected light plus emitted fluorescence (eqs. 1, 6, 7).

    ``f_p(λ) = η · mean_λ'(a_p(λ') l(λ')) · e_p(λ) / mean(e_p)``: the absorbed light (excitation-weighted
    illuminant, 400–700 nm) re-emitted with the emission spectrum's shape.
    """
    ex0, em0 = shipped_fluorophores()
    ex = ex0 if excitation is None else np.asarray(excitation, dtype=float)
    em = em0 if emission is None else np.asarray(emission, dtype=float)
    c = np.asarray(sensitivities, dtype=float)
    e = np.asarray(illuminant, dtype=float)
    s = fluorescent_reflectances(ex)
    k = quantum_yield * (ex * e[:, None]).mean(axis=0)  # P
    f = (em / em.mean(axis=0)) * k  # 61 × P
    return (s * e) @ c + f.T @ c


def separate_fluorescence_Han2012(
    fluorescent_rgb: ArrayLike,
    fluorescent_reflectances: ArrayLike,
    reference_rgb: ArrayLike,
    reference_reflectances: ArrayLike,
) -> NDArray[np.float64]:
    """Fluorescent components (P × 3) of fluorescent patches, Han et al. eqs. (8)–(11).

    The reference chart gives the unknown integrals ``∫ b_n c l`` (eq. 10, least squares over Q ≥ 8 patches);
    the reflective parts follow from eq. (9) and are subtracted (eq. 11).

    References
    ----------
    .. [Han2012] Han et al., CVPR 2012: eqs. 6–11, reflective and fluorescent parts.
    """
    basis = reflectance_basis().functions  # 61 × 8, orthonormal
    a_ref = np.asarray(reference_reflectances, dtype=float) @ basis
    integrals = np.linalg.lstsq(a_ref, np.asarray(reference_rgb, dtype=float), rcond=None)[0]  # 8 × 3
    a_fl = np.asarray(fluorescent_reflectances, dtype=float) @ basis
    return np.asarray(fluorescent_rgb, dtype=float) - a_fl @ integrals


def sensitivities_Han2012(
    chart_rgb: ArrayLike,
    chart_reflectances: ArrayLike,
    *,
    fluorescent_rgb: ArrayLike,
    fluorescent_emissions: ArrayLike,
    fluorescent_reflectances: ArrayLike,
    n_fourier: int = 9,
    smoothness: tuple[float, float, float] = (8.0, 8.0, 3.0),
    smoothness_scale: float = 1e-6,
    **_: object,
) -> SensitivityResult:
    """Estimate sensitivities from a fluorescent chart and a reference chart in one frame (Han et al. 2012).

    Parameters
    ----------
    chart_rgb, chart_reflectances
        The non-fluorescent reference chart: camera values (Q × 3) and reflectances (Q × 61), Q ≥ 8.
    fluorescent_rgb
        Camera values of the fluorescent patches (P × 3), same frame and scale as ``chart_rgb``.
    fluorescent_emissions
        Their emission spectra on the grid (61 × P), any scale.
    fluorescent_reflectances
        Their reflective spectra (P × 61).
    n_fourier
        Fourier functions per channel (eq. 12; the paper uses 9).
    smoothness, smoothness_scale
        Weights ``(w_R, w_G, w_B)`` of eq. (16) and a factor that converts them to this discretisation (the
        second derivatives are per wavelength range, sampled at the 61 grid points).

    Returns
    -------
    SensitivityResult
        Max-normalised sensitivities (no illuminant: the method never needs it; see
        :func:`illumon.sensitivity.daylight_recovery.daylight_Han2012`).

    References
    ----------
    .. [Han2012] Han et al., CVPR 2012: eqs. 12–16, the sensitivities from the fluorescent chromaticities.
    """
    x, r = check_chart(chart_rgb, chart_reflectances)
    fl = separate_fluorescence_Han2012(fluorescent_rgb, fluorescent_reflectances, x, r)
    fl = np.clip(fl, 1e-12, None)
    chroma = fl / fl.sum(axis=1, keepdims=True)  # eq. (5)
    em = np.asarray(fluorescent_emissions, dtype=float)
    em = em / em.sum(axis=0)
    b = fourier_basis(n_fourier)
    t = em.T @ b  # P × M, t_{p,m} = ∫ e_p b_m (eq. 13)
    rows = []
    for p in range(t.shape[0]):
        for k in range(3):
            blocks = [chroma[p, k] * t[p] for _ in range(3)]
            blocks[k] = (chroma[p, k] - 1.0) * t[p]
            rows.append(np.concatenate(blocks))  # eq. (14)
    a = np.asarray(rows)  # eq. (15): 3P × 3M
    phi = fourier_basis(n_fourier, order=2)
    z = np.zeros_like(phi)
    s = [smoothness_scale * w for w in smoothness]
    smooth = np.block([[s[0] * phi, z, z], [z, s[1] * phi, z], [z, z, s[2] * phi]])  # eq. (16)
    full = np.vstack([a / np.linalg.norm(a), smooth])
    _, vecs = np.linalg.eigh(full.T @ full)
    beta = vecs[:, 0]
    c = np.column_stack([b @ beta[k * n_fourier : (k + 1) * n_fourier] for k in range(3)])
    if c.sum() < 0:
        c = -c
    return finish(c, None, "han2012", fluorescent_components=fl.tolist())
