"""Where the service estimates: every call into core's estimators (the scene model, retrieval, the diagnosis's
tone-curve test) goes through this package; all numerics live in the core library.

* :func:`estimate_frame` — per-frame estimate at ingest (:mod:`.frame`). Uses the camera view's learned scene model
  (:mod:`illumon.model`) once a refit has fitted one (:mod:`.models`: ``<data dir>/models/camera-<id>….json``);
  otherwise returns ``None`` and the frame is estimated by the next refit.
* :func:`refit_estimates` — over a camera's stored history (:mod:`.fit`): by default fits the scene model
  (:func:`illumon.model.fit_scene_model`), saves it for the per-frame estimates at ingest and estimates every stored
  frame with it (``illumon fit`` + ``illumon estimate --model``); or multi-frame retrieval
  (:func:`illumon.retrieval.retrieve_illuminants`, ``illumon estimate --method``) followed by a model fit.
* :func:`check_response` — the declared tone response against the stored history (:mod:`.response`).
* :mod:`.history` — stored rows as the estimators' input: applied gains and exposure divided out
  (:func:`illumon.camera.undo_applied`), observations, calibration images with their references' reflectances.

Confidence (0…1): with a scene model, its posterior probability that the camera white is within 1° of the truth
(:mod:`illumon.model`); from a retrieval-method refit, the fraction of the camera's regions seen in the frame (a
ranking aid, not a probability). Intervals (95 %: ``cct_lo/hi``, ``duv_lo/hi``, ``gain_lo/hi``) come from the model.

The service imports core elsewhere only for what is not estimation: the cameras' tone curves to measure pixels
(:class:`illumon.camera.ResponseCurve` in :mod:`..regions`, :mod:`..calibration`, :mod:`..proposals`), sensitivities
resampled onto the grid at registration (:mod:`illumon.spectra`, the cameras route), white to gains in camera-software
conventions (:mod:`illumon.gains`, the gains route), the BLAS thread limit of the refit workers (:mod:`..jobs`) and the
simulated day of :mod:`..demo`.
"""

from .batch import RefitEstimates
from .fit import RefitInputError, fit_model, refit_estimates, retrieve
from .frame import GRID_WAVELENGTHS, estimate_frame, json_safe
from .history import (
    CALIBRATION_PREFIX,
    build_observations,
    calibration_frames,
    camera_primaries,
    history_arrays,
    history_row,
    seen_patches,
    sensitivities_array,
    undo_camera_gains,
    undo_camera_gains_sd,
)
from .models import (
    current_model,
    model_available,
    model_path,
    remove_old_models,
    versioned_model_path,
    view_model_key,
)
from .response import RESPONSE_CHECK_FRAMES, check_response

__all__ = [
    "RefitEstimates", "RefitInputError", "fit_model", "refit_estimates", "retrieve",
    "GRID_WAVELENGTHS", "estimate_frame", "json_safe",
    "CALIBRATION_PREFIX", "build_observations", "calibration_frames", "camera_primaries", "history_arrays", "history_row",
    "seen_patches", "sensitivities_array", "undo_camera_gains", "undo_camera_gains_sd",
    "current_model", "model_available", "model_path", "remove_old_models", "versioned_model_path", "view_model_key",
    "RESPONSE_CHECK_FRAMES", "check_response",
]
