"""Marguier & Süsstrunk's θ curve passes through the CIE D-series it was built from."""

import numpy as np
from illumon.daylight import cie, marguier2007


def test_theta_curve_passes_through_d_series():
    curve = marguier2007.theta_curve()
    t = cie.cie_d_cct([4000, 6500, 10000])
    spd = cie.daylight_spectrum(cie.daylight_locus_xy(t))
    theta = curve.theta_of(spd / np.linalg.norm(spd, axis=1, keepdims=True))
    back = curve.spectrum(theta)
    back = 100 * back / back[:, [(560 - 400) // 5]]
    assert np.max(np.abs(back - spd) / spd) < 0.03
