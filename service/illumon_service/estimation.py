"""The service's only doorway to estimation; all numerics live in the core library.

* :func:`estimate_frame` — per-frame estimate at ingest. Uses the learned scene model (:mod:`illumon.model`) when the
  module is importable and a model has been fitted for the camera (``<data dir>/models/camera-<id>.json``); otherwise
  returns ``None`` and the frame is estimated by the next refit.
* :func:`refit_estimates` — over a camera's stored history: by default fits the scene model
  (:func:`illumon.model.fit_scene_model`), saves it for the per-frame estimates at ingest and estimates every stored
  frame with it (``illumon fit`` + ``illumon estimate --model``); or multi-frame retrieval
  (:func:`illumon.retrieval.retrieve_illuminants`, ``illumon estimate --method``) followed by a model fit.

Confidence (0…1): with a scene model, its posterior probability that the camera white is within 1° of the truth
(:mod:`illumon.model`); from a retrieval-method refit, the fraction of the camera's regions seen in the frame (a
ranking aid, not a probability). Intervals (95 %: ``cct_lo/hi``, ``duv_lo/hi``, ``gain_lo/hi``) come from the model.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from illumon import model as scene_model
from illumon.model import FrameSolver
from illumon.observations import Observations
from illumon.retrieval.common import RetrievalResult
from illumon.spectra import WAVELENGTHS
from numpy.typing import NDArray

__all__ = [
    "camera_primaries",
    "RefitInputError",
    "RESPONSE_CHECK_FRAMES",
    "check_response",
    "model_path",
    "model_available",
    "view_model_key",
    "versioned_model_path",
    "current_model",
    "sensitivities_array",
    "undo_camera_gains",
    "undo_camera_gains_sd",
    "CALIBRATION_PREFIX",
    "build_observations",
    "estimate_frame",
    "refit_estimates",
]

log = logging.getLogger("illumon_service.estimation")


class RefitInputError(ValueError):
    """A refit that cannot run because of what the user stored (too few frames, no usable region): an ordinary
    condition, reported in the job's summary and logged in one line, never with a traceback."""


def model_path(data_dir: Path | str, camera_id: int, view: str | None = None) -> Path:
    """Where the fitted scene model of a camera (of one of its views, a PTZ preset) is stored."""
    suffix = "" if view is None else f"-view-{view}"
    return Path(data_dir) / "models" / f"camera-{camera_id}{suffix}.json"


def model_available(data_dir: Path | str, camera_id: int, view: str | None = None) -> bool:
    """Whether per-frame estimation is possible for the camera (a scene model has been fitted)."""
    return model_path(data_dir, camera_id, view).is_file()


def view_model_key(view: str | None) -> str:
    """Key of a view in :attr:`.storage.Camera.models` (``default`` for a fixed camera's one view)."""
    return "default" if view is None else f"v-{view}"


def versioned_model_path(data_dir: Path | str, camera_id: int, view: str | None, version: str) -> Path:
    """Where a refit writes a new scene model: ``models/camera-<id>[-view-<view>].<version>.json`` (a new file per
    refit; the camera row says which one is in use)."""
    legacy = model_path(data_dir, camera_id, view)
    return legacy.with_name(f"{legacy.stem}.{version}.json")


def current_model(data_dir: Path | str, models: dict | None, camera_id: int, view: str | None = None
                  ) -> tuple[Path, str] | None:
    """``(file, version)`` of the scene model a camera's view uses (:attr:`.storage.Camera.models`), or the
    unversioned file of an older version (version ``legacy``) when the camera row names none; ``None`` before the
    first refit."""
    entry = (models or {}).get(view_model_key(view))
    if entry and entry.get("file"):
        return Path(data_dir) / "models" / str(entry["file"]), str(entry.get("version") or "")
    legacy = model_path(data_dir, camera_id, view)
    return (legacy, "legacy") if legacy.is_file() else None


def camera_primaries(response: dict | None, measured: bool) -> str:
    """The camera's output space (``response.primaries``); cameras registered before it existed get the default of
    :class:`~.api.schemas.ResponseIn`: ``srgb`` for an unmeasured camera with an ``srgb`` or ``table`` encoding."""
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
    """Standard errors of region means (:attr:`.storage.Frame.patch_sd`) through the same linear map as
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


def _row(result: RetrievalResult, i: int, confidence: float, source: str, intervals: dict | None = None) -> dict:
    return {
        "cct_k": float(result.cct[i]),
        "duv": float(result.duv[i]),
        "xy": [float(v) for v in result.xy[i]],
        "white_rgb": [float(v) for v in result.white[i]],
        "gains_rgb": [float(v) for v in result.gains[i]],
        "confidence": float(np.clip(confidence, 0.0, 1.0)),
        "spectrum": [float(v) for v in result.spectra[i]],
        "intervals": intervals,
        "source": source,
    }


@dataclass
class _Loaded:
    """A scene model file as loaded (its modification time) and the per-frame solvers built for it, one per list of
    the camera's regions (building one costs more than solving a frame)."""

    mtime: int
    model: scene_model.SceneModel
    solvers: dict[tuple[int, ...], FrameSolver] = field(default_factory=dict)


