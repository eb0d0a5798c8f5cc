"""Correlated colour temperature (CCT) and Duv ↔ chromaticity, through a tabulated Planckian locus.

A chromaticity is parameterised by its correlated colour temperature (K) and its signed distance Duv from the
Planckian locus in the CIE 1960 UCS (u, v) diagram, with Ohno's sign convention: positive above the locus (towards
green), negative below (towards magenta). The locus is tabulated once on reciprocal temperature (mired, MK⁻¹) with its
derivative and unit normal, so both directions of the conversion are vectorised and cheap enough for per-frame
solves; they agree with colour-science's :func:`colour.temperature.CCT_to_uv_Ohno2013` and
:func:`colour.temperature.uv_to_CCT_Ohno2013` to < 1e-5 in uv.

References
----------
.. [Ohno2013] Ohno, LEUKOS 2014.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import colour
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from .._tables import cached_arrays

__all__ = ["PlanckLocus", "planck_locus", "xy_from_cct_duv", "cct_duv_from_xy"]


@dataclass(frozen=True)
class PlanckLocus:
    """The Planckian locus tabulated on reciprocal temperature (CIE 1960 uv, derivative and unit normal)."""

    mired: NDArray[np.float64]
    uv: NDArray[np.float64]
    duv_dm: NDArray[np.float64]  # derivative of uv with respect to mired
    normal: NDArray[np.float64]  # unit normal pointing "above" the locus (Ohno's positive Duv side)


@lru_cache(maxsize=1)
def planck_locus() -> PlanckLocus:
    """The tabulated Planckian locus (5–1000 MK⁻¹ at 0.25 MK⁻¹; CIE 1931 2° observer, c₂ = 1.4388e-2 m K).

    Returns
    -------
    PlanckLocus
        Reciprocal temperatures, CIE 1960 uv of the blackbody at each, the derivative of uv with respect to mired and
        the unit normal on Ohno's positive-Duv side.

    References
    ----------
    .. [Ohno2013] Ohno, LEUKOS 2014: the Planckian table the CCT and Duv are measured against.
    """
    # computed once a machine (~15 ms), then read from the disk cache bit for bit (:mod:`illumon._tables`)
    return PlanckLocus(*cached_arrays("planck-locus", (), (__file__,), _planck_table))


def _planck_table() -> tuple[NDArray[np.float64], ...]:
    """:func:`planck_locus`'s four arrays, computed."""
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    wl = np.asarray(cmfs.wavelengths, dtype=float) * 1e-9
    xyz_bar = np.asarray(cmfs.values, dtype=float)
    mired = np.arange(5.0, 1000.0 + 1e-9, 0.25)
    t = 1e6 / mired
    c2 = 1.4388e-2
    # spd = 1 / (λ⁵ (exp(c₂ / λT) − 1)), the same operations in the same order in one buffer (bit for bit the
    # expression; its four temporaries of 3 981 × 471 values each were most of this once-a-process table's time)
    spd = wl[None, :] * t[:, None]
    np.divide(c2, spd, out=spd)
    np.expm1(spd, out=spd)
    spd *= wl[None, :] ** 5
    np.divide(1.0, spd, out=spd)
    xyz = spd @ xyz_bar
    den = xyz[:, 0] + 15 * xyz[:, 1] + 3 * xyz[:, 2]
    uv = np.stack([4 * xyz[:, 0] / den, 6 * xyz[:, 1] / den], axis=1)
    d = np.gradient(uv, mired, axis=0)
    tangent = d / np.linalg.norm(d, axis=1, keepdims=True)
    # Rotate the tangent (direction of increasing mired, i.e. decreasing CCT) so that the normal points to +v.
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    normal *= np.sign(normal[:, 1:2])
    return mired, uv, d, normal


@lru_cache(maxsize=1)
def _locus_tree() -> cKDTree:
    """A k-d tree over the tabulated locus's uv points: each chromaticity's nearest table point in O(log n) (the
    brute-force search over all 3 981 points took 1 s for the 4 000 points of the daylight locus's Duv table)."""
    return cKDTree(planck_locus().uv)


def _xy_from_uv(uv: NDArray[np.float64]) -> NDArray[np.float64]:
    """CIE 1960 uv → CIE 1931 xy (…, 2)."""
    u, v = uv[..., 0], uv[..., 1]
    den = 2 * u - 8 * v + 4
    return np.stack([3 * u / den, 2 * v / den], axis=-1)


