"""The output space is part of the camera: sensor primaries (raw) or sRGB / BT.709 primaries (rendered output).

A raw or machine-vision camera without a colour matrix delivers its sensor's RGB: its effective sensitivities are the
sensor's, and a camera nobody measured starts from the mean of the measured cameras
(:func:`illumon.camera.calibration.prior_sensitivities`). An IP, surveillance or phone camera delivers *rendered*
output: its pipeline multiplies the sensor's RGB by white-balance gains and a colour matrix towards the sRGB / BT.709
primaries, so its effective sensitivities are close to the linear-sRGB colour-matching functions (the CIE 1931 2°
CMFs through the XYZ → linear sRGB matrix, negative lobes included) times a diagonal: the white-balance preset, which
makes the light the camera was balanced for grey. A priori that light is CIE D65 (``srgb`` output of a daylight preset
or of an auto white balance that neutralised the scene's light). The spread of real cameras around that prior is
measured, not assumed: :func:`srgb_prior_white_spread`.

References
----------
.. [IEC61966-2-1] IEC 61966-2-1:1999 (sRGB).
.. [Finlayson1997] Finlayson & Drew, CIC 1997.
"""

from __future__ import annotations

import math
from functools import lru_cache

import colour
import numpy as np
from numpy.typing import NDArray

from ..daylight import CIEDaylight
from ..priors.scene_average import SCENE_SPREAD, rendered_probability, scene_average_evidence
from ..registry import Registry
from ..spectra import GRID

__all__ = ["PRIMARIES", "SRGB_BALANCE_SD", "RENDERED_WARNING_PROBABILITY", "WEAKEST_CHANNEL", "srgb_sensitivities",
           "check_primaries", "to_srgb_primaries", "srgb_matrix_for", "daylight_prior_for", "chromaticity_spread",
           "weakest_channel", "output_space_warning"]

PRIMARIES = Registry.choices({
    "camera": "sensor RGB: raw output, machine-vision cameras without a colour matrix",
    "srgb": "rendered output: the camera applied white-balance gains and a colour matrix to sRGB / BT.709 primaries",
})
"""The output spaces a camera may deliver, by name (CLI ``--primaries``, the service's ``response.primaries``)."""


SRGB_BALANCE_SD = 0.056
"""Standard deviation (log r/g and b/g, pooled) of a history's mean white around grey for a camera balanced for
daylight (a D65 preset, or an auto white balance): the geometric-mean white of 33 development runs of 40 Granada
spectra through the D65-balanced linear-sRGB colour-matching functions (``python tools/srgb_balance_spread.py``:
0.052 r/g, 0.059 b/g; within a run 0.18). Along the daylight locus that is ≈ 11 MK⁻¹
(d log(r/g, b/g) / d mired = (0.0040, −0.0064) at D65)."""

SRGB_MIRED_BETWEEN = 11.0
""":data:`SRGB_BALANCE_SD` along the daylight locus (MK⁻¹): the spread of a rendered camera's history-mean light
around the D65 it is balanced for, the ``mired_between`` of its hierarchical daylight prior."""


RENDERED_WARNING_PROBABILITY = 0.9
"""A history declared sensor RGB whose patches spread like rendered output with at least this probability
(:func:`illumon.priors.scene_average.rendered_probability`: a spread of 0.95 or more) is warned of
(:func:`output_space_warning`). None of the 280 development scenes of measured surfaces seen as sensor RGB reaches it
(largest 0.90, probability 0.81; ``python tools/scene_average_spread.py``)."""


WEAKEST_CHANNEL = 0.02
"""A history declared sensor RGB whose most saturated well-exposed patch keeps, in most frames, less than this share
of its strongest channel in its weakest is warned of too (:func:`output_space_warning`). A sensor's channels overlap,
so every lit surface gives all three: the 280 development scenes of measured surfaces as sensor RGB keep at least
0.032 (1 %: 0.041, median 0.139; ``python tools/scene_average_spread.py``), the real sensor-RGB chart (``sony-raw``)
0.22–0.27 and the real lamp-lit scenes 0.43–0.84; through each camera's colour matrix to sRGB, 232 of the 280 fall
below 0.03 (median 0: the matrix takes a saturated surface's weakest channel below zero and the output clips it)."""


def chromaticity_spread(values: NDArray[np.float64]) -> float:
    """The scene's chromaticity spread (:attr:`illumon.priors.scene_average.SceneAverage.spread`) over the patches
    seen with every channel above 0; ``values`` F × P × 3, NaN where unseen."""
    y = np.asarray(values, dtype=float)
    present = np.all(np.isfinite(y) & (y > 0), axis=-1)
    return scene_average_evidence(np.where(present[..., None], y, 0.0), present).spread


def weakest_channel(values: NDArray[np.float64]) -> float:
    """The median over frames of the smallest ratio of a patch's weakest channel to its strongest, among the patches
    whose strongest channel is at least a tenth of the frame's brightest value (dark patches' ratios are noise);
    ``values`` F × P × 3, NaN where unseen. ``inf`` where no frame has such a patch."""
    y = np.asarray(values, dtype=float)
    hi = np.max(np.where(np.isfinite(y), y, -np.inf), axis=-1)  # F × P
    lo = np.min(np.where(np.isfinite(y), y, np.inf), axis=-1)
    ok = np.all(np.isfinite(y), axis=-1) & (hi > 0)
    frame_max = np.max(np.where(ok, hi, 0.0), axis=1, keepdims=True)
    lit = ok & (hi >= 0.1 * frame_max) & (frame_max > 0)
    ratio = np.where(lit, np.clip(lo, 0.0, None) / np.where(lit, hi, 1.0), np.inf)
    per_frame = ratio.min(axis=1)
    per_frame = per_frame[np.isfinite(per_frame)]
    return float(np.median(per_frame)) if per_frame.size else math.inf


