"""The per-frame estimate at ingest (and of frames stored while a refit ran): the camera view's fitted scene model
with its cached solver, about 1 ms a frame; and the stored form of an estimate (a row of the ``estimates`` table)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from illumon.retrieval.common import RetrievalResult
from illumon.spectra import WAVELENGTHS

from ..storage import spectrum_bytes
from .history import build_observations
from .models import load_model, model_path, solver_for

__all__ = ["estimate_row", "json_safe", "frame_intervals", "estimate_frame", "GRID_WAVELENGTHS"]

log = logging.getLogger("illumon_service.estimation")


def _floats(row: Any) -> list[float]:
    return np.asarray(row, dtype=float).tolist()


def estimate_row(result: RetrievalResult, i: int, confidence: float, source: str, intervals: dict | None = None) -> dict:
    """The stored form of estimate ``i`` of ``result`` (a refit writes 100k of these: no per-value numpy scalars); its
    spectrum as float32 bytes (:attr:`~..storage.Estimate.spectrum_f32`)."""
    c = float(confidence)
    return {
        "cct_k": float(result.cct[i]),
        "duv": float(result.duv[i]),
        "xy": _floats(result.xy[i]),
        "white_rgb": _floats(result.white[i]),
        "gains_rgb": _floats(result.gains[i]),
        "confidence": min(max(c, 0.0), 1.0),  # np.clip's answer (NaN stays NaN)
        "spectrum": None,  # older versions' JSON column: JSON null (NOT NULL in their databases)
        "spectrum_f32": spectrum_bytes(result.spectra[i]),
        "intervals": intervals,
        "source": source,
    }



def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by ``None`` (JSON has no infinity: PostgreSQL's JSON type and
    strict JSON parsers refuse ``Infinity``). An unbounded interval end — a 95 % CCT interval reaching past infinite
    temperature (reciprocal temperature ≤ 0) — is then ``null``."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def frame_intervals(result: RetrievalResult, extra: dict, i: int) -> dict | None:
    """95 % intervals of frame ``i`` (``cct_lo`` … ``gain_hi``); an unbounded end is ``None``."""
    out: dict[str, Any] = {k: float(np.asarray(v)[i]) for k, v in (extra or {}).items() if k != "confidence"}
    for k in ("gain_lo", "gain_hi"):
        if k in result.info:
            out[k] = [float(v) for v in np.asarray(result.info[k])[i]]
    return json_safe(out) or None


def estimate_frame(
    data_dir: Path | str, camera_id: int, frame_id: str, taken_at: str, patches: dict, region_ids: Sequence[str],
    view: str | None = None, sd: dict | None = None, model_file: Path | None = None,
) -> dict | None:
    """Per-frame estimate from the camera's (view's) fitted scene model, or ``None`` when there is none (yet);
    ``sd``: the regions' standard errors (see :func:`build_observations`); ``model_file``: the model to use (default:
    the view's unversioned file of older versions)."""
    path = model_path(data_dir, camera_id, view) if model_file is None else Path(model_file)
    if not path.is_file():
        return None
    obs = build_observations([(frame_id, taken_at, patches, sd)], region_ids)
    present = obs.present[0]
    if present.sum() < 2:
        return None
    try:
        loaded = load_model(path)
        result, extra = loaded.model.estimate(obs, solver=solver_for(loaded, list(region_ids)))
    except Exception as exc:  # noqa: BLE001 - the frame is stored either way; an unreadable model must not lose it
        log.warning("scene model estimate failed for camera %s: %s", camera_id, exc)
        return None
    if not np.all(np.isfinite(result.white[0])):
        return None
    conf = float(np.asarray(extra["confidence"])[0]) if extra and "confidence" in extra else float(present.mean())
    return estimate_row(result, 0, conf, "model", frame_intervals(result, extra, 0))



GRID_WAVELENGTHS = [float(v) for v in WAVELENGTHS]
"""Wavelengths (nm) of stored spectra."""
