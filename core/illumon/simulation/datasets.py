"""Loaders for the measured data sets beside the project (``../shared/data``), used by tests, benchmarks and the tools
that derive the bases shipped in :mod:`illumon.data`. Nothing at run time depends on them.

The location is ``$ILLUMON_SHARED_DATA`` if set, else ``<project root>/../shared/data``.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..spectra import GRID, read_sensitivities, read_spectral_csv, resample_columns

__all__ = [
    "shared_data_dir",
    "camera_names",
    "load_camera",
    "load_granada_daylight",
    "load_reflectance_set",
    "REFLECTANCE_SETS",
]

REFLECTANCE_SETS = (
    "munsell_matt_1269",
    "natural_vrhel",
    "natural_joensuu_219",
    "sfu_dupont_120",
    "sfu_barnard_57",
)


def shared_data_dir() -> Path | None:
    """The measured-data folder, or ``None`` when it is absent."""
    env = os.environ.get("ILLUMON_SHARED_DATA")
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    candidates += [p / "shared" / "data" for p in here.parents]
    candidates.append(Path.cwd().parent / "shared" / "data")
    for c in candidates:
        if (c / "cameras").is_dir():
            return c
    return None


def _require() -> Path:
    d = shared_data_dir()
    if d is None:
        raise FileNotFoundError("measured data not found: set ILLUMON_SHARED_DATA or place shared/data beside the project")
    return d


def camera_names() -> list[str]:
    """Names (file stems) of the measured cameras."""
    return sorted(p.stem for p in (_require() / "cameras").glob("*.csv"))


@lru_cache(maxsize=64)
def load_camera(name: str) -> NDArray[np.float64]:
    """Measured sensitivities of camera ``name`` on the grid, max-normalised over all channels (61 × 3)."""
    css = read_sensitivities(_require() / "cameras" / f"{name}.csv")
    return css / css.max()


@lru_cache(maxsize=1)
def load_granada_daylight() -> tuple[list[str], NDArray[np.float64]]:
    """The 2600 Granada daylight spectra on the grid, each scaled to 100 at 560 nm: ``(ids, spectra (2600 × 61))``."""
    wl, values, names = read_spectral_csv(_require() / "daylight" / "granada_2600.csv")
    on_grid = resample_columns(wl, values, GRID).T
    i560 = int(np.argmin(np.abs(np.asarray(GRID.wavelengths) - 560)))
    return names, 100.0 * on_grid / on_grid[:, i560 : i560 + 1]


@lru_cache(maxsize=8)
def load_reflectance_set(name: str) -> tuple[list[str], NDArray[np.float64]]:
    """One measured reflectance set on the grid: ``(ids, reflectances (n × 61))``, clipped to 0…1."""
    wl, values, names = read_spectral_csv(_require() / "reflectances" / f"{name}.csv")
    return names, np.clip(resample_columns(wl, values, GRID).T, 0.0, 1.0)
