"""Stored rows as estimation's input: region means with the camera's applied gains and exposure divided out, the
camera's sensitivities and output space, observations (:class:`illumon.observations.Observations`) from history
rows, and calibration images as extra frames with their references' known reflectances."""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import chain
from typing import Any

import numpy as np
from illumon.observations import Observations
from numpy.typing import NDArray

from ..storage import as_utc

__all__ = ["camera_primaries", "sensitivities_array", "undo_camera_gains", "undo_camera_gains_sd",
           "CALIBRATION_PREFIX", "build_observations", "seen_patches", "history_row", "history_arrays",
           "calibration_frames"]


def camera_primaries(response: dict | None, measured: bool) -> str:
    """The camera's output space (``response.primaries``); cameras registered before it existed get the default of
    :class:`~..api.schemas.ResponseIn`: ``srgb`` for an unmeasured camera with an ``srgb`` or ``table`` encoding."""
    r = response or {}
    if r.get("primaries") in ("camera", "srgb"):
        return r["primaries"]
    return "srgb" if (not measured and r.get("encoding", "srgb") in ("srgb", "table")) else "camera"


def sensitivities_array(stored: Sequence[Sequence[float]]) -> NDArray[np.float64] | None:
    """Stored sensitivities (61 lists of r, g, b on the grid) as an array; ``None`` for a camera nobody measured."""
    return np.asarray(stored, dtype=float) if len(stored) else None


def undo_camera_gains(
    patches: dict[str, Any], applied_gains: Sequence[float] | None, exposure: float | None,
    matrix: Sequence[Sequence[float]] | None = None,
) -> dict[str, Any]:
    """Region means with the white-balance gains and exposure the camera applied divided out
    (:func:`illumon.camera.undo_applied`; with the camera's colour ``matrix`` the gains are undone before it), so a
    history stays consistent while the camera's own white balance changes — and the gains the service returns apply
    to linear values as the camera delivers them at unit gains."""
    if applied_gains is None and exposure is None:
        return patches
    from illumon.camera import undo_applied

    ids = [k for k, v in patches.items() if v is not None]
    if not ids:
        return patches
    out = undo_applied(np.array([patches[k] for k in ids], dtype=float), applied_gains, exposure, matrix)
    return {**patches, **{k: [float(x) for x in v] for k, v in zip(ids, out, strict=True)}}


def undo_camera_gains_sd(
    sd: dict[str, Any] | None, applied_gains: Sequence[float] | None, exposure: float | None,
    matrix: Sequence[Sequence[float]] | None = None,
) -> dict[str, Any] | None:
    """Standard errors of region means (:attr:`..storage.Frame.patch_sd`) through the same linear map as
    :func:`undo_camera_gains` (variances through the map's squared entries: the channels' errors taken as independent)."""
    if not sd or (applied_gains is None and exposure is None):
        return sd
    from illumon.camera import undo_applied

    op2 = undo_applied(np.eye(3), applied_gains, exposure, matrix).T ** 2  # out = op @ v
    return {k: None if v is None else [float(x) for x in np.sqrt(op2 @ np.square(np.asarray(v, dtype=float)))]
            for k, v in sd.items()}


CALIBRATION_PREFIX = "calibration-"
"""Frame ids of calibration images in a refit's history (``calibration-<id>``); they get no stored estimate."""


def build_observations(
    frames: Sequence[tuple[str, str, dict[str, Any]] | tuple[str, str, dict[str, Any], dict[str, Any] | None]],
    region_ids: Sequence[str],
) -> Observations:
    """Observations from ``(frame id, ISO time, {region id: [r, g, b] | None})`` triples (values linear 0…1), or
    quadruples whose fourth item holds the regions' standard errors (``{region id: [r, g, b] | None}`` or ``None``,
    measured at ingest from the pixels' spread; they become :attr:`Observations.sd`)."""
    values = np.full((len(frames), len(region_ids), 3), np.nan)
    sd = np.full_like(values, np.nan)
    for i, frame in enumerate(frames):
        patches = frame[2]
        spread = frame[3] if len(frame) > 3 else None
        for j, rid in enumerate(region_ids):
            v = patches.get(rid)
            if v is not None:
                values[i, j] = v
                e = (spread or {}).get(rid)
                if e is not None:
                    sd[i, j] = e
    has_sd = bool(np.isfinite(sd).any())
    return Observations([f[0] for f in frames], list(region_ids), values, [f[1] for f in frames],
                        sd if has_sd else None)



def seen_patches(obs: Observations) -> Observations:
    """``obs`` without the patches never seen (a region always occluded or clipped cannot be fitted)."""
    seen = obs.present.any(axis=0)
    if seen.all():
        return obs
    return obs.select_patches([p for p, s in zip(obs.patches, seen, strict=True) if s])



