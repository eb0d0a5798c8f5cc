"""Diagnosis of histories measured from images: the failures of the image-based simulator (``benchmarks/imgsim.py``),
each reproduced on its development split (Nikon and Point Grey cameras, development surfaces and daylight, seeds
3 000…: ``benchmarks/diagnose.py --split dev --sims imgsim``), never on a score seed.

Each test names the assumption of the diagnosis that the image pipeline broke and checks the history the failure was
found on; where the fix is a switch (values measured from images or not), the test also shows the failure without it.
"""

from __future__ import annotations

import numpy as np
import pytest
from illumon.diagnosis import noise as dnoise
from illumon.diagnosis import stages
from illumon.diagnosis.fit import NONE_MARGIN, diagnose
from illumon.diagnosis.stages import bilinear_stage, tone_stage
from illumon.simulation.effects import EFFECTS

imgsim = pytest.importorskip("imgsim")
rawsim = pytest.importorskip("rawsim")


def _img_dev(effect: str, i: int):
    """The ``i``-th development history of ``effect`` of the image-based simulator, as the benchmark draws it."""
    seed = 3000 + 1000 * EFFECTS.index(effect) + i
    return imgsim.hide_effect_img(effect, rawsim.DEV_CAMERAS[i % len(rawsim.DEV_CAMERAS)], seed, split="dev")


def _pedestal(h) -> np.ndarray:
    """The hidden pedestal in the output space (the simulator adds it before its colour matrix)."""
    m = np.eye(3) if h.parameters["matrix"] is None else np.asarray(h.parameters["matrix"])
    return m @ np.asarray(h.parameters["offsets"])


def test_codec_noise_is_learned_up_to_its_cap():
    """Output-domain noise of constant variance on a rank-4 history: learned as the codec's variance (within 30 %)
    when allowed, and absent (0) when not."""
    rng = np.random.default_rng(7)
    u = np.abs(rng.normal(1.0, 0.3, (40, 4)))
    v = np.abs(rng.normal(0.05, 0.03, (4, 30)))
    clean = u @ v
    var = 0.6 * dnoise.CODEC_NOISE
    y = clean + np.sqrt(var) * rng.standard_normal(clean.shape)
    with_codec = dnoise.estimate_noise(y, 4, codec_cap=dnoise.CODEC_NOISE)
    without = dnoise.estimate_noise(y, 4)
    assert with_codec.codec == pytest.approx(var, rel=0.3)
    assert without.codec == 0.0
    assert with_codec.codec_cap == dnoise.CODEC_NOISE and without.codec_cap == 0.0


def test_clean_linear_jpeg_history_is_not_a_tone_curve(shared_data):
    """A clean camera encoding linear 8-bit JPEG (quality 91): the region means' error, 0.2…0.35 codes whatever the
    value, is noise of the output domain. Taken for photon noise in linear light (``SHOT_SHARE``) it is what a
    γ ≈ 1.5 curve makes of shot noise: ΔBIC −160. With the codec's noise learned it is not a tone curve."""
    h = _img_dev("none", 10)
    assert h.parameters["jpeg"] and h.parameters["declared_tone"] is None
    f = h.observations.values.shape[0]
    y = h.observations.values.reshape(f, -1)
    margin = NONE_MARGIN["nonlinear_response"]
    assert tone_stage(y, 4)[0].score < -margin  # the failure, linear-light noise alone
    assert tone_stage(y, 4, codec_cap=dnoise.CODEC_NOISE)[0].score > -margin
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "none"


def test_pedestal_on_linear_jpeg_is_named_with_its_noise(shared_data):
    """A 2…4 % pedestal under linear JPEG: with the noise of the signal without the pedestal, the constant codec
    noise gives the dark values far too much weight and the pedestal scored +43 (worse than none); with the noise of
    the value (the base's), −22. The better of the two counts."""
    h = _img_dev("black_offset", 9)
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "black_offset"
    np.testing.assert_allclose(d.parameters["offsets"], _pedestal(h), atol=0.02)


def test_a_negative_pedestal_is_not_a_black_offset(shared_data):
    """An sRGB curve declared linear fits as pedestals of −4.5…−6.5 % (ΔBIC −249, beating the curve's −237): a
    pedestal is light or signal added, never negative, so the curve is named."""
    h = _img_dev("nonlinear_response", 12)
    f = h.observations.values.shape[0]
    _, cands, _ = bilinear_stage(h.observations.values.reshape(f, -1), 4, NONE_MARGIN["clipping"], True,
                                 dnoise.CODEC_NOISE, True)
    offset = next(c for c in cands if c.effect == "black_offset")
    assert offset.score > -NONE_MARGIN["black_offset"]
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "nonlinear_response"


