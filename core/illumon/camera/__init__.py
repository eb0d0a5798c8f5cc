"""The camera as part of the model: image formation, the output pipeline, references of known reflectance, and
calibration of a camera nobody measured.

* :mod:`~illumon.camera.formation` — ``rgb = k · Σλ C(λ) E(λ) R(λ)``, camera white, gains, angular error;
* :mod:`~illumon.camera.pipeline` — black level, tone curve (linear, sRGB, gamma, table), colour matrix, and the
  camera's own per-frame gains and exposure (:func:`undo_applied`);
* :mod:`~illumon.camera.references` — grey card, ColorChecker, measured surfaces (``KNOWN.csv``);
* :mod:`~illumon.camera.calibration` — sensitivities as ``C0 T`` with a Gaussian posterior on ``T`` (Kinoshita & Kiya),
  estimated jointly with the scene;
* :mod:`~illumon.camera.noise` — the noise of patch means and the auto-exposure (:class:`CameraNoise`).
"""

from .formation import angular_error_deg, camera_white, gains_from_white, render
from .noise import DEFAULT_NOISE, CameraNoise
from .pipeline import ENCODINGS, CameraPipeline, ResponseCurve, undo_applied
from .references import colourchecker_references, grey_card_reference, read_known_reflectances

__all__ = [
    "render",
    "camera_white",
    "gains_from_white",
    "angular_error_deg",
    "ENCODINGS",
    "ResponseCurve",
    "CameraPipeline",
    "undo_applied",
    "colourchecker_references",
    "grey_card_reference",
    "read_known_reflectances",
    "CameraNoise",
    "DEFAULT_NOISE",
]
