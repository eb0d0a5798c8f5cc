"""White-balance gains in the conventions of camera software.

Everything starts from the camera white ``w = (w_r, w_g, w_b)``: the linear camera response to a perfect white diffuser
under the estimated illuminant (:attr:`illumon.retrieval.RetrievalResult.white`). The white-balance gains that make it
neutral, with green fixed, are ``g = (w_g / w_r, 1, w_g / w_b)`` (:func:`illumon.camera.gains_from_white`). The
conversions below only rescale, round or reorder these numbers:

``rgb``
    ``[g_r, 1, g_b]``: multiply linear raw red and blue by these.
``onvif``
    ONVIF Imaging Service ``WhiteBalance`` (``ImagingSettings20``): ``Mode = "MANUAL"``, ``CrGain`` and ``CbGain``.
    ONVIF calls them unitless red / blue gains whose valid range a device reports in ``GetOptions`` (``YrGain`` /
    ``YbGain``). Without a range the gains are returned as they are; with a vendor range ``(lo, hi)`` ``log2(gain)``
    from −2…+2 (gain ¼…4) is mapped linearly onto ``lo…hi``, so unity gain sits at the middle of the range. Ranges and
    their meaning differ between vendors: check one camera before relying on it.
``libcamera``
    ``ColourGains = [g_r, g_b]`` (floats, green implicitly 1) and ``ColourTemperature`` (integer kelvin, informative;
    setting ColourGains disables AWB).
``v4l2``
    ``red_balance`` / ``blue_balance`` integer controls as ``round(gain × unity)`` (unity 1000 by default, as the
    Raspberry Pi bcm2835 driver; drivers report their own range with ``v4l2-ctl -L``), and
    ``white_balance_temperature`` in kelvin, clamped to the UVC usual 2800…6500 K.
``dng``
    ``AsShotNeutral``: the camera neutral in linear camera values, green = 1, i.e. ``1 / g`` (DNG 1.6 §AsShotNeutral).
``android``
    Camera2 ``COLOR_CORRECTION_GAINS`` as ``RggbChannelVector(red, greenEven, greenOdd, blue) = [g_r, 1, 1, g_b]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .camera import gains_from_white

__all__ = [
    "rgb_gains",
    "onvif_white_balance",
    "libcamera_controls",
    "v4l2_controls",
    "dng_as_shot_neutral",
    "android_rggb",
    "all_conventions",
]

ONVIF_LOG2_SPAN = 2.0
"""Half-width in log2 units of the gain range mapped onto an ONVIF vendor range (gain ¼…4)."""


def rgb_gains(white: ArrayLike) -> list[float]:
    """Gains ``[g_r, 1, g_b]`` that make the camera white ``white`` (3,) neutral."""
    w = np.asarray(white, dtype=float)
    if w.shape != (3,) or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise ValueError("camera white must be three positive finite numbers")
    return [float(v) for v in gains_from_white(w)]


def onvif_white_balance(gains: Sequence[float], vendor_range: tuple[float, float] | None = None) -> dict:
    """ONVIF ``WhiteBalance`` settings from gains ``[g_r, 1, g_b]`` (see module docstring for the mapping)."""
    gr, gb = float(gains[0]), float(gains[2])
    if vendor_range is None:
        return {"Mode": "MANUAL", "CrGain": gr, "CbGain": gb}
    lo, hi = float(vendor_range[0]), float(vendor_range[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise ValueError("ONVIF range must be two finite numbers lo < hi")

    def to_vendor(g: float) -> float:
        t = (np.clip(math.log2(g), -ONVIF_LOG2_SPAN, ONVIF_LOG2_SPAN) + ONVIF_LOG2_SPAN) / (2 * ONVIF_LOG2_SPAN)
        return float(lo + t * (hi - lo))

    return {"Mode": "MANUAL", "CrGain": to_vendor(gr), "CbGain": to_vendor(gb), "range": [lo, hi]}


def libcamera_controls(gains: Sequence[float], cct_k: float) -> dict:
    """libcamera ``ColourGains`` ``[g_r, g_b]`` and ``ColourTemperature`` (K, rounded)."""
    return {"ColourGains": [float(gains[0]), float(gains[2])], "ColourTemperature": int(round(cct_k))}


def v4l2_controls(
    gains: Sequence[float], cct_k: float, *, unity: int = 1000, temperature_range: tuple[int, int] = (2800, 6500)
) -> dict:
    """V4L2 ``red_balance`` / ``blue_balance`` (``round(gain × unity)``) and ``white_balance_temperature`` (K)."""
    t = int(round(min(max(cct_k, temperature_range[0]), temperature_range[1])))
    return {
        "red_balance": int(round(float(gains[0]) * unity)),
        "blue_balance": int(round(float(gains[2]) * unity)),
        "white_balance_temperature": t,
        "unity": unity,
    }


def dng_as_shot_neutral(gains: Sequence[float]) -> list[float]:
    """DNG ``AsShotNeutral``: the camera neutral ``1 / gains`` with green = 1."""
    return [1.0 / float(gains[0]), 1.0, 1.0 / float(gains[2])]


def android_rggb(gains: Sequence[float]) -> list[float]:
    """Android Camera2 ``RggbChannelVector`` ``[red, greenEven, greenOdd, blue]``."""
    return [float(gains[0]), 1.0, 1.0, float(gains[2])]


def all_conventions(
    white: ArrayLike,
    cct_k: float,
    *,
    onvif_range: tuple[float, float] | None = None,
    v4l2_unity: int = 1000,
) -> dict:
    """Gains from the camera white in every convention of the module docstring, keyed by convention."""
    g = rgb_gains(white)
    return {
        "rgb": g,
        "onvif": onvif_white_balance(g, onvif_range),
        "libcamera": libcamera_controls(g, cct_k),
        "v4l2": v4l2_controls(g, cct_k, unity=v4l2_unity),
        "dng": {"AsShotNeutral": dng_as_shot_neutral(g)},
        "android": {"RggbChannelVector": android_rggb(g)},
    }
