"""A refit's numerics: the scene model fitted on a camera view's history (:func:`illumon.model.fit_scene_model`),
saved, and every frame estimated with it; or a multi-frame retrieval (:func:`illumon.retrieval.retrieve_illuminants`)
followed by a model fit."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from illumon import model as scene_model
from illumon.observations import Observations
from illumon.retrieval.common import RetrievalResult
from numpy.typing import NDArray

from .batch import RefitEstimates
from .history import CALIBRATION_PREFIX, build_observations, seen_patches
from .models import forget_model, known_indices, save_model

__all__ = ["RefitInputError", "fit_model", "refit_estimates", "retrieve", "ESTIMATE_CHUNK"]

log = logging.getLogger("illumon_service.estimation")


class RefitInputError(ValueError):
    """A refit that cannot run because of what the user stored (too few frames, no usable region): an ordinary
    condition, reported in the job's summary and logged in one line, never with a traceback."""



def _known_seen(obs: Observations, known: dict[str, NDArray[np.float64]] | None) -> dict | None:
    """The references among ``obs``'s patches (a reference never measured, e.g. every chart patch clipped, is left
    out: the fit refuses a known patch it never sees)."""
    if not known:
        return None
    return {k: v for k, v in known.items() if k in obs.patches} or None


def fit_model(obs: Observations, css: NDArray[np.float64] | None, path: Path, max_fit_frames: int = 300,
               known: dict[str, NDArray[np.float64]] | None = None, primaries: str = "camera") -> str:
    """Fit and save a scene model with :mod:`illumon.model`; returns a status string."""
    try:
        seen = seen_patches(obs)
        fitted = scene_model.fit_scene_model(seen, css, known_reflectances=_known_seen(seen, known),
                                             max_fit_frames=max_fit_frames, primaries=primaries)
        save_model(fitted, path)
    except Exception as exc:  # noqa: BLE001 - the retrieval's estimates still stand
        log.warning("scene model fit failed: %s", exc)
        return f"scene model fit failed: {exc}"
    return "fitted"


ESTIMATE_CHUNK = 10_000
"""Frames estimated per call of the scene model at a refit."""


def _history_estimates(fitted: scene_model.SceneModel, obs: Observations) -> Iterator[tuple[RetrievalResult, dict]]:
    """``fitted.estimate`` of every frame of ``obs`` in chunks (they keep the solver's temporaries in cache); the
    fit's own estimate of the same frames when it has one (computed for its training summary: the same numbers)."""
    done = fitted.history_estimate
    if done is not None and list(done[0].frames) == list(obs.frames):
        yield done
        return
    solver = None
    for start in range(0, len(obs.frames), ESTIMATE_CHUNK):
        part = obs.subset(slice(start, start + ESTIMATE_CHUNK))
        if solver is None:
            solver = fitted.solver(list(known_indices(fitted, part.patches)))
        try:
            est = fitted.estimate(part, solver=solver)
        except ValueError:  # no frame of this chunk has two of the model's patches
            continue
        yield est


def _refit_with_model(
    obs: Observations, css: NDArray[np.float64] | None, model_file: Path | None, max_fit_frames: int,
    known: dict[str, NDArray[np.float64]] | None = None, primaries: str = "camera",
) -> tuple[RefitEstimates, dict]:
    """Fit the scene model on the history (reflectances on ≤ ``max_fit_frames`` frames spread over the illuminant
    range), save it, and estimate every frame with it: ``illumon fit`` then ``illumon estimate --model``."""
    seen = seen_patches(obs)
    fitted = scene_model.fit_scene_model(seen, css, known_reflectances=_known_seen(seen, known),
                                         max_fit_frames=max_fit_frames, primaries=primaries)
    if model_file is not None:
        save_model(fitted, model_file)
        forget_model(model_file)
    out = RefitEstimates()
    for result, extra in _history_estimates(fitted, obs):
        ok = np.all(np.isfinite(result.white), axis=1)
        keep = ok & np.array([not str(fid).startswith(CALIBRATION_PREFIX) for fid in result.frames])
        out.add(result, extra["confidence"], keep, "refit:model", extra)
    cct = out.cct()
    summary = {
        "frames": len(out),
        "method": "model",
        "model": "fitted" if model_file is not None else "not saved",
        "frames_used_for_reflectances": fitted.training.get("frames_used_for_reflectances"),
        "cct_k_median": float(np.median(cct)) if cct.size else None,
        "identifiability_warnings": list(fitted.identifiability.get("warnings", [])),
        "camera": getattr(fitted, "camera", None) or {},
    }
    return out, summary


