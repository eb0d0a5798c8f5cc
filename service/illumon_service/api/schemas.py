"""Request and response bodies. Floats reject NaN and infinity; lengths and signs are checked."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, field_validator, model_validator

from ..limits import (
    EXPOSURE_RANGE,
    GAINS_RANGE,
    GAMMA_RANGE,
    LEVEL_MAX,
    MATRIX_MAX,
    MATRIX_MAX_CONDITION,
    MAX_VALUE,
    SENSITIVITY_MAX,
    WAVELENGTH_RANGE,
    check_text,
    regions_outside,
)


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

__all__ = [
    "SensitivitiesIn", "RegionIn", "ResponseIn", "CameraIn", "RegionsIn", "ObservationIn", "ErrorOut", "ERROR_RESPONSES",
    "FRAME_UPLOAD", "MAX_LIST", "multipart_body", "CAMERA_APPLIED", "EstimateOut", "SpectrumOut", "IlluminantOut", "JobRef",
    "HealthOut", "CameraOut", "CameraCreated", "FrameIngestOut", "FrameOut", "WbGainsOut", "JobOut", "CalibrationOut",
    "ProposalsOut", "DeletedOut",
]

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


class _Strict(BaseModel):
    model_config = ConfigDict(allow_inf_nan=False, extra="forbid")


Sensitivity = Annotated[float, Field(allow_inf_nan=False, ge=0, le=SENSITIVITY_MAX, strict=True)]


class SensitivitiesIn(_Strict):
    """Camera spectral sensitivities: one wavelength (nm) and three values per sample; must cover 400–700 nm.

    At least 6 samples (the spline interpolation onto the 5-nm grid needs them).
    """

    wavelength_nm: list[Annotated[float, Field(allow_inf_nan=False, ge=WAVELENGTH_RANGE[0], le=WAVELENGTH_RANGE[1],
                                               strict=True)]] = Field(min_length=6, max_length=2000)
    r: list[Sensitivity]
    g: list[Sensitivity]
    b: list[Sensitivity]

    @model_validator(mode="after")
    def _lengths(self) -> SensitivitiesIn:
        n = len(self.wavelength_nm)
        if not (len(self.r) == len(self.g) == len(self.b) == n):
            raise ValueError("wavelength_nm, r, g and b must have the same length")
        for ch in ("r", "g", "b"):
            if max(getattr(self, ch), default=0.0) <= 0:
                raise ValueError(f"sensitivities {ch}: every value is 0 (the channel would see nothing)")
        return self


MAX_LIST = 100_000
"""Largest ``limit`` of a list route (``/frames``, ``/estimates``); outside 1…MAX_LIST answers 422."""

MAX_SIDE = 1_000_000
"""Largest region coordinate or side in pixels (beyond any image the service accepts)."""


class RegionIn(_Strict):
    """A rectangle of static scene in pixels (origin top-left)."""

    id: Text = Field(min_length=1, max_length=100)
    x: int = Field(ge=0, le=MAX_SIDE, strict=True)
    y: int = Field(ge=0, le=MAX_SIDE, strict=True)
    width: int = Field(gt=0, le=MAX_SIDE, strict=True)
    height: int = Field(gt=0, le=MAX_SIDE, strict=True)


def _unique(regions: list[RegionIn]) -> list[RegionIn]:
    ids = [r.id for r in regions]
    if len(set(ids)) != len(ids):
        raise ValueError("region ids must be unique")
    return regions


MatrixEntry = Annotated[float, Field(allow_inf_nan=False, ge=-MATRIX_MAX, le=MATRIX_MAX, strict=True)]


class ResponseIn(_Strict):
    """The camera's output pipeline: tone curve, levels in the image's units (white level defaults to the image's
    full scale) and, optionally, the fixed 3 × 3 colour matrix it applies (output = ``matrix`` @ sensor RGB).

    The default is what an ordinary camera's JPEG or PNG holds: sRGB-encoded values over the image's full scale
    (8-bit: 0…255). Declare ``linear`` for raw or linear (e.g. 16-bit scientific) output, ``gamma`` with ``gamma``,
    or ``table`` with ``table``: the linear value (0…1, non-decreasing) of encoded values spaced evenly from the black
    to the white level. A refit warns when the stored history still looks non-linear for the declared encoding.
    """

    encoding: Literal["linear", "srgb", "gamma", "table"] = "srgb"
    gamma: float = Field(default=2.2, ge=GAMMA_RANGE[0], le=GAMMA_RANGE[1], allow_inf_nan=False, strict=True)
    black_level: float = Field(default=0.0, ge=0, lt=LEVEL_MAX, allow_inf_nan=False, strict=True)
    white_level: float | None = Field(default=None, gt=0, le=LEVEL_MAX, allow_inf_nan=False, strict=True)
    table: list[Annotated[float, Field(allow_inf_nan=False, ge=0, le=1, strict=True)]] | None = Field(
        default=None, min_length=2, max_length=65536)
    matrix: list[Annotated[list[MatrixEntry], Field(min_length=3, max_length=3)]] | None = Field(
        default=None, min_length=3, max_length=3)
    primaries: Literal["camera", "srgb"] | None = None
    """The output space: ``srgb`` (rendered output — the camera white-balanced its sensor and applied a colour matrix
    to sRGB / BT.709 primaries: IP, surveillance, phone cameras) or ``camera`` (sensor RGB: raw, machine-vision cameras
    without a colour matrix). Default: ``srgb`` for a camera registered without sensitivities whose encoding is
    ``srgb`` or ``table``, ``camera`` otherwise (measured sensitivities are taken as the output's own unless
    ``srgb`` is given)."""

    def resolved(self, measured: bool) -> dict:
        """The response as stored: ``primaries`` filled in with its default."""
        out = self.model_dump()
        if out["primaries"] is None:
            out["primaries"] = "srgb" if (not measured and self.encoding in ("srgb", "table")) else "camera"
        return out

    @model_validator(mode="after")
    def _levels(self) -> ResponseIn:
        if self.white_level is not None and self.white_level <= self.black_level:
            raise ValueError("white_level must exceed black_level")
        if (self.encoding == "table") != (self.table is not None):
            raise ValueError("give 'table' exactly when encoding is 'table'")
        if self.table is not None and (any(b < a for a, b in zip(self.table, self.table[1:], strict=False))
                                       or self.table[-1] <= 0):
            raise ValueError("table must be non-decreasing and end above 0")
        if self.matrix is not None:
            m = np.asarray(self.matrix)
            if abs(np.linalg.det(m)) < 1e-9 or np.linalg.cond(m) > MATRIX_MAX_CONDITION:
                raise ValueError(f"matrix is singular or nearly so (condition number above {MATRIX_MAX_CONDITION:g})")
        return self


class ImageSizeIn(_Strict):
    """Width and height of a camera's frames in pixels."""

    width: int = Field(gt=0, le=MAX_SIDE, strict=True)
    height: int = Field(gt=0, le=MAX_SIDE, strict=True)


