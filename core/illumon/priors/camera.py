"""Gaussian prior on camera spectral sensitivities, built from measured cameras.

:class:`CameraPrior` models the 183-vector of a camera's (R, G, B) sensitivities on :data:`~illumon.spectra.GRID`,
max-normalised over all channels, as ``mean + components @ z`` with ``z ~ N(0, diag(variances))`` (joint principal
components, so correlations *between* channels are kept). It also carries per-channel uncentred eigenvectors, the basis
Jiang et al. use. It feeds the single-chart sensitivity estimators (:mod:`illumon.sensitivity`) and stands for the
camera nobody measured (:mod:`illumon.camera.calibration`).

It can be rebuilt from arrays (:func:`build_camera_prior`), which is what the leave-one-camera-out tests and benchmark
do: the camera under test is never in its own prior. The shipped version (``illumon/data/camera_prior.csv|json``) is
derived from all 24 measured cameras by ``tools/build_sensitivity_priors.py``; so is the *rendered* cameras' prior
(:func:`rendered_camera_prior`, ``illumon/data/rendered_camera_prior.csv|json``): the same cameras each carried to sRGB
primaries with a D65 daylight preset as a camera's pipeline does it
(:func:`illumon.camera.primaries.to_srgb_primaries`), what a camera with its colour matrix on delivers.

References
----------
.. [Jiang2013] Jiang et al., WACV 2013.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import colour
import numpy as np
from colour.recovery import PCA_Jiang2013
from numpy.typing import ArrayLike, NDArray

from ..spectra import WAVELENGTHS
from ._data import shipped_csv, shipped_json

__all__ = [
    "SMOOTH_FLOOR",
    "CameraPrior",
    "camera_prior_covariance",
    "smooth_kernel",
    "build_camera_prior",
    "default_camera_prior",
    "rendered_camera_prior",
    "max_normalise",
    "jiang2013_channel_bases",
]

N_WL = WAVELENGTHS.size


def max_normalise(sensitivities: ArrayLike) -> NDArray[np.float64]:
    """Sensitivities (61 × 3) divided by their maximum over all channels."""
    c = np.asarray(sensitivities, dtype=float)
    return c / c.max()


@dataclass(frozen=True)
class CameraPrior:
    """Gaussian prior on camera sensitivities (see module docstring).

    Attributes
    ----------
    mean
        Mean sensitivities (61 × 3), of max-normalised cameras.
    components
        Joint principal components (183 × K), columns are the stacked ``[r; g; b]`` curves, orthonormal.
    variances
        Variance of each component's coefficient (K,).
    channel_bases
        Per-channel uncentred eigenvectors (3 × 61 × J), largest first (Jiang et al. 2013's basis).
    residual_variance
        Mean per-sample variance left outside the K components (used as a white-noise floor of the prior).
    provenance
        What built it.
    """

    mean: NDArray[np.float64]
    components: NDArray[np.float64]
    variances: NDArray[np.float64]
    channel_bases: NDArray[np.float64]
    residual_variance: float
    provenance: dict = field(default_factory=dict)

    @property
    def size(self) -> int:
        """Number of joint components K."""
        return int(self.components.shape[1])

    def spectra(self, coefficients: ArrayLike) -> NDArray[np.float64]:
        """Sensitivities (61 × 3) for joint coefficients (K,)."""
        v = self.mean.T.reshape(-1) + self.components @ np.asarray(coefficients, dtype=float)
        return v.reshape(3, N_WL).T

    def covariance(self, floor: float | None = None) -> NDArray[np.float64]:
        """Prior covariance of the stacked 183-vector, with a white floor (default: the residual variance)."""
        f = self.residual_variance if floor is None else floor
        return (self.components * self.variances) @ self.components.T + f * np.eye(3 * N_WL)

    def truncated(self, k: int) -> CameraPrior:
        """The same prior keeping the first ``k`` joint components."""
        return CameraPrior(
            self.mean,
            self.components[:, :k],
            self.variances[:k],
            self.channel_bases,
            self.residual_variance + float(self.variances[k:].sum()) / (3 * N_WL),
            self.provenance,
        )


def build_camera_prior(
    cameras: Sequence[ArrayLike],
    n_components: int | None = None,
    n_channel_basis: int = 3,
    provenance: dict | None = None,
) -> CameraPrior:
    """Build a :class:`CameraPrior` from measured sensitivities.

    Parameters
    ----------
    cameras
        Sensitivities on the grid (each 61 × 3); each is max-normalised over all channels first.
    n_components
        Joint components kept (default: all, ``len(cameras) − 1``).
    n_channel_basis
        Per-channel eigenvectors kept for the Jiang et al. (2013) basis.
    provenance
        Stored with the prior.

    Notes
    -----
    The per-channel basis follows Jiang et al. (2013) as implemented by :func:`colour.recovery.PCA_Jiang2013`:
    eigenvectors of the uncentred scatter matrix of each channel's curves, each curve normalised to a maximum of 1.

    References
    ----------
    .. [Jiang2013] Jiang et al., WACV 2013: the per-channel basis.
    """
    arr = np.stack([max_normalise(c) for c in cameras])  # n × 61 × 3
    n = arr.shape[0]
    if n < 2:
        raise ValueError("a camera prior needs at least two cameras")
    stacked = arr.transpose(0, 2, 1).reshape(n, -1)  # n × 183, [r; g; b]
    mean = stacked.mean(0)
    _, s, vt = np.linalg.svd(stacked - mean, full_matrices=False)
    var = s**2 / max(n - 1, 1)
    k = min(n - 1, n_components if n_components is not None else n - 1)
    comps = vt[:k].T
    for j in range(k):
        if comps[np.argmax(np.abs(comps[:, j])), j] < 0:
            comps[:, j] *= -1
    residual = float(var[k:].sum()) / stacked.shape[1] + 1e-6
    bases = jiang2013_channel_bases(arr, n_channel_basis)
    return CameraPrior(
        mean=mean.reshape(3, N_WL).T,
        components=comps,
        variances=var[:k],
        channel_bases=np.stack(bases),
        residual_variance=residual,
        provenance=dict(provenance or {"cameras": n}),
    )


def jiang2013_channel_bases(cameras: Sequence[ArrayLike], n_basis: int = 3) -> NDArray[np.float64]:
    """Per-channel eigenvectors (3 × 61 × ``n_basis``) of Jiang et al. (2013), via
    :func:`colour.recovery.PCA_Jiang2013`.

    Each channel curve is normalised to a maximum of 1 and the eigenvectors of the uncentred scatter matrix are
    taken, largest eigenvalue first, signs fixed so that each vector's largest excursion is positive.

    References
    ----------
    .. [Jiang2013] Jiang et al., WACV 2013.
    """
    msds = {
        str(i): colour.MultiSpectralDistributions(np.asarray(c, dtype=float), WAVELENGTHS, labels=list("RGB"))
        for i, c in enumerate(cameras)
    }
    vectors = PCA_Jiang2013(msds, n_basis)
    bases = []
    for v in vectors:
        v = np.array(v, dtype=float)
        for j in range(v.shape[1]):
            if v[np.argmax(np.abs(v[:, j])), j] < 0:
                v[:, j] *= -1
        bases.append(v)
    return np.stack(bases)


SMOOTH_FLOOR = 1.6e-3
"""Variance of the smooth prior floor outside the PCA span of the training cameras. Chosen leave-one-manufacturer-out
on the development cameras (``benchmarks/rawsim.py``: Nikon and Point Grey, each manufacturer held out in turn, charts
of the linear model and of the raw pipeline under development daylight): mean RMSE 0.046 at 1e-4 (the former
value, chosen leave-one-camera-out), 0.042 at 4e-4, 0.038 at 1.6e-3, 0.039 at 6.4e-3, 0.047 at 2.5e-2 (length
30 nm; 60 nm and 20 nm were worse). A prior that has not seen the manufacturer must let curves leave the span of the
others' more freely."""


def smooth_kernel(length_nm: float) -> NDArray[np.float64]:
    """Squared-exponential correlation (61 × 61) between grid wavelengths with length scale ``length_nm``."""
    dl = WAVELENGTHS[:, None] - WAVELENGTHS[None, :]
    return np.exp(-0.5 * (dl / length_nm) ** 2)


def camera_prior_covariance(
    prior: CameraPrior, floor: float = SMOOTH_FLOOR, length_nm: float = 30.0
) -> NDArray[np.float64]:
    """Prior covariance (183 × 183) of stacked sensitivities: PCA part plus a smooth per-channel floor."""
    pca = (prior.components * prior.variances) @ prior.components.T
    return pca + floor * np.kron(np.eye(3), smooth_kernel(length_nm)) + 1e-8 * np.eye(pca.shape[0])


@lru_cache(maxsize=1)
def default_camera_prior() -> CameraPrior:
    """The shipped camera prior, built from all 24 measured cameras (see ``illumon/data/README.md``)."""
    return _shipped_camera_prior("camera_prior")


@lru_cache(maxsize=1)
def rendered_camera_prior() -> CameraPrior:
    """The shipped prior of rendered cameras: the 24 measured cameras each carried to sRGB primaries with a D65
    daylight preset (:func:`illumon.camera.primaries.to_srgb_primaries`), as a camera with its colour matrix on
    delivers them (see ``illumon/data/README.md``)."""
    return _shipped_camera_prior("rendered_camera_prior")


def _shipped_camera_prior(stem: str) -> CameraPrior:
    """A camera prior shipped as ``illumon/data/<stem>.csv|json`` (``tools/build_sensitivity_priors.py``)."""
    values, names = shipped_csv(f"{stem}.csv")
    meta = shipped_json(f"{stem}.json")
    col = {n: i for i, n in enumerate(names)}
    mean = values[:, [col["mean_r"], col["mean_g"], col["mean_b"]]]
    k = int(meta["n_components"])
    comps = np.column_stack(
        [np.concatenate([values[:, col[f"pc{j + 1}_{c}"]] for c in "rgb"]) for j in range(k)]
    )
    nb = int(meta["n_channel_basis"])
    bases = np.stack(
        [np.column_stack([values[:, col[f"jiang{j + 1}_{c}"]] for j in range(nb)]) for c in "rgb"]
    )
    return CameraPrior(
        mean=mean,
        components=comps,
        variances=np.asarray(meta["variances"], dtype=float),
        channel_bases=bases,
        residual_variance=float(meta["residual_variance"]),
        provenance={k_: meta[k_] for k_ in ("cameras", "source", "licence")},
    )
