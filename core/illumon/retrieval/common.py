"""Shared pieces of the multi-frame retrieval methods: the result type and the linear imaging operators."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..camera import camera_white, gains_from_white
from ..daylight import cct_duv_from_xy, daylight_locus_duv, daylight_spectrum, xy_from_cct_duv, xy_from_spectrum
from ..observations import Observations, count_over_patches
from ..priors import ReflectanceBasis

__all__ = ["RetrievalResult", "imaging_operators", "make_result", "grey_world", "grey_world_mired", "CENSORED", "NEAR_WHITE",
           "censored", "white_level"]

CENSORED = 2.0
"""A channel value below this many absolute noise levels (0.4 % of the history's median green) is taken as censored
at 0 — a dark channel clipped after the black level or a colour matrix — and carries no weight."""

NEAR_WHITE = 0.95
"""A channel value at or above this fraction of the white level (observations are 0…1 of it) may be clipped — the
region's brightest pixels at white, its mean biased low — and carries no weight either. Found on the development
camera Point Grey Grasshopper2 through the independent raw pipeline (``benchmarks/rawsim.py``): its blue saturates
on bright patches when the exposure is metered on all channels; the 5 % margin is the same as
:data:`illumon.sensitivity.default.NEAR_CLIP`'s."""


def white_level(values: NDArray[np.float64]) -> float:
    """The white level of observations: 1 when every value is within it (observations are 0…1 of the white level),
    ``inf`` when some exceed it (renderings at an arbitrary scale, e.g. the noise-free paper protocol: no clip level
    is known, nothing is censored at the top)."""
    top = np.nanmax(values) if np.isfinite(values).any() else 0.0
    return 1.0 if top <= 1.0 + 1e-9 else float("inf")


def censored(values: NDArray[np.float64], absolute_error: float, white: float) -> NDArray[np.bool_]:
    """Channel values that carry no weight: below :data:`CENSORED` absolute noise levels (clipped at 0) or at/above
    :data:`NEAR_WHITE` of the ``white`` level (possibly clipped; both on the values' scale)."""
    return (values < CENSORED * absolute_error) | (values >= NEAR_WHITE * white)


@dataclass
class RetrievalResult:
    """Per-frame illuminants and the static patches' reflectances recovered from a history.

    Attributes
    ----------
    frames, patches
        Identifiers, as in the observations.
    spectra
        Estimated illuminant spectra (F × 61), 100 at 560 nm.
    xy, cct, duv
        Chromaticity, correlated colour temperature (K) and Duv of each estimate.
    white
        Camera response to a perfect white diffuser under each estimate (F × 3), green = 1.
    gains
        White-balance gains (F × 3), ``gain_g = 1``.
    exposures
        Relative exposure of each frame (F,), or NaN where a method does not estimate it.
    reflectances
        Recovered patch reflectances (P × 61) on an absolute scale fixed by the reflectance prior, or NaN.
    method
        Name of the method that produced it.
    info
        Diagnostics: cost, iterations, starts, condition numbers.
    """

    frames: list[str]
    patches: list[str]
    spectra: NDArray[np.float64]
    xy: NDArray[np.float64]
    cct: NDArray[np.float64]
    duv: NDArray[np.float64]
    white: NDArray[np.float64]
    gains: NDArray[np.float64]
    exposures: NDArray[np.float64]
    reflectances: NDArray[np.float64]
    method: str
    times: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)