class CameraIn(_Strict):
    """Registration of a camera; without ``sensitivities`` the camera is unmeasured (a prior from measured cameras,
    pinned by a calibration image: ``POST /v1/cameras/{id}/calibration``)."""

    name: Text = Field(min_length=1, max_length=200)
    sensitivities: SensitivitiesIn | None = None
    regions: list[RegionIn] = Field(default_factory=list, max_length=500)
    """Without regions, frames are stored (with thumbnails) until regions are confirmed (region proposals)."""
    response: ResponseIn = ResponseIn()
    image_size: ImageSizeIn | None = None
    """The frames' size in pixels, when known at registration: every region must then lie inside it (422
    otherwise), and ``PUT …/regions`` checks against it until a frame is stored."""

    _check_regions = field_validator("regions")(_unique)

    @model_validator(mode="after")
    def _regions_inside(self) -> CameraIn:
        if self.image_size is not None:
            size = (self.image_size.width, self.image_size.height)
            outside = regions_outside([r.model_dump() for r in self.regions], size)
            if outside:
                raise ValueError(f"region(s) {', '.join(map(repr, outside))} lie outside the {size[0]}×{size[1]} "
                                 "image (image_size): x + width ≤ width, y + height ≤ height")
        return self


class RegionsIn(_Strict):
    """Replacement of a camera's regions."""

    regions: list[RegionIn] = Field(min_length=1, max_length=500)

    _check_regions = field_validator("regions")(_unique)


class ObservationIn(_Strict):
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