def test_region_clipped_in_every_frame_is_clipping(shared_data):
    """Over-exposure that clips the brightest region in every frame: the service leaves it out of every frame, and
    missing regions were tested only for following the predicted brightness, which a region never seen has not
    (7 such development histories missed). The service's robust means keep at least half of a region's unclipped
    pixels, so a region it leaves out clipped: named for values measured from images, not otherwise."""
    h = _img_dev("clipping", 4)
    assert np.isnan(h.observations.values).all(axis=(0, 2)).any()
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "clipping"
    f = h.observations.values.shape[0]
    _, cands, _ = bilinear_stage(h.observations.values.reshape(f, -1), 4, NONE_MARGIN["clipping"], True)
    assert next(c for c in cands if c.effect == "clipping").score > -NONE_MARGIN["clipping"]


def test_two_values_at_a_shared_level_are_a_note_when_not_reestimating(shared_data, monkeypatch):
    """Two values of a fluorescent patch within 0.2 % of each other at the history's top (0.58) passed as clipping
    (ΔBIC −14.6) and, since the note rule needed the illuminant change only a re-estimating diagnosis computed,
    stayed the effect; then, modelled, a patch "changing" beside the fluorescent one was preferred to it. Taken as a
    clip level (values sharing the top level, :func:`illumon.diagnosis.stages._saturated` bypassed) the two values are
    a note, the change is put down to the other patch's emission, and the fluorescent patch is named. With their
    standard errors they are no clip level at all (their pixels do not saturate): no note, the same diagnosis."""
    h = _img_dev("fluorescence", 5)
    with monkeypatch.context() as m:
        m.setattr(stages, "_saturated", lambda y, se, at_level: at_level)
        d = diagnose(h.observations, h.sensitivities, reestimate=False)
        assert d.effect == "fluorescence" and d.patch_index == h.patch
        assert len(d.notes) == 1 and "a note, not an effect" in d.notes[0]
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "fluorescence" and d.patch_index == h.patch and d.notes == []


def test_lamp_lit_frames_late_in_a_history_are_not_a_patch_change(shared_data):
    """Seven frames lit 62…96 % by a fluorescent lamp, five of them at the end: read as a patch changing at frame 26
    (ΔBIC −42) beside the lamp's −67. The patch change vanishes without the lamp-lit frames and the lamp survives the
    patch split, so the lamp is named."""
    h = _img_dev("off_locus_illuminant", 2)
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "off_locus_illuminant"
    assert len(set(d.parameters["frame_indices"]) & set(h.parameters["frames"])) >= 4


def test_shaded_patch_is_not_put_down_to_its_own_fluorescence(shared_data):
    """A shaded patch misfits the spectral model too (it passed the fluorescence margin on that very patch): a
    local effect is put down to fluorescence only of another patch, and the shadow is named, with no clipping read
    into the run its modelling drops."""
    h = _img_dev("shadow", 1)
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "shadow" and d.patch_index == h.patch
    assert "clipping" not in [e["effect"] for e in d.effects]


def test_pedestal_hidden_by_auto_exposure_is_found_by_the_spectral_model(shared_data):
    """An auto-exposure that keeps the scene's mean brightness steady makes one combination of the bilinear model's
    frame factors constant, which carries the pedestal (ΔBIC +20 as an offset); the spectral model misfits it as
    lamp light (−112). Fitted there, the pedestal explains the lamp (which no longer passes with it subtracted) and
    survives without the frames the lamp was seen in. Its size is less certain than a bilinear pedestal's (the
    spectral model's own misfit: 0.045 / 0.068 / 0.063 found for 0.043 / 0.055 / 0.020)."""
    h = _img_dev("black_offset", 7)
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "black_offset" and d.parameters.get("found_by") == "spectral"
    assert min(d.parameters["offsets"]) > 0.0
    np.testing.assert_allclose(d.parameters["offsets"], _pedestal(h), atol=0.05)


