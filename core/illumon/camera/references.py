"""Surfaces of known reflectance seen by a camera: a grey card, a ColorChecker, or any measured surface.

A reference is a patch id mapped to its reflectance spectrum on :data:`~illumon.spectra.GRID` (61 values, 0…1). It
typically appears in one frame (a card held up at installation); :mod:`illumon.camera.calibration` uses it to pin what
an unmeasured camera's sensitivities cannot tell: a grey card fixes each channel's scale, a chart also the mixing of
channels by a colour matrix.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..priors import colourchecker_reflectances
from ..registry import Registry
from ..spectra import GRID, SpectralInputError, read_spectral_csv, resample_columns

__all__ = [
    "REFERENCE_KINDS",
    "colourchecker_references",
    "grey_card_reference",
    "read_known_reflectances",
    "check_known_reflectances",
    "references_kind",
    "coloured_only",
    "coloured_only_warning",
    "neutral_references",
    "reference_chroma",
]

REFERENCE_KINDS = Registry.choices({
    "colorchecker": "a ColorChecker Classic chart (24 patches), found in the image or at the given corners",
    "grey": "a spectrally flat grey card in the given region (reflectance 0.18 unless given)",
})
"""The kinds of reference a calibration image may show, by the name typed (the service's ``kind`` form field)."""


def colourchecker_references(prefix: str = "chart:", chart: str = "BabelColor Average") -> dict[str, NDArray[np.float64]]:
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


NEUTRAL_CHROMA = 0.04
"""Largest distance (log X/Y and Z/Y under CIE D65, the CIE 1931 observer) from a flat spectrum's chromaticity at which a
reference counts as neutral: the ColorChecker's greys 19–24 lie within 0.02, its least saturated colour patch beyond 0.1."""

CHART_SPREAD = 0.05
"""Second singular value (per reference, log-chromaticity units) the references' chromaticities must reach to pin a
3 × 3 colour matrix: they must span both chromatic directions, not one line through grey."""


def reference_chroma(spectra: NDArray[np.float64]) -> NDArray[np.float64]:
    """Log chromaticity ``(log X/Y, log Z/Y)`` of reflectances (P × 61) under CIE D65 for the CIE 1931 2° observer,
    relative to a flat spectrum's (P × 2): a camera-independent measure of how coloured a reference is."""
    import colour

    cmfs = np.asarray(colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(GRID).values, dtype=float)
    d65 = np.asarray(colour.SDS_ILLUMINANTS["D65"].copy().align(GRID).values, dtype=float)
    xyz = (np.atleast_2d(spectra) * d65) @ cmfs
    flat = d65 @ cmfs
    xyz = np.clip(xyz, 1e-9, None) / flat
    return np.log(xyz[:, [0, 2]] / xyz[:, 1:2])


def neutral_references(known: Mapping[str, NDArray[np.float64]]) -> list[str]:
    """Ids of the references that are neutral (grey card, a chart's greys; :data:`NEUTRAL_CHROMA`)."""
    ids = list(known)
    if not ids:
        return []
    chroma = reference_chroma(np.stack([np.asarray(known[p], dtype=float) for p in ids]))
    return [p for p, c in zip(ids, chroma, strict=True) if np.abs(c).max() < NEUTRAL_CHROMA]


def references_kind(known: Mapping[str, NDArray[np.float64]]) -> str:
    """``"grey"`` when the references' chromaticities span less than both chromatic directions (greys, or greys and
    one colour: only channel scales can be pinned), ``"chart"`` when they are rich enough to pin a 3 × 3 colour matrix
    (:data:`CHART_SPREAD`). The six greys of a ColorChecker are ``"grey"``."""
    r = np.stack([np.asarray(v, dtype=float) for v in known.values()])
    if r.shape[0] < 4:
        return "grey"
    chroma = reference_chroma(r)
    sv = np.linalg.svd(chroma - chroma.mean(axis=0), compute_uv=False)
    return "chart" if sv.size >= 2 and sv[1] / math.sqrt(r.shape[0]) > CHART_SPREAD else "grey"


def coloured_only(known: Mapping[str, NDArray[np.float64]]) -> bool:
    """References that pin no white for a camera nobody measured: no neutral among them (:func:`neutral_references`)
    and too few colours to pin a 3 × 3 (:func:`references_kind` ``"grey"``). Their values then set the camera's
    channel scales only through how it renders colours, which the measured cameras leave uncertain by 0.08–0.10 in
    log r/g and b/g a ColorChecker colour under CIE D65 and A (RMS over the 24 cameras and 18 colours, up to 0.48;
    rendered to sRGB primaries a saturated colour's weakest channel is off by far more), no better than the scene's
    own average. On the development photographs (``python benchmarks/real.py``'s sets with one, two or three of the
    chart's colours known in frame 0) they left the white 2.9–26.5° off (medians), where no reference left it 0.5–5.0°."""
    return bool(known) and not neutral_references(known) and references_kind(known) == "grey"


def coloured_only_warning(ids: list[str]) -> str:
    """The warning of references :func:`coloured_only` set aside."""
    return (f"known patch(es) {', '.join(ids)} set aside: without a neutral among them, so few coloured references pin "
            "the camera's white only through how it renders colours, which a camera nobody measured does not tell; "
            "estimated as without a reference — show a grey card or a chart's greys, or register the camera's "
            "sensitivities")
