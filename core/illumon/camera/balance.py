"""Cameras that balance themselves: the fixed-pipeline assumption, and what a history can tell of it.

illumon's model holds the camera's pipeline fixed: the light changes, the camera's gains do not (or the camera
reports them: ``applied_gains``). A camera whose own auto white balance changes its gains from frame to frame breaks
that: its output shows the light *as balanced*, which barely changes colour however much the daylight does, and a
reference held up in one frame then says nothing of the next.

From static patches alone such a camera is hard to tell from one under a steady light: a gray-world balance follows
the daylight's own low-dimensional changes, so its histories stay as low-rank as a fixed camera's (measured on
``benchmarks/unmeasured.py``'s rendered and auto-balanced cases: a rank-4 model with per-frame channel gains is
favoured by ΔBIC in neither). What does give it away is time: over hours of daylight the light's colour moves by tens
of MK⁻¹ (Granada runs: 0.18 in log r/g, b/g within a run, ~24 MK⁻¹), so a history spanning a day whose estimated light
hardly moves was balanced by the camera — or lit by a lamp. :func:`self_balance_warning` says so.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

import numpy as np
from numpy.typing import NDArray

from .formation import angular_error_deg

__all__ = ["MIN_HOURS", "MAX_SPREAD_MIRED", "self_balance_warning", "unbalanced_warning"]

MIN_HOURS = 6.0
"""A history must span at least this many hours before a steady light colour is taken as a sign of self-balancing."""

MAX_SPREAD_MIRED = 8.0
"""Standard deviation of the frames' estimated reciprocal temperature (MK⁻¹) below which the light is called steady.
Chosen on development cameras (Nikon D80, D3, D5100; ``benchmarks/unmeasured.py`` rawsim, seeds 5 and 6, 30 frames):
auto-balanced histories 0.5–1.8, the same days through a fixed preset 37–43; 8 is about the geometric middle."""


def _hours(times: Sequence[str]) -> float | None:
    stamps = []
    for t in times:
        if not t:
            continue
        try:
            stamps.append(datetime.fromisoformat(str(t).replace("Z", "+00:00")).timestamp())
        except ValueError:
            continue
    if len(stamps) < 2:
        return None
    return (max(stamps) - min(stamps)) / 3600.0


def self_balance_warning(times: Sequence[str], mired: NDArray[np.float64]) -> str | None:
    """A warning when a history spans ≥ :data:`MIN_HOURS` and its light barely changes colour
    (:data:`MAX_SPREAD_MIRED`), else ``None``."""
    hours = _hours(times)
    m = np.asarray(mired, dtype=float)
    m = m[np.isfinite(m)]
    if hours is None or hours < MIN_HOURS or m.size < 3:
        return None
    spread = float(np.std(m))
    if spread >= MAX_SPREAD_MIRED:
        return None
    return (f"the light's colour hardly changed over {hours:.0f} hours (σ = {spread:.1f} MK⁻¹; daylight moves tens): "
            "either a steady lamp lights the scene, or the camera's white balance is automatic — if so, lock it, or send "
            "applied_gains with every frame; a reference then holds for every frame")


def unbalanced_warning(level: Sequence[float]) -> str:
    """The warning of rendered output (``primaries`` ``srgb``) whose every frame reads as lit by light the camera was
    not balanced for (:func:`illumon.model.lamps.unbalanced_probability` above 0.5): the history's mean white,
    ``level`` (log r/g, b/g), is far from the grey a camera balanced for daylight shows.

    Either lamps light the scene throughout — then the estimates follow them — or the output is not what ``srgb``
    declares: a camera that does not white-balance (raw sensor values, whose daylight white is far from grey) or one
    locked to an indoor preset. Sensor RGB declared ``srgb`` reads so in most histories (development, no reference,
    ``python tools/output_space_check.py --declared srgb``: 20 of 28 ``none``, 28 of 28 ``pale``; its white then
    8.8° off, 2.3° declared ``camera``; held out: 20 of 20, 20 of 20); rendered daylight histories never (0 of 56,
    ``none+rendered``, ``none+awb``; held out 0 of 40).
    """
    angle = float(angular_error_deg(np.exp([level[0], 0.0, level[1]]), np.ones(3)))
    return (f"every frame reads as lit by lamps: the history's mean white is {angle:.0f}° from the grey a camera "
            "balanced for daylight shows. If daylight lights the scene, the frames are not balanced rendered output: "
            "raw sensor values need primaries camera, and a camera locked to an indoor white-balance preset should be "
            "set to daylight (or send applied_gains)")
