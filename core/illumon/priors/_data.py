"""Reading the files shipped in ``illumon/data`` (spectral CSV on the grid, JSON)."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
from numpy.typing import NDArray

from ..spectra import GRID, read_spectral_csv, resample_columns


def shipped_csv(name: str) -> tuple[NDArray[np.float64], list[str]]:
    """The columns of ``illumon/data/<name>`` resampled to the grid (61 × n) and their names."""
    text = (resources.files("illumon") / "data" / name).read_text()
    wl, values, names = read_spectral_csv(name, text=text)
    return resample_columns(wl, values, GRID), names


def shipped_json(name: str) -> dict:
    """The JSON document ``illumon/data/<name>``."""
    return json.loads((resources.files("illumon") / "data" / name).read_text())