class EstimateOut(BaseModel):
    """A frame's estimate: CCT (K), Duv (Ohno 2013), CIE 1931 xy, camera white (``white_rgb``, green = 1) and gains
    (``gains_rgb`` = [G/R, 1, G/B]) in the camera's output space, ``confidence`` (posterior probability that the camera
    white is within 1° of the truth; the fraction of regions seen for a retrieval-method estimate) and its ``source``."""

    frame_id: int
    taken_at: str
    cct_k: float | None
    duv: float | None
    xy: list[float | None]
    white_rgb: list[float | None]
    gains_rgb: list[float | None]
    confidence: float | None
    non_daylight: float | None = None
    """Posterior probability that the frame's light is not daylight (``null`` where the estimate was made without
    the test: retrieval methods, models saved before it)."""
    source: str


class SpectrumOut(BaseModel):
    """Relative spectral power (100 at 560 nm) on the wavelengths given."""

    wavelength_nm: list[float]
    values: list[float | None] | None


class IlluminantOut(EstimateOut):
    """The estimate nearest the requested time with its spectrum and 95 % intervals (``null`` where the method gives
    none; an unbounded interval end is ``null``)."""

    spectrum: SpectrumOut
    intervals: dict[str, Any] | None


class JobRef(BaseModel):
    """A queued job; poll ``GET /v1/jobs/{job_id}``."""

    job_id: str


class HealthOut(BaseModel):
    """``ok`` when the database answers."""

    status: str


def _optional_key(description: str) -> Any:
    """A key that an answer may lack (never ``null``): the schema lists no default; routes answering a model with one
    set ``response_model_exclude_unset`` so that a missing key stays missing."""
    return Field(default=None, description=description, json_schema_extra=lambda s: s.pop("default", None))


Patch = tuple[float, float, float]
"""Linear ``[r, g, b]`` (0…1); a tuple: validated three times faster than a list of three, the same JSON."""
RegionValues = dict[str, Patch | None]
"""Region id → linear ``[r, g, b]`` means (0…1), ``null`` where the region was not usable."""


class ResponseOut(BaseModel):
    """A camera's output pipeline as registered (see :class:`ResponseIn`); cameras registered by older versions may
    lack keys, which the answer then lacks too."""

    model_config = ConfigDict(extra="allow")

    encoding: Literal["linear", "srgb", "gamma", "table"] = _optional_key("tone curve")
    gamma: float = _optional_key("exponent of the ``gamma`` encoding")
    black_level: float = _optional_key("black level in the image's units")
    white_level: float | None = _optional_key("white level in the image's units (``null``: the image's full scale)")
    table: list[float] | None = _optional_key("``table`` encoding: linear values of evenly spaced codes")
    matrix: list[list[float]] | None = _optional_key("3 × 3 colour matrix the camera applies (output = matrix @ RGB)")
    primaries: Literal["camera", "srgb"] = _optional_key("output space: sensor RGB or rendered sRGB primaries")


class CalibrationRef(BaseModel):
    """A stored calibration image of a camera."""

    calibration_id: int
    kind: Literal["colorchecker", "grey"]
    created_at: str


class AlertOut(BaseModel):
    """An alert of the status page (:mod:`illumon_service.status`): a stable ``kind``, a short ``label``, a sentence
    and a severity."""

    kind: str
    label: str
    message: str
    severity: Literal["info", "warning"]


class CameraOut(BaseModel):
    """A camera's public view (never its token): regions of its default view and of its other ``views`` (PTZ preset
    id → regions), pipeline, whether its sensitivities were measured, what calibrates it (``chart`` | ``grey`` |
    ``measured`` | ``none``), its stored calibrations, the warnings of its latest refit and its alerts."""

    id: int
    name: str
    regions: list[RegionIn]
    response: ResponseOut
    sensitivities: Literal["measured", "unmeasured"]
    calibration: Literal["chart", "grey", "measured", "none"]
    calibrations: list[CalibrationRef]
    created_at: str
    warnings: list[str]
    not_estimated: dict[str, int]
    """Stored frames without an estimate, counted by reason (see :class:`FrameOut`)."""
    views: dict[str, list[RegionIn]]
    alerts: list[AlertOut]


class CameraCreated(BaseModel):
    """A registered camera's id and its bearer token (shown only once: only its hash is stored)."""

    id: int
    token: str


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


