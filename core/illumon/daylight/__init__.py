"""Daylight: the CIE D-series, CCT / Duv conversions, Marguier & Süsstrunk's θ curve, measured daylight, and the
registry of the daylight models the solvers use (``--daylight-model``).

One module per source:

* :mod:`.ohno2013` — CCT and Duv ↔ chromaticity through a tabulated Planckian locus (Ohno 2013);
* :mod:`.cie` — the CIE D-series (CIE 015): spectrum from chromaticity, daylight locus, :class:`CIEDaylight`;
* :mod:`.marguier2007` — the θ curve through CIE D40…D100 (Marguier & Süsstrunk 2007);
* :mod:`.measured` — :class:`MeasuredDaylight`, a PCA basis of measured (Granada) daylight with an off-locus prior;
* :mod:`.base` — the :class:`DaylightModel` interface and :data:`MIRED_RANGE`.

This package holds the registry (:data:`DAYLIGHT_MODELS`, :func:`daylight_model`), above both models, and re-exports
their public names, so ``from illumon.daylight import daylight_spectrum`` is the way in.
"""

from __future__ import annotations

from ..registry import Registry
from .base import MIRED_RANGE, DaylightModel
from .cie import (
    CIE_D_BASIS,
    CMFS,
    CIEDaylight,
    cie_d_cct,
    cie_d_weights,
    daylight_locus_duv,
    daylight_locus_xy,
    daylight_spectrum,
    xy_from_spectrum,
)
from .marguier2007 import ThetaCurve, theta_curve
from .measured import MeasuredDaylight, MeasuredDaylightData, shipped_measured_daylight
from .ohno2013 import cct_duv_from_xy, xy_from_cct_duv

__all__ = [
    "CIE_D_BASIS",
    "CMFS",
    "MIRED_RANGE",
    "cie_d_weights",
    "daylight_spectrum",
    "daylight_locus_xy",
    "cie_d_cct",
    "daylight_locus_duv",
    "xy_from_cct_duv",
    "cct_duv_from_xy",
    "xy_from_spectrum",
    "ThetaCurve",
    "theta_curve",
    "DaylightModel",
    "CIEDaylight",
    "MeasuredDaylight",
    "MeasuredDaylightData",
    "shipped_measured_daylight",
    "DAYLIGHT_MODELS",
    "daylight_model",
]

DAYLIGHT_MODELS: Registry[type[DaylightModel]] = Registry({
    "cie": (CIEDaylight, "CIE D-series daylight, two parameters a frame"),
    "measured": (MeasuredDaylight, "the measured-daylight model: PCA basis of Granada skies, off-locus prior"),
})
"""Daylight models by name (``illumon estimate --daylight-model``); more may be registered here."""


def daylight_model(name: str | DaylightModel = "cie") -> DaylightModel:
    """A daylight model instance by name (``"cie"`` or ``"measured"``), or the instance itself.

    Parameters
    ----------
    name
        A key of :data:`DAYLIGHT_MODELS`, or a model instance (returned as is).

    Returns
    -------
    DaylightModel
        A new instance with default parameters.

    Raises
    ------
    ValueError
        For an unknown name (the message lists the known ones).
    """
    if isinstance(name, DaylightModel):
        return name
    try:
        return DAYLIGHT_MODELS[name]()
    except KeyError:
        raise ValueError(f"unknown daylight model {name!r}; choose from {', '.join(DAYLIGHT_MODELS)}") from None
