"""Pipeline variants of the independent raw simulator (issue 16 robustness checks): the standard histories are
unchanged by their existence, and each variant changes what it says."""

from __future__ import annotations

import numpy as np
import pytest
import rawsim
from illumon.simulation import datasets

pytestmark = pytest.mark.skipif(datasets.shared_data_dir() is None, reason="measured data (../shared/data) not found")

CAM = rawsim.SCORE_CAMERAS[0]


def _h(effect: str = "none", variant: str | None = None, seed: int = 10_007):
    return rawsim.hide_effect_raw(effect, CAM, seed, split="score", frames=12, patches=6, variant=variant)


def test_default_is_the_standard_pipeline():
    a, b = _h(), _h()
    np.testing.assert_array_equal(a.observations.values, b.observations.values)
    assert "variant" not in a.parameters


@pytest.mark.parametrize("variant", sorted(rawsim.PIPELINE_VARIANTS))
def test_variant_keeps_the_scene_and_changes_the_pipeline(variant):
    std, v = _h("nonlinear_response"), _h("nonlinear_response", variant)
    np.testing.assert_array_equal(std.history.illuminants, v.history.illuminants)
    np.testing.assert_array_equal(std.history.reflectances, v.history.reflectances)
    assert v.parameters["variant"] == variant
    s = v.history.settings
    if variant in ("8bit", "jpeg"):
        assert s["bits"] == 8
    if variant == "16bit":
        assert s["bits"] == 16
    if variant == "iso6400":
        assert s["conversion_gain"] < std.history.settings["conversion_gain"] / 16
    if variant == "bt709":
        assert s["tone"] == "bt709"
    if variant == "small":
        assert 16 <= s["pixels"] <= 64 and s["texture"] == 0.0
    if variant == "rounded":
        levels = 2 ** s["mean_bits"] - 1
        assert s["mean_bits"] in (8, 10)
        codes = v.observations.values * levels
        np.testing.assert_allclose(codes, np.round(codes), atol=1e-9)
    else:
        assert s["mean_bits"] is None


def test_bt709_tone_round_trips():
    x = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(rawsim.decode_tone(rawsim.encode_tone(x, "bt709"), "bt709"), x, atol=1e-9)
    assert rawsim.encode_tone(0.5, "bt709") == pytest.approx(1.099 * 0.5**0.45 - 0.099)


def test_jpeg_like_rounding_moves_block_means_to_the_dc_step():
    rng = np.random.default_rng(0)
    enc = np.round(rng.uniform(0.2, 0.8, (2, 3, 128)) * 255) / 255
    out = rawsim._jpeg_like(enc, 2.0 / 255, 255)
    for b in (slice(0, 64), slice(64, 128)):
        m = out[..., b].mean(axis=-1) * 255 / 2.0
        # block means on the DC grid, up to the per-pixel rounding back to codes (≤ half a code in the mean)
        assert np.max(np.abs(m - np.round(m))) <= 0.25 + 1e-9
    assert np.all(np.abs(out * 255 - np.round(out * 255)) < 1e-9)


def test_rendering_to_srgb_primaries():
    """A rendered camera (issue 26): the preset's matrix keeps CIE D65 grey, saturated patches leave the gamut (the
    pipeline clips them at 0), and automatic balance makes every frame's scene mean the same colour."""
    import colour
    from illumon.priors import colourchecker_reflectances
    from illumon.spectra import GRID

    css = datasets.load_camera(CAM)
    rng = np.random.default_rng(3)
    e = rawsim.daylight_run("dev", 6, rng)
    scene = rawsim.draw_reflectances("dev", 8, rng)
    m, gains = rawsim.rendering(css, e, scene, "preset")
    assert gains is None
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(GRID).values
    white = m @ (d65 @ css)
    assert np.ptp(white / white.mean()) < 1e-6
    _, chart = colourchecker_reflectances("BabelColor Average")
    out = (d65 * chart) @ css @ m.T
    assert (out < 0).any()  # a real matrix to sRGB takes saturated patches out of gamut
    m2, gains = rawsim.rendering(css, e, scene, "auto")
    np.testing.assert_allclose(m2, m)
    means = np.einsum("fl,pl,lc->fc", e, scene, css) * gains
    chroma = means / means[:, 1:2]
    np.testing.assert_allclose(chroma, np.broadcast_to(chroma[0], chroma.shape), rtol=1e-9)
    assert np.ptp(gains[:, 0]) > 0.01  # the light changed, so the gains did
    with pytest.raises(ValueError, match="white_balance"):
        rawsim.rendering(css, e, scene, "daylight")
