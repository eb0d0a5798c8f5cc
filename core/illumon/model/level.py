"""The level common to a rendered camera's history: balanced daylight, or light the camera was not balanced for.

Static patches cannot see a shift common to every frame's light (a tilt of every reflectance undoes it). For output a
camera white-balanced itself (``--primaries srgb``) two pieces of evidence place that level: the balance (a history
of daylight has a mean white grey within :data:`~illumon.camera.primaries.SRGB_BALANCE_SD`) and the scene's average
colour. The balance is a statement about *daylight*: a history lit only by lamps (street lamps at night, a lamp-lit
room, a light box) is as warm or cold as its lamps, whatever the camera's preset — the assumption that hid the real
lamp-lit scenes' 10–16° errors (every simulator's history was daylight). So the level's prior is a mixture of two
components:

- **balanced** — the history's mean white is grey within ``balance_sd`` (log r/g, b/g);
- **lamp-lit** — near the white of one of the lamps of the CIE tables through the camera, alone or half and half with
  daylight (:func:`illumon.model.lamps.lamp_population`), within :data:`LAMP_LEVEL_SD`.

The scene average (gray-world over the static patches) is the evidence between them. Its uncertainty is the
assumption's own (``SCENE_GREY_SD``, the spread of a scene's average around grey where its regions are nearly
achromatic) plus the sampling error of the patches' chromaticities (their spread over √N): a ColorChecker's
saturated patches say little (gray-world 6–14° off on the development charts), a scene of grey and pale surfaces a
lot. The component with the larger posterior is taken (a mixture mean would land between the two, wrong for both),
and its Gaussian posterior gives the level and its spread; the lamp-lit component's probability is reported as the
history's ``non_daylight`` evidence.

Parameters chosen on development data only (``benchmarks/lamps.py``: MIMO ``bmug``, ``diff``; ``benchmarks/real.py``:
the ``sony-dolp`` sets); ``lion`` and ``spdif`` are held out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..priors.scene_average import SceneAverage, expected_offset

__all__ = ["LAMP_LEVEL_SD", "UNBALANCED_PRIOR", "CommonLevel", "common_level_posterior", "daylight_level",
           "anchor_common_level", "mean_log_chroma", "scene_reading", "verdict_shift"]

LAMP_LEVEL_SD = 0.15
"""Spread (log r/g, b/g) of a lamp-lit history's mean white around one of the CIE lamps' whites (alone or half and half
with daylight, :func:`illumon.model.lamps.lamp_population`): lamps of one type differ, a history's frames mix lamps,
and the tables are a sample of the lamps in use."""

UNBALANCED_PRIOR = 0.2
"""Prior probability that a history is lit by light its camera was not balanced for (lamps only)."""


@dataclass(frozen=True)
class CommonLevel:
    """The posterior of a history's mean white (log r/g, b/g) and which component it came from."""

    mean: NDArray[np.float64]
    sd: float
    unbalanced: float
    """Posterior probability of the lamp-lit component (light the camera was not balanced for)."""
    other: NDArray[np.float64] | None = None
    """The mean white of the component not taken (lamp-lit for a balanced verdict, balanced for a lamp-lit one), where
    both could be weighed: what the level would be had the verdict gone the other way (:func:`verdict_shift`)."""


def _log_mixture(x: NDArray[np.float64], centres: NDArray[np.float64], var: float,
                 logw: NDArray[np.float64] | None = None) -> float:
    """log of the Gaussian mixture density (isotropic variance ``var``) over ``centres`` at ``x``, with log weights
    ``logw`` (normalised here; default equal)."""
    d2 = np.sum((centres - x) ** 2, axis=1)
    lw = np.full(len(centres), -math.log(len(centres))) if logw is None else logw - np.logaddexp.reduce(logw)
    return float(np.logaddexp.reduce(lw - 0.5 * d2 / var) - math.log(2 * math.pi * var))


