"""Bodies of frame ingest: client-measured region means in, a stored frame and its estimate out."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from ...limits import MAX_VALUE, check_text
from .common import CAMERA_APPLIED, Exposure, Gains, IsoDateTime, NonNegative, Strict, multipart_body
from .estimates import EstimateOut

__all__ = ["ObservationIn", "Patch", "RegionValues", "RegistrationOut", "FrameIngestOut", "FrameOut", "FRAME_UPLOAD"]


class ObservationIn(Strict):
    """Region means measured by the client: linear values divided by ``white_level`` (default 1: already 0…1)."""

    taken_at: IsoDateTime | None = None
    patches: dict[str, Annotated[list[NonNegative], Field(min_length=3, max_length=3)] | None] = Field(min_length=1)
    """Region id → ``[r, g, b]``, or ``null`` where the region is not usable; at least one must have a value."""
    sd: dict[str, Annotated[list[NonNegative], Field(min_length=3, max_length=3)] | None] | None = None
    """Optional standard errors of the means (region id → ``[r, g, b]``, same scale as ``patches``; e.g. the pixels'
    standard deviation over √pixels): a noisy region then weighs less and widens the frame's intervals."""
    white_level: float = Field(default=1.0, gt=0, le=1e9, allow_inf_nan=False, strict=True)
    applied_gains: Gains | None = None
    """White-balance gains (r, g, b) the camera applied to linear values in this frame; divided out."""
    exposure: Exposure | None = None
    """Relative exposure the camera applied in this frame; divided out."""

    @model_validator(mode="after")
    def _within_white(self) -> ObservationIn:
        """Means and standard errors at most :data:`~illumon_service.limits.MAX_VALUE` × ``white_level``."""
        limit = MAX_VALUE * self.white_level
        for field, values in (("patches", self.patches), ("sd", self.sd or {})):
            for rid, v in values.items():
                check_text(rid, f"{field} key")
                if v is not None and max(v) > limit:
                    raise ValueError(f"{field}[{rid!r}]: {max(v):g} exceeds {MAX_VALUE:g} × white_level ({limit:g}): "
                                     "region means are linear values on the 0…white_level scale")
        return self


Patch = tuple[float, float, float]
"""Linear ``[r, g, b]`` (0…1); a tuple: validated three times faster than a list of three, the same JSON."""
RegionValues = dict[str, Patch | None]
"""Region id → linear ``[r, g, b]`` means (0…1), ``null`` where the region was not usable."""


class RegistrationOut(BaseModel):
    """Where a frame lies relative to its view's reference frame: ``state`` (``reference``, ``ok``, ``featureless``
    or ``view_change``), the scene's shift ``[dx, dy]`` in pixels and the phase-correlation peak (``null`` for the
    reference itself)."""

    model_config = ConfigDict(extra="allow")

    state: str
    shift: list[float]
    response: float | None


class FrameIngestOut(BaseModel):
    """A stored frame: its region means (linear 0…1, the camera's gains and exposure not yet divided out), what the
    camera applied, how many regions were usable, its view and registration, its estimate (``null`` when the frame
    could not be estimated; see ``warnings``)."""

    frame_id: int
    taken_at: str
    regions: RegionValues
    applied_gains: list[float] | None
    exposure: float | None
    usable_regions: int
    view: str | None
    registration: RegistrationOut | None
    estimate: EstimateOut | None
    warnings: list[str]


class FrameOut(BaseModel):
    """A stored frame: region means (linear 0…1), image size (``null`` for client-side observations), what the camera
    applied, its view and registration."""

    frame_id: int
    taken_at: str
    regions: RegionValues
    width: int | None
    height: int | None
    applied_gains: list[float] | None
    exposure: float | None
    view: str | None
    registration: RegistrationOut | None
    not_estimated: str | None
    """Why the frame has no estimate (``view_change``, ``no_regions``, ``too_few_regions``, ``no_model``,
    ``invalid_values``, ``estimate_failed``; ``pending`` for frames of older versions), ``null`` once estimated."""


FRAME_UPLOAD: dict[str, Any] = multipart_body(["image"], {
    "image": {"type": "string", "format": "binary",
              "description": "PNG, JPEG or TIFF, 8- or 16-bit, RGB (a grey, single-channel image answers 422)"},
    "taken_at": {"type": "string", "format": "date-time", "description": "ISO 8601; naive means UTC; now when absent"},
    **CAMERA_APPLIED,
})
"""OpenAPI request body of ``POST /v1/cameras/{id}/frames`` (parsed by hand, so FastAPI cannot infer it)."""
