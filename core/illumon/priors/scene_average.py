"""The prior on a static scene's average colour, and gray-world over a history read as evidence of the light.

A scene's average colour under a light is the light's white times the scene's average reflectance. Where the scene
spreads like the measured surfaces (:data:`MEASURED_SURFACE_SPREAD`), that average is the mean measured surface's
within :data:`illumon.camera.calibration.SCENE_AVERAGE_SD`; where its patches barely differ in colour (walls, road,
table tops, the development lamp-lit scenes), it sits near grey within :data:`SCENE_GREY_SD`. The patches' own
chromaticity spread says which, and how many independent colours the average is taken over — the sampling error of
gray-world (Buchsbaum 1980) over the scene.

References
----------
.. [Buchsbaum1980] Buchsbaum, 1980: grey world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["SCENE_GREY_SD", "MEASURED_SURFACE_SPREAD", "SURFACE_SPREAD", "SCENE_SPREAD", "SceneAverage",
           "scene_average_evidence", "grey_share", "expected_offset", "rendered_probability", "log_chroma"]

SCENE_GREY_SD = 0.033
"""Spread (log r/g, b/g) of a nearly achromatic scene's average colour around grey: the RMS of the gray-world errors
of the development lamp-lit scenes' histories (``bmug`` −0.023 / +0.024, ``diff`` +0.024 / −0.051 in log r/g, b/g;
their regions spread 0.004–0.07 in log chromaticity; ``benchmarks/lamps.py``)."""

MEASURED_SURFACE_SPREAD = 0.53
"""Chromaticity spread (as :attr:`SceneAverage.spread`) of a scene of ten surfaces drawn from the development
measured reflectance sets under development Granada runs, 14 development cameras: median 0.53 (10–90 %: 0.38–0.71).
The development lamp-lit scenes' regions spread 0.004–0.09, a ColorChecker's colour patches 0.49 (sensor RGB) to 1.8
(rendered, clipped). A scene that spreads like the measured surfaces averages like them (SCENE_AVERAGE_SD around the
mean measured surface); one whose patches barely differ averages near grey (:data:`SCENE_GREY_SD`)."""

SURFACE_SPREAD = {"camera": MEASURED_SURFACE_SPREAD, "srgb": 0.81}
""":data:`MEASURED_SURFACE_SPREAD` per output space (:data:`illumon.camera.primaries.PRIMARIES`). Rendered output
spreads the same surfaces 2.4 × as much: a colour matrix to sRGB primaries undoes the overlap of the sensor's
channels. The 280 development scenes through each development camera's matrix to sRGB (``python
tools/scene_average_spread.py``): median 1.26, 10–90 % 0.81–1.65 (as sensor RGB 0.53, 0.38–0.71). Held against the
sensor's 0.53, a rendered scene of pale surfaces (their saturation cut to 15 %: spread 0.115 rendered, 0.065 as sensor
RGB) read as a fifth of the measured surfaces' spread instead of about a tenth, and its expected average kept twice
the mean surface's warmth it has: a rendered camera lit only by lamps read its level that far off (development
``none+lamps``, ``python benchmarks/unmeasured.py --split dev --seeds 1``: the Nikon D80's history 3.70° median where
gray-world was 0.32°). Rendered output is held against the low end (10 %) of its measured-surface scenes, not their
median: against 1.26 a rendered daylight scene of measured surfaces spreading 0.90 read as 29 % grey, its reading
moved towards its gray-world (24° off) and the history was judged lamp-lit (the Nikon D3's, 3.1° → 13.6°; with
veiling glare, which narrows the spread, 8 of the 56 rendered daylight histories without a reference). Sensor RGB
keeps the median the lamp-lit and pale cases were chosen with: its low end (0.38), tried, took the simulated
``none`` histories 2.27 / 2.25° → 2.10 / 2.04° (``illumon`` / ``rawsim``; with glare 2.64 / 2.62° → 2.18 / 2.12°)
and ``pale`` 0.59 / 0.50° → 0.65 / 0.58°, but every real set the other way: ``sony-raw`` 1.60° → 1.80°, the MIMO
``bmug`` and ``diff`` read as sensor RGB 1.21° → 1.24° and 1.40° → 1.44°."""

SCENE_SPREAD = {"camera": (0.534, 0.243), "srgb": (1.264, 0.281)}
"""Median and standard deviation of the log of a scene's chromaticity spread (:attr:`SceneAverage.spread`) per output
space, for :func:`rendered_probability`: the 280 development scenes of ten measured surfaces under development
Granada runs through the 14 development cameras, as sensor RGB and through each camera's colour matrix to sRGB
primaries (``python tools/scene_average_spread.py``; sensor RGB 1–99 % 0.29–0.87, largest 0.90; rendered 1–99 %
0.55–1.94)."""

_CHROMA_FLOOR = 0.01
"""Added to each channel (× the frame's mean level) before the log-chromaticities of dark or clipped patches."""


@dataclass(frozen=True)
class SceneAverage:
    """Gray-world over a history's static patches (:func:`scene_average_evidence`)."""

    mean: NDArray[np.float64]
    """Mean over frames of each frame's gray-world white, log r/g and b/g."""
    sd: float
    """Its standard deviation as evidence of the light: ``sqrt(SCENE_GREY_SD² + spread² / patches)``."""
    spread: float
    """The patches' chromaticity spread (log units, pooled over r/g and b/g; median over frames)."""
    patches: float
    """Mean number of patches per frame."""
    reference: float = MEASURED_SURFACE_SPREAD
    """The spread of a scene of measured surfaces in the same output space (:data:`SURFACE_SPREAD`)."""


def scene_average_evidence(y: NDArray[np.float64], present: NDArray[np.bool_], primaries: str = "camera"
                           ) -> SceneAverage:
    """Gray-world over a history's patches (log r/g, b/g), its standard deviation and the patches' spread.

    ``y`` (F × P × 3) are the observations, ``present`` (F × P) where all three channels were seen. The mean over
    frames of each frame's gray-world white, and ``sqrt(SCENE_GREY_SD² + spread² / N)`` with the patches' chromaticity
    spread (median over frames, pooled over r/g and b/g) and the mean number of patches per frame. ``primaries``: the
    observations' output space, which sets the measured surfaces' spread the patches' is held against
    (:data:`SURFACE_SPREAD`).
    """
    reference = SURFACE_SPREAD[primaries]
    y = np.asarray(y, dtype=float)
    present = np.asarray(present, dtype=bool)
    count = present.sum(axis=1)
    logs, spreads, used = np.empty((len(y), 2)), np.empty(len(y)), np.zeros(len(y), dtype=bool)
    # Frames with the same number of patches at once, each frame's patches gathered in order (k × 3): every value
    # is the frame-by-frame computation's bit for bit (sums over a frame's k patches are numpy's over an axis of
    # length k either way; tests/core/priors/test_scene_average.py keeps the frame-by-frame reference). Issue 29:
    # the Python loop over a 300-frame fit's frames took ~15 ms.
    for k in np.unique(count[count >= 2]).tolist():
        rows = np.flatnonzero(count == k)
        which = np.argsort(~present[rows], axis=1, kind="stable")[:, :k]  # the present patches, in order
        v = y[rows[:, None], which]  # n × k × 3
        m = v.sum(axis=1) / k
        good = np.all(m > 0, axis=1)
        rows, v, m = rows[good], v[good], m[good]
        logs[rows] = np.log(m[:, [0, 2]] / m[:, 1:2])
        eps = (_CHROMA_FLOOR * m.mean(axis=1))[:, None, None]
        lc = np.log((np.clip(v[..., [0, 2]], 0, None) + eps) / (np.clip(v[..., 1:2], 0, None) + eps))  # n × k × 2
        dev = lc - lc.sum(axis=1, keepdims=True) / k  # np.var's own steps
        dev *= dev
        spreads[rows] = np.sqrt((dev.sum(axis=1) / k).mean(axis=1))
        used[rows] = True
    if not used.any():
        return SceneAverage(np.zeros(2), math.inf, math.inf, 0.0, reference)
    spread, n = float(np.median(spreads[used])), float(np.mean(count[used]))
    return SceneAverage(np.mean(logs[used], axis=0), math.sqrt(SCENE_GREY_SD**2 + spread**2 / n), spread, n, reference)


def rendered_probability(spread: float) -> float:
    """Probability that a scene whose patches spread ``spread`` (:attr:`SceneAverage.spread`) was seen through a
    colour matrix to sRGB primaries (rendered output) rather than as sensor RGB, at even prior odds: the two output
    spaces' log-normal spreads of scenes of measured surfaces (:data:`SCENE_SPREAD`). A colour matrix undoes the overlap
    of a sensor's channels and spreads the same surfaces 2.4 × as much, so a scene spreading well beyond what sensor
    RGB gives is rendered. Evidence one way only: a pale scene (walls, roads) spreads little in either space, and
    reads as sensor RGB here whatever it is (the test warns of rendered output declared as sensor RGB, not the
    reverse)."""
    if not (math.isfinite(spread) and spread > 0):
        return 0.0
    logp = {}
    for space, (median, sd) in SCENE_SPREAD.items():
        z = (math.log(spread) - math.log(median)) / sd
        logp[space] = -0.5 * z * z - math.log(sd)
    return 1.0 / (1.0 + math.exp(min(logp["camera"] - logp["srgb"], 700.0)))


def grey_share(average: SceneAverage) -> float:
    """How far a scene's expected average moves from the mean measured surface's towards grey: 1 for a scene whose
    patches do not differ in colour, 0 for one that spreads like the measured surfaces in its output space
    (``1 − min(1, spread / reference)``, :attr:`SceneAverage.reference`)."""
    if not math.isfinite(average.spread):
        return 0.0
    return 1.0 - min(1.0, average.spread / average.reference)


def expected_offset(light: NDArray[np.float64], sensitivities: NDArray[np.float64], rb, average: SceneAverage
                    ) -> NDArray[np.float64]:
    """Where a scene's average colour is expected relative to its light's white, per frame (F × 2, log r/g and b/g):
    the mean measured surface's offset under each frame's ``light`` (F × grid) through ``sensitivities`` (``rb``:
    the reflectance prior), times ``1 − grey_share(average)`` — all of it for a scene as varied as the measured
    surfaces, none for one whose patches do not differ in colour."""
    mean_surface = np.clip(rb.functions @ rb.prior_mean, 0.0, 1.0)
    white = log_chroma(light @ sensitivities)
    surface = log_chroma((light * mean_surface) @ sensitivities)
    return (1.0 - grey_share(average)) * (surface - white)


def log_chroma(rgb: ArrayLike) -> NDArray[np.float64]:
    """Log chromaticity (… × 2: log r/g, log b/g) of camera values or whites (… × 3), each channel clipped at 1e-12."""
    rgb = np.asarray(rgb, dtype=float)
    return np.log(np.clip(rgb[..., [0, 2]], 1e-12, None) / np.clip(rgb[..., 1:2], 1e-12, None))