_SENSOR_SPREAD = "scenes seen as sensor RGB spread {:.2f}–{:.2f}".format(
    SCENE_SPREAD["camera"][0] * math.exp(-2.33 * SCENE_SPREAD["camera"][1]),
    SCENE_SPREAD["camera"][0] * math.exp(2.33 * SCENE_SPREAD["camera"][1]))
"""What :func:`output_space_warning` says of sensor RGB's spread: the 1–99 % of :data:`SCENE_SPREAD`'s log-normal."""


def output_space_warning(values: NDArray[np.float64]) -> str | None:
    """A warning when observations declared sensor RGB (``primaries`` ``camera``) look like rendered output, else
    ``None``. ``values`` (F × P × 3): the static scene's patches, references left out.

    Declared the wrong way, a camera's white is wrong by several degrees whichever it is: rendered output fitted as
    sensor RGB without a reference was 8.3° off (median of the 14 development cameras, ``benchmarks/unmeasured.py``
    case ``none+matrix``; 1.6° when declared ``srgb``), sensor RGB fitted as rendered 8.8° (2.3° declared
    ``camera``). Only the first shows in the data, two ways: a colour matrix spreads the patches' colours beyond what
    a sensor's overlapping channels give (:func:`illumon.priors.scene_average.rendered_probability` at least
    :data:`RENDERED_WARNING_PROBABILITY`), and it takes a saturated patch's weakest channel to nothing
    (:func:`weakest_channel` below :data:`WEAKEST_CHANNEL`)."""
    spread = chromaticity_spread(values)
    weakest = weakest_channel(values)
    if rendered_probability(spread) >= RENDERED_WARNING_PROBABILITY:
        seen = f"the patches' colours spread like rendered output (chromaticity spread {spread:.2f}; {_SENSOR_SPREAD})"
    elif weakest < WEAKEST_CHANNEL:
        seen = (f"a saturated patch's weakest channel is {100 * weakest:.1f} % of its strongest (a sensor's overlapping "
                "channels keep 3 % or more: a colour matrix clipped it)")
    else:
        return None
    return (f"{seen}, not like the sensor RGB the camera was declared: if it applies a colour matrix (IP, "
            "surveillance and phone cameras do), use primaries srgb — declared the wrong way, its white is several "
            "degrees off")


def daylight_prior_for(primaries: str):
    """The daylight prior of a camera's output space: for ``camera`` the default (Granada: N(150, 45²) MK⁻¹ per frame,
    frames independent); for ``srgb`` the light *as the balanced output shows it*: centred on D65 (the light the
    camera makes grey), each frame N(153.8, 45²), and the frames of one history sharing a level that departs from D65
    by :data:`SRGB_MIRED_BETWEEN` — the camera's own white balance is information the raw prior does not have."""
    if check_primaries(primaries) == "srgb":
        return CIEDaylight(mired_mean=1e6 / 6504.0, mired_between=SRGB_MIRED_BETWEEN)
    return CIEDaylight()


def check_primaries(name: str) -> str:
    """``name`` if it is one of :data:`PRIMARIES`, else ``ValueError`` naming the choices."""
    if name not in PRIMARIES:
        raise ValueError(f"unknown primaries {name!r}; use {' or '.join(PRIMARIES)}")
    return name


@lru_cache(maxsize=1)
def srgb_sensitivities() -> NDArray[np.float64]:
    """Linear-sRGB colour-matching functions on the grid (61 × 3), balanced for CIE D65: the camera white under D65 is
    (1, 1, 1) up to a common scale, and the largest value is 1.

    The CIE 1931 2° CMFs (colour-science) through the IEC 61966-2-1 XYZ → linear sRGB matrix; they have negative lobes
    (a colour matrix produces them from a real sensor too), so values below 0 are kept.
    """
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(GRID)
    xyz = np.asarray(cmfs.values, dtype=float)
    m = np.asarray(colour.models.RGB_COLOURSPACE_sRGB.matrix_XYZ_to_RGB, dtype=float)
    rgb = xyz @ m.T
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(GRID)
    white = np.asarray(d65.values, dtype=float) @ rgb
    rgb = rgb / white  # the daylight preset: D65 is grey
    return rgb / rgb.max()


def srgb_matrix_for(sensitivities: NDArray[np.float64]) -> NDArray[np.float64]:
    """The 3 × 3 ``M`` (``output = sensor @ M``, row vectors) a camera's pipeline would use to carry these sensor
    sensitivities (61 × 3) to sRGB primaries with a D65 daylight preset: least squares to the linear-sRGB
    colour-matching functions under D65 light, then each output channel scaled so D65 stays grey — white-preserving
    (Finlayson & Drew [Finlayson1997]_). The white-balance preset is folded into ``M``."""
    c = np.asarray(sensitivities, dtype=float)
    target = srgb_sensitivities()
    d65 = np.asarray(colour.SDS_ILLUMINANTS["D65"].copy().align(GRID).values, dtype=float)
    w = np.sqrt(d65 / d65.mean())[:, None]
    m = np.linalg.lstsq(c * w, target * w, rcond=None)[0]
    return m * ((d65 @ target) / np.maximum(d65 @ (c @ m), 1e-12))[None, :]


def to_srgb_primaries(sensitivities: NDArray[np.float64]) -> NDArray[np.float64]:
    """Measured sensor sensitivities (61 × 3) carried to sRGB primaries the way a camera's pipeline does it
    (:func:`srgb_matrix_for`); returns ``sensitivities @ M`` scaled to a largest absolute value of 1."""
    out = np.asarray(sensitivities, dtype=float) @ srgb_matrix_for(sensitivities)
    return out / np.abs(out).max()
