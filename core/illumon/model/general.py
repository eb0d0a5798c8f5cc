"""Illuminants that are not daylight: the CIE lamp tables on the grid, and a *general* illuminant — a basis for any
light a fixed camera meets with a Gaussian prior on its coefficients — fitted to a frame's patches given the
reflectances learned under daylight (:func:`general_whites`, the white :mod:`.lamps` gives a lamp-lit frame).

References
----------
.. [CIE015] CIE 015:2018: illuminant A and the F, HP and LED illuminant tables (via colour-science).
.. [Kinoshita2023] Kinoshita & Kiya, 2023: the linear Gaussian posterior, eqs. 13–14, with the roles of light and
   surface exchanged.
"""

from __future__ import annotations

from functools import lru_cache

import colour
import numpy as np
from numpy.typing import NDArray

from .._tables import cached_arrays
from ..daylight import CIEDaylight
from ..retrieval.common import imaging_operators
from ..spectra import GRID, resample_columns

__all__ = ["cie_lamp_spectra", "GENERAL_COMPONENTS", "general_basis", "general_whites"]

_LAMPS = (
    "A", "FL1", "FL2", "FL3", "FL4", "FL5", "FL6", "FL7", "FL8", "FL9", "FL10", "FL11", "FL12",
    "FL3.1", "FL3.2", "FL3.3", "FL3.4", "FL3.5", "FL3.6", "FL3.7", "FL3.8", "FL3.9", "FL3.10", "FL3.11", "FL3.12",
    "FL3.13", "FL3.14", "FL3.15", "HP1", "HP2", "HP3", "HP4", "HP5",
    "LED-B1", "LED-B2", "LED-B3", "LED-B4", "LED-B5", "LED-BH1", "LED-RGB1", "LED-V1", "LED-V2",
)
"""The CIE lamps (colour-science's names): incandescent A, fluorescent FL1–FL12 and FL3.1–FL3.15, high-pressure
HP1–HP5 and the LED tables."""


@lru_cache(maxsize=1)
def cie_lamp_spectra() -> NDArray[np.float64]:
    """Every lamp of :data:`_LAMPS` on the grid (N × 61), 100 at 560 nm: resampled once a machine (~10 ms), then
    read from the disk cache bit for bit (:mod:`illumon._tables`)."""
    from .. import spectra

    return cached_arrays("cie-lamps", _LAMPS, (__file__, spectra.__file__), _lamp_table)[0]


def _lamp_table() -> tuple[NDArray[np.float64]]:
    """:func:`cie_lamp_spectra`, computed."""
    out = []
    for name in _LAMPS:
        sd = colour.SDS_ILLUMINANTS[name]
        v = resample_columns(sd.wavelengths, np.asarray(sd.values, dtype=float)[:, None], GRID)[:, 0]
        out.append(100.0 * v / v[32])
    return (np.array(out),)


GENERAL_COMPONENTS = 6
"""Components of the general illuminant basis (:func:`general_basis`)."""


@lru_cache(maxsize=4)
def general_basis(components: int = GENERAL_COMPONENTS) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                                  NDArray[np.float64]]:
    """A basis for any illuminant a fixed camera meets, and its Gaussian prior: the leading singular vectors of the
    lamp population (the CIE lamps alone and mixed half and half with daylight) and of CIE daylight from 4 000 to
    25 000 K, each spectrum scaled to unit norm. Returns the basis (61 × K), the prior mean and covariance of the
    coefficients of a unit-norm spectrum."""
    dm = CIEDaylight()
    lo, hi = dm.bounds()
    day = dm.spectra(np.stack([np.linspace(lo[0], hi[0], 40), np.zeros(40)], axis=1))
    lamps = cie_lamp_spectra()
    mixes = [0.5 * lamps + 0.5 * d[None, :] * 100.0 / d[32] for d in day[::8]]
    pop = np.concatenate([day, lamps, *mixes])
    pop = pop / np.linalg.norm(pop, axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(pop, full_matrices=False)
    basis = vt[:components].T
    if basis[:, 0].sum() < 0:
        basis[:, 0] = -basis[:, 0]
    coef = pop @ basis
    return basis, coef.mean(axis=0), np.cov(coef.T) + 1e-6 * np.eye(components)


def general_whites(model, obs, theta: NDArray[np.float64], frames: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Camera whites (F × 3, NaN for frames not selected) of the selected frames under a *general* illuminant: the
    illuminant in :func:`general_basis` that best explains the frame's patches given the model's learned
    reflectances — a linear Gaussian posterior (Kinoshita & Kiya's eqs. 13–14 with the roles of light and surface
    exchanged), its scale set by the frame's exposure under the daylight fit. Lamp light changes the patches' colours
    relative to each other, not only the white (metamerism); the reflectances learned from the daylight frames say how.
    """
    basis, mu, cov = general_basis()
    index = {p: i for i, p in enumerate(model.patches)}
    shared = [(j, index[p]) for j, p in enumerate(obs.patches) if p in index]
    oj, mi = [s[0] for s in shared], [s[1] for s in shared]
    rb = model.reflectance_basis()
    k_ops, w_ops = imaging_operators(model.sensitivities, basis, rb)  # K × 3 × J, K × 3
    g = np.einsum("kcj,pj->pck", k_ops, model.coefficients[mi])  # P × 3 × K
    values = np.asarray(obs.values, dtype=float)
    selected = np.flatnonzero(frames)
    # the selected frames' values only (the whole history's were copied and scaled for a few lamp-lit frames: ~0.04 s
    # of a 100k-frame refit); the same numbers
    y = values[selected][:, oj] / model.noise["scale"]
    n = model.noise
    out = np.full((len(values), 3), np.nan)
    lam = np.linalg.inv(cov)
    solver = model.solver(mi)
    for row, f in enumerate(selected):
        ok = np.all(np.isfinite(y[row]), axis=-1)
        if ok.sum() < 2 or not np.all(np.isfinite(theta[f])):
            continue
        yy = y[row, ok]
        var = n["noise_scale"] ** 2 * ((n["relative_error"] * yy) ** 2 + n["absolute_error"] ** 2)
        a = g[ok].reshape(-1, basis.shape[1])
        wgt = 1.0 / var.ravel()
        # the scale of the frame's light: its daylight fit's white in green, on the unit-norm population's scale
        b_day = solver._b(theta[f:f + 1, 0], theta[f:f + 1, 1], theta[f:f + 1, 2])[0]
        day_spec = b_day @ solver.daylight.basis.T
        k = float(np.linalg.norm(day_spec))
        prec = a.T @ (wgt[:, None] * a) + lam / k**2
        rhs = a.T @ (wgt * yy.ravel()) + lam @ (k * mu) / k**2
        b = np.linalg.solve(prec, rhs)
        w = b @ w_ops
        if np.all(w > 0):
            out[f] = w / w[1]
    return out
