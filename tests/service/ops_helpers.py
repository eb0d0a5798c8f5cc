"""A small rendered camera for the operations tests (backup, retention, idempotency), needing no measured data: the
README's stand-in sensitivities, six ColorChecker patches as regions on a grey background, CIE daylight 4000–9000 K,
noise, sRGB 8-bit PNG."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
from illumon.camera import render
from illumon.daylight import daylight_locus_xy, daylight_spectrum
from illumon.priors import colourchecker_reflectances
from illumon.spectra import sensitivities_from_arrays
from svc_helpers import encode_png, paint_srgb

WL = [400, 450, 500, 550, 600, 650, 700]
SENS = {"wavelength_nm": WL, "r": [0.02, 0.03, 0.05, 0.25, 1.00, 0.55, 0.05],
        "g": [0.05, 0.25, 0.80, 1.00, 0.35, 0.05, 0.01], "b": [0.35, 1.00, 0.55, 0.10, 0.03, 0.02, 0.01]}
REGIONS = [{"id": f"p{i}", "x": 20 + 110 * (i % 3), "y": 30 + 120 * (i // 3), "width": 60, "height": 60} for i in range(6)]
PATCHES = ["dark skin", "foliage", "moderate red", "yellow green", "blue", "neutral 5 (.70 D)"]
T0 = datetime(2025, 6, 1, 6, tzinfo=timezone.utc)


def camera_body(name: str = "ops camera") -> dict:
    """Registration body of the rendered camera."""
    return {"name": name, "sensitivities": SENS, "regions": REGIONS, "response": {"encoding": "srgb"}}


def render_frames(n: int, seed: int = 27) -> list[bytes]:
    """``n`` PNG frames of the camera under daylight of shuffled temperatures."""
    css = sensitivities_from_arrays(WL, np.column_stack([SENS["r"], SENS["g"], SENS["b"]]), source="test")
    names, refl = colourchecker_reflectances()
    refl = refl[[names.index(p) for p in PATCHES]]
    rng = np.random.default_rng(seed)
    ccts = rng.uniform(4000, 9000, n)
    e = np.stack([daylight_spectrum(xy) for xy in daylight_locus_xy(ccts)])
    lin = render(css, e, refl)
    grey = render(css, e, np.full((1, 61), 0.2))[:, 0]
    out = []
    for f in range(n):
        k = 0.8 / lin[f].max()
        out.append(encode_png(paint_srgb((340, 240), grey[f] * k, list(zip(REGIONS, lin[f] * k, strict=True)), rng)))
    return out


def frame_time(k: int, minutes: int = 20) -> str:
    """ISO time of the ``k``-th frame."""
    return (T0 + timedelta(minutes=minutes * k)).isoformat()
