"""Learned scene models: fit a fixed camera's patch reflectances once, then estimate each new frame in well under 1 ms.

* :mod:`.scene` — :class:`SceneModel` (patch reflectances with their posterior, the camera, daylight prior, noise,
  training summary, identifiability) and its versioned JSON;
* :mod:`.fit` — :func:`fit_scene_model`, block coordinate descent on the joint posterior (Kinoshita & Kiya's
  reflectance posterior, eqs. 11–16, alternating with the per-frame solver), unmeasured cameras through
  :mod:`illumon.camera.calibration`;
* :mod:`.solver` — :class:`FrameSolver`, every frame's daylight and exposure for fixed reflectances (a 3 × 3 linear
  solve and a 3-parameter Gauss–Newton, vectorised over frames);
* :mod:`.intervals` — 95 % intervals of CCT, Duv and the gains, and ``confidence``, the posterior probability that the
  camera white is within 1° of the truth;
* :mod:`.identifiability` — whether a history determines its illuminants;
* :mod:`.weights` — tabulated CIE D-series weights for the solver's inner loop.
"""

from .fit import fit_scene_model
from .identifiability import IdentifiabilityWarning, identifiability
from .intervals import MODEL_ERROR, interval_columns
from .scene import MODEL_FORMAT, MODEL_VERSION, SceneModel, estimate_with_model
from .solver import CENSORED, NEAR_WHITE, FrameSolver

__all__ = [
    "MODEL_FORMAT",
    "MODEL_VERSION",
    "MODEL_ERROR",
    "CENSORED",
    "NEAR_WHITE",
    "SceneModel",
    "FrameSolver",
    "IdentifiabilityWarning",
    "identifiability",
    "fit_scene_model",
    "estimate_with_model",
    "interval_columns",
]
