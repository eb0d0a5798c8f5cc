"""What illumon knows before it sees a camera's frames: priors built from measured data, one module per quantity.

* :mod:`.camera` — :class:`CameraPrior`, a Gaussian on camera sensitivities from the measured cameras (the camera
  nobody measured, and the single-chart sensitivity estimators);
* :mod:`.daylight` — :class:`DaylightPrior`, a Gaussian on daylight spectra from the Granada measurements;
* :mod:`.surfaces` — :class:`ReflectanceBasis`, the 8-function reflectance basis with its Gaussian coefficient prior,
  and the ColorChecker and unseen test reflectances shipped with colour-science.

The priors sit one layer above :mod:`illumon.spectra` and below everything that estimates (camera calibration,
retrieval, the scene model, sensitivity, diagnosis), so those import them downwards and never from one another.
"""

from .camera import (
    CameraPrior,
    build_camera_prior,
    default_camera_prior,
    jiang2013_channel_bases,
    max_normalise,
    rendered_camera_prior,
)
from .daylight import DaylightPrior, build_daylight_prior, default_daylight_prior
from .surfaces import ReflectanceBasis, colourchecker_reflectances, reflectance_basis, unseen_reflectances

__all__ = [
    "CameraPrior",
    "build_camera_prior",
    "default_camera_prior",
    "rendered_camera_prior",
    "jiang2013_channel_bases",
    "max_normalise",
    "DaylightPrior",
    "build_daylight_prior",
    "default_daylight_prior",
    "ReflectanceBasis",
    "reflectance_basis",
    "colourchecker_reflectances",
    "unseen_reflectances",
]
