"""Gray-world over a history as evidence of the light (:func:`illumon.priors.scene_average.scene_average_evidence`)."""

from __future__ import annotations

import math

import numpy as np
from illumon.priors import scene_average as sa


def _per_frame(y: np.ndarray, present: np.ndarray) -> sa.SceneAverage:
    """The frame-by-frame computation :func:`~illumon.priors.scene_average.scene_average_evidence` replaced."""
    logs, spreads, counts = [], [], []
    for yf, pf in zip(y, present, strict=True):
        v = yf[pf]
        if len(v) < 2:
            continue
        m = v.mean(axis=0)
        if not np.all(m > 0):
            continue
        logs.append(np.log(m[[0, 2]] / m[1]))
        eps = sa._CHROMA_FLOOR * float(m.mean())
        lc = np.log((np.clip(v[:, [0, 2]], 0, None) + eps) / (np.clip(v[:, 1:2], 0, None) + eps))
        spreads.append(float(np.sqrt(np.mean(np.var(lc, axis=0)))))
        counts.append(len(v))
    if not logs:
        return sa.SceneAverage(np.zeros(2), math.inf, math.inf, 0.0)
    spread, n = float(np.median(spreads)), float(np.mean(counts))
    return sa.SceneAverage(np.mean(logs, axis=0), math.sqrt(sa.SCENE_GREY_SD**2 + spread**2 / n), spread, n)


def test_equals_frame_by_frame_bit_for_bit() -> None:
    """Every frame count, patch count, missing pattern, dark and negative value: the same four numbers, bit for
    bit (issue 29)."""
    rng = np.random.default_rng(1)
    for trial in range(300):
        f, p = int(rng.integers(1, 60)), int(rng.integers(1, 20))
        y = np.exp(rng.normal(-1, 1, (f, p, 3))) * rng.choice([1, 1, 1, 0, -0.01], (f, p, 3))
        if trial % 3 == 0:
            y = rng.uniform(0, 1, (f, p, 3))
        present = rng.random((f, p)) < rng.uniform(0.1, 1)
        y[~present] = np.nan
        got, want = sa.scene_average_evidence(y, present), _per_frame(y, present)
        np.testing.assert_array_equal(got.mean, want.mean)
        assert (got.sd, got.spread, got.patches) == (want.sd, want.spread, want.patches) or (
            math.isinf(got.sd) and math.isinf(want.sd)), trial


def test_rendered_probability_separates_the_output_spaces() -> None:
    """A scene's chromaticity spread as evidence of rendered output: the development scenes' sensor-RGB spreads
    (1–99 % 0.29–0.87, largest 0.90) stay below the warning's 0.9, rendered ones from 1.0 up are above it, and the
    probability rises with the spread; pale scenes (0.03–0.19 in the simulated histories) read as sensor RGB."""
    from illumon.camera.primaries import RENDERED_WARNING_PROBABILITY
    from illumon.priors.scene_average import rendered_probability

    spreads = np.array([0.03, 0.19, 0.29, 0.53, 0.87, 0.90, 1.0, 1.26, 1.94])
    p = np.array([rendered_probability(s) for s in spreads])
    assert np.all(np.diff(p) > 0) and p[0] < 1e-6
    assert np.all(p[spreads <= 0.90] < RENDERED_WARNING_PROBABILITY)
    assert np.all(p[spreads >= 1.0] > RENDERED_WARNING_PROBABILITY)
    assert rendered_probability(float("inf")) == 0.0 and rendered_probability(0.0) == 0.0


def test_output_space_warning_on_a_matrixed_scene() -> None:
    """Ten ColorChecker surfaces seen through the sRGB colour-matching functions (output clipped at 0, as a camera
    clips what its matrix makes negative) spread like rendered output (1.29) and are warned of; the same surfaces
    through the measured cameras' mean sensitivities (sensor RGB, 0.64) are not."""
    from illumon.camera.calibration import prior_sensitivities
    from illumon.camera.primaries import output_space_warning, srgb_sensitivities
    from illumon.daylight import CIEDaylight
    from illumon.priors import colourchecker_reflectances

    _, refl = colourchecker_reflectances()
    surfaces = refl[[0, 2, 3, 6, 7, 10, 11, 13, 14, 17]]
    light = CIEDaylight().spectra(np.array([[160.0, 0.0], [180.0, 0.0], [200.0, 0.0]]))
    for css, warned in ((srgb_sensitivities(), True), (prior_sensitivities(), False)):
        values = np.clip(np.einsum("fl,pl,lc->fpc", light, surfaces, css), 0.0, None)  # an output clips at 0
        assert (output_space_warning(values) is not None) is warned


def test_weakest_channel_tells_a_clipped_matrix_from_a_sensor() -> None:
    """:func:`illumon.camera.primaries.weakest_channel`: a sensor's overlapping channels leave every lit surface all
    three (the ColorChecker's colour patches through the measured cameras' mean keep ≥ 3 %); a colour matrix to sRGB
    takes a saturated patch's weakest channel below zero, clipped to nothing — warned of even in a scene of greys
    that spreads too little to tell (one saturated patch among nine greys); a dark patch's noisy channel is not
    counted (its strongest channel under a tenth of the frame's brightest)."""
    from illumon.camera.calibration import prior_sensitivities
    from illumon.camera.primaries import WEAKEST_CHANNEL, output_space_warning, srgb_sensitivities, weakest_channel
    from illumon.daylight import CIEDaylight
    from illumon.priors import colourchecker_reflectances

    _, refl = colourchecker_reflectances()
    light = CIEDaylight().spectra(np.array([[160.0, 0.0], [180.0, 0.0], [200.0, 0.0]]))
    sensor = np.einsum("fl,pl,lc->fpc", light, refl[:18], prior_sensitivities())
    assert weakest_channel(sensor) > 1.5 * WEAKEST_CHANNEL
    scene = np.concatenate([refl[[17]], np.repeat(refl[[19, 20, 21]], 3, axis=0)])  # cyan among greys
    rendered = np.clip(np.einsum("fl,pl,lc->fpc", light, scene, srgb_sensitivities()), 0.0, None)
    assert weakest_channel(rendered) < WEAKEST_CHANNEL
    said = output_space_warning(rendered)
    assert said is not None and "weakest channel" in said
    dark = sensor.copy()
    dark[:, 0] = [1e-4, 0.0, 1e-4]  # a black patch with a channel at zero: not lit, not counted
    assert weakest_channel(dark) == weakest_channel(sensor)
    assert weakest_channel(np.full((2, 3, 3), np.nan)) == np.inf
