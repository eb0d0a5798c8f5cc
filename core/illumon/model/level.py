"""The level common to a rendered camera's history: balanced daylight, or light the camera was not balanced for.

Static patches cannot see a shift common to every frame's light (a tilt of every reflectance undoes it). For output a
camera white-balanced itself (``--primaries srgb``) two pieces of evidence place that level: the balance (a history
of daylight has a mean white grey within :data:`~illumon.camera.primaries.SRGB_BALANCE_SD`) and the scene's average
colour. The balance is a statement about *daylight*: a history lit only by lamps (street lamps at night, a lamp-lit
room, a light box) is as warm or cold as its lamps, whatever the camera's preset — the assumption that hid the real
lamp-lit scenes' 10–16° errors (every simulator's history was daylight). So the level's prior is a mixture of two
components:

- **balanced** — the history's mean white is grey within ``balance_sd`` (log r/g, b/g);
- **unbalanced** — anywhere within :data:`UNBALANCED_SD` of grey (lamps from sodium to cold LED).

The scene average (gray-world over the static patches) is the evidence between them. Its uncertainty is the
assumption's own (:data:`SCENE_GREY_SD`, the spread of a scene's average around grey where its regions are nearly
achromatic) plus the sampling error of the patches' chromaticities (their spread over √N): a ColorChecker's
saturated patches say little (gray-world 6–14° off on the development charts), a scene of grey and pale surfaces a
lot. The component with the larger posterior is taken (a mixture mean would land between the two, wrong for both),
and its Gaussian posterior gives the level and its spread; the unbalanced component's probability is reported as the
history's ``non_daylight`` evidence.

Parameters chosen on development data only (``benchmarks/lamps.py``: MIMO ``bmug``, ``diff``; ``benchmarks/real.py``:
the ``sony-dolp`` sets); ``lion`` and ``spdif`` are held out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["SCENE_GREY_SD", "UNBALANCED_SD", "UNBALANCED_PRIOR", "CommonLevel", "scene_average_evidence",
           "common_level_posterior"]

SCENE_GREY_SD = 0.05
"""Spread (log r/g, b/g) of a nearly achromatic scene's average colour around grey: the gray-world errors of the
development lamp-lit scenes (``bmug`` 0.02–0.03, ``diff`` 0.02–0.05 in log units, regions of chromaticity spread
0.004–0.07)."""

UNBALANCED_SD = 0.3
"""Prior spread (log r/g, b/g) of the mean white of a history lit by light the camera was not balanced for, centred
on grey: ±0.3 spans 2700 K incandescent to 10 000 K shade seen through a D65 preset."""

UNBALANCED_PRIOR = 0.2
"""Prior probability that a history is lit by light its camera was not balanced for (lamps only)."""

_CHROMA_FLOOR = 0.01
"""Added to each channel (× the frame's mean level) before the log-chromaticities of dark or clipped patches."""


@dataclass(frozen=True)
class CommonLevel:
    """The posterior of a history's mean white (log r/g, b/g) and which component it came from."""

    mean: NDArray[np.float64]
    sd: float
    unbalanced: float
    """Posterior probability of the unbalanced component."""


def scene_average_evidence(y: NDArray[np.float64], present: NDArray[np.bool_]) -> tuple[NDArray[np.float64], float]:
    """Gray-world over a history's patches, in log r/g, b/g, and its standard deviation.

    ``y`` (F × P × 3) are the observations, ``present`` (F × P) where all three channels were seen. The mean over
    frames of each frame's gray-world white, and ``sqrt(SCENE_GREY_SD² + spread² / N)`` with the patches' chromaticity
    spread (median over frames, pooled over r/g and b/g) and the mean number of patches per frame.
    """
    logs, spreads, counts = [], [], []
    for yf, pf in zip(y, present, strict=True):
        v = yf[pf]
        if len(v) < 2:
            continue
        m = v.mean(axis=0)
        if not np.all(m > 0):
            continue
        logs.append(np.log(m[[0, 2]] / m[1]))
        eps = _CHROMA_FLOOR * float(m.mean())
        lc = np.log((np.clip(v[:, [0, 2]], 0, None) + eps) / (np.clip(v[:, 1:2], 0, None) + eps))
        spreads.append(float(np.sqrt(np.mean(np.var(lc, axis=0)))))
        counts.append(len(v))
    if not logs:
        return np.zeros(2), math.inf
    spread = float(np.median(spreads))
    return np.mean(logs, axis=0), math.sqrt(SCENE_GREY_SD**2 + spread**2 / float(np.mean(counts)))


def _gauss(x: NDArray[np.float64], var: float) -> float:
    return float(np.exp(-0.5 * np.sum(x**2) / var) / (2 * math.pi * var))


def common_level_posterior(
    fit_level: NDArray[np.float64], fit_sd: float, balance_sd: float, scene: NDArray[np.float64], scene_sd: float,
) -> CommonLevel:
    """The mean white's posterior under the two-component prior of the module's docstring.

    The scene average (``scene`` ± ``scene_sd``, :func:`scene_average_evidence`) weighs the components (balanced: grey
    ± ``balance_sd``; unbalanced: grey ± :data:`UNBALANCED_SD`); the more probable one gives the level — balanced:
    with the fit's own level (``fit_level`` ± ``fit_sd``, what the reflectance prior makes of the scene), unbalanced:
    with the scene average instead (the two read the same evidence)."""
    fit_level = np.asarray(fit_level, dtype=float)
    scene = np.asarray(scene, dtype=float)
    finite = math.isfinite(scene_sd)
    # Evidence for each component: the scene average under its prior (the fit's level is common to both).
    weights = []
    for prior_sd, prior_p in ((balance_sd, 1.0 - UNBALANCED_PRIOR), (UNBALANCED_SD, UNBALANCED_PRIOR)):
        weights.append(prior_p * (_gauss(scene, prior_sd**2 + scene_sd**2) if finite else 1.0))
    p_unbalanced = weights[1] / sum(weights) if sum(weights) > 0 else 0.0
    if finite and p_unbalanced > 0.5:
        # the fit's level is the reflectance prior's reading of the same scene average (a scene of measured surfaces,
        # its mean 14° yellow of grey under D65): the scene's own spread replaces it
        precision = 1.0 / UNBALANCED_SD**2 + 1.0 / scene_sd**2
        info = scene / scene_sd**2
    else:  # balanced: the balance and the fit's level, as before lamp-lit histories were told apart
        precision = 1.0 / balance_sd**2 + 1.0 / fit_sd**2
        info = fit_level / fit_sd**2
    return CommonLevel(mean=info / precision, sd=math.sqrt(1.0 / precision), unbalanced=float(p_unbalanced))
