"""The chart-consistency statistic of ``benchmarks/flare.py``: colour patches against their greys' light."""

from __future__ import annotations

import flare
import numpy as np
import real
from illumon.camera.calibration import prior_sensitivities


def _chart(light: str, glare: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A noiseless chart through the prior camera under ``light`` (24 × 3, white at 0.8, plus ``glare`` in every
    channel), and the statistic's expectation (the same camera under D65)."""
    spectra = flare.chart_spectra()
    css = prior_sensitivities()
    values = 0.8 * flare.effective_reflectances(css, flare._cie_light(light), spectra) + glare
    return values, flare.effective_reflectances(css, flare._cie_light("D65"), spectra)


def test_a_chart_lit_as_expected_reads_zero_whatever_its_glare():
    values, expected = _chart("D65", glare=0.03)
    dev = flare.against_greys(values, expected)
    assert dev.shape == (18,)
    # the greys are not quite flat: their line's offset and slope are a little off the chart's own (−0.008…−0.024 here)
    np.testing.assert_allclose(dev, 0.0, atol=0.03)


def test_colour_patches_lit_more_than_their_greys_read_that_factor():
    values, expected = _chart("D65", glare=0.02)
    lit = values.copy()
    colours = [real.ALL.index(p) for p in real.SCENE]
    lit[colours] = 1.3 * (values[colours] - 0.02) + 0.02  # the colour rows under 1.3 × the greys' light
    dev = flare.against_greys(lit, expected) - flare.against_greys(values, expected)
    np.testing.assert_allclose(dev, np.log(1.3), atol=2e-3)
    trend = flare.trend(flare.against_greys(lit, expected), flare.chart_spectra())
    assert abs(trend["per_row"]) < 0.05  # a uniform excess has no row trend


def test_a_row_gradient_is_read_per_row():
    values, expected = _chart("D65")
    graded = values.copy()
    for i in range(18):  # rows 1, 2, 3: 1.0, 0.8, 0.64 × the light
        graded[i] *= 0.8 ** (i // 6)
    trend = flare.trend(flare.against_greys(graded, expected), flare.chart_spectra())
    assert abs(trend["per_row"] - np.log(0.8)) < 0.02
    assert trend["explained"] > 0.9
