"""Multi-frame illuminant retrieval from static scene patches with unknown reflectances.

Methods (``retrieve_illuminants(..., method=...)``):

``joint`` (default)
    illumon's solver of Marguier & Süsstrunk's model: all frames' daylight parameters, exposures and the patches'
    reflectances fitted jointly by bounded non-linear least squares (variable projection, then a full polish), with
    Gaussian priors on reflectance and daylight (:func:`.joint.illuminant_retrieval_illumon`).
``marguier2007``
    J. Marguier & S. Süsstrunk, "Illuminant retrieval for fixed location cameras", CIC 2007, as written
    (:mod:`illumon.retrieval.marguier2007`).
``gray_world``
    Buchsbaum's grey world on the same patches, the baseline (:func:`illuminant_retrieval_Buchsbaum1980`).

References
----------
.. [Marguier2007] Marguier & Süsstrunk, CIC 2007.
.. [Buchsbaum1980] Buchsbaum, 1980: grey world.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from .._blas import single_blas_thread
from ..camera.formation import gains_from_white
from ..daylight import daylight_locus_duv, daylight_spectrum, xy_from_cct_duv
from ..observations import Observations
from ..registry import Registry
from .common import RetrievalResult, grey_world, make_result
from .joint import illuminant_retrieval_illumon
from .marguier2007 import illuminant_retrieval_Marguier2007

__all__ = [
    "METHODS",
    "MULTI_FRAME",
    "RetrievalResult",
    "retrieve_illuminants",
    "illuminant_retrieval_illumon",
    "illuminant_retrieval_Marguier2007",
    "illuminant_retrieval_Buchsbaum1980",
]


def illuminant_retrieval_Buchsbaum1980(obs: Observations, sensitivities: NDArray[np.float64]) -> RetrievalResult:
    """Gray-world baseline (Buchsbaum 1980): the camera white of each frame is the mean of its patches.

    The illuminant reported is the CIE daylight whose camera white is closest in chromaticity to that mean.

    References
    ----------
    .. [Buchsbaum1980] Buchsbaum, 1980: grey world.
    """
    gw = grey_world(obs)
    mired = np.linspace(40.0, 400.0, 721)
    cct = 1e6 / mired
    xy = xy_from_cct_duv(cct, daylight_locus_duv(cct))
    spectra = daylight_spectrum(xy)
    whites = spectra @ sensitivities
    chrom = np.log(whites[:, [0, 2]] / whites[:, 1:2])
    d = ((np.log(np.clip(gw[:, [0, 2]], 1e-9, None))[:, None] - chrom[None]) ** 2).sum(-1)
    k = np.argmin(d, axis=1)
    res = make_result(obs, sensitivities, spectra[k], "gray_world", xy=xy[k])
    res.white = gw
    res.gains = gains_from_white(gw)
    return res


METHODS: Registry[Callable[..., RetrievalResult]] = Registry({
    "joint": (illuminant_retrieval_illumon,
              "illumon's joint fit of every frame's daylight and exposure and the patches' reflectances"),
    "marguier2007": (illuminant_retrieval_Marguier2007, "Marguier & Süsstrunk (CIC 2007) as published"),
    "gray_world": (illuminant_retrieval_Buchsbaum1980, "Buchsbaum's grey world on the same patches, the baseline"),
})
"""Retrieval methods by name (``illumon estimate --method``, the service's ``ILLUMON_REFIT_METHOD``)."""

MULTI_FRAME = frozenset({"joint", "marguier2007"})
"""The methods that learn the patches' reflectances from several frames (gray-world reads each frame alone)."""


@single_blas_thread
def retrieve_illuminants(
    observations: Observations, sensitivities: NDArray[np.float64], method: str = "joint", **kwargs
) -> RetrievalResult:
    """Retrieve every frame's illuminant from static patches, with the named method (see module docstring).

    Parameters
    ----------
    observations
        Patch means: at least two frames for the methods of :data:`MULTI_FRAME`, one for gray-world.
    sensitivities
        Camera sensitivities on the grid (61 × 3).
    method
        One of :data:`METHODS`.
    **kwargs
        Passed to the method.

    Returns
    -------
    RetrievalResult
        Per-frame illuminant (CCT, Duv, xy, spectrum), camera white, gains and recovered patch reflectances.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    if method in MULTI_FRAME and len(observations.frames) < 2:
        raise ValueError("at least two frames are needed to retrieve illuminants from unknown reflectances")
    if method in MULTI_FRAME and observations.present.sum(axis=0).max() < 2:
        raise ValueError("no patch is seen in two frames")
    return METHODS[method](observations, sensitivities, **kwargs)
