"""Physics of the independent raw-camera simulator ``benchmarks/rawsim.py`` (issue 16)."""

from __future__ import annotations

import numpy as np
import pytest
import rawsim
from illumon.simulation import datasets
from illumon.spectra import WAVELENGTHS

needs_data = pytest.mark.skipif(datasets.shared_data_dir() is None, reason="measured data (../shared/data) not found")


def _flat_camera() -> np.ndarray:
    """Three box channels (blue, green, red) so expected signals are easy to compute."""
    c = np.zeros((61, 3))
    c[(WAVELENGTHS >= 600), 0] = 1.0
    c[(WAVELENGTHS >= 500) & (WAVELENGTHS < 600), 1] = 1.0
    c[(WAVELENGTHS < 500), 2] = 1.0
    return c


def test_shot_noise_variance_follows_signal_and_conversion_gain():
    c = _flat_camera()
    e = np.ones((1, 61))
    r = np.full((3, 61), 1.0) * np.array([0.1, 0.3, 0.8])[:, None]
    signal = (e[0] @ c)[1]  # green signal of a unit reflectance
    for gain in (2.0, 8.0):
        k = 0.9 * 40_000 / signal  # brightest region at 0.72 of a 40 000 e⁻ well
        h = rawsim.simulate_raw_history(c, e, r, rng=3, bits=16, adc_bits=16, conversion_gain=gain, read_noise_e=0.0,
                                        full_well_e=40_000, exposure=[k], pixels=20_000)
        white_dn = 2**16 - 1 - 256
        mean = h.observations.values[0, :, 1]
        var = h.pixel_sd[0, :, 1] ** 2
        # Poisson electrons: var(DN) = mean(e⁻)/gain², so var = mean / (gain · white_dn) on the 0…1 scale
        np.testing.assert_allclose(var, mean / (gain * white_dn), rtol=0.05)
    # and the mean is the exposure times the linear signal
    np.testing.assert_allclose(mean, k * r[:, 0] * signal / (gain * white_dn), rtol=2e-3)


def test_black_subtraction_censors_dark_blue_at_zero_under_warm_light():
    import colour
    from illumon.spectra import GRID, resample_columns

    sd = colour.SDS_ILLUMINANTS["A"]
    warm = resample_columns(sd.wavelengths, sd.values[:, None], GRID)[:, 0][None]
    c = _flat_camera()
    r = np.array([np.full(61, 0.001), np.full(61, 0.9)])
    # expose so the bright patch's red fills 80 % of the well: the dark patch's blue is below 1 DN, read noise 2 DN
    sig = np.einsum("fl,pl,lc->fpc", warm, r, c)
    k = 0.8 * 20_000 / sig[0, 1, 0]
    h1 = rawsim.simulate_raw_history(c, warm, r, rng=0, bits=12, read_noise_e=10.0, conversion_gain=5.0, exposure=[k],
                                     pixels=1)
    hn = rawsim.simulate_raw_history(c, np.repeat(warm, 40, 0), r, rng=0, bits=12, read_noise_e=10.0,
                                     conversion_gain=5.0, exposure=np.full(40, k), pixels=1)
    true_blue = k * sig[0, 0, 2] / (5.0 * (4095 - 256))
    blue = hn.observations.values[:, 0, 2]
    assert true_blue < 1.0 / 4095
    assert (blue == 0).mean() > 0.2  # many pixels censored at 0
    assert blue.min() == 0.0 and h1.observations.values.min() >= 0.0
    # the mean of censored values is biased upward (E[max(X, 0)] > E[X])
    hm = rawsim.simulate_raw_history(c, warm, r, rng=1, bits=12, read_noise_e=10.0, conversion_gain=5.0, exposure=[k],
                                     pixels=20_000)
    assert hm.observations.values[0, 0, 2] > true_blue + 0.3 / 4095


@pytest.mark.parametrize("bits", [8, 10, 12])
def test_values_lie_on_the_quantisation_grid(bits):
    c = _flat_camera()
    rng = np.random.default_rng(5)
    e = 50 + 50 * rng.random((6, 61))
    r = rng.uniform(0.02, 0.9, (8, 61))
    h = rawsim.simulate_raw_history(c, e, r, rng=2, bits=bits, pixels=1)
    codes = h.observations.values * (2**bits - 1)
    np.testing.assert_allclose(codes, np.round(codes), atol=1e-9)
    assert len(np.unique(np.round(codes))) > 10
    # region means of many pixels are not quantised
    hm = rawsim.simulate_raw_history(c, e, r, rng=2, bits=bits, pixels=400)
    cm = hm.observations.values * (2**bits - 1)
    assert np.abs(cm - np.round(cm)).max() > 0.05


