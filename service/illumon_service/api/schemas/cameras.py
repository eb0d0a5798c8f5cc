"""Bodies of the cameras: registration (sensitivities, regions, output pipeline), regions, and a camera's public view
with its calibrations and alerts."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from illumon.camera import ENCODINGS
from illumon.camera.primaries import PRIMARIES
from illumon.camera.references import REFERENCE_KINDS
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from ...limits import (
    GAMMA_RANGE,
    LEVEL_MAX,
    MATRIX_MAX,
    MATRIX_MAX_CONDITION,
    SENSITIVITY_MAX,
    WAVELENGTH_RANGE,
    regions_outside,
)
from .common import MAX_SIDE, Strict, Text, optional_key

__all__ = ["SensitivitiesIn", "RegionIn", "ResponseIn", "ImageSizeIn", "CameraIn", "RegionsIn", "ResponseOut",
           "CalibrationRef", "AlertOut", "CameraOut", "CameraCreated", "DeletedOut"]

Encoding = ENCODINGS.literal()
"""A tone curve by name (:data:`illumon.camera.ENCODINGS`)."""
Primaries = PRIMARIES.literal()
"""An output space by name (:data:`illumon.camera.primaries.PRIMARIES`)."""
ReferenceKind = REFERENCE_KINDS.literal()
"""A calibration reference by name (:data:`illumon.camera.references.REFERENCE_KINDS`)."""


Sensitivity = Annotated[float, Field(allow_inf_nan=False, ge=0, le=SENSITIVITY_MAX, strict=True)]


class SensitivitiesIn(Strict):
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


class RegionIn(Strict):
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


class ResponseIn(Strict):
    """The camera's output pipeline: tone curve, levels in the image's units (white level defaults to the image's
    full scale) and, optionally, the fixed 3 × 3 colour matrix it applies (output = ``matrix`` @ sensor RGB).

    The default is what an ordinary camera's JPEG or PNG holds: sRGB-encoded values over the image's full scale
    (8-bit: 0…255). Declare ``linear`` for raw or linear (e.g. 16-bit scientific) output, ``gamma`` with ``gamma``,
    or ``table`` with ``table``: the linear value (0…1, non-decreasing) of encoded values spaced evenly from the black
    to the white level. A refit warns when the stored history still looks non-linear for the declared encoding.
    """

    encoding: Encoding = "srgb"
    gamma: float = Field(default=2.2, ge=GAMMA_RANGE[0], le=GAMMA_RANGE[1], allow_inf_nan=False, strict=True)
    black_level: float = Field(default=0.0, ge=0, lt=LEVEL_MAX, allow_inf_nan=False, strict=True)
    white_level: float | None = Field(default=None, gt=0, le=LEVEL_MAX, allow_inf_nan=False, strict=True)
    table: list[Annotated[float, Field(allow_inf_nan=False, ge=0, le=1, strict=True)]] | None = Field(
        default=None, min_length=2, max_length=65536)
    matrix: list[Annotated[list[MatrixEntry], Field(min_length=3, max_length=3)]] | None = Field(
        default=None, min_length=3, max_length=3)
    primaries: Primaries | None = None
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


class ImageSizeIn(Strict):
    """Width and height of a camera's frames in pixels."""

    width: int = Field(gt=0, le=MAX_SIDE, strict=True)
    height: int = Field(gt=0, le=MAX_SIDE, strict=True)


class CameraIn(Strict):
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


class RegionsIn(Strict):
    """Replacement of a camera's regions."""

    regions: list[RegionIn] = Field(min_length=1, max_length=500)

    _check_regions = field_validator("regions")(_unique)


class ResponseOut(BaseModel):
    """A camera's output pipeline as registered (see :class:`ResponseIn`); cameras registered by older versions may
    lack keys, which the answer then lacks too."""

    model_config = ConfigDict(extra="allow")

    encoding: Encoding = optional_key("tone curve")
    gamma: float = optional_key("exponent of the ``gamma`` encoding")
    black_level: float = optional_key("black level in the image's units")
    white_level: float | None = optional_key("white level in the image's units (``null``: the image's full scale)")
    table: list[float] | None = optional_key("``table`` encoding: linear values of evenly spaced codes")
    matrix: list[list[float]] | None = optional_key("3 × 3 colour matrix the camera applies (output = matrix @ RGB)")
    primaries: Primaries = optional_key("output space: sensor RGB or rendered sRGB primaries")


class CalibrationRef(BaseModel):
    """A stored calibration image of a camera."""

    calibration_id: int
    kind: ReferenceKind
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


class DeletedOut(BaseModel):
    """What an admin ``DELETE`` removed: the camera (and frame) and the number of stored rows of each kind."""

    camera_id: int
    frame_id: int | None
    deleted: dict[str, int]
