"""Camera spectral sensitivities from one chart image under unknown light, daylight recovery, colour correction.

Methods (select by name with :func:`estimate_sensitivities`):

``default``
    illumon's estimator: measured-camera and measured-daylight Gaussian priors, sensitivities integrated out to
    choose the daylight, then a non-negative MAP (:func:`~illumon.sensitivity.default.sensitivities_illumon`).
``kinoshita2023`` (formerly ``bayes``)
    Kinoshita & Kiya's Gaussian posteriors (eqs. 11–16), alternated for an unknown daylight.
``jiang2013``
    Jiang et al. (WACV 2013): 2 eigenvectors per channel and a CIE-D search, with colour-science's
    :func:`colour.recovery.RGB_to_msds_camera_sensitivities_Jiang2013`.
``huynh2014`` (formerly ``huynh2016``)
    Huynh & Robles-Kelly: NNLS (eq. 3) and coordinate descent on eq. (8).
``han2012``
    Han et al. (CVPR 2012): fluorescent chart + reference chart (eqs. 6–16); needs the fluorescent chart's inputs.
"""

from __future__ import annotations

from collections.abc import Callable

from numpy.typing import ArrayLike

from .._blas import single_blas_thread
from ..registry import Registry
from .common import SensitivityResult, rmse_per_channel
from .correction import (
    channel_gains_Han2012,
    correct_Han2012,
    to_cie1931_Huynh2014,
    transfer_matrix_Huynh2014,
)
from .daylight_recovery import daylight_Han2012
from .default import sensitivities_illumon
from .han2012 import sensitivities_Han2012
from .huynh2014 import sensitivities_Huynh2014
from .jiang2013 import sensitivities_Jiang2013
from .kinoshita2023 import sensitivities_Kinoshita2023

__all__ = [
    "METHODS",
    "ALIASES",
    "estimate_sensitivities",
    "SensitivityResult",
    "rmse_per_channel",
    "sensitivities_illumon",
    "sensitivities_Kinoshita2023",
    "sensitivities_Jiang2013",
    "sensitivities_Huynh2014",
    "sensitivities_Han2012",
    "daylight_Han2012",
    "channel_gains_Han2012",
    "correct_Han2012",
    "transfer_matrix_Huynh2014",
    "to_cie1931_Huynh2014",
]

METHODS: Registry[Callable[..., SensitivityResult]] = Registry({
    "default": (sensitivities_illumon, "illumon's estimator: measured-camera and measured-daylight priors"),
    "kinoshita2023": (sensitivities_Kinoshita2023,
                      "Kinoshita & Kiya's Gaussian posteriors, alternated for an unknown daylight"),
    "jiang2013": (sensitivities_Jiang2013, "Jiang et al. (WACV 2013): camera PCA basis and a CIE daylight search"),
    "huynh2014": (sensitivities_Huynh2014, "Huynh & Robles-Kelly (ICPR 2014): NNLS and coordinate descent"),
    "han2012": (sensitivities_Han2012, "Han et al. (CVPR 2012): a fluorescent chart beside a reference chart"),
})
"""Sensitivity estimators by name (after the paper and year each implements; ``illumon sensitivity --method``)."""

ALIASES: dict[str, str] = {"bayes": "kinoshita2023", "huynh2016": "huynh2014"}
"""Earlier names of methods, still accepted: ``huynh2016`` was misdated (the paper is ICPR 2014)."""


@single_blas_thread
def estimate_sensitivities(
    chart_rgb: ArrayLike, chart_reflectances: ArrayLike, method: str = "default", **kwargs: object
) -> SensitivityResult:
    """Estimate camera sensitivities from one chart image with the method named ``method``.

    Parameters
    ----------
    chart_rgb
        Linear camera values of the chart patches (P × 3).
    chart_reflectances
        Patch reflectances on the grid (P × 61).
    method
        A key of :data:`METHODS`.
    **kwargs
        Passed to the method (priors, parameters; ``han2012`` needs ``fluorescent_rgb``,
        ``fluorescent_emissions`` and ``fluorescent_reflectances``).
    """
    try:
        fn = METHODS[ALIASES.get(method, method)]
    except KeyError:
        raise ValueError(f"unknown sensitivity method {method!r}; choose from {', '.join(METHODS)}") from None
    return fn(chart_rgb, chart_reflectances, **kwargs)