def test_matrix_and_tone_are_applied_as_declared():
    c = _flat_camera()
    rng = np.random.default_rng(7)
    e = 50 + 50 * rng.random((5, 61))
    r = rng.uniform(0.05, 0.7, (6, 61))
    m = np.array([[1.6, -0.4, -0.2], [-0.2, 1.5, -0.3], [0.0, -0.5, 1.5]])
    kw = {"rng": 11, "bits": 16, "pixels": 1, "ae_error_stops": 0.0}
    lin = rawsim.simulate_raw_history(c, e, r, **kw)
    out = rawsim.simulate_raw_history(c, e, r, matrix=m, tone="srgb", **kw)
    expect = np.clip(np.einsum("ij,fpj->fpi", m, lin.observations.values), 0, 1)
    np.testing.assert_allclose(out.linear_output, expect, atol=2e-4)
    assert np.abs(out.observations.values - out.linear_output).max() > 0.1  # the encoded values differ
    np.testing.assert_allclose(out.true_white, lin.true_white_raw @ m.T, rtol=1e-12)
    g = rawsim.simulate_raw_history(c, e, r, tone=2.2, **kw)
    np.testing.assert_allclose(g.observations.values, lin.observations.values ** (1 / 2.2), atol=2e-4)


def test_auto_exposure_moves_in_third_stops():
    c = _flat_camera()
    rng = np.random.default_rng(1)
    e = (50 + 50 * rng.random((20, 61))) * np.exp(rng.normal(0, 0.5, 20))[:, None]
    h = rawsim.simulate_raw_history(c, e, rng.uniform(0.05, 0.9, (8, 61)), rng=4)
    steps = 3 * np.log2(h.exposure[1:] / h.exposure[:-1])
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    assert np.any(steps != 0)
    fixed = rawsim.simulate_raw_history(c, e, rng.uniform(0.05, 0.9, (8, 61)), rng=4, auto_exposure=False)
    assert np.all(fixed.exposure == fixed.exposure[0])


@needs_data
def test_splits_keep_manufacturers_and_collections_apart():
    cams = set(datasets.camera_names())
    assert set(rawsim.DEV_CAMERAS) | set(rawsim.SCORE_CAMERAS) == cams
    assert not set(rawsim.DEV_CAMERAS) & set(rawsim.SCORE_CAMERAS)
    assert not {rawsim.manufacturer(x) for x in rawsim.DEV_CAMERAS} & {rawsim.manufacturer(x) for x in rawsim.SCORE_CAMERAS}
    dev = np.concatenate(rawsim.reflectance_pool("dev"))
    score = np.concatenate(rawsim.reflectance_pool("score"))
    d = np.abs(dev[:, None, :] - score[None, :, :]).max(-1)
    assert d.min() > 1e-3  # no score surface is a development surface
    assert rawsim.daylight_pool("dev").shape[0] + rawsim.daylight_pool("score").shape[0] == 2600


@needs_data
def test_a_room_lit_by_lamps_is_the_daylit_rooms_surfaces_under_the_lamps(monkeypatch: pytest.MonkeyPatch):
    """``benchmarks/unmeasured.py``'s ``room+lamps``: the surfaces of ``room`` (averaging grey) under a lamp run drawn
    from the same generator, as the real chart-free rooms are lit indoors."""
    import unmeasured
    from illumon.camera.formation import angular_error_deg

    monkeypatch.setattr(unmeasured, "FRAMES", 4)
    cam, seed = "Nikon_D3", 7100
    _, _, lamps = unmeasured._light(cam, "room+lamps", seed)
    np.testing.assert_array_equal(lamps, rawsim.lamp_run(4, np.random.default_rng(seed)))
    obs, white, known = unmeasured.render("rawsim", cam, "room+lamps", seed)
    assert not known
    # the room still averages grey under the lamps: gray-world over its patches is the light's white
    gw = angular_error_deg(np.nanmean(obs.values, axis=1), white)
    assert np.all(gw < 0.5), gw
    # and it is the daylit room's scene, not the pale one the other lamp-lit cases draw
    daylit, white_day, _ = unmeasured.render("rawsim", cam, "room", seed)
    assert np.all(angular_error_deg(np.nanmean(daylit.values, axis=1), white_day) < 0.5)
    pale, white_pale, _ = unmeasured.render("rawsim", cam, "raw+lamps", seed)
    assert np.median(angular_error_deg(np.nanmean(pale.values, axis=1), white_pale)) > 2 * np.median(gw)