def refit_estimates(
    frames: Sequence[tuple[str, str, dict[str, Any]]] | Observations,
    region_ids: Sequence[str],
    sensitivities: NDArray[np.float64] | None,
    *,
    method: str = "model",
    model_file: Path | None = None,
    max_fit_frames: int = 300,
    calibrations: Sequence[tuple[str, str, dict[str, Any]]] = (),
    known_reflectances: dict[str, NDArray[np.float64]] | None = None,
    primaries: str = "camera",
) -> tuple[RefitEstimates, dict]:
    """Estimates of the given frames: ``(estimates by frame id, summary)``; ``frames``: history rows
    (:func:`~.history.history_row`) or their observations (:func:`~.history.build_observations`).

    ``method="model"`` (default) fits the learned scene model (:func:`illumon.model.fit_scene_model`, reflectances
    on at most ``max_fit_frames`` frames spread over the illuminant range), saves it to ``model_file`` and estimates
    every frame with it — the same numbers as ``illumon fit`` then ``illumon estimate --model``; its cost grows
    linearly with the history. The retrieval methods (``joint``, ``marguier2007``, ``gray_world``) run
    :func:`illumon.retrieval.retrieve_illuminants` over all the given frames (``illumon estimate --method``; the
    joint fit grows faster than linearly: keep such histories to a few hundred frames) and then fit a model too.

    ``sensitivities=None`` is a camera nobody measured (the model's prior from measured cameras). ``calibrations``
    are extra frames (ids ``calibration-<id>``) holding only reference patches whose spectra ``known_reflectances``
    gives (a ColorChecker, a grey card): they join the fit's history, pin the camera, and get no estimate of their
    own; one that shows two or more of the scene's regions beside its reference counts as a view of the scene. Frames
    with fewer than two regions seen are left out. Raises :class:`RefitInputError` when fewer than two views remain
    (at least one of them a frame), or for a retrieval method on an unmeasured camera.
    """
    if sensitivities is None and method != "model":
        raise RefitInputError(f"refit method {method!r} needs measured sensitivities; this camera has none (use the "
                              "default method 'model', which calibrates from the prior and calibration images)")
    n = len(frames.frames) if isinstance(frames, Observations) else len(frames)
    # a calibration image that shows two or more of the scene's regions is a view of the scene too (the installer's
    # chart shot, then one frame, is a two-frame history): the model counts it
    views = _calibration_views(calibrations, region_ids) if method == "model" else 0
    also = f" and {views} calibration image{'s' if views > 1 else ''} showing the regions" if views else ""
    if n < 1 or n + views < 2:
        raise RefitInputError(f"refit needs at least two frames with two regions seen; {n} stored{also}: post "
                              "frames (POST /v1/cameras/{id}/frames), then refit")
    obs = frames if isinstance(frames, Observations) else build_observations(frames, region_ids)
    usable = np.flatnonzero(obs.present.sum(axis=1) >= 2)
    if usable.size < 1 or usable.size + views < 2:
        raise RefitInputError(f"refit needs at least two frames with two regions seen; {usable.size} available "
                              f"(of {n} stored){also}: post more frames, then refit")
    if usable.size < n:
        obs = obs.subset(usable)
    skipped = n - int(usable.size)
    if method == "model":
        if calibrations:
            obs = _with_calibrations(obs, calibrations)
        out, summary = _refit_with_model(obs, sensitivities, model_file, max_fit_frames, known_reflectances, primaries)
        summary["calibration_frames"] = len(calibrations)
        summary["skipped_frames"] = n - len(out)
        return out, summary
    kwargs = {"daylight": "cie"} if method == "joint" else {}
    result = retrieve(obs, sensitivities, method, kwargs)
    out = RefitEstimates()
    out.add(result, obs.present.mean(axis=1), np.ones(len(result.frames), bool), f"refit:{method}")
    summary = {
        "frames": len(result.frames),
        "skipped_frames": skipped,
        "method": method,
        "cost": result.info.get("cost"),
        "cct_k_median": float(np.median(result.cct)),
    }
    if model_file is not None:
        summary["model"] = fit_model(obs, sensitivities, model_file, max_fit_frames, primaries=primaries)
    return out, summary



def _calibration_views(calibrations: Sequence[tuple[str, str, dict[str, Any]]], region_ids: Sequence[str]) -> int:
    """How many calibration images show two or more of the scene's regions (``region_ids``)."""
    regions = set(region_ids)
    return sum(1 for _, _, patches in calibrations if sum(1 for k in patches if k in regions) >= 2)


def _with_calibrations(obs: Observations, calibrations: Sequence[tuple[str, str, dict[str, Any]]]) -> Observations:
    """``obs`` followed by the calibration images as frames (their reference patches after the regions): what
    :func:`~.history.build_observations` makes of the usable history rows and the calibrations together."""
    ids = list(obs.patches) + sorted({k for _, _, p in calibrations for k in p} - set(obs.patches))
    cal = build_observations(list(calibrations), ids)
    values = np.full((len(obs.frames), len(ids), 3), np.nan)
    values[:, : len(obs.patches)] = obs.values
    sd = np.full_like(values, np.nan)
    if obs.sd is not None:
        sd[:, : len(obs.patches)] = obs.sd
    sd = np.concatenate([sd, np.full_like(cal.values, np.nan) if cal.sd is None else cal.sd])
    return Observations(list(obs.frames) + list(cal.frames), ids, np.concatenate([values, cal.values]),
                        list(obs.times) + list(cal.times), sd if np.isfinite(sd).any() else None)


def retrieve(obs: Observations, css: NDArray[np.float64], method: str, kwargs: dict) -> RetrievalResult:
    """Call :func:`illumon.retrieval.retrieve_illuminants` (imported lazily: it loads SciPy)."""
    from illumon.retrieval import retrieve_illuminants

    return retrieve_illuminants(obs, css, method=method, **kwargs)

