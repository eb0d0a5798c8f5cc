"""The light of a frame that shows a chart, read from the chart alone with the camera unknown.

A ColorChecker seen by a camera nobody measured says little about its light through the camera transform ``T`` that
:mod:`.calibration` fits (a 3 × 3 absorbs any smooth change of the light), but it says something through the prior of
what cameras are: with the measured cameras' sensitivities as a Gaussian prior (:class:`~illumon.priors.CameraPrior`),
the chart values under a daylight ``E`` are Gaussian with the sensitivities integrated out, ``x ~ N(a A(E) μ, a² (A(E)
Σ A(E)ᵀ + N))`` (``A(E)`` maps stacked sensitivities to the chart's values, ``N`` the values' relative noise and model
error), and the light's reciprocal temperature has a likelihood of its own — the marginal likelihood of
:func:`illumon.sensitivity.sensitivities_illumon`, restricted to the CIE daylight locus, its exposure ``a`` profiled
in closed form, each channel's veiling-glare offset (:data:`~illumon.camera.formation.FLARE_SD` of its mean value)
integrated out with the camera. It is independent of the history's static patches, which cannot see a shift common
to every frame's light (:mod:`illumon.model.level`): a history whose other frames are lit by lamps (a light booth)
bends the patches' shared reflectances and moves every frame's temperature together — the D65 frame of a booth read
as 17 000–25 000 K.

References
----------
.. [Kinoshita2023] Kinoshita & Kiya, 2023: the sensitivity's Gaussian posterior given the illuminant (eqs. 15–16),
   here integrated out.
.. [Huynh2014] Huynh & Robles-Kelly, ICPR 2014: sensitivities and light from one chart under unknown light.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_factor, cho_solve

from ..daylight import CIEDaylight
from ..priors import CameraPrior
from ..priors.camera import camera_prior_covariance
from .formation import FLARE_SD

__all__ = ["CHART_LIGHT_NOISE", "ChartLight", "chart_light_illumon"]

CHART_LIGHT_NOISE = 0.01
"""Relative standard deviation of a chart value around the linear model (noise, the patch's texture, the CIE daylight
model's mismatch to the light), floored at 5 % of the chart's brightest value."""

CHANNEL_GAIN_SD = 0.1
"""Relative standard deviation of each channel's gain beyond the camera prior's, in the direction of that channel's
mean curve: sensor RGB with an in-camera white-balance preset, or a sensor unlike the measured ones. The real
development chart of ``benchmarks/real.py`` (``sony-raw``, a polarisation sensor: white r/g 0.79, b/g 0.82 indoors)
is explained by no measured camera under any daylight — with no gain spread its likelihood peaks at the grid's warm
end, 505 MK⁻¹, ± 6–14; with 0.1 it is flat (± 50–170). On development cameras under a D65 simulator (``rawsim``, prior
without their maker) the readings' RMS error is 14.2 MK⁻¹ without and 15.5 with it; under six development Granada
spectra (112–192 MK⁻¹, ``rawsim`` 12-bit charts, 84 readings) 16.8 without (6 refused) and 18.1 with it (1 refused).
Over :data:`CHART_LIGHT_NOISE` 0.005–0.02 and this spread 0–0.2 the RMS stayed within 16.0–22.4: the pair was not
tuned further. On the development light booth (``python benchmarks/lightbox.py``, 2026-11-28) 0.3 brought the D65
frame's median to 6 596 K (6 357 K with 0.1; the lamp 6 504 K) but spread the cameras wider: 9–12 of 14 inside
5 900–7 200 K over the four booth histories, where 0.1 keeps 11–12 (the Point Grey Grasshopper2, whose channels are
2.4 × the prior's, 5 354 K and 5 726 K): kept."""

NEAR_CLIP = 0.95
"""Values at or above this fraction of the chart's brightest are left out (possibly clipped; as
:data:`illumon.sensitivity.default.NEAR_CLIP`)."""

MAX_MISFIT = 1.0
"""Largest :attr:`ChartLight.misfit` a reading is given with: beyond it no daylight through a camera of the prior
explains the chart, and it says nothing of the light. On development cameras (``rawsim``, 12-bit, prior without their
maker): sensor RGB under a D65 simulator or CIE A 0.38–0.86; the same charts through the camera's colour matrix to
sRGB (a rendering camera declared as sensor RGB) 1.13–1.34, read 20–60 MK⁻¹ too warm; under TL84 1.19–1.38 (its
spikes: readings ~60 MK⁻¹ too cold)."""

MIRED_GRID = np.arange(60.0, 505.0, 5.0)
"""The coarse grid of reciprocal temperatures (MK⁻¹) the likelihood is evaluated on, refined near its maximum."""


@dataclass(frozen=True)
class ChartLight:
    """The chart's reading of its frame's light: reciprocal temperature on the daylight locus (MK⁻¹) and the standard
    deviation of its likelihood (flat prior over :data:`MIRED_GRID`)."""

    mired: float
    sd: float
    misfit: float = float("nan")
    """The values' squared Mahalanobis distance from the model at the reading, per value (≈ 1 where the model
    holds)."""


def chart_light_illumon(values: NDArray[np.float64], reflectances: NDArray[np.float64], prior: CameraPrior,
                        daylight: CIEDaylight | None = None, *, noise: float = CHART_LIGHT_NOISE,
                        gain_sd: float = CHANNEL_GAIN_SD, flare_sd: float = FLARE_SD) -> ChartLight | None:
    """The reciprocal temperature of one frame's light from the chart it shows, the camera's sensitivities integrated
    out over ``prior``.

    Parameters
    ----------
    values
        The chart's linear camera values in that frame (P × 3), NaN where not seen.
    reflectances
        Its patches' reflectances on the grid (P × 61).
    prior
        The camera prior (the measured cameras; benchmarks pass one without the scored camera's maker).
    daylight
        The daylight model whose locus is searched (default :class:`~illumon.daylight.CIEDaylight`).
    noise
        :data:`CHART_LIGHT_NOISE`.
    gain_sd
        :data:`CHANNEL_GAIN_SD`.
    flare_sd
        Spread of the frame's veiling glare, one additive offset per channel, relative to the channel's mean value
        (:data:`~illumon.camera.formation.FLARE_SD`), integrated out like the camera.

    Returns
    -------
    ChartLight or None
        ``None`` when fewer than six values are usable, when the likelihood is largest at an end of
        :data:`MIRED_GRID` or the values' misfit exceeds :data:`MAX_MISFIT` (the chart is explained by no daylight
        through a camera of the prior).

    References
    ----------
    .. [Kinoshita2023] Kinoshita & Kiya, 2023, eqs. 15–16.
    """
    dm = daylight or CIEDaylight()
    v = np.asarray(values, dtype=float)
    top = np.nanmax(v) if np.isfinite(v).any() else 0.0
    if not top > 0:
        return None
    v = v / top
    r = np.asarray(reflectances, dtype=float)
    use = np.isfinite(v) & (v < NEAR_CLIP) & (v > 1e-3)  # P × 3
    if use.sum() < 6:
        return None
    x = np.concatenate([v[use[:, c], c] for c in range(3)])
    mu = prior.mean.T.reshape(-1)
    cov = camera_prior_covariance(prior)
    for c in range(3):  # each channel's unknown gain: the mean curve's direction, ± gain_sd of it
        block = slice(c * prior.mean.shape[0], (c + 1) * prior.mean.shape[0])
        cov[block, block] += gain_sd**2 * np.outer(mu[block], mu[block])

    # each used value's patch and channel (values stacked channel by channel, as ``x``)
    channel = np.concatenate([np.full(int(use[:, c].sum()), c) for c in range(3)])
    patch = np.concatenate([np.flatnonzero(use[:, c]) for c in range(3)])
    n_wl = r.shape[1]
    columns = channel[:, None] * n_wl + np.arange(n_wl)  # a value's sensitivity samples in the stacked vector
    # veiling glare: one additive offset per channel over the whole chart, ± flare_sd of the channel's mean value
    level = np.array([x[channel == c].mean() for c in range(3)])
    glare = (channel[:, None] == channel[None, :]) * (flare_sd * level[channel]) ** 2

    def nll(mired: float) -> tuple[float, float]:
        """−log likelihood at ``mired`` and the values' squared Mahalanobis distance from the model there."""
        e = dm.spectra(np.array([[mired, 0.0]]))[0]
        a = np.zeros((x.size, mu.size))
        np.put_along_axis(a, columns, (r * e)[patch], axis=1)
        m = a @ mu
        scale = float(x @ m) / max(float(m @ m), 1e-300)
        a, m = a * scale, m * scale
        k = a @ cov @ a.T + np.diag((noise * np.maximum(x, 0.05)) ** 2) + glare
        fac = cho_factor(k)
        qx, qm = cho_solve(fac, x), cho_solve(fac, m)
        xqx, xqm, mqm = float(x @ qx), float(x @ qm), float(m @ qm)
        b = (xqm + math.sqrt(xqm**2 + 4.0 * xqx * x.size)) / (2.0 * xqx)
        dist = b * b * xqx - 2.0 * b * xqm + mqm
        return -(x.size * math.log(b) - 0.5 * dist) + float(np.log(np.diag(fac[0])).sum()), dist

    coarse = np.array([nll(m)[0] for m in MIRED_GRID])
    p = np.exp(-(coarse - coarse.min()))
    p /= p.sum()
    mean = float(p @ MIRED_GRID)
    sd = float(math.sqrt(p @ (MIRED_GRID - mean) ** 2))
    i = int(np.argmin(coarse))
    if i in (0, MIRED_GRID.size - 1):  # no daylight through any measured camera explains the chart: no reading
        return None
    step = float(MIRED_GRID[1] - MIRED_GRID[0])
    fine = np.arange(MIRED_GRID[i] - step, MIRED_GRID[i] + step + 1e-9, step / 10)
    scored = [nll(m) for m in fine]
    j = int(np.argmin([c for c, _ in scored]))
    best, misfit = float(fine[j]), scored[j][1] / x.size
    if misfit > MAX_MISFIT:
        return None
    return ChartLight(best, max(sd, step / math.sqrt(12.0)), misfit)
