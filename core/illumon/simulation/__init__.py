"""Simulated fixed-camera histories for tests, benchmarks and the daylight report; nothing that estimates imports it.

* :mod:`.simulate` — render a history of static patches under a sequence of illuminants, with the camera's
  auto-exposure and noise (:class:`~illumon.camera.noise.CameraNoise`), and its ground truth;
* :mod:`.scenarios` — Marguier & Süsstrunk's synthetic protocol and measured-daylight histories;
* :mod:`.effects` — the effects that break the linear model and :func:`~.effects.hide_effect`, which hides one in a
  simulated history (the draws the three simulators share);
* :mod:`.datasets` — loaders of the measured data beside the project (``../shared/data``).

The package sits above the camera, daylight and priors it renders with and below the reports and the command line;
the estimators (camera calibration, retrieval, model, sensitivity, diagnosis) never import it.
"""

from ..camera.noise import DEFAULT_NOISE, CameraNoise
from . import datasets
from .scenarios import PAPER_PATCH_SETS, PAPER_TABLES, measured_daylight_history, paper_cct, paper_protocol
from .simulate import SimulatedHistory, simulate_history

__all__ = [
    "CameraNoise",
    "DEFAULT_NOISE",
    "SimulatedHistory",
    "simulate_history",
    "PAPER_TABLES",
    "PAPER_PATCH_SETS",
    "paper_cct",
    "paper_protocol",
    "measured_daylight_history",
    "datasets",
]