def imaging_operators(
    sensitivities: NDArray[np.float64], illuminant_basis: NDArray[np.float64], reflectance: ReflectanceBasis
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Precompute ``K[k] = Cᵀ diag(E_k) S`` (nb × 3 × K) and ``w[k] = Cᵀ E_k`` (nb × 3).

    With illuminant ``E = Σ_k a_k E_k`` and reflectance ``R = S σ`` the camera response is ``(Σ_k a_k K[k]) σ`` and the
    camera white ``Σ_k a_k w[k]``: both linear, so solvers never touch the wavelength axis in their loops.
    """
    c = np.asarray(sensitivities, dtype=float)
    e = np.asarray(illuminant_basis, dtype=float)
    s = reflectance.functions
    k = np.einsum("lc,lk,lj->kcj", c, e, s)
    w = e.T @ c
    return k, w


def make_result(
    obs: Observations,
    sensitivities: NDArray[np.float64],
    spectra: NDArray[np.float64],
    method: str,
    *,
    xy: NDArray[np.float64] | None = None,
    exposures: NDArray[np.float64] | None = None,
    reflectances: NDArray[np.float64] | None = None,
    info: dict | None = None,
) -> RetrievalResult:
    """Assemble a :class:`RetrievalResult` from estimated spectra (chromaticity from ``xy`` when the model knows it)."""
    f = len(obs.frames)
    if xy is None:
        xy = xy_from_spectrum(spectra)
    cct, duv = cct_duv_from_xy(xy)
    white = camera_white(sensitivities, spectra)
    white = white / white[:, 1:2]
    return RetrievalResult(
        frames=list(obs.frames),
        patches=list(obs.patches),
        spectra=spectra,
        xy=xy,
        cct=cct,
        duv=duv,
        white=white,
        gains=gains_from_white(white),
        exposures=exposures if exposures is not None else np.full(f, np.nan),
        reflectances=reflectances if reflectances is not None else np.full((len(obs.patches), spectra.shape[1]), np.nan),
        method=method,
        times=list(obs.times),
        info=info or {},
    )


def grey_world(obs: Observations) -> NDArray[np.float64]:
    """Gray-world camera white per frame (F × 3): the mean of the frame's observed patches (Buchsbaum 1980).

    References
    ----------
    .. [Buchsbaum1980] Buchsbaum, 1980: grey world.
    """
    # np.nanmean over the patches of the finite values (np.where → NaN, then NaN → 0, counts and sum) without its
    # copies: the values with 0 for those not finite summed by numpy over the same axis of an array of the same shape
    # and layout, their count and the same division (issue 29: 0.07–0.24 s → ~0.03 s for 100k frames; the same
    # whites, bit for bit, and the same warning for a frame without a patch)
    ok = np.isfinite(obs.values)
    count = count_over_patches(ok, np.intp)
    total = np.where(ok, obs.values, 0.0).sum(axis=1)
    if (count == 0).any():
        warnings.warn("Mean of empty slice", RuntimeWarning, stacklevel=2)  # as np.nanmean warns
    with np.errstate(invalid="ignore", divide="ignore"):
        white = np.true_divide(total, count, out=total, casting="unsafe")
    return white / white[:, 1:2]


def grey_world_mired(obs: Observations, sensitivities: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-frame reciprocal temperature whose camera white is closest in chromaticity to the gray-world white."""
    grid = np.linspace(45.0, 380.0, 200)
    cct = 1e6 / grid
    xy = xy_from_cct_duv(cct, daylight_locus_duv(cct))
    whites = daylight_spectrum(xy) @ sensitivities
    chrom = np.log(whites[:, [0, 2]] / whites[:, 1:2])
    gw = grey_world(obs)
    gchrom = np.log(np.clip(gw[:, [0, 2]], 1e-9, None))
    out = np.empty(len(gchrom))
    c0, c1 = chrom[:, 0], chrom[:, 1]
    for i in range(0, len(gchrom), _MIRED_CHUNK):  # frames × grid distances a chunk at a time (100k: 480 MB at once)
        g = gchrom[i:i + _MIRED_CHUNK]
        # the two squared differences added as the sum over their axis adds them (a + b), without the frames × grid
        # × 2 temporary and its reduction over an axis of two (issue 29: ~5 × faster; the same distances, bit for bit)
        d = (g[:, 0:1] - c0) ** 2
        d += (g[:, 1:2] - c1) ** 2
        out[i:i + _MIRED_CHUNK] = grid[np.argmin(d, axis=1)]
    return out


_MIRED_CHUNK = 2048
"""Frames :func:`grey_world_mired` measures against its grid at once (2 048 × 200 distances, ~3 MB: 8 192's ~13 MB
took a 100k-frame history ~0.04 s against ~0.03 s; the same distances)."""
