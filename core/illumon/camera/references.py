"""Surfaces of known reflectance seen by a camera: a grey card, a ColorChecker, or any measured surface.

A reference is a patch id mapped to its reflectance spectrum on :data:`~illumon.spectra.GRID` (61 values, 0…1). It
typically appears in one frame (a card held up at installation); :mod:`illumon.camera.calibration` uses it to pin what
an unmeasured camera's sensitivities cannot tell: a grey card fixes each channel's scale, a chart also the mixing of
channels by a colour matrix.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..reflectance import colourchecker_reflectances
from ..spectra import GRID, SpectralInputError, read_spectral_csv, resample_columns

__all__ = [
    "colorchecker_references",
    "grey_card_reference",
    "read_known_reflectances",
    "check_known_reflectances",
    "references_kind",
]


def colorchecker_references(prefix: str = "chart:", chart: str = "BabelColor Average") -> dict[str, NDArray[np.float64]]:
    """The 24 ColorChecker patches as references, ids ``{prefix}01`` … ``{prefix}24`` in the chart's standard order
    (dark skin … black), reflectances from colour-science's ``chart`` data."""
    _, spectra = colourchecker_reflectances(chart)
    return {f"{prefix}{i + 1:02d}": spectra[i].copy() for i in range(spectra.shape[0])}


def grey_card_reference(patch_id: str = "grey", reflectance: float = 0.18) -> dict[str, NDArray[np.float64]]:
    """A spectrally flat grey card (only its flatness matters for white balance; the level sets exposure)."""
    if not 0 < reflectance <= 1:
        raise ValueError("a grey card's reflectance must lie in (0, 1]")
    return {patch_id: np.full(GRID.wavelengths.size, float(reflectance))}


def check_known_reflectances(known: Mapping[str, object], source: str = "known reflectances") -> dict[str, NDArray[np.float64]]:
    """Validate references: every spectrum 61 finite values within 0…1 (a hair of measurement noise above 1 is
    clipped). Raises :class:`~illumon.spectra.SpectralInputError` naming the patch otherwise."""
    out: dict[str, NDArray[np.float64]] = {}
    for pid, spectrum in known.items():
        r = np.asarray(spectrum, dtype=float)
        if r.shape != (GRID.wavelengths.size,) or not np.all(np.isfinite(r)):
            raise SpectralInputError(f"{source}: patch {pid!r}: expected {GRID.wavelengths.size} finite values on the grid")
        if r.min() < -0.005 or r.max() > 1.005:
            raise SpectralInputError(
                f"{source}: patch {pid!r}: reflectance must lie within 0…1 (found {r.min():.3g}…{r.max():.3g})"
            )
        out[str(pid)] = np.clip(r, 0.0, 1.0)
    if not out:
        raise SpectralInputError(f"{source}: no reference patches")
    return out


def read_known_reflectances(path: str | Path) -> dict[str, NDArray[np.float64]]:
    """Read ``KNOWN.csv`` (``wavelength_nm,<patch id>,…``; any sampling covering 400–700 nm; values 0…1).

    Returns patch id → reflectance on the grid. Errors (:class:`~illumon.spectra.SpectralInputError`) name the file
    and the problem: not covering 400–700 nm, a value outside 0…1, no header with patch ids.
    """
    source = str(path)
    wl, values, names = read_spectral_csv(path)
    if names and names[0] == "s1" and all(n == f"s{j + 1}" for j, n in enumerate(names)):
        raise SpectralInputError(f"{source}: needs a header row wavelength_nm,<patch id>,… naming the patches")
    if len(set(names)) != len(names):
        raise SpectralInputError(f"{source}: repeated patch id in the header")
    bad = np.argwhere((values < -0.005) | (values > 1.005))
    if bad.size:
        i, j = bad[0]
        raise SpectralInputError(
            f"{source}: patch {names[j]!r}: reflectance {values[i, j]:g} at {wl[i]:g} nm is outside 0…1"
        )
    try:
        if wl.size < 6:  # too few samples for colour-science's interpolators: straight lines between them
            if wl[0] > GRID.start or wl[-1] < GRID.end:
                raise SpectralInputError(f"data cover {wl[0]:g}–{wl[-1]:g} nm but {GRID.start:g}–{GRID.end:g} nm are needed")
            grid = np.column_stack([np.interp(GRID.wavelengths, wl, v) for v in values.T])
        else:
            grid = resample_columns(wl, values, GRID)
    except SpectralInputError as exc:
        raise SpectralInputError(f"{source}: {exc}") from None
    return check_known_reflectances({n: grid[:, j] for j, n in enumerate(names)}, source)


def references_kind(known: Mapping[str, NDArray[np.float64]]) -> str:
    """``"grey"`` when the references span no more than one chromatic direction (flat cards: only channel scales can
    be pinned), ``"chart"`` when they are chromatically rich enough to pin a 3 × 3 colour matrix."""
    r = np.stack([np.asarray(v, dtype=float) for v in known.values()])
    shapes = r / np.maximum(r.mean(axis=1, keepdims=True), 1e-9)
    flat = np.all(np.abs(shapes - 1.0).max(axis=1) < 0.1)
    if flat or r.shape[0] < 4:
        return "grey"
    sv = np.linalg.svd(shapes - shapes.mean(0), compute_uv=False)
    return "chart" if sv.size >= 2 and sv[1] > 0.05 * max(sv[0], 1e-12) else "grey"
