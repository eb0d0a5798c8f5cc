"""Reproducible evaluation scenarios built from measured spectra, shared by tests and benchmarks.

* :func:`paper_protocol` — Marguier & Süsstrunk's synthetic protocol (CIC 2007, Tables 1–3): a ColorChecker seen by
  a measured camera under CIE D40…D100, 6 patches, 2–4 images.
* :func:`measured_daylight_history` — a fixed camera over many frames lit by measured Granada daylight, with patches
  the reflectance basis never saw (:func:`illumon.priors.unseen_reflectances`).

Both need the measured data beside the project (:mod:`illumon.simulation.datasets`).
"""

from __future__ import annotations

import numpy as np

from ..camera import DEFAULT_NOISE, CameraNoise
from ..daylight import cie_d_cct, daylight_locus_xy, daylight_spectrum, theta_curve
from ..priors import colourchecker_reflectances, unseen_reflectances
from . import datasets
from .simulate import SimulatedHistory, simulate_history

__all__ = ["PAPER_TABLES", "PAPER_PATCH_SETS", "paper_cct", "paper_protocol", "measured_daylight_history"]

PAPER_TABLES: dict[int, list[tuple[int, ...]]] = {
    1: [(40, 50), (40, 90), (40, 100), (65, 80), (65, 90), (65, 100), (80, 90), (80, 100)],
    2: [(40, 50, 60), (40, 50, 80), (40, 50, 100), (65, 75, 85), (65, 75, 100), (75, 80, 85), (80, 90, 100)],
    3: [
        (40, 50, 60, 70), (40, 50, 80, 90), (40, 50, 80, 100), (40, 60, 80, 100),
        (55, 65, 75, 95), (65, 75, 85, 95), (65, 75, 90, 100), (75, 80, 85, 90),
    ],
}
"""Illuminant combinations of the paper's Tables 1–3 (CIE D-series, hundreds of K)."""

PAPER_PATCH_SETS: list[tuple[int, ...]] = [
    (0, 1, 2, 3, 4, 5),  # first row: natural colours
    (6, 8, 11, 13, 15, 17),  # second/third rows: saturated
    (1, 3, 7, 12, 18, 21),  # mixed with neutrals
    (0, 5, 9, 14, 16, 22),
]
"""Which 6 ColorChecker patches (0-based, standard order) stand for the paper's unspecified 6 patches."""


def paper_cct(temps_hundreds: tuple[int, ...]) -> np.ndarray:
    """Correlated colour temperatures (K) of the protocol's CIE illuminants D40…D100 (:func:`~illumon.daylight.cie_d_cct`
    of the nominal temperatures, given in hundreds of K)."""
    return cie_d_cct(np.asarray(temps_hundreds, dtype=float) * 100)


def paper_protocol(
    camera: str,
    temps_hundreds: tuple[int, ...],
    patches: tuple[int, ...],
    *,
    noise: CameraNoise | None,
    seed: int = 0,
    illuminant_scale: str = "cie",
) -> SimulatedHistory:
    """One case of the paper's protocol: CIE D illuminants (:func:`paper_cct`) on a ColorChecker.

    ``illuminant_scale`` sets each illuminant's brightness, which matters only without noise (the noise model's
    auto-exposure rescales every frame): ``"cie"`` is the CIE normalisation (100 at 560 nm); ``"model"`` is the one
    Marguier & Süsstrunk's model assumes, ``ε1 = 1`` on the θ-curve basis (:func:`illumon.daylight.theta_curve`,
    built from unit-norm D40…D100), so that eq. (3) compares absolute responses at the scale they were rendered;
    ``"unit"`` is unit norm on the wavelength grid (equal power, the scale ``joint(exposure="shared")`` assumes).
    """
    e = daylight_spectrum(daylight_locus_xy(paper_cct(temps_hundreds)))
    if illuminant_scale == "model":
        e = e / np.linalg.lstsq(theta_curve().basis, e.T, rcond=None)[0][0][:, None]
    elif illuminant_scale == "unit":
        e = e / np.linalg.norm(e, axis=1, keepdims=True)
    elif illuminant_scale != "cie":
        raise ValueError(f"illuminant_scale must be 'cie', 'model' or 'unit', not {illuminant_scale!r}")
    _, cc = colourchecker_reflectances("BabelColor Average")
    return simulate_history(datasets.load_camera(camera), e, cc[list(patches)], noise=noise, rng=seed)


def measured_daylight_history(
    camera: str,
    *,
    frames: int = 30,
    patches: int = 10,
    seed: int = 0,
    contiguous: bool = False,
    noise: CameraNoise | None = DEFAULT_NOISE,
    missing_fraction: float = 0.0,
) -> SimulatedHistory:
    """A fixed camera lit by measured Granada daylight with unseen patch reflectances.

    ``contiguous`` takes a run of consecutive Granada spectra (the file is in acquisition order, so a run is
    a stretch of days) instead of a random draw.
    """
    rng = np.random.default_rng(seed)
    _, daylight = datasets.load_granada_daylight()
    if contiguous:
        start = int(rng.integers(0, daylight.shape[0] - frames))
        e = daylight[start : start + frames]
    else:
        e = daylight[rng.choice(daylight.shape[0], frames, replace=False)]
    _, refl = unseen_reflectances()
    r = refl[rng.choice(refl.shape[0], patches, replace=False)]
    return simulate_history(
        datasets.load_camera(camera), e, r, noise=noise, rng=rng, missing_fraction=missing_fraction
    )
