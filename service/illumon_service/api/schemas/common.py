"""What every body shares: checked number and text types, the strict base of request bodies, ISO 8601 times, the
error answers and the hand-parsed multipart bodies of the OpenAPI schema."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field

from ...limits import EXPOSURE_RANGE, GAINS_RANGE, check_text

__all__ = ["IsoDateTime", "Finite", "NonNegative", "Positive", "Gain", "Gains", "Exposure", "Text", "Strict", "MAX_LIST",
           "MAX_SIDE", "optional_key", "HealthOut", "ErrorOut", "ERROR_RESPONSES", "multipart_body", "CAMERA_APPLIED"]


def _iso_text(value: Any) -> Any:
    """Let only ISO 8601 text (or a datetime) through: pydantic's lax mode would read a number, or numeric text such
    as ``0.0``, as a Unix time, which the OpenAPI schema (``string``, ``date-time``) does not allow."""
    if isinstance(value, (int, float)):
        raise ValueError("expected an ISO 8601 date-time string such as 2025-06-01T12:00:00Z, not a number")
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            return value
        raise ValueError(f"{value!r} is a number; expected an ISO 8601 date-time such as 2025-06-01T12:00:00Z")
    return value


IsoDateTime = Annotated[datetime, BeforeValidator(_iso_text)]
"""A date-time given as ISO 8601 text (naive means UTC); numbers and numeric text answer 422."""

# strict: JSON numbers only (pydantic's lax mode would read true/false or numeric text as numbers, which the OpenAPI
# schema does not allow)
Finite = Annotated[float, Field(allow_inf_nan=False, strict=True)]
NonNegative = Annotated[float, Field(allow_inf_nan=False, ge=0, strict=True)]
Positive = Annotated[float, Field(allow_inf_nan=False, gt=0, strict=True)]
Gain = Annotated[float, Field(allow_inf_nan=False, ge=GAINS_RANGE[0], le=GAINS_RANGE[1], strict=True)]
Gains = Annotated[list[Gain], Field(min_length=3, max_length=3)]
"""r, g, b multipliers a camera applied to linear values (within :data:`~illumon_service.limits.GAINS_RANGE`)."""
Exposure = Annotated[float, Field(allow_inf_nan=False, ge=EXPOSURE_RANGE[0], le=EXPOSURE_RANGE[1], strict=True)]
"""A relative exposure (within :data:`~illumon_service.limits.EXPOSURE_RANGE`)."""


def _plain_text(value: str) -> str:
    return check_text(value, "text")


Text = Annotated[str, AfterValidator(_plain_text)]
"""A string without control characters (NUL and the like: 422 on every database)."""


class Strict(BaseModel):
    """Request bodies: no NaN or infinity, no unknown keys."""

    model_config = ConfigDict(allow_inf_nan=False, extra="forbid")


MAX_LIST = 100_000
"""Largest ``limit`` of a list route (``/frames``, ``/estimates``); outside 1…MAX_LIST answers 422."""

MAX_SIDE = 1_000_000
"""Largest region coordinate or side in pixels (beyond any image the service accepts)."""


class HealthOut(BaseModel):
    """``ok`` when the database answers."""

    status: str


def optional_key(description: str) -> Any:
    """A key that an answer may lack (never ``null``): the schema lists no default; routes answering a model with one
    set ``response_model_exclude_unset`` so that a missing key stays missing."""
    return Field(default=None, description=description, json_schema_extra=lambda s: s.pop("default", None))


class ErrorOut(BaseModel):
    """Every 4xx/5xx answer: ``{"detail": ...}`` — a sentence, or for malformed bodies a list of
    ``{"loc", "msg", "type"}`` items."""

    detail: str | list[dict[str, Any]]


ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorOut, "description": "Malformed request (e.g. a body that is not valid multipart)"},
    401: {"model": ErrorOut, "description": "Missing or unknown bearer token"},
    403: {"model": ErrorOut, "description": "Admin token required"},
    404: {"model": ErrorOut, "description": "Unknown resource, or another camera's"},
    413: {"model": ErrorOut, "description": "Upload or image too large"},
    415: {"model": ErrorOut, "description": "Unsupported content type or image format"},
    422: {"model": ErrorOut, "description": "Invalid values (schema, NaN/infinite/negative numbers, regions, images)"},
}
"""Error answers documented on every ``/v1`` route (the OpenAPI schema lists what the routes really answer)."""

def multipart_body(required: list[str], properties: dict[str, dict]) -> dict[str, Any]:
    """``openapi_extra`` of a route whose ``multipart/form-data`` body is parsed by hand (FastAPI cannot infer it)."""
    schema = {"type": "object", "required": required, "properties": properties}
    return {"requestBody": {"required": True, "content": {"multipart/form-data": {"schema": schema}}}}


CAMERA_APPLIED: dict[str, dict] = {
    "applied_gains": {"type": "string", "pattern": r"^[^,]+,[^,]+,[^,]+$",
                      "description": "'r,g,b': white-balance gains the camera applied to linear values (positive); "
                                     "divided out"},
    "exposure": {"type": "string", "description": "relative exposure the camera applied (positive); divided out"},
}
"""Form fields of an upload saying what the camera itself applied to the image."""
