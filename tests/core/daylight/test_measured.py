"""Measured-daylight model: interface for the solvers, shipped basis, held-out gain over CIE D."""

import numpy as np
import pytest
from illumon.daylight import (
    cct_duv_from_xy,
    daylight_locus_duv,
    daylight_model,
    daylight_spectrum,
    xy_from_spectrum,
)
from illumon.daylight.measured import MeasuredDaylight, shipped_measured_daylight, split_indices, unit_mean
from illumon.reports.metrics import gfc
from illumon.simulation import datasets

needs_data = pytest.mark.skipif(datasets.shared_data_dir() is None, reason="shared measured data not found")


def test_interface_and_registry():
    m = daylight_model("measured")
    assert isinstance(m, MeasuredDaylight) and m.n_params == 3 and m.basis.shape == (61, 8)
    p = m.start(np.array([40.0, 150.0, 400.0, 500.0]))
    lo, hi = m.bounds()
    assert np.all(p >= lo) and np.all(p <= hi)
    assert m.prior_residuals(p).shape == (4, 3) and m.weights(p).shape == (4, 8)
    assert np.all(m.spectra(p) > 0)
    # (mired, δ) is exactly the spectrum's chromaticity, whatever z.
    q = np.array([[100.0, 0.002, 1.0], [200.0, -0.003, -2.0]])
    cct, duv = cct_duv_from_xy(xy_from_spectrum(m.spectra(q)))
    np.testing.assert_allclose(cct, [10000, 5000], rtol=2e-4)
    np.testing.assert_allclose(duv, daylight_locus_duv(cct) + q[:, 1], atol=2e-5)


def test_shipped_provenance():
    d = shipped_measured_daylight()
    assert d.k == 7 and "Granada" in d.provenance["source"] or "JOSA" in d.provenance["source"]
    assert d.provenance["split"] == "time" and d.provenance["n_training_spectra"] == 1300


@needs_data
def test_beats_cie_on_held_out():
    _, e = datasets.load_granada_daylight()
    _, test = split_indices(len(e), "time")
    e = unit_mean(e[test])
    xy = xy_from_spectrum(e)
    g_cie = gfc(daylight_spectrum(xy), e)
    g_meas = gfc(shipped_measured_daylight().predict(xy), e)
    assert np.mean(g_meas >= 0.999) > np.mean(g_cie >= 0.999) + 0.2  # 0.85 vs 0.57 at writing
    cam = datasets.load_camera("Canon_40D")
    from illumon.camera import angular_error_deg

    a_cie = np.median(angular_error_deg(daylight_spectrum(xy) @ cam, e @ cam))
    a_meas = np.median(angular_error_deg(shipped_measured_daylight().predict(xy) @ cam, e @ cam))
    assert a_meas < 0.8 * a_cie  # 0.060° vs 0.086° at writing
