"""Bodies of a camera's estimates: an estimate, the illuminant with its spectrum and intervals, and the white-balance
gains in every camera-software convention."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["EstimateOut", "SpectrumOut", "IlluminantOut", "OnvifGains", "OnvifVendorGains", "LibcameraGains",
           "V4l2Gains", "DngGains", "AndroidGains", "WbGainsOut"]


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