def _uv_from_xy(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """CIE 1931 xy → CIE 1960 uv (…, 2)."""
    x, y = xy[..., 0], xy[..., 1]
    den = -2 * x + 12 * y + 3
    return np.stack([4 * x / den, 6 * y / den], axis=-1)


_FEW_POINTS = 16
"""At most this many points :func:`_locus_at` interpolates with four ``np.interp`` calls (the same values)."""

_COLUMNS: dict[int, tuple[PlanckLocus, NDArray[np.float64]]] = {}


def _columns(p: PlanckLocus) -> NDArray[np.float64]:
    """``(u0, v0, nu, nv)`` of the table as one (N × 4) array, made once per table (kept with it)."""
    hit = _COLUMNS.get(id(p))
    if hit is None or hit[0] is not p:
        hit = (p, np.stack([p.uv[:, 0], p.uv[:, 1], p.normal[:, 0], p.normal[:, 1]], axis=1))
        hit[1].flags.writeable = False
        if len(_COLUMNS) > 4:
            _COLUMNS.clear()
        _COLUMNS[id(p)] = hit
    return hit[1]


def _locus_at(p: PlanckLocus, m: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """The locus point ``(u0, v0)`` and its unit normal ``(nu, nv)`` at reciprocal temperatures ``m``, interpolated
    linearly in the table: ``np.interp`` of each column, with the search for each point's table interval done once
    for the four (issue 29: 2.5 × faster, ~15 ms of a 2k refit). The same values bit for bit: ``np.interp``'s own
    arithmetic, ``(f[j+1] − f[j]) / (x[j+1] − x[j]) · (m − x[j]) + f[j]`` for ``x[j] ≤ m < x[j+1]``, the end values
    outside the table and at its last node, NaN for NaN (``tests/core/daylight/test_ohno2013.py`` compares them)."""
    x = np.asarray(m, dtype=float)
    xp = p.mired
    if x.size <= _FEW_POINTS:  # a frame's own estimate: np.interp itself is quicker for a few points
        return (np.interp(x, xp, p.uv[:, 0]), np.interp(x, xp, p.uv[:, 1]),
                np.interp(x, xp, p.normal[:, 0]), np.interp(x, xp, p.normal[:, 1]))
    cols = _columns(p)
    j = np.clip(np.searchsorted(xp, x, side="right") - 1, 0, len(xp) - 2)
    x0 = xp[j]
    f0 = cols[j]
    r = (cols[j + 1] - f0) / (xp[j + 1] - x0)[..., None] * (x - x0)[..., None] + f0
    below, above = x < xp[0], x >= xp[-1]
    if np.any(below) or np.any(above):
        r = np.where(np.asarray(below)[..., None], cols[0], np.where(np.asarray(above)[..., None], cols[-1], r))
    return r[..., 0], r[..., 1], r[..., 2], r[..., 3]


def xy_from_cct_duv(cct: ArrayLike, duv: ArrayLike) -> NDArray[np.float64]:
    """Chromaticity ``xy`` of the point at ``cct`` (K) and ``duv`` from the Planckian locus (Ohno 2013 convention).

    Vectorised through a dense tabulated locus (0.25 MK⁻¹ steps, linearly interpolated), so it is cheap enough for
    per-frame solves; agrees with :func:`colour.temperature.CCT_to_uv_Ohno2013` to < 1e-5 in uv.

    Parameters
    ----------
    cct
        Correlated colour temperatures (K).
    duv
        Signed distances from the Planckian locus in CIE 1960 uv (positive above), broadcast against ``cct``.

    Returns
    -------
    ndarray
        CIE 1931 chromaticities (…, 2).

    References
    ----------
    .. [Ohno2013] Ohno, LEUKOS 2014: the point at distance Duv along the locus normal.
    """
    m = 1e6 / np.asarray(cct, dtype=float)
    duv = np.asarray(duv, dtype=float)
    u0, v0, nu, nv = _locus_at(planck_locus(), m)
    uv = np.stack([u0 + duv * nu, v0 + duv * nv], axis=-1)
    return _xy_from_uv(uv)


def cct_duv_from_xy(xy: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """CCT (K) and Duv of chromaticities ``xy`` (…, 2) by nearest point on the tabulated Planckian locus.

    The nearest table point is refined by projecting onto the local tangent, which makes the result accurate to well
    under 1 K around daylight temperatures.

    Parameters
    ----------
    xy
        CIE 1931 chromaticities (…, 2).

    Returns
    -------
    cct, duv
        Correlated colour temperatures (K) and signed distances from the locus (…).

    References
    ----------
    .. [Ohno2013] Ohno, LEUKOS 2014: CCT as the temperature of the nearest locus point in uv, Duv as the signed
       distance to it.
    """
    p = planck_locus()
    uv = _uv_from_xy(np.asarray(xy, dtype=float))
    flat = uv.reshape(-1, 2)
    finite = np.all(np.isfinite(flat), axis=1)
    k = np.zeros(flat.shape[0], dtype=np.int64)  # the first table point where there is no chromaticity (NaN out)
    if finite.any():
        k[finite] = _locus_tree().query(flat[finite])[1]
    base = p.uv[k]
    deriv = p.duv_dm[k]
    dm = ((flat - base) * deriv).sum(1) / (deriv * deriv).sum(1)
    m = np.clip(p.mired[k] + dm, p.mired[0], p.mired[-1])
    u0, v0, nu, nv = _locus_at(p, m)
    cct = 1e6 / m
    duv = (flat[:, 0] - u0) * nu + (flat[:, 1] - v0) * nv
    return cct.reshape(uv.shape[:-1]), duv.reshape(uv.shape[:-1])
