"""Wavelength grid, spectral CSV input / output and resampling.

Every spectral quantity inside illumon lives on one grid, :data:`GRID`: 400–700 nm at 5 nm (61 samples). The camera
sensitivity databases are sampled at 10 nm, daylight at 5 nm and reflectances at 1–5 nm, so 5 nm keeps the finest common
detail without inventing any; 400–700 nm is the range every measured camera covers. Resampling goes through
colour-science (``SpectralDistribution.align``: Sprague / cubic-spline interpolation, no extrapolation beyond the data).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable
from pathlib import Path

import colour
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "GRID",
    "WAVELENGTHS",
    "SpectralInputError",
    "finite_number",
    "resample",
    "resample_columns",
    "read_spectral_csv",
    "write_spectral_csv",
    "read_sensitivities",
    "sensitivities_from_arrays",
]

GRID = colour.SpectralShape(400, 700, 5)
"""The wavelength grid of every spectrum inside illumon (nm)."""

WAVELENGTHS: NDArray[np.float64] = np.asarray(GRID.wavelengths, dtype=float)
"""Wavelengths of :data:`GRID` as an array (nm)."""


class SpectralInputError(ValueError):
    """A spectral file or array that illumon cannot use, with a message naming where and why."""


def finite_number(cell: str, where: str, error: type[ValueError] = ValueError) -> float:
    """``cell`` (a text field of an input file) as a finite float, or ``error`` naming ``where`` and the value."""
    try:
        value = float(cell)
    except ValueError:
        raise error(f"{where}: non-numeric value {cell!r}") from None
    if not math.isfinite(value):
        raise error(f"{where}: non-finite value {cell!r}")
    return value


def resample(
    wavelengths: ArrayLike,
    values: ArrayLike,
    shape: colour.SpectralShape = GRID,
) -> NDArray[np.float64]:
    """Resample one spectrum onto ``shape`` with colour-science interpolation.

    Parameters
    ----------
    wavelengths
        Sample wavelengths (nm), strictly increasing.
    values
        Spectral values at ``wavelengths``.
    shape
        Target grid; must lie within the data's range.

    Returns
    -------
    ndarray
        Values on ``shape.wavelengths``.
    """
    return resample_columns(wavelengths, np.asarray(values, dtype=float)[:, None], shape)[:, 0]


def resample_columns(
    wavelengths: ArrayLike,
    values: ArrayLike,
    shape: colour.SpectralShape = GRID,
) -> NDArray[np.float64]:
    """Resample the columns of ``values`` (samples × spectra) onto ``shape``.

    Uses :class:`colour.MultiSpectralDistributions` with its default interpolator (Sprague for uniform data, cubic
    spline otherwise); raises :class:`SpectralInputError` if the data do not cover ``shape``.
    """
    wl = np.asarray(wavelengths, dtype=float)
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[:, None]
    if wl.size < 2 or np.any(np.diff(wl) <= 0):
        raise SpectralInputError("wavelengths must be strictly increasing")
    if wl[0] > shape.start + 1e-9 or wl[-1] < shape.end - 1e-9:
        raise SpectralInputError(
            f"data cover {wl[0]:g}–{wl[-1]:g} nm but {shape.start:g}–{shape.end:g} nm are needed"
        )
    target = np.asarray(shape.wavelengths, dtype=float)
    steps = np.diff(wl)
    if np.allclose(steps, steps[0]) and np.all(np.isin(np.round(target, 6), np.round(wl, 6))):
        index = np.searchsorted(wl, target)
        return v[index]
    msd = colour.MultiSpectralDistributions(v, wl)
    # Interpolate onto the target wavelengths; data are trimmed, never extrapolated.
    return np.asarray(msd.copy().interpolate(colour.SpectralShape(shape.start, shape.end, shape.interval)).values)


def _parse_rows(text: str, source: str) -> tuple[list[str] | None, list[tuple[int, list[str]]]]:
    header: list[str] | None = None
    rows: list[tuple[int, list[str]]] = []
    for lineno, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        if not row or not "".join(row).strip():
            continue
        if row[0].lstrip().startswith("#"):
            continue
        cells = [c.strip() for c in row]
        if header is None and not rows:
            try:
                float(cells[0])
            except ValueError:
                header = cells
                continue
        rows.append((lineno, cells))
    return header, rows


def read_spectral_csv(
    path: str | Path, *, text: str | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64], list[str]]:
    """Read a spectral CSV: first column wavelength (nm), one column per spectrum.

    ``#`` comment lines are ignored; a header row is optional. Returns ``(wavelengths, values, names)`` with values
    shaped samples × spectra, sorted by wavelength. Errors name the file, the row and the problem.
    """
    source = str(path)
    if text is None:
        try:
            text = Path(path).read_text(encoding="utf-8-sig")
        except OSError as exc:
            raise SpectralInputError(f"{source}: cannot read file ({exc.strerror or exc})") from exc
    header, rows = _parse_rows(text, source)
    if not rows:
        raise SpectralInputError(f"{source}: no data rows")
    width = len(rows[0][1])
    if header is not None and len(header) != width:
        raise SpectralInputError(f"{source}: header has {len(header)} columns but data rows have {width}")
    data = np.empty((len(rows), width))
    for i, (lineno, cells) in enumerate(rows):
        if len(cells) != width:
            raise SpectralInputError(f"{source}: row {lineno}: expected {width} columns, found {len(cells)}")
        for j, cell in enumerate(cells):
            data[i, j] = finite_number(cell, f"{source}: row {lineno}", SpectralInputError)
    order = np.argsort(data[:, 0], kind="stable")
    data = data[order]
    if np.any(np.diff(data[:, 0]) == 0):
        raise SpectralInputError(f"{source}: repeated wavelength")
    names = header[1:] if header is not None else [f"s{j}" for j in range(1, width)]
    return data[:, 0], data[:, 1:], names


def write_spectral_csv(
    path: str | Path,
    wavelengths: Iterable[float],
    columns: dict[str, ArrayLike],
    *,
    comments: Iterable[str] = (),
) -> None:
    """Write spectra as ``wavelength_nm,<name>…`` CSV with optional ``#`` comment lines."""
    wl = np.asarray(list(wavelengths), dtype=float)
    arrays = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
    with open(path, "w", newline="") as fh:
        for line in comments:
            fh.write(f"# {line}\n")
        w = csv.writer(fh)
        w.writerow(["wavelength_nm", *arrays])
        for i, lam in enumerate(wl):
            w.writerow([f"{lam:g}", *(f"{a[i]:.8g}" for a in arrays.values())])