@pytest.mark.parametrize(("i", "effect"), [(117, "patch_change"), (76, "shadow")])
def test_channel_a_colour_matrix_clips_at_0_is_censored(shared_data, i, effect, monkeypatch):
    """A colour matrix takes a saturated surface's channel below 0 in some frames: its pixels clip at 0 and the
    region's robust mean is a few stray codes (1e-5 of white, not 0), weighed with a learned noise far below a code.
    Measured as values (the censoring at 0 alone), the clean history reads as ``effect`` of that patch (ΔBIC −205,
    −277); censored at black (:data:`illumon.diagnosis.stages.BLACK_CODE`), it is clean."""
    h = _img_dev("none", i)
    assert h.parameters["matrix"] is not None and np.min(h.noiseless) < 0
    f = h.observations.values.shape[0]
    y = h.observations.values.reshape(f, -1)
    margin = NONE_MARGIN[effect]

    def score() -> float:
        _, cands, _ = bilinear_stage(y, 4, NONE_MARGIN["clipping"], True, dnoise.CODEC_NOISE, True)
        return next(c.score for c in cands if c.effect == effect)

    with monkeypatch.context() as m:
        m.setattr(stages, "BLACK_CODE", 0.0)  # the failure: only values at 0 censored
        assert score() < -margin
    assert score() > -margin
    assert diagnose(h.observations, h.sensitivities, reestimate=False).effect == "none"


@pytest.mark.parametrize("i", [68, 187])
def test_linear_8bit_noise_is_not_a_tone_curve_from_one_start(shared_data, i, monkeypatch):
    """Clean linear 8-bit histories (JPEG quality 86…92): learned from linear light's noise alone, the linear hypothesis
    keeps shot noise while the tone hypotheses reach the output-domain noise the codec cap allows, and the same noise
    described twice reads as a tone curve (ΔBIC −62, −60). Every hypothesis also started from the output-domain noise
    alone (:data:`illumon.diagnosis.noise.OUTPUT_NOISE_START`), the curve is gone."""
    h = _img_dev("none", i)
    assert h.parameters["declared_tone"] is None and h.parameters["jpeg"]
    f = h.observations.values.shape[0]
    y = h.observations.values.reshape(f, -1)
    margin = NONE_MARGIN["nonlinear_response"]
    with monkeypatch.context() as m:
        m.setattr(dnoise, "OUTPUT_NOISE_START", False)
        assert tone_stage(y, 4, codec_cap=dnoise.CODEC_NOISE)[0].score < -margin  # the failure
    assert tone_stage(y, 4, codec_cap=dnoise.CODEC_NOISE)[0].score > -margin
    assert diagnose(h.observations, h.sensitivities, reestimate=False).effect == "none"


def test_a_shadow_taking_a_channel_near_black_is_still_named(shared_data, monkeypatch):
    """A shadow that takes a dark channel to 1…4·10⁻³ of white is in those values: censored up to one 8-bit code it
    was lost (``none``); at black (a quarter code) it is named, patch and first frame."""
    h = _img_dev("shadow", 4)
    with monkeypatch.context() as m:
        m.setattr(stages, "BLACK_CODE", 1.0 / 255.0)
        assert diagnose(h.observations, h.sensitivities, reestimate=False).effect == "none"
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert (d.effect, d.patch_index, d.frame_index) == ("shadow", h.patch, h.frame)


def test_codec_pedestal_is_judged_by_its_luma():
    """A pedestal lifts luma; 4:2:0 JPEG's chroma subsampling moves chroma only. The smallest pedestal the simulators
    hide (1.5 % of white in every channel) lifts luma by 3.8 codes and is kept; the offsets fitted to clean JPEG
    histories (luma 0.96 and 0.24 code) are the codec's."""
    assert not stages.codec_pedestal(np.full(3, 0.015))
    assert not stages.codec_pedestal(np.array([0.06, 0.058, 0.0125]))
    assert stages.codec_pedestal(np.array([0.00518, 0.00404, -0.00128]))
    assert stages.codec_pedestal(np.array([0.00418, -0.00042, -0.0006]))
    assert sum(stages.CODEC_LUMA) == pytest.approx(1.0)