MODEL_CACHE_SIZE = 256
"""Scene models kept loaded (oldest dropped first)."""
_MODEL_CACHE: dict[str, _Loaded] = {}
_CACHE_LOCK = threading.Lock()


def _load_model(path: Path) -> _Loaded:
    """The scene model at ``path``, loaded once per file version (the per-frame solve is then ~1 ms)."""
    mtime = path.stat().st_mtime_ns
    key = str(path)
    with _CACHE_LOCK:
        hit = _MODEL_CACHE.get(key)
        if hit is not None and hit.mtime == mtime:
            return hit
    loaded = _Loaded(mtime, scene_model.SceneModel.load(path))
    with _CACHE_LOCK:
        if len(_MODEL_CACHE) >= MODEL_CACHE_SIZE:  # versioned files: old versions are never asked for again
            _MODEL_CACHE.pop(next(iter(_MODEL_CACHE)))
        _MODEL_CACHE[key] = loaded
    return loaded


def _known_indices(model: scene_model.SceneModel, region_ids: Sequence[str]) -> tuple[int, ...]:
    """The model's indices of the regions it knows, in the regions' order (as ``SceneModel.estimate`` matches them)."""
    index = {p: i for i, p in enumerate(model.patches)}
    return tuple(index[p] for p in region_ids if p in index)


def _solver(loaded: _Loaded, region_ids: list[str]) -> FrameSolver:
    """The model's per-frame solver over the regions it knows, built once per loaded model and region list and kept
    in the service's cache. ``SceneModel.estimate`` matches patches in this same order."""
    mi = _known_indices(loaded.model, region_ids)
    with _CACHE_LOCK:
        hit = loaded.solvers.get(mi)
    if hit is None:
        hit = loaded.model.solver(list(mi))
        with _CACHE_LOCK:
            loaded.solvers[mi] = hit
    return hit


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


def _intervals(result: RetrievalResult, extra: dict, i: int) -> dict | None:
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
        loaded = _load_model(path)
        result, extra = loaded.model.estimate(obs, solver=_solver(loaded, list(region_ids)))
    except Exception as exc:  # noqa: BLE001 - the frame is stored either way; an unreadable model must not lose it
        log.warning("scene model estimate failed for camera %s: %s", camera_id, exc)
        return None
    if not np.all(np.isfinite(result.white[0])):
        return None
    conf = float(np.asarray(extra["confidence"])[0]) if extra and "confidence" in extra else float(present.mean())
    return _row(result, 0, conf, "model", _intervals(result, extra, 0))