def common_level_posterior(
    fit_level: NDArray[np.float64], fit_sd: float, balance_sd: float, scene: SceneAverage,
    reading: NDArray[np.float64], lamps: NDArray[np.float64], *,
    balanced: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None, camera_sd: float = 0.0,
) -> CommonLevel:
    """The mean white's posterior under the two-component prior of the module's docstring.

    ``reading`` (± ``scene.sd``) is the mean white the scene average implies (:func:`scene_reading`); it weighs the
    components — balanced: grey ± ``balance_sd``; lamp-lit: a mixture over the lamps' whites through the camera
    ``lamps`` (M × 2, log r/g, b/g), each ± :data:`LAMP_LEVEL_SD`. The more probable one gives the level — balanced:
    with the fit's own level (``fit_level`` ± ``fit_sd``, what the reflectance prior makes of the scene), lamp-lit:
    with the reading instead (the two read the same evidence), under the lamp mixture.

    For sensor RGB of a camera nobody measured (``camera_level`` of :func:`illumon.model.fit_scene_model`'s fixed-camera
    fit) the balanced component is instead
    ``balanced`` = (centres N × 2, log weights N): the daylight whites through the prior camera, each ± ``balance_sd``
    (the measured cameras' spread), and every lamp white carries that spread too (``camera_sd``).
    """
    fit_level = np.asarray(fit_level, dtype=float)
    reading = np.asarray(reading, dtype=float)
    lamps = np.asarray(lamps, dtype=float)
    r2 = scene.sd**2
    v = LAMP_LEVEL_SD**2 + camera_sd**2
    if not (math.isfinite(r2) and np.all(np.isfinite(reading)) and len(lamps)):
        p_lamp = 0.0
    else:
        centres, logw = (np.zeros((1, 2)), None) if balanced is None else balanced
        log_a = math.log(1.0 - UNBALANCED_PRIOR) + _log_mixture(reading, centres, balance_sd**2 + r2, logw)
        log_b = math.log(UNBALANCED_PRIOR) + _log_mixture(reading, lamps, v + r2)
        p_lamp = float(1.0 / (1.0 + math.exp(min(log_a - log_b, 700.0))))
    # balanced: the balance and the fit's level, as before lamp-lit histories were told apart
    precision = 1.0 / balance_sd**2 + 1.0 / fit_sd**2
    balanced_mean = fit_level / fit_sd**2 / precision
    if not (math.isfinite(r2) and np.all(np.isfinite(reading)) and len(lamps)):
        return CommonLevel(mean=balanced_mean, sd=math.sqrt(1.0 / precision), unbalanced=p_lamp)
    # each lamp's component: the Gaussian product of its prior and the reading, weighted by its evidence
    d2 = np.sum((lamps - reading) ** 2, axis=1)
    w = np.exp(-0.5 * (d2 - d2.min()) / (v + r2))
    w /= w.sum()
    means = (lamps * r2 + reading * v) / (v + r2)
    mean = w @ means
    if p_lamp > 0.5:
        var = v * r2 / (v + r2) + float(w @ np.sum((means - mean) ** 2, axis=1)) / 2
        # the daylight alternative: the balance's level, or sensor RGB's own (the fit keeps it, :mod:`.fit`)
        return CommonLevel(mean=mean, sd=math.sqrt(var), unbalanced=p_lamp,
                           other=balanced_mean if balanced is None else fit_level)
    return CommonLevel(mean=balanced_mean, sd=math.sqrt(1.0 / precision), unbalanced=p_lamp, other=mean)


CONFLICT = 3.0
"""Standard deviations (RMS over log r/g and b/g) apart beyond which :func:`daylight_level` takes the scene average's
reading alone rather than its combination with the fit's level."""


def daylight_level(fit_level: NDArray[np.float64], fit_sd: float, scene: SceneAverage, reading: NDArray[np.float64],
                   unbalanced: float) -> CommonLevel | None:
    """A measured sensor's daylight history: the fit's level (± ``fit_sd``) joined by the scene average's reading
    (± ``scene.sd``) where the reading is the more precise of the two — a scene whose patches barely differ in colour
    (walls, roads, table tops: the development lamp-lit scenes spread 0.004–0.09), for which the reflectance prior's
    mean measured surface is the wrong guess — else ``None`` (the fit's level stands: for a scene as varied as the
    measured surfaces the reading adds little and, drawn from the same patches, is not independent of the fit).

    On development histories with the sensitivities given (``benchmarks/unmeasured.py`` cases, development cameras ×
    2 seeds, illumon / rawsim simulators): pale daylight scenes 1.33 / 1.30° → 0.77 / 0.71° median (gray-world
    0.64°); lamp-lit ones judged daylight (lamps near the locus) mean 2.26 / 2.44° → 1.18 / 1.27°; scenes of measured
    surfaces unchanged."""
    r2 = scene.sd**2
    if not (math.isfinite(r2) and r2 < fit_sd**2 and np.all(np.isfinite(reading))):
        return None
    f2 = fit_sd**2
    fit_level, reading = np.asarray(fit_level, dtype=float), np.asarray(reading, dtype=float)
    if float(np.sum((fit_level - reading) ** 2)) > CONFLICT**2 * 2 * (f2 + r2):
        # the two disagree beyond their spreads: the fit's level is the one with a known way to fail (light the daylight
        # model does not hold, whose frames bend the reflectances), the reading stands alone
        return CommonLevel(mean=reading, sd=scene.sd, unbalanced=unbalanced)
    mean = (fit_level / f2 + reading / r2) / (1.0 / f2 + 1.0 / r2)
    return CommonLevel(mean=mean, sd=math.sqrt(1.0 / (1.0 / f2 + 1.0 / r2)), unbalanced=unbalanced)