def test_chroma_subsampling_is_not_a_black_offset(shared_data, monkeypatch):
    """A clean linear JPEG history at ISO 1600 (development seed 3114): 4:2:0 chroma subsampling desaturates its
    regions' means, which the rank-4 model reads as a pedestal of 0.0052 / 0.0040 / −0.0013 of white at ΔBIC −18.1
    (margin 10; the failure, without the luma test). Its luma is below a code: not a black offset, ``none``. Written
    with 4:4:4 sampling the same history has no pedestal to fit even without the test."""
    h = _img_dev("none", 114)
    assert h.parameters["jpeg"] and h.parameters["declared_tone"] is None
    f = h.observations.values.shape[0]
    y = h.observations.values.reshape(f, -1)
    margin = NONE_MARGIN["black_offset"]
    codec_pedestal = stages.codec_pedestal

    def offset(values: np.ndarray) -> object:
        _, cands, _ = bilinear_stage(values, 4, NONE_MARGIN["clipping"], True, dnoise.CODEC_NOISE, True)
        return next(c for c in cands if c.effect == "black_offset")

    with monkeypatch.context() as m:
        m.setattr(stages, "codec_pedestal", lambda b: False)
        old = offset(y)
        assert old.score == pytest.approx(-18.1, abs=3.0) and old.score < -margin  # the failure
        np.testing.assert_allclose(old.parameters["offsets"], [0.0052, 0.0040, -0.0013], atol=0.001)
        assert codec_pedestal(np.asarray(old.parameters["offsets"]))
        encode = imgsim.cv2.imencode

        def encode_444(ext: str, img: np.ndarray, params: list | tuple = ()) -> tuple:
            extra = [imgsim.cv2.IMWRITE_JPEG_SAMPLING_FACTOR, imgsim.cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]
            return encode(ext, img, [*params, *extra] if ext == ".jpg" else params)

        m.setattr(imgsim.cv2, "imencode", encode_444)
        h444 = _img_dev("none", 114)
        assert offset(h444.observations.values.reshape(f, -1)).score > margin  # no pedestal to fit at 4:4:4
    assert offset(y).score > -margin
    assert diagnose(h.observations, h.sensitivities, reestimate=False).effect == "none"


def test_a_highlight_guard_level_is_not_clipping(shared_data):
    """The auto-exposure's highlight guard holds the brightest region at one level (0.8232 of white) in the 15 frames
    it binds (development seed 3175, PNG, linear): 15 values share the history's highest level and read as clipped
    at ΔBIC −14.1 (margin 10; the failure, without standard errors). Their standard errors, 0.16–0.18 code, are those
    of every value that bright: no pixel saturates there, so it is no clip level, and the history is ``none``."""
    h = _img_dev("none", 175)
    f = h.observations.values.shape[0]
    y = h.observations.values.reshape(f, -1)
    se = h.observations.sd.reshape(f, -1)
    margin = NONE_MARGIN["clipping"]

    def clipping(**kw: object) -> object:
        _, cands, _ = bilinear_stage(y, 4, margin, True, dnoise.CODEC_NOISE, True, **kw)
        return next(c for c in cands if c.effect == "clipping")

    old = clipping()
    assert old.score == pytest.approx(-14.1, abs=3.0) and old.parameters["clipped_values"] == 15  # the failure
    assert clipping(se=se).score > -margin
    assert diagnose(h.observations, h.sensitivities, reestimate=False).effect == "none"


def test_values_whose_pixels_saturate_below_the_service_clip_are_clipping():
    """A camera that clips below the service's own clip level (video-range output: 235 of 255 codes) leaves regions
    whose pixels all hold the clip code: their means share the level with no pixel spread (standard error 0), and
    the clip level is found with the standard errors given; with every value's spread alike it is not."""
    rng = np.random.default_rng(11)
    u = np.abs(rng.normal(1.0, 0.3, (40, 4)))
    v = np.abs(rng.normal(0.12, 0.08, (4, 30)))
    clean = u @ v
    clean *= 1.1 * 235.0 / 255.0 / np.quantile(clean, 0.97)
    level = 235.0 / 255.0
    y = np.minimum(clean + 0.002 * rng.standard_normal(clean.shape), level)
    at = y >= level
    assert 10 <= at.sum() <= 0.1 * at.size
    se = np.where(at, 0.0, 0.0007)
    _, cands, _ = bilinear_stage(y, 4, NONE_MARGIN["clipping"], True, dnoise.CODEC_NOISE, True, se=se)
    clip = next(c for c in cands if c.effect == "clipping")
    assert clip.score < -NONE_MARGIN["clipping"] and clip.parameters["clip_level"] == pytest.approx(level, abs=1e-4)
    assert clip.parameters["clipped_values"] == int(at.sum())
    _, cands, _ = bilinear_stage(y, 4, NONE_MARGIN["clipping"], True, dnoise.CODEC_NOISE, True,
                                 se=np.full(y.shape, 0.0007))
    assert next(c for c in cands if c.effect == "clipping").score == np.inf