def sensitivities_from_arrays(
    wavelengths: ArrayLike, rgb: ArrayLike, *, source: str = "sensitivities"
) -> NDArray[np.float64]:
    """Validate camera sensitivities (samples × 3) and resample them onto :data:`GRID`.

    Raises :class:`SpectralInputError` if they do not cover 400–700 nm, contain negative or non-finite values, or are
    all zero in a channel.
    """
    wl = np.asarray(wavelengths, dtype=float)
    v = np.asarray(rgb, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] != wl.size:
        raise SpectralInputError(f"{source}: expected one wavelength and three values (r, g, b) per row")
    if not np.all(np.isfinite(v)) or not np.all(np.isfinite(wl)):
        raise SpectralInputError(f"{source}: non-finite value")
    if np.any(v < 0):
        i = int(np.argwhere(v < 0)[0, 0])
        raise SpectralInputError(f"{source}: negative sensitivity at {wl[i]:g} nm")
    order = np.argsort(wl)
    wl, v = wl[order], v[order]
    if wl[0] > GRID.start or wl[-1] < GRID.end:
        raise SpectralInputError(
            f"{source}: sensitivities cover {wl[0]:g}–{wl[-1]:g} nm; 400–700 nm are required"
        )
    try:
        out = resample_columns(wl, v, GRID)
    except SpectralInputError as exc:
        raise SpectralInputError(f"{source}: {exc}") from None
    out = np.clip(out, 0.0, None)
    if np.any(out.max(axis=0) <= 0):
        raise SpectralInputError(f"{source}: a channel is zero everywhere in 400–700 nm")
    return out


def read_sensitivities(path: str | Path) -> NDArray[np.float64]:
    """Read camera spectral sensitivities from ``wavelength_nm,r,g,b`` CSV onto :data:`GRID` (61 × 3).

    ``#`` comment lines and a header are allowed; any sampling is accepted and resampled with colour-science.
    """
    wl, values, _ = read_spectral_csv(path)
    if values.shape[1] != 3:
        raise SpectralInputError(f"{path}: expected columns wavelength_nm,r,g,b; found {values.shape[1] + 1} columns")
    return sensitivities_from_arrays(wl, values, source=str(path))
