"""CIE D-series (CIE 015): spectra from chromaticity, the daylight locus, the CIE daylight model and its priors."""

import colour
import numpy as np
import pytest
from illumon.daylight import cie, ohno2013


def test_cie_d65_from_basis_matches_colour():
    xy = cie.daylight_locus_xy(6504)
    spd = cie.daylight_spectrum(xy)
    ref = colour.SDS_ILLUMINANTS["D65"].copy().align(colour.SpectralShape(400, 700, 5)).values
    ref = 100 * ref / ref[(560 - 400) // 5]
    assert np.max(np.abs(spd - ref) / ref) < 0.01


def test_daylight_locus_duv_positive_around_d65():
    assert 0.002 < float(cie.daylight_locus_duv(6500)) < 0.0045


def test_cie_model_prior_and_spectra():
    m = cie.CIEDaylight()
    p = m.start(np.array([150.0, 200.0]))
    s = m.spectra(p)
    assert s.shape == (2, 61)
    cct, _ = ohno2013.cct_duv_from_xy(cie.xy_from_spectrum(s))
    assert np.allclose(cct, [1e6 / 150, 1e6 / 200], rtol=0.01)
    assert np.allclose(m.prior_residuals(p)[:, 1], 0)


def test_history_prior_independent_and_hierarchical():
    """The history prior is −2 log N(θ; m·1, σ_w² I + σ_b² 11ᵀ) up to a constant; with no spread between histories
    it is the sum of the per-frame priors (the scene model's fit is unchanged by default)."""
    from scipy.stats import multivariate_normal

    rng = np.random.default_rng(3)
    params = np.column_stack([150 + 30 * rng.standard_normal(12), 0.002 * rng.standard_normal(12)])
    dm = cie.CIEDaylight()
    assert np.isclose(dm.history_prior_cost(params), (dm.prior_residuals(params) ** 2).sum(), rtol=1e-12)
    hier = cie.CIEDaylight(mired_between=12.0, duv_between=0.0008)
    f = len(params)
    cost_shifted = []
    for p in (params, params + np.array([20.0, 0.001])):
        expected = 0.0
        for k, (mean, sigma, between) in enumerate([(150.0, 45.0, 12.0), (0.0, 0.003, 0.0008)]):
            cov = (sigma**2 - between**2) * np.eye(f) + between**2 * np.ones((f, f))
            expected += -2 * multivariate_normal(np.full(f, mean), cov).logpdf(p[:, k])
        cost_shifted.append((hier.history_prior_cost(p), expected))
    # equal up to the same constant for both histories
    assert np.isclose(cost_shifted[1][0] - cost_shifted[0][0], cost_shifted[1][1] - cost_shifted[0][1], rtol=1e-9)
    # a common shift of every frame costs less than under independent frames
    shift = np.array([20.0, 0.0])
    assert hier.history_prior_cost(params + shift) - hier.history_prior_cost(params) < (
        dm.history_prior_cost(params + shift) - dm.history_prior_cost(params))
    with pytest.raises(ValueError):
        cie.CIEDaylight(mired_between=45.0)