def mean_log_chroma(dm, css: NDArray[np.float64], theta: NDArray[np.float64]) -> NDArray[np.float64]:
    """Mean over frames of the log r/g, b/g of each frame's daylight white through ``css`` (``theta``: F × ≥2)."""
    white = dm.spectra(theta[:, :2]) @ css
    return np.mean(np.log(np.clip(white[:, [0, 2]], 1e-12, None) / np.clip(white[:, 1:2], 1e-12, None)), axis=0)


def verdict_shift(dm, css: NDArray[np.float64], theta: NDArray[np.float64], taken: NDArray[np.float64],
                  level: CommonLevel) -> tuple[float, float]:
    """What the history's lamp-lit-or-balanced verdict leaves uncertain in its light's temperature: ``(shift, p)``,
    the reciprocal-temperature shift (MK⁻¹) that would move the mean white from ``taken`` (the level the fit keeps,
    log r/g, b/g) to the other component's (``level.other``), along the daylight locus through ``css`` at the frames'
    light (``theta``), and that component's probability. ``(0, 0)`` where only one component could be weighed.

    The verdict moves every frame's temperature by that shift, so a frame's temperature is a two-point mixture: its
    interval (:func:`illumon.model.intervals.assemble_estimates`) is the mixture's. On the development sensor-RGB
    histories lit only by lamps (``benchmarks/unmeasured.py`` case ``raw+lamps``), the five of 14 cameras judged
    daylight at ``p`` 0.36–0.41 read every frame 70–150 MK⁻¹ too blue (their whites right), and their 95 % CCT
    intervals held none of the lamps' temperatures."""
    if level.other is None or not np.all(np.isfinite(level.other)):
        return 0.0, 0.0
    h = 1.0
    up, down = theta.copy(), theta.copy()
    up[:, 0] += h
    down[:, 0] -= h
    g = (mean_log_chroma(dm, css, up) - mean_log_chroma(dm, css, down)) / (2 * h)
    gg = float(g @ g)
    if not (gg > 0 and math.isfinite(gg)):
        return 0.0, 0.0
    shift = float(g @ (np.asarray(level.other, dtype=float) - np.asarray(taken, dtype=float))) / gg
    p = min(max(level.unbalanced, 0.0), 1.0)
    return shift, (p if p <= 0.5 else 1.0 - p)


def scene_reading(dm, css: NDArray[np.float64], theta: NDArray[np.float64], scene: SceneAverage, rb
                  ) -> NDArray[np.float64]:
    """The history's mean white (log r/g, b/g) the scene average implies: its gray-world reading less the colour the
    scene is expected to average to — the mean measured surface's under the frames' light (``theta`` through
    ``css``; ``rb`` the reflectance prior) for a scene as varied as the measured surfaces, grey for one whose patches
    barely differ (:func:`~illumon.priors.scene_average.grey_share`)."""
    return scene.mean - np.mean(expected_offset(dm.spectra(theta[:, :2]), css, rb, scene), axis=0)


def anchor_common_level(objective, theta: NDArray[np.float64], css: NDArray[np.float64], level: CommonLevel
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Move every frame's ``(mired, δ)`` by the one common shift that puts the history's mean white at
    ``level.mean`` and re-solve the reflectances at the shifted light (the data fit is unchanged to first order: that
    is the direction static patches cannot see). ``objective``: the scene fit's joint objective (its daylight model
    ``dm`` and ``reflectances(theta)``). Returns the shifted ``θ``, the coefficients and the posterior standard
    deviation of the common ``(mired, δ)`` shift (``level.sd`` through the same Jacobian)."""
    dm = objective.dm
    lo_b, hi_b = dm.bounds()
    shift = np.zeros(2)
    steps = np.array([1.0, 1e-4])

    def shifted(d: NDArray[np.float64]) -> NDArray[np.float64]:
        th = theta.copy()
        th[:, 0] = np.clip(th[:, 0] + d[0], lo_b[0], hi_b[0])
        th[:, 1] = np.clip(th[:, 1] + d[1], lo_b[1], hi_b[1])
        return th

    jac = np.eye(2)
    for _ in range(8):  # Gauss–Newton on two unknowns
        f0 = mean_log_chroma(dm, css, shifted(shift)) - level.mean
        if np.max(np.abs(f0)) < 1e-5:
            break
        jac = np.stack([(mean_log_chroma(dm, css, shifted(shift + steps * e)) - level.mean - f0) / steps[i]
                        for i, e in enumerate(np.eye(2))], axis=1)
        try:
            shift = shift - np.linalg.solve(jac, f0)
        except np.linalg.LinAlgError:
            break
    theta = shifted(shift)
    coef, _ = objective.reflectances(theta)
    try:
        sd = np.sqrt(np.clip(np.diag(level.sd**2 * np.linalg.inv(jac.T @ jac)), 0, None))
    except np.linalg.LinAlgError:
        sd = np.array([dm.mired_sigma, dm.duv_sigma])
    return theta, coef, sd