def history_row(r: Any, matrix: list | None) -> tuple[str, str, dict, dict | None]:
    """A stored frame (a row with the frame's columns by name) as a history row for :func:`build_observations`: id,
    time, region means and their standard errors, with the camera's applied gains and exposure divided out."""
    return (str(r.id), as_utc(r.taken_at).isoformat(), undo_camera_gains(r.patches, r.applied_gains, r.exposure, matrix),
            undo_camera_gains_sd(r.patch_sd, r.applied_gains, r.exposure, matrix))


_MISSING = (math.nan, math.nan, math.nan)


def _floats(triples: list, frames: int, patches: int) -> NDArray[np.float64]:
    """Triples of numbers, ``patches`` per frame, as a ``frames`` × ``patches`` × 3 array (``float`` of each, as
    numpy converts a list of them; ~3 × faster than ``np.array`` of the nested lists)."""
    flat = np.fromiter(chain.from_iterable(triples), dtype=float, count=3 * len(triples))
    return flat.reshape(frames, patches, 3)


def history_arrays(frames: Sequence[Any], region_ids: Sequence[str],
                   matrix: list | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Region means and their standard errors of stored frames (rows with the frame's columns by name, whose values
    :func:`..limits.frame_problem` accepts) as F × P × 3 arrays, NaN where missing (a standard error only where its
    mean is present), the camera's applied gains and exposure divided out: the ``values`` and ``sd`` (NaN for none)
    :func:`build_observations` makes of the frames' :func:`history_row`, bit for bit, built for all the frames at
    once. Without a colour ``matrix`` the gains and exposure are undone on the arrays (the same divisions, and the
    standard errors through the same squares, as :func:`undo_camera_gains` and :func:`undo_camera_gains_sd`); with
    one, frame by frame through :func:`history_row` (batched, its products could round otherwise)."""
    n, p = len(frames), len(region_ids)
    if matrix is not None:
        obs = build_observations([history_row(f, matrix) for f in frames], region_ids)
        return obs.values, obs.sd if obs.sd is not None else np.full_like(obs.values, np.nan)
    values = _floats([_MISSING if v is None else v for f in frames for v in map(f.patches.get, region_ids)], n, p)
    with_sd = np.array([bool(f.patch_sd) for f in frames], dtype=bool)
    sd = _floats([_MISSING if e is None or v is None else e for f in frames if f.patch_sd
                  for v, e in zip(map(f.patches.get, region_ids), map(f.patch_sd.get, region_ids), strict=True)],
                 int(with_sd.sum()), p)
    if not with_sd.all():
        full = np.full_like(values, np.nan)
        full[with_sd] = sd
        sd = full
    undo = np.array([f.applied_gains is not None or f.exposure is not None for f in frames], dtype=bool)
    if undo.any():
        k = np.array([1.0 if f.exposure is None else f.exposure for f in frames], dtype=float)[undo]
        g = np.array([(1.0, 1.0, 1.0) if f.applied_gains is None else f.applied_gains for f in frames],
                     dtype=float)[undo]
        values[undo] = values[undo] / k[:, None, None] / g[:, None, :]  # x / 1.0 is x: one gain or exposure alone
        scale = np.square((1.0 / k[:, None]) / g)  # the diagonal of undo_camera_gains_sd's squared map
        sd[undo] = np.sqrt(scale[:, None, :] * np.square(sd[undo]))
    return values, sd


def calibration_frames(
    cals: Sequence[Any], matrix: list | None = None
) -> tuple[list[tuple[str, str, dict]], dict[str, np.ndarray], list[str]]:
    """Stored calibrations (:class:`~..storage.Calibration` rows) as extra frames of a refit's history:
    ``calibration-<id>`` holding the reference patches and the camera's regions seen in the same image (the camera's
    applied gains divided out); the known reflectances of the references — the ColorChecker's
    (:func:`illumon.camera.colourchecker_references`, ids ``chart:01`` …) and each grey card's
    (:func:`illumon.camera.grey_card_reference`, id ``grey:<calibration id>``); and a warning for each calibration
    left out because its image shows fewer than two usable regions of the scene."""
    from illumon.camera import colourchecker_references, grey_card_reference

    frames, known, warnings = [], {}, []
    chart: dict[str, np.ndarray] = {}  # the chart's references, made once a chart is shown (0.08 s a process)
    for c in cals:
        scene = {k: v for k, v in (c.scene or {}).items() if v is not None}
        refs = {k: v for k, v in c.patches.items() if v is not None}
        if len(scene) < 2 or not refs:
            warnings.append(f"calibration {c.id} ({c.kind}) left out: its image shows fewer than two usable regions "
                            "of the scene" if refs else f"calibration {c.id} ({c.kind}) left out: no usable patch")
            continue
        if c.kind == "grey":
            pid = f"grey:{c.id}"
            refs = {pid: refs["grey"]}
            known.update(grey_card_reference(pid, c.reflectance or 0.18))
        else:
            chart = chart or colourchecker_references()
            known.update({k: chart[k] for k in refs})
        patches = undo_camera_gains({**scene, **refs}, c.applied_gains, c.exposure, matrix)
        frames.append((f"{CALIBRATION_PREFIX}{c.id}", as_utc(c.created_at).isoformat(), patches))
    return frames, known, warnings
