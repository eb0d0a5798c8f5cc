"""What the service accepts at the door: the ranges of every number a client sends, and text without control
characters, so that nothing a client sends and the service accepts can later break the camera's refit or a database.

Every value is checked where it enters (request bodies, form fields, the regions page) and refused with a 422 that
names the field; the refit checks the stored history again with :func:`frame_problem` (rows stored by older versions,
or anything that slipped through) and leaves a frame it cannot use out, with its reason, instead of failing.

The ranges are wide enough for every real camera and narrow enough that no accepted value overflows the fit:

* region means (and their standard errors) on the 0…1 scale of the white level: at most :data:`MAX_VALUE` (a mean of
  static scene cannot exceed the white level by more than rounding; a value of 100 × white alone made the joint fit
  ill-conditioned);
* ``exposure``: :data:`EXPOSURE_RANGE` (relative exposures of one camera from night to noon span ~10⁴);
* ``applied_gains``: :data:`GAINS_RANGE` (white-balance gains of real cameras lie in 0.25…8);
* ``gamma``: :data:`GAMMA_RANGE`; ``black_level`` / ``white_level``: :data:`LEVEL_MAX` (16-bit codes);
* colour matrices: entries within ±:data:`MATRIX_MAX`, condition number at most :data:`MATRIX_MAX_CONDITION`;
* sensitivities: values at most :data:`SENSITIVITY_MAX`, wavelengths in :data:`WAVELENGTH_RANGE`;
* regions: inside the view's image (its reference frame's size) wherever that size is known.
"""

from __future__ import annotations

import math
import unicodedata
from collections.abc import Mapping, Sequence

__all__ = [
    "MAX_VALUE", "EXPOSURE_RANGE", "GAINS_RANGE", "GAMMA_RANGE", "LEVEL_MAX", "MATRIX_MAX", "MATRIX_MAX_CONDITION",
    "SENSITIVITY_MAX", "WAVELENGTH_RANGE", "MAX_UNDONE", "control_character", "check_text", "check_gains",
    "check_exposure", "frame_problem", "regions_outside",
]

MAX_VALUE = 2.0
"""Largest region mean or standard error, as a fraction of the white level."""
EXPOSURE_RANGE = (1e-6, 1e6)
"""Accepted relative exposure."""
GAINS_RANGE = (1.0 / 64.0, 64.0)
"""Accepted white-balance gains the camera says it applied (each channel)."""
GAMMA_RANGE = (0.2, 5.0)
"""Accepted exponent of a ``gamma`` tone response."""
LEVEL_MAX = 65535.0
"""Largest black or white level (image codes: 8- or 16-bit)."""
MATRIX_MAX = 100.0
"""Largest magnitude of a colour-matrix entry."""
MATRIX_MAX_CONDITION = 1e6
"""Largest condition number of a colour matrix."""
SENSITIVITY_MAX = 1e6
"""Largest sensitivity value (any unit: the service normalises them)."""
WAVELENGTH_RANGE = (200.0, 2000.0)
"""Accepted sensitivity wavelengths (nm)."""
MAX_UNDONE = 1e9
"""Largest region mean once the camera's exposure and gains are divided out (the product of the ranges above stays
far below; a stored value beyond it is left out of a refit)."""


def control_character(text: str) -> str | None:
    """The first control character (Unicode category ``Cc``: NUL, escape, …) or lone surrogate (``Cs``, not
    encodable as UTF-8) in ``text``, shown as ``U+XXXX``; ``None`` when there is none."""
    for ch in text:
        if unicodedata.category(ch) in ("Cc", "Cs"):
            return f"U+{ord(ch):04X}"
    return None


def check_text(text: str, field: str) -> str:
    """``text`` unchanged; ``ValueError`` naming ``field`` when it holds a control character (PostgreSQL refuses NUL
    in text, terminals and logs misread the others)."""
    bad = control_character(text)
    if bad is not None:
        raise ValueError(f"{field}: control character {bad} not allowed")
    return text


def _in(value: float, lo: float, hi: float) -> bool:
    return math.isfinite(value) and lo <= value <= hi


def check_gains(gains: Sequence[float], field: str = "applied_gains") -> list[float]:
    """Three gains within :data:`GAINS_RANGE`; ``ValueError`` naming ``field`` otherwise."""
    lo, hi = GAINS_RANGE
    if len(gains) != 3 or not all(_in(float(g), lo, hi) for g in gains):
        raise ValueError(f"{field}: expected three gains r,g,b within {lo:g}…{hi:g}")
    return [float(g) for g in gains]


def check_exposure(value: float, field: str = "exposure") -> float:
    """A relative exposure within :data:`EXPOSURE_RANGE`; ``ValueError`` naming ``field`` otherwise."""
    lo, hi = EXPOSURE_RANGE
    if not _in(float(value), lo, hi):
        raise ValueError(f"{field}: expected a relative exposure within {lo:g}…{hi:g}")
    return float(value)


def _values_problem(values: Mapping[str, object] | None, what: str) -> str | None:
    top = MAX_VALUE
    for rid, v in (values or {}).items():
        if v is None:
            continue
        if type(v) is list and len(v) == 3:  # the common case first (a refit checks every stored value)
            r, g, b = v
            if (type(r) is float and type(g) is float and type(b) is float
                    and 0.0 <= r <= top and 0.0 <= g <= top and 0.0 <= b <= top):  # NaN and ±inf fail these
                continue
        if not isinstance(v, (list, tuple)) or len(v) != 3:
            return f"{what} of region {rid!r} is not three numbers"
        for x in v:
            if not isinstance(x, (int, float)) or isinstance(x, bool) or not _in(float(x), 0.0, MAX_VALUE):
                return f"{what} of region {rid!r} outside 0…{MAX_VALUE:g} × white ({v})"
    return None


def frame_problem(patches: Mapping[str, object] | None, sd: Mapping[str, object] | None,
                  applied_gains: Sequence[float] | None, exposure: float | None) -> str | None:
    """Why a stored frame cannot enter a refit (a value outside the ranges above), or ``None`` when it can."""
    bad = _values_problem(patches, "value") or _values_problem(sd, "standard error")
    if bad:
        return bad
    if applied_gains is not None:
        try:
            check_gains([float(g) for g in applied_gains])
        except (TypeError, ValueError):
            return f"applied_gains {applied_gains} outside {GAINS_RANGE[0]:g}…{GAINS_RANGE[1]:g}"
    if exposure is not None:
        try:
            check_exposure(float(exposure))
        except (TypeError, ValueError):
            return f"exposure {exposure} outside {EXPOSURE_RANGE[0]:g}…{EXPOSURE_RANGE[1]:g}"
    return None


def regions_outside(regions: Sequence[Mapping[str, int]], size: tuple[int, int] | None) -> list[str]:
    """Ids of the regions that do not lie wholly inside an image of ``size`` (width, height); none when the size is
    unknown."""
    if size is None:
        return []
    w, h = size
    return [str(r["id"]) for r in regions if r["x"] + r["width"] > w or r["y"] + r["height"] > h]
