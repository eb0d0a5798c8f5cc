"""Surface reflectance basis and prior.

Reflectances are expressed with 8 basis functions (Marguier & Süsstrunk 2007 use 8 principal components of Munsell,
Macbeth and natural spectra; Maloney 1986 shows 6–8 suffice). illumon's basis is the first 8 right singular vectors
of 1835 measured reflectances (Munsell matte, Vrhel objects, Joensuu natural colours, DuPont paints, SFU surfaces),
each set weighted equally; it ships in ``illumon/data/reflectance_basis.csv`` with the coefficient mean and covariance
of those sets (``reflectance_prior.json``), which serve as the Gaussian reflectance prior (Kinoshita & Kiya 2023).

References
----------
.. [Marguier2007] Marguier & Süsstrunk, CIC 2007: 8 principal components of measured reflectances.
.. [Maloney1986] Maloney, JOSA A 1986.
.. [Kinoshita2023] Kinoshita & Kiya, 2023: the Gaussian prior on reflectance coefficients.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import colour
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..spectra import GRID, resample_columns
from ._data import shipped_csv, shipped_json

__all__ = ["ReflectanceBasis", "reflectance_basis", "colourchecker_reflectances", "unseen_reflectances"]


@dataclass(frozen=True)
class ReflectanceBasis:
    """An orthonormal reflectance basis on the grid with a Gaussian prior on its coefficients.

    Attributes
    ----------
    functions
        Basis functions (61 × K), orthonormal columns.
    prior_mean, prior_covariance
        Mean (K,) and covariance (K × K) of measured reflectances' coefficients.
    provenance
        What data built it.
    """

    functions: NDArray[np.float64]
    prior_mean: NDArray[np.float64]
    prior_covariance: NDArray[np.float64]
    provenance: dict

    @property
    def size(self) -> int:
        """Number of components K."""
        return self.functions.shape[1]

    def coefficients(self, reflectance: ArrayLike) -> NDArray[np.float64]:
        """Least-squares coefficients (…, K) of grid reflectances (…, 61)."""
        return np.asarray(reflectance, dtype=float) @ self.functions

    def spectra(self, coefficients: ArrayLike) -> NDArray[np.float64]:
        """Reflectance spectra (…, 61) from coefficients (…, K)."""
        return np.asarray(coefficients, dtype=float) @ self.functions.T


@lru_cache(maxsize=1)
def reflectance_basis() -> ReflectanceBasis:
    """The shipped 8-component reflectance basis (see module docstring for provenance)."""
    funcs, _ = shipped_csv("reflectance_basis.csv")
    prior = shipped_json("reflectance_prior.json")
    return ReflectanceBasis(
        functions=funcs,
        prior_mean=np.asarray(prior["coefficient_mean"]),
        prior_covariance=np.asarray(prior["coefficient_covariance"]),
        provenance={k: prior[k] for k in ("sets", "energy_captured", "rmse_reconstruction")},
    )


@lru_cache(maxsize=8)
def colourchecker_reflectances(name: str = "BabelColor Average") -> tuple[list[str], NDArray[np.float64]]:
    """The 24 ColorChecker reflectances shipped with colour-science, in standard order, on the grid (24 × 61)."""
    if name not in colour.SDS_COLOURCHECKERS:
        known = ", ".join(k for k in colour.SDS_COLOURCHECKERS if " " in k)
        raise KeyError(f"unknown chart {name!r}; known: {known}")
    sds = colour.SDS_COLOURCHECKERS[name]
    names = list(sds)
    out = []
    for n in names:
        sd = sds[n]
        out.append(resample_columns(sd.wavelengths, sd.values[:, None], GRID)[:, 0])
    return names, np.clip(np.asarray(out), 0.0, 1.0)


@lru_cache(maxsize=1)
def unseen_reflectances() -> tuple[list[str], NDArray[np.float64]]:
    """ColorChecker (BabelColor average), CIE 1995 TCS01–14 and NIST CQS 9.0 VS1–15, all shipped with colour-science
    (53 spectra, on the grid), used by :mod:`illumon.simulation.scenarios` to simulate scenes. The ColorChecker and TCS spectra
    were never used to build the shipped basis; the fifteen VS spectra were (they are Munsell matt chips, identical
    to spectra of ``munsell_matt_1269``), so scoring that must not see the basis' surfaces uses the first 38 only
    (``benchmarks/rawsim.py``'s score surfaces)."""
    from colour.quality.datasets import SDS_TCS, SDS_VS

    names, cc = colourchecker_reflectances("BabelColor Average")
    names = [f"cc_{n}" for n in names]
    out = [cc]
    for label, sds in (("tcs", SDS_TCS["CIE 1995"]), ("vs", SDS_VS["NIST CQS 9.0"])):
        for key, sd in sds.items():
            names.append(f"{label}_{key}")
            out.append(resample_columns(sd.wavelengths, sd.values[:, None], GRID)[:, 0][None])
    return names, np.clip(np.concatenate(out), 0.0, 1.0)