def _save_model(fitted: scene_model.SceneModel, path: Path) -> None:
    """Write a fitted scene model atomically: readers see the old or the new model, never half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")
    fitted.save(tmp)
    os.replace(tmp, path)


def _seen_patches(obs: Observations) -> Observations:
    """``obs`` without the patches never seen (a region always occluded or clipped cannot be fitted)."""
    seen = obs.present.any(axis=0)
    if seen.all():
        return obs
    return obs.select_patches([p for p, s in zip(obs.patches, seen, strict=True) if s])


def _known_seen(obs: Observations, known: dict[str, NDArray[np.float64]] | None) -> dict | None:
    """The references among ``obs``'s patches (a reference never measured, e.g. every chart patch clipped, is left
    out: the fit refuses a known patch it never sees)."""
    if not known:
        return None
    return {k: v for k, v in known.items() if k in obs.patches} or None


def _fit_model(obs: Observations, css: NDArray[np.float64] | None, path: Path, max_fit_frames: int = 300,
               known: dict[str, NDArray[np.float64]] | None = None, primaries: str = "camera") -> str:
    """Fit and save a scene model with :mod:`illumon.model`; returns a status string."""
    try:
        seen = _seen_patches(obs)
        fitted = scene_model.fit_scene_model(seen, css, known_reflectances=_known_seen(seen, known),
                                             max_fit_frames=max_fit_frames, primaries=primaries)
        _save_model(fitted, path)
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
            solver = fitted.solver(list(_known_indices(fitted, part.patches)))
        try:
            est = fitted.estimate(part, solver=solver)
        except ValueError:  # no frame of this chunk has two of the model's patches
            continue
        yield est


def _refit_with_model(
    obs: Observations, css: NDArray[np.float64] | None, model_file: Path | None, max_fit_frames: int,
    known: dict[str, NDArray[np.float64]] | None = None, primaries: str = "camera",
) -> tuple[dict[str, dict], dict]:
    """Fit the scene model on the history (reflectances on ≤ ``max_fit_frames`` frames spread over the illuminant
    range), save it, and estimate every frame with it: ``illumon fit`` then ``illumon estimate --model``."""
    seen = _seen_patches(obs)
    fitted = scene_model.fit_scene_model(seen, css, known_reflectances=_known_seen(seen, known),
                                         max_fit_frames=max_fit_frames, primaries=primaries)
    if model_file is not None:
        _save_model(fitted, model_file)
        _MODEL_CACHE.pop(str(model_file), None)
    out: dict[str, dict] = {}
    ccts = []
    for result, extra in _history_estimates(fitted, obs):
        ok = np.all(np.isfinite(result.white), axis=1)
        conf = np.asarray(extra["confidence"], dtype=float)
        keep = ok & np.array([not str(fid).startswith(CALIBRATION_PREFIX) for fid in result.frames])
        out.update({
            fid: _row(result, i, conf[i], "refit:model", _intervals(result, extra, i))
            for i, fid in enumerate(result.frames) if keep[i]
        })
        ccts.append(result.cct[keep])
    cct = np.concatenate(ccts) if ccts else np.array([])
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
    frames: Sequence[tuple[str, str, dict[str, Any]]],
    region_ids: Sequence[str],
    sensitivities: NDArray[np.float64] | None,
    *,
    method: str = "model",
    model_file: Path | None = None,
    max_fit_frames: int = 300,
    calibrations: Sequence[tuple[str, str, dict[str, Any]]] = (),
    known_reflectances: dict[str, NDArray[np.float64]] | None = None,
    primaries: str = "camera",
) -> tuple[dict[str, dict], dict]:
    """Estimates of the given frames: ``({frame id: estimate}, summary)``.

    ``method="model"`` (default) fits the learned scene model (:func:`illumon.model.fit_scene_model`, reflectances
    on at most ``max_fit_frames`` frames spread over the illuminant range), saves it to ``model_file`` and estimates
    every frame with it — the same numbers as ``illumon fit`` then ``illumon estimate --model``; its cost grows
    linearly with the history. The retrieval methods (``joint``, ``marguier2007``, ``gray_world``) run
    :func:`illumon.retrieval.retrieve_illuminants` over all the given frames (``illumon estimate --method``; the
    joint fit grows faster than linearly: keep such histories to a few hundred frames) and then fit a model too.

    ``sensitivities=None`` is a camera nobody measured (the model's prior from measured cameras). ``calibrations``
    are extra frames (ids ``calibration-<id>``) holding only reference patches whose spectra ``known_reflectances``
    gives (a ColorChecker, a grey card): they join the fit's history, pin the camera, and get no estimate of their
    own. Frames with fewer than two regions seen are left out. Raises :class:`RefitInputError` when fewer than two
    frames remain, or for a retrieval method on an unmeasured camera.
    """
    if sensitivities is None and method != "model":
        raise RefitInputError(f"refit method {method!r} needs measured sensitivities; this camera has none (use the "
                              "default method 'model', which calibrates from the prior and calibration images)")
    if len(frames) < 2:
        raise RefitInputError(f"refit needs at least two frames with two regions seen; {len(frames)} stored: post "
                              "frames (POST /v1/cameras/{id}/frames), then refit")
    obs = build_observations(frames, region_ids)
    usable = np.flatnonzero(obs.present.sum(axis=1) >= 2)
    if usable.size < 2:
        raise RefitInputError(f"refit needs at least two frames with two regions seen; {usable.size} available "
                              f"(of {len(frames)} stored): post more frames, then refit")
    if usable.size < len(frames):
        obs = obs.subset(usable)
    skipped = len(frames) - int(usable.size)
    if method == "model":
        if calibrations:
            ids = list(region_ids) + sorted({k for _, _, p in calibrations for k in p} - set(region_ids))
            obs = build_observations([frames[i] for i in usable] + list(calibrations), ids)
        out, summary = _refit_with_model(obs, sensitivities, model_file, max_fit_frames, known_reflectances, primaries)
        summary["calibration_frames"] = len(calibrations)
        summary["skipped_frames"] = len(frames) - len(out)
        return out, summary
    kwargs = {"daylight": "cie"} if method == "joint" else {}
    result = retrieve(obs, sensitivities, method, kwargs)
    frac = obs.present.mean(axis=1)
    out = {fid: _row(result, i, frac[i], f"refit:{method}") for i, fid in enumerate(result.frames)}
    summary = {
        "frames": len(result.frames),
        "skipped_frames": skipped,
        "method": method,
        "cost": result.info.get("cost"),
        "cct_k_median": float(np.median(result.cct)),
    }
    if model_file is not None:
        summary["model"] = _fit_model(obs, sensitivities, model_file, max_fit_frames, primaries=primaries)
    return out, summary



def retrieve(obs: Observations, css: NDArray[np.float64], method: str, kwargs: dict) -> RetrievalResult:
    """Call :func:`illumon.retrieval.retrieve_illuminants` (imported lazily: it loads SciPy)."""
    from illumon.retrieval import retrieve_illuminants

    return retrieve_illuminants(obs, css, method=method, **kwargs)


GRID_WAVELENGTHS = [float(v) for v in WAVELENGTHS]
"""Wavelengths (nm) of stored spectra."""


RESPONSE_CHECK_FRAMES = 48
"""Frames (spread evenly over the history) the tone-response check diagnoses; ~2 s on 48 frames × 8 regions."""


def check_response(
    frames: Sequence[tuple[str, str, dict[str, Any]]],
    region_ids: Sequence[str],
    sensitivities: NDArray[np.float64] | None,
    encoding: str,
    max_frames: int = RESPONSE_CHECK_FRAMES,
) -> dict:
    """Does the stored history (values linearised with the declared response) still look non-linear?

    Runs the diagnosis's tone-curve test (:func:`illumon.diagnosis.stages.tone_stage`, the bilinear stage's test:
    the history is fitted as ``y = x^(1/γ)`` of a rank-4 linear model and γ is accepted by ΔBIC, Schwarz 1978) on at
    most ``max_frames`` frames spread evenly over the history. When the tone curve beats the linear model by the
    diagnosis's own margin (ΔBIC < −15, :data:`illumon.diagnosis.fit.NONE_MARGIN`) — whichever effect the whole
    diagnosis would finally name: an sRGB curve read as linear also fits as a *negative* black offset, often better —
    the declared ``encoding`` does not match what the camera sends: γ > 1 means the values are still tone-encoded
    (a camera sending sRGB declared ``linear``), γ < 1 that they were linearised once too often.

    Only the tone-curve test runs (issue 29): its candidate is the one the whole diagnosis computes, so the verdict
    is the same, at a fifth of the cost (the other extensions and the spectral stage took ~60 % of a 2k-frame refit).
    The test is camera-agnostic: ``sensitivities`` are not used.

    Returns
    -------
    dict
        ``{"checked", "effect"`` (``nonlinear_response`` when the tone curve is supported, else ``none``; before
        issue 29 the whole diagnosis's answer), ``"tone_score"`` (ΔBIC of the tone curve), ``"gamma"``
        (when the tone curve is supported), ``"warnings": [str, ...], "reason"}``;
        ``checked`` is false (and ``reason`` says why) when the history is too short (the test needs 6 frames
        and 3 regions) or the test fails.
    """
    from illumon._blas import single_blas_thread
    from illumon.diagnosis.fit import NONE_MARGIN, RANK
    from illumon.diagnosis.stages import tone_stage

    obs = build_observations(frames, region_ids)
    keep = np.flatnonzero(obs.present.sum(axis=1) >= 3)
    if keep.size > max_frames:
        keep = keep[np.round(np.linspace(0, keep.size - 1, max_frames)).astype(int)]
    out: dict[str, Any] = {"checked": False, "effect": None, "gamma": None, "warnings": [], "reason": ""}
    if keep.size < RANK + 2 or len(region_ids) < 3:
        out["reason"] = f"tone response not checked: needs {RANK + 2} frames with 3 regions seen, {keep.size} stored"
        return out
    obs = _seen_patches(obs.subset(keep))
    try:
        f, p, _ = obs.values.shape
        if p < 3:  # as the diagnosis requires
            raise ValueError(f"diagnosis needs at least 3 patches, got {p}")
        tone, _ = single_blas_thread(tone_stage)(obs.values.reshape(f, 3 * p), RANK)
    except Exception as exc:  # noqa: BLE001 - a check that cannot run must not fail the refit
        log.warning("tone-response check failed: %s", exc)
        out["reason"] = f"tone response not checked: {exc}"
        return out
    supported = tone.score < -NONE_MARGIN["nonlinear_response"]
    out.update(checked=True, effect="nonlinear_response" if supported else "none",
               tone_score=round(float(tone.score), 1))
    if supported:
        g = float(tone.parameters["gamma"])
        out["gamma"] = g
        if g > 1:
            hint = (f"the frames still look tone-encoded (values ≈ linear^(1/{g:.2f})) although the camera is declared "
                    f"'{encoding}': most cameras send sRGB-encoded JPEG; register it with response encoding 'srgb' (or "
                    "'gamma'), else every estimate is off")
        else:
            hint = (f"the frames look linearised twice (values ≈ linear^(1/{g:.2f})) with the declared response '{encoding}': "
                    "the camera probably sends linear (raw) values; declare response encoding 'linear'")
        out["warnings"].append(hint)
    return out
