"""The image-based simulator (issue 16, held out for scoring): reproducible, clean histories measure the noiseless
scene, and the effects it renders show in the values the service measures."""

from __future__ import annotations

import numpy as np
import pytest
import rawsim
from illumon.simulation import datasets

imgsim = pytest.importorskip("imgsim")

pytestmark = pytest.mark.skipif(datasets.shared_data_dir() is None, reason="measured data (../shared/data) not found")

CAM = rawsim.SCORE_CAMERAS[2]


def _h(effect: str = "none", seed: int = 20_011, **kw):
    kw.setdefault("frames", 6)
    return imgsim.hide_effect_img(effect, CAM, seed, patches=8, **kw)


def test_seeded_reproducibility():
    a, b, c = _h(), _h(), _h(seed=20_012)
    np.testing.assert_array_equal(a.observations.values, b.observations.values)
    np.testing.assert_array_equal(a.observations.sd, b.observations.sd)
    assert a.parameters == b.parameters
    assert not np.allclose(a.noiseless, c.noiseless)
    assert imgsim.body_profile(CAM, 400.0) == imgsim.body_profile(CAM, 400.0)


def test_shapes_and_effective_sensitivities():
    h = _h(tone="srgb", jpeg=False)
    f, p = 6, 8
    assert h.observations.values.shape == (f, p, 3) and h.true_white.shape == (f, 3) and h.sensitivities.shape == (61, 3)
    css = datasets.load_camera(CAM)
    m = np.eye(3) if h.parameters["matrix"] is None else np.asarray(h.parameters["matrix"])
    np.testing.assert_allclose(h.sensitivities, css @ np.diag(h.parameters["wb_gains"]) @ m.T, rtol=1e-12)
    # a region's noiseless mean is exposure · (E R) through the effective sensitivities times a fixed (achromatic)
    # vignetting and texture factor: the same for every frame and channel
    k = np.asarray(h.parameters["exposure"])
    model = k[:, None, None] * np.einsum("fl,pl,lc->fpc", h.illuminants, h.reflectances, h.sensitivities)
    ratio = h.noiseless / model
    np.testing.assert_allclose(ratio, ratio[:1, :, :1] * np.ones_like(ratio), rtol=1e-9)
    assert 0.5 < ratio.min() and ratio.max() < 1.1
    np.testing.assert_allclose(h.true_white, k[:, None] * (h.illuminants @ h.sensitivities), rtol=1e-12)


@pytest.mark.parametrize("tone", ["srgb", 2.2])
def test_clean_history_measures_the_noiseless_scene(tone):
    h = _h(tone=tone, jpeg=False)
    o, n = h.observations.values, h.noiseless
    assert not np.isnan(o).any()
    assert n.max() < 0.9  # the highlight guard keeps a clean history unclipped
    ok = n > 0.02
    rel = np.abs(o - n)[ok] / n[ok]
    assert np.median(rel) < 0.005
    assert np.percentile(rel, 95) < 0.03
    # a region's standard error is its pixels' spread over √pixels: small but not zero
    assert 0 < np.nanmedian(h.observations.sd) < 0.01


def test_pedestal_is_left_in_the_values():
    h = _h("black_offset", tone=None, jpeg=False)
    m = np.eye(3) if h.parameters["matrix"] is None else np.asarray(h.parameters["matrix"])
    expected = m @ np.asarray(h.parameters["offsets"])
    assert np.all(expected > 0.01)
    shift = np.nanmedian(h.observations.values - h.noiseless, axis=(0, 1))
    np.testing.assert_allclose(shift, expected, atol=0.004)


def test_clipping_censors_the_brightest_region():
    h = _h("clipping", tone="srgb", jpeg=False)
    o, n = h.observations.values, h.noiseless
    target = h.parameters["exposure_beyond_white"]
    assert 1.05 <= target <= 1.4
    for i in range(o.shape[0]):
        j, c = np.unravel_index(np.argmax(n[i]), n[i].shape)
        assert n[i, j, c] == pytest.approx(target, rel=1e-9)
        assert np.isnan(o[i, j, c]) or o[i, j, c] < 0.98 < n[i, j, c] - 0.05


def test_undeclared_tone_curve_shows():
    for seed in (20_011, 20_013):
        h = _h("nonlinear_response", seed=seed, jpeg=False)
        assert h.parameters["declared_tone"] is None
        o, n = h.observations.values, h.noiseless
        ok = n > 0.05
        assert np.median(o[ok] / n[ok]) > 1.2  # an encoded value read as linear: well above the linear value
        enc = imgsim.encode_output(n, h.parameters["tone"])
        assert np.median(np.abs(o - enc)[ok]) < 0.004  # one 8-bit code


def test_jpeg_differs_from_png_by_its_rounding():
    png = _h(tone="srgb", jpeg=False, keep_images=True)
    jpg = _h(tone="srgb", jpeg=True, keep_images=True)
    np.testing.assert_array_equal(png.noiseless, jpg.noiseless)  # the same scene, exposure and noise draws
    assert 85 <= jpg.parameters["jpeg_quality"] <= 95
    px = np.sqrt(np.mean((np.stack(png.images).astype(float) - np.stack(jpg.images)) ** 2))
    assert 1.0 < px < 10.0  # pixels: a few codes (texture and noise are what JPEG discards)
    codes = [255 * imgsim.encode_output(h.observations.values, "srgb") for h in (png, jpg)]
    d = np.abs(codes[0] - codes[1])
    assert 0.05 < np.median(d) < 1.5  # region means: about a code (DC quantisation, 4:2:0 chroma at the edges)
    assert d.max() < 8.0


def test_unknown_effect_is_refused():
    with pytest.raises(ValueError, match="unknown effect"):
        imgsim.hide_effect_img("lens_flare", CAM, 1)