class OnvifGains(BaseModel):
    """ONVIF ``WhiteBalance``: CrGain/CbGain as unitless gains (no ``onvif_range`` given)."""

    model_config = ConfigDict(extra="forbid")

    Mode: Literal["MANUAL"]
    CrGain: float
    CbGain: float


class OnvifVendorGains(OnvifGains):
    """ONVIF ``WhiteBalance``: CrGain/CbGain mapped (log2) onto the vendor ``range`` given as ``onvif_range``."""

    range: list[float] = Field(min_length=2, max_length=2)


class LibcameraGains(BaseModel):
    """libcamera ``ColourGains`` ``[r, b]`` and ``ColourTemperature`` (K)."""

    ColourGains: list[float]
    ColourTemperature: int


class V4l2Gains(BaseModel):
    """V4L2 controls: ``red_balance``/``blue_balance`` = gain × ``unity``, ``white_balance_temperature`` (K) clamped to
    ``temperature_range_k`` (``temperature_clamped`` says when)."""

    red_balance: int
    blue_balance: int
    white_balance_temperature: int
    unity: int
    temperature_range_k: list[int]
    temperature_clamped: bool


class DngGains(BaseModel):
    """DNG ``AsShotNeutral`` = 1 / gains."""

    AsShotNeutral: list[float]


class AndroidGains(BaseModel):
    """Android Camera2 ``RggbChannelVector`` ``[r, 1, 1, b]``."""

    RggbChannelVector: list[float]


class WbGainsOut(BaseModel):
    """White-balance gains of one estimate in every supported camera-software convention (:mod:`illumon.gains`)."""

    rgb: list[float]
    onvif: OnvifGains | OnvifVendorGains
    libcamera: LibcameraGains
    v4l2: V4l2Gains
    dng: DngGains
    android: AndroidGains
    frame_id: int
    taken_at: str
    confidence: float | None
    cct_k: float
    notes: list[str]


class JobOut(BaseModel):
    """A refit job: state, progress (0…1), summary (``null`` until it ends; ``{"error": …}`` when it failed; otherwise
    what the refit measured, open-ended) and times."""

    job_id: str
    camera_id: int
    state: Literal["queued", "running", "done", "failed"]
    progress: float
    summary: dict[str, Any] | None
    created_at: str
    finished_at: str | None


class CalibrationPatchOut(BaseModel):
    """A measured patch: linear means (``null`` when mostly clipped or occluded) and whether pixels clipped."""

    id: str
    r: float | None
    g: float | None
    b: float | None
    clipped: bool


class CalibrationOut(BaseModel):
    """A stored calibration image: its patches, how many clipped, how many of the camera's own regions the image
    shows (``scene_regions``: fewer than two and a refit leaves it out) and warnings."""

    calibration_id: int
    kind: Literal["colorchecker", "grey"]
    patches: list[CalibrationPatchOut]
    clipped: int
    scene_regions: int
    warnings: list[str]


class ProposalReasons(BaseModel):
    """What a proposal's score rests on (:func:`illumon_service.proposals.propose_regions`)."""

    model_config = ConfigDict(extra="allow")

    change: float
    drift: float
    texture: float
    clipped: float
    dark: float
    chroma: list[float]
    diversity: float


class ProposalOut(BaseModel):
    """A proposed region in the view's reference-frame pixels with its score (0…1)."""

    x: int
    y: int
    width: int
    height: int
    score: float
    reasons: ProposalReasons


class ProposalsOut(BaseModel):
    """Region proposals of a view, best first, with the number of frames used and the hours of the day they cover."""

    frames_used: int
    view: str | None
    hours_covered: int
    proposals: list[ProposalOut]
    warnings: list[str]


class DeletedOut(BaseModel):
    """What an admin ``DELETE`` removed: the camera (and frame) and the number of stored rows of each kind."""

    camera_id: int
    frame_id: int | None
    deleted: dict[str, int]


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

FRAME_UPLOAD: dict[str, Any] = multipart_body(["image"], {
    "image": {"type": "string", "format": "binary",
              "description": "PNG, JPEG or TIFF, 8- or 16-bit, RGB (a grey, single-channel image answers 422)"},
    "taken_at": {"type": "string", "format": "date-time", "description": "ISO 8601; naive means UTC; now when absent"},
    **CAMERA_APPLIED,
})
"""OpenAPI request body of ``POST /v1/cameras/{id}/frames`` (parsed by hand, so FastAPI cannot infer it)."""
