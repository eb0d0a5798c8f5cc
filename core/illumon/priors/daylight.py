"""Gaussian prior on daylight spectra, built from measured daylight (the 2600 Granada spectra).

:class:`DaylightPrior` models daylight spectra scaled to unit mean over 400–700 nm as ``mean + components @ y`` with
``y ~ N(coefficient_mean, coefficient_covariance)``. It feeds the single-chart sensitivity estimators
(:mod:`illumon.sensitivity`) and the diagnosis's mixture of measured skies (:mod:`illumon.diagnosis.spectral`). It can
be rebuilt from arrays (:func:`build_daylight_prior`); the shipped version (``illumon/data/daylight_prior.csv|json``)
is derived from all Granada spectra by ``tools/build_sensitivity_priors.py``.

References
----------
.. [HernandezAndres2001] Hernández-Andrés et al., JOSA A 2001.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._data import shipped_csv, shipped_json

__all__ = ["DaylightPrior", "build_daylight_prior", "default_daylight_prior"]


@dataclass(frozen=True)
class DaylightPrior:
    """Gaussian prior on daylight spectra scaled to unit mean over the grid.

    Attributes
    ----------
    mean
        Mean spectrum (61,).
    components
        Orthonormal principal components (61 × J).
    coefficient_mean, coefficient_covariance
        Gaussian on the coefficients (J,), (J × J).
    provenance
        What built it.
    """

    mean: NDArray[np.float64]
    components: NDArray[np.float64]
    coefficient_mean: NDArray[np.float64]
    coefficient_covariance: NDArray[np.float64]
    provenance: dict = field(default_factory=dict)

    @property
    def size(self) -> int:
        """Number of components J."""
        return int(self.components.shape[1])

    @property
    def basis(self) -> NDArray[np.float64]:
        """Mean followed by the components (61 × (J + 1)), for linear least-squares fits."""
        return np.column_stack([self.mean, self.components])

    def spectra(self, coefficients: ArrayLike) -> NDArray[np.float64]:
        """Spectra (…, 61) for coefficients (…, J)."""
        return self.mean + np.asarray(coefficients, dtype=float) @ self.components.T


def build_daylight_prior(
    spectra: ArrayLike, n_components: int = 4, provenance: dict | None = None
) -> DaylightPrior:
    """Build a :class:`DaylightPrior` from measured daylight spectra (n × 61), each scaled to unit mean
    first.

    Parameters
    ----------
    spectra
        Measured daylight on the grid (n × 61), any scale.
    n_components
        Principal components kept.
    provenance
        Stored with the prior.

    References
    ----------
    .. [HernandezAndres2001] Hernández-Andrés et al., JOSA A 2001: the Granada spectra and their principal
       components.
    """
    d = np.asarray(spectra, dtype=float)
    d = d / d.mean(axis=1, keepdims=True)
    mean = d.mean(0)
    _, _, vt = np.linalg.svd(d - mean, full_matrices=False)
    comps = vt[:n_components].T
    for j in range(n_components):
        if comps[np.argmax(np.abs(comps[:, j])), j] < 0:
            comps[:, j] *= -1
    coef = (d - mean) @ comps
    return DaylightPrior(
        mean=mean,
        components=comps,
        coefficient_mean=coef.mean(0),
        coefficient_covariance=np.cov(coef, rowvar=False),
        provenance=dict(provenance or {"spectra": int(d.shape[0])}),
    )


@lru_cache(maxsize=1)
def default_daylight_prior() -> DaylightPrior:
    """The shipped daylight prior, from the 2600 Granada spectra (see ``illumon/data/README.md``)."""
    values, names = shipped_csv("daylight_prior.csv")
    meta = shipped_json("daylight_prior.json")
    col = {n: i for i, n in enumerate(names)}
    j = int(meta["n_components"])
    return DaylightPrior(
        mean=values[:, col["mean"]],
        components=np.column_stack([values[:, col[f"pc{i + 1}"]] for i in range(j)]),
        coefficient_mean=np.asarray(meta["coefficient_mean"], dtype=float),
        coefficient_covariance=np.asarray(meta["coefficient_covariance"], dtype=float),
        provenance={k_: meta[k_] for k_ in ("spectra", "source", "licence")},
    )
