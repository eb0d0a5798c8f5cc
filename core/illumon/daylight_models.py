"""Daylight models by name (``--daylight-model``): the registry and its factory, in one place above both models
(:class:`illumon.daylight.CIEDaylight`, :class:`illumon.daylight_measured.MeasuredDaylight`)."""

from __future__ import annotations

from .daylight import CIEDaylight, DaylightModel
from .daylight_measured import MeasuredDaylight

__all__ = ["DAYLIGHT_MODELS", "daylight_model"]

DAYLIGHT_MODELS: dict[str, type[DaylightModel]] = {"cie": CIEDaylight, "measured": MeasuredDaylight}
"""Daylight models by name; more may be registered here."""


def daylight_model(name: str | DaylightModel = "cie") -> DaylightModel:
    """A daylight model instance by name (``"cie"`` or ``"measured"``), or the instance itself."""
    if isinstance(name, DaylightModel):
        return name
    try:
        return DAYLIGHT_MODELS[name]()
    except KeyError:
        raise ValueError(f"unknown daylight model {name!r}; choose from {', '.join(DAYLIGHT_MODELS)}") from None
