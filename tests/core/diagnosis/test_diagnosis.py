"""Diagnosis: hidden effects in simulated histories must be found, named, located and measured.

Histories: :func:`illumon.simulation.effects.hide_effect` with the test cameras (``TEST_CAMERAS``) and seeds 10 000…
19 999, never used while developing the method (development: ``DEV_CAMERAS``, seeds < 10 000; benchmark: held-out
cameras, seeds ≥ 1 000 000); and histories of the independent raw pipeline (``benchmarks/rawsim.py``, issue 16) on its
score cameras and surfaces, seeds 10 000…
"""

from __future__ import annotations

import numpy as np
import pytest
from illumon.camera import angular_error_deg
from illumon.diagnosis import bilinear as bl
from illumon.diagnosis import noise as dnoise
from illumon.diagnosis.correction import corrected_observations, estimate_with_effect
from illumon.diagnosis.fit import NONE_MARGIN, diagnose
from illumon.diagnosis.stages import MIN_OFFSET
from illumon.diagnosis.tone import MIN_GAMMA
from illumon.retrieval import retrieve_illuminants
from illumon.simulation.effects import EFFECTS, LOCATED_EFFECTS, TEST_CAMERAS, hide_effect

SEED0 = 10_000
SEEDS = 4
"""Seeds per effect; most histories are small (24 frames × 8 patches) to keep the suite fast on two shared cores."""

REQUIRED = {
    "none": SEEDS - 1,
    "nonlinear_response": SEEDS - 1,
    "black_offset": SEEDS,
    "clipping": SEEDS,
    "patch_change": SEEDS,
    "shadow": SEEDS,
    "off_locus_illuminant": SEEDS - 1,
    "fluorescence": SEEDS - 1,
}
"""Histories per effect (of ``SEEDS``) that must be diagnosed correctly, from the rates on the development seeds: the
bilinear effects ~100 % (the tone curve a little less on 24 × 8 histories), clean ~99 %, off-locus light ~90 %,
fluorescence ~80 % (65…90 % on batches of 20…50 development histories; only visible against the spectral model,
whose own error limits it; see the benchmark's figures). Fluorescence needs 3 of 4 (all 4 are named and located
today): 2 of 4 let a diagnosis that finds half the fluorescent patches pass."""


SIZE = {"off_locus_illuminant": (32, 10), "fluorescence": (32, 10)}
"""History sizes (frames, patches) where 24 × 8 is too small: effects seen only against the spectral model need the
typical scene (the benchmark draws 24…40 frames and 8…12 patches)."""


def _hist(effect: str, i: int):
    frames, patches = SIZE.get(effect, (24, 8))
    return hide_effect(effect, TEST_CAMERAS[i % len(TEST_CAMERAS)], SEED0 + 100 * EFFECTS.index(effect) + i,
                       frames=frames, patches=patches)


def _correct(h, d) -> bool:
    if d.effect != h.effect:
        return False
    where = LOCATED_EFFECTS.get(h.effect, ())
    if "patch" in where and d.patch_index != h.patch:
        return False
    if "frame" in where and (d.frame_index is None or abs(d.frame_index - h.frame) > 2):
        return False
    return True


@pytest.mark.slow
@pytest.mark.parametrize("effect", EFFECTS)
def test_hidden_effect_is_named_and_located(shared_data, effect):
    results = []
    for i in range(SEEDS):
        h = _hist(effect, i)
        d = diagnose(h.observations, h.history.sensitivities, reestimate=False)
        results.append((_correct(h, d), d.effect, d.patch_index, d.frame_index, h.patch, h.frame))
    n_ok = sum(r[0] for r in results)
    assert n_ok >= REQUIRED[effect], results


def test_generator_is_seeded_and_hides_what_it_says(shared_data):
    a = hide_effect("shadow", "Canon_300D", SEED0, frames=20, patches=8)
    b = hide_effect("shadow", "Canon_300D", SEED0, frames=20, patches=8)
    np.testing.assert_array_equal(a.observations.values, b.observations.values)
    shaded = a.parameters["shaded_frames"]
    assert shaded[0] == a.frame and shaded[-1] < 19  # the run ends inside the history
    v = a.observations.values[:, a.patch, 1] / np.nanmedian(a.observations.values[:, :, 1], axis=1)
    assert v[shaded].mean() < 0.6 * np.delete(v, shaded).mean()  # dimmer
    clip = hide_effect("clipping", "Canon_300D", SEED0, frames=20, patches=8)
    assert (clip.observations.values >= 1.0).sum() >= 2
    clean = hide_effect("none", "Canon_300D", SEED0, frames=20, patches=8)
    assert clean.observations.values.max() < 0.95  # metering keeps clean histories below the white level
    with pytest.raises(ValueError, match="unknown effect"):
        hide_effect("dust", "Canon_300D", 0)


def test_lamp_frames_minority_and_majority(shared_data):
    """``lamp_frames``: the default lights a minority of frames as before; ``majority`` two thirds at 35–80 % (the
    outside check's histories); the lamp-lit frames' light departs from their daylight by the stated share."""
    a = hide_effect("off_locus_illuminant", "Canon_300D", SEED0, frames=36, patches=8)
    b = hide_effect("off_locus_illuminant", "Canon_300D", SEED0, frames=36, patches=8, lamp_frames="minority")
    np.testing.assert_array_equal(a.observations.values, b.observations.values)  # the default is unchanged
    assert 3 <= len(a.parameters["frames"]) <= 36 // 5 and min(a.parameters["lamp_fraction"]) >= 0.6
    m = hide_effect("off_locus_illuminant", "Canon_300D", SEED0, frames=36, patches=8, lamp_frames="majority")
    assert len(m.parameters["frames"]) == 24
    assert 0.35 <= min(m.parameters["lamp_fraction"]) and max(m.parameters["lamp_fraction"]) <= 0.8
    day = np.setdiff1d(np.arange(36), m.parameters["frames"])
    clean = hide_effect("none", "Canon_300D", SEED0, frames=36, patches=8)  # the same daylight run, unlit by lamps
    np.testing.assert_allclose(m.history.illuminants[day], clean.history.illuminants[day])
    assert not np.allclose(m.history.illuminants[m.parameters["frames"]], clean.history.illuminants[m.parameters["frames"]])
    with pytest.raises(ValueError, match="unknown lamp_frames"):
        hide_effect("off_locus_illuminant", "Canon_300D", SEED0, lamp_frames="most")


def test_fitted_parameters_match_the_hidden_ones(shared_data):
    """The tone curve is detected with the noise learned from the history; γ is then estimated with shot noise plus a
    floor (``GAMMA_NOISE_FLOOR``), less tightly than with the project simulator's own noise assumed (within 8 % before
    issue 16)."""
    for i in (9, 11):
        h = _hist("nonlinear_response", i)
        d = diagnose(h.observations, h.history.sensitivities, reestimate=False)
        assert d.effect == "nonlinear_response" and d.parameters["curve"] == "gamma"
        assert h.parameters["gamma"] * 0.9 < d.parameters["gamma"] < h.parameters["gamma"] * 1.6
    # black offsets: ~92 % named on development histories (one in 12 taken for a tone curve, as is seed 7 here); with
    # the noise learned from the history the offsets themselves are looser than with the simulator's noise assumed
    # (before issue 16 within 0.006; now e.g. 0.003 for 0.022 in one channel)
    named = 0
    for i in (5, 6, 7):
        h = _hist("black_offset", i)
        d = diagnose(h.observations, h.history.sensitivities, reestimate=False)
        if d.effect == "black_offset":
            named += 1
            np.testing.assert_allclose(d.parameters["offsets"], h.parameters["offsets"], atol=0.025)
            assert np.max(np.abs(np.subtract(d.parameters["offsets"], h.parameters["offsets"]))) < 0.5 * max(
                h.parameters["offsets"])
    assert named >= 2


def test_clean_low_rank_data_fit_to_noise_level(shared_data):
    h = _hist("none", 9)
    f, p, _ = h.observations.values.shape
    y = h.observations.values.reshape(f, -1)
    fit = bl.wals(y, dnoise.noise_weights(y), 4)
    # the rank-4 bilinear model leaves residuals at the simulated noise level (whitened variance ≈ 1)
    assert 0.7 < fit.wrss / (fit.n - fit.k) < 1.4


def test_extending_the_model_reduces_the_illuminant_error(shared_data):
    fast = {"start_offsets": (0.0,), "polish_max_frames": 0}
    e0, e1 = [], []
    for i in range(3):
        h = hide_effect("nonlinear_response", TEST_CAMERAS[i], SEED0 + 50 + i, frames=36, patches=10)
        css = h.history.sensitivities
        d = diagnose(h.observations, css, reestimate=False)
        assert d.effect == "nonlinear_response"
        assert d.parameters["gamma"] == pytest.approx(h.parameters["gamma"], rel=0.15)
        before = retrieve_illuminants(h.observations, css, **fast)
        after = estimate_with_effect(h.observations, css, d, base_result=before, **fast)
        e0.append(np.median(angular_error_deg(before.white, h.history.true_white)))
        e1.append(np.median(angular_error_deg(after.white, h.history.true_white)))
    assert np.mean(e1) < np.mean(e0)


def test_corrected_observations_split_and_drop(shared_data):
    h = _hist("patch_change", 13)
    d = diagnose(h.observations, h.history.sensitivities, reestimate=False)
    assert d.effect == "patch_change"
    c = corrected_observations(h.observations, d)
    assert len(c.patches) == len(h.observations.patches) + 1
    assert np.isnan(c.values[d.frame_index :, d.patch_index]).all()
    assert np.isfinite(c.values[d.frame_index :, -1]).all() and np.isnan(c.values[: d.frame_index, -1]).all()


def test_a_single_daylight_frame_is_judged_for_its_light(shared_data):
    """One frame of a clean daylight history (sensor RGB, measured camera) is judged for its light alone: ``none``,
    with the note; no frame at all is refused."""
    h = _hist("none", 0)
    d = diagnose(h.observations.subset(slice(0, 1)), h.history.sensitivities)
    assert d.effect == "none" and d.effects == [] and any(n.startswith("only 1 frame:") for n in d.notes)
    with pytest.raises(ValueError, match="at least"):
        diagnose(h.observations.subset(slice(0, 0)), h.history.sensitivities)


def test_a_history_too_short_for_the_bilinear_effects_is_judged_for_its_light(shared_data):
    """Four frames of a clean daylight history (sensor RGB, measured camera): fewer than the bilinear effects need
    (rank + 2 = 6), judged for its light alone — daylight, ``none``, with the note."""
    h = _hist("none", 0)
    d = diagnose(h.observations.subset(slice(0, 4)), h.history.sensitivities)
    assert d.effect == "none" and d.effects == [] and any("need at least 6 frames" in n for n in d.notes)


def test_generator_fluorophores_are_short_wave_excited_and_daylight_mixture_is_normalised(shared_data):
    from illumon.diagnosis.spectral import daylight_mixture
    from illumon.simulation.effects import SHORT_WAVE_EXCITATION_NM, _compilation_fluorophores
    from illumon.spectra import WAVELENGTHS

    fl = _compilation_fluorophores()
    assert len(fl) > 300
    assert all(WAVELENGTHS[np.argmax(ex)] < SHORT_WAVE_EXCITATION_NM for _, ex, _ in fl)
    w, mu, cov = daylight_mixture()
    assert w.sum() == pytest.approx(1.0) and mu.shape == (w.size, 4) and cov.shape == (w.size, 4, 4)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def _raw(effect: str, seed: int):
    import rawsim

    return rawsim.hide_effect_raw(effect, rawsim.SCORE_CAMERAS[seed % len(rawsim.SCORE_CAMERAS)], seed, split="score",
                                  frames=24, patches=8)


@pytest.mark.parametrize("seed", [10002, 10006])
def test_raw_pipeline_clean_history_is_not_a_tone_curve(shared_data, seed):
    """Clean 10- and 8-bit raw-pipeline histories (black clipping, rounding, per-camera gain): with the noise assumed
    (the method before issue 16) both were reported as ``nonlinear_response``."""
    h = _raw("none", seed)
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    tone = next(c for c in d.candidates if c.effect == "nonlinear_response")
    assert d.effect == "none", [(c.effect, round(c.score, 1)) for c in d.candidates]
    assert tone.score > -NONE_MARGIN["nonlinear_response"]


@pytest.mark.parametrize("seed", [10000, 10003])
def test_raw_pipeline_srgb_output_is_named_nonlinear_response(shared_data, seed):
    """sRGB-encoded output (a gamma with a linear toe): with a pure gamma only, it was reported as ``black_offset``."""
    h = _raw("nonlinear_response", seed)
    assert h.parameters["tone"] == "srgb"
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "nonlinear_response" and d.parameters["curve"] == "srgb"
    assert d.parameters["gamma"] > 1.0  # the best pure gamma: encoded, as the service's tone hint reads it
    c = corrected_observations(h.observations, d)
    np.testing.assert_allclose(c.values, h.history.linear_output, atol=2e-3)


def test_noise_is_learned_from_the_residuals(shared_data):
    """Clean 12-bit raw-pipeline history: the shot-noise coefficient learned from the rank-4 residuals is the region
    mean's, 1 / (gain · white · pixels) (the default assumed 2e-5 is ~100× too large)."""
    import rawsim
    from illumon.simulation import datasets

    rng = np.random.default_rng(3)
    e = rawsim.daylight_run("score", 30, rng)
    r = rawsim.draw_reflectances("score", 10, rng)
    h = rawsim.simulate_raw_history(datasets.load_camera("Canon_50D"), e, r, rng=4, bits=12, conversion_gain=1.5,
                                    read_noise_e=3.0, pixels=200)
    y = h.observations.values.reshape(30, -1)
    nz = dnoise.estimate_noise(y, 4)
    a_true = 1.0 / (1.5 * (4095 - 256) * 200)
    assert 0.5 * a_true < nz.shot < 2.0 * a_true
    assert nz.step == 0.0 and not nz.censored.any()
    q = np.round(y * 255) / 255  # delivered as 8-bit codes: on the grid, black values censored
    nq = dnoise.estimate_noise(q, 4)
    assert nq.step == pytest.approx(1 / 255) and nq.read >= (1 / 255) / np.sqrt(12) - 1e-12


@pytest.mark.parametrize("seed", [10021, 10031])
def test_raw_pipeline_undithered_dark_values_are_neither_tone_curve_nor_offset(shared_data, seed):
    """Clean 8-bit raw-pipeline histories at ISO 100: the pixel noise of dark regions is below half a code, so the
    output rounding biases their means far beyond the learned noise. Before the change the tone test read that bias as
    a γ (ΔBIC −27 and −31 against a margin of 25) and the offset test as a pedestal of a fraction of a code (−19);
    the tone test now raises its censoring level while the band above it misfits the learned noise, and the offset
    test leaves out the values near black."""
    h = _raw("none", seed)
    assert h.parameters["bits"] == 8 and h.parameters["iso"] == 100.0
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    scores = {c.effect: c.score for c in d.candidates}
    assert d.effect == "none", [(c.effect, round(c.score, 1)) for c in d.candidates]
    assert scores["nonlinear_response"] > -NONE_MARGIN["nonlinear_response"] / 2
    assert scores["black_offset"] > -NONE_MARGIN["black_offset"]
    assert d.info["dark_level"] > dnoise.DARK_LEVEL  # the censoring level was raised by the data


def test_tone_test_keeps_the_fixed_dark_level_when_dark_values_fit_the_noise(shared_data):
    """The project's simulator adds the noise the model assumes (no rounding): the tone test's censoring stays at
    DARK_LEVEL and a hidden γ is still named."""
    h = _hist("nonlinear_response", 0)
    d = diagnose(h.observations, h.history.sensitivities, reestimate=False)
    assert d.effect == "nonlinear_response"
    assert d.info["dark_level"] == pytest.approx(dnoise.DARK_LEVEL)


@pytest.mark.parametrize("seed", [10001, 10005])
def test_raw_pipeline_bt709_output_is_named_nonlinear_response(shared_data, seed):
    """BT.709-encoded output (a 0.45 power with an offset and a linear toe; the raw pipeline's ``bt709`` variant):
    with only a pure gamma and sRGB it was reported as ``black_offset`` (ΔBIC −436 and −931 against the tone curve's
    +6 and −331)."""
    import rawsim

    h = rawsim.hide_effect_raw("nonlinear_response", rawsim.SCORE_CAMERAS[seed % len(rawsim.SCORE_CAMERAS)], seed,
                               split="score", frames=24, patches=8, variant="bt709")
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "nonlinear_response" and d.parameters["curve"] == "bt709"
    c = corrected_observations(h.observations, d)
    np.testing.assert_allclose(c.values, h.history.linear_output, atol=2e-3)


def _raw_dev(effect: str, seed: int, variant: str | None = None):
    """A raw-pipeline history of the development split (Nikon and Point Grey cameras, development surfaces and
    daylight, seeds 3 000…: ``benchmarks/diagnose.py --split dev``). The failures the fixes below came from were seen
    on the diagnosis benchmark's score split (seeds ≥ 1 000 000); each test reproduces its failure on development
    seeds instead, so no test pins a score history."""
    import rawsim

    return rawsim.hide_effect_raw(effect, rawsim.DEV_CAMERAS[seed % len(rawsim.DEV_CAMERAS)], seed, split="dev",
                                  variant=variant)


def test_clean_10bit_history_is_not_an_expanding_tone_curve(shared_data, monkeypatch):
    """A clean 10-bit raw-pipeline history: its bilinear misfit is fitted by an *expanding* γ ≈ 0.3 at ΔBIC −222 when
    the tone test may search γ < 1 (reproduced here). No output encoding expands (``MIN_GAMMA``): the tone test
    searches γ ≥ 1 only, and the history is clean."""
    from illumon.diagnosis import tone as tone_test

    h = _raw_dev("none", 3126)
    assert h.parameters["bits"] == 10
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    tone = next(c for c in d.candidates if c.effect == "nonlinear_response")
    assert d.effect == "none", [(c.effect, round(c.score, 1)) for c in d.candidates]
    assert tone.parameters["gamma"] >= MIN_GAMMA and tone.score > -NONE_MARGIN["nonlinear_response"] / 2
    monkeypatch.setattr(tone_test, "MIN_GAMMA", 0.3)  # the failure without the fix
    d_old = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d_old.effect == "nonlinear_response" and d_old.parameters["gamma"] < 1.0


def test_pedestal_absorbed_at_full_rank_is_found(shared_data):
    """A 10-bit history with pedestals of 2.1 / 3.4 / 5.6 % of white (development split): a rank-4 frame factor can
    absorb the constant (on a score history the alternation from the old starts ended at offsets of 2.5 / 12.9 / 1.4 %
    for pedestals of 4.9 / 1.6 / 2.2 %, reported ``none``); the start from the rank-3 fit's offsets finds them."""
    h = _raw_dev("black_offset", 3002)
    assert h.parameters["bits"] == 10
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "black_offset"
    np.testing.assert_allclose(d.parameters["offsets"], h.parameters["offsets"], atol=2e-3)


@pytest.mark.parametrize(("seed", "mimic"), [(3003, "nonlinear_response")])
def test_lamp_light_that_mimics_a_global_effect_is_named(shared_data, seed, mimic):
    """A lamp breaks the rank-4 structure of its frames (a tone curve at ΔBIC −190 on this development history):
    without the lamp-lit frames no evidence of it is left, so the lamp is named. (The score split also had a sodium
    lamp saturating the red channel, clipping at −320; no development history of seeds 3 000…3 059 reproduces a
    clipping mimic, so that case has no test.)"""
    h = _raw_dev("off_locus_illuminant", seed)
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    scores = {c.effect: c.score for c in d.candidates}
    assert scores[mimic] < -NONE_MARGIN[mimic]  # the bilinear stage alone would name it
    assert d.effect == "off_locus_illuminant"
    assert len(set(d.parameters["frame_indices"]) & set(h.parameters["frames"])) >= 3


def test_sub_code_pedestal_is_not_a_black_offset(shared_data):
    """An 8-bit ISO 100 history with a fluorescent patch (development split): the offset test finds pedestals below
    0.001 of white (a quarter of an 8-bit code: the rounding bias of dark regions; on a score history at ΔBIC −14);
    below ``MIN_OFFSET`` it is not reported and the fluorescent patch is."""
    h = _raw_dev("fluorescence", 3006)
    assert h.parameters["bits"] == 8 and h.parameters["iso"] == 100
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    offset = next(c for c in d.candidates if c.effect == "black_offset")
    assert max(abs(v) for v in offset.parameters["offsets"]) < MIN_OFFSET
    assert offset.score > 0
    assert d.effect == "fluorescence" and d.patch_index == h.patch


def test_one_frame_outlier_is_not_a_shadow(shared_data):
    """One patch darkened to 40 % in a single frame (an occluder or a glitch, not a shadow, which lasts several
    frames): the shadow scan considers runs of ``MIN_SHADOW_FRAMES`` or more, so the candidate is not that frame;
    a two-frame run at the same level is found."""
    h = _hist("none", 0)
    obs = h.observations
    one = obs.values.copy()
    one[10, 3] *= 0.4
    y = one.reshape(one.shape[0], -1)
    w = dnoise.noise_weights(y)
    U = bl.wals(y, w, 4).U
    sc = bl.scan_patch_effects(y[:, 9:12], w[:, 9:12], U)
    assert sc["shadow_run"][0, 1] - sc["shadow_run"][0, 0] >= bl.MIN_SHADOW_FRAMES
    two = obs.values.copy()
    two[10:12, 3] *= 0.4
    y2 = two.reshape(two.shape[0], -1)
    sc2 = bl.scan_patch_effects(y2[:, 9:12], w[:, 9:12], U)
    assert tuple(sc2["shadow_run"][0]) == (10, 12)


def test_quantisation_step_finds_the_grid_of_delivered_codes():
    """Values delivered as codes: 8- and 10-bit grids, 12-bit codes in a 16-bit container (the common divisor of the
    codes), and means of coded pixels, which lie on no grid."""
    rng = np.random.default_rng(0)
    assert dnoise.quantisation_step(rng.integers(0, 256, 200) / 255) == pytest.approx(1 / 255)
    assert dnoise.quantisation_step(rng.integers(0, 1024, 200) / 1023) == pytest.approx(1 / 1023)
    assert dnoise.quantisation_step(16 * rng.integers(0, 4096, 200) / 65535) == pytest.approx(16 / 65535)
    assert dnoise.quantisation_step(rng.integers(0, 256, (200, 37)).mean(axis=1) / 255) == 0.0


@pytest.mark.parametrize("i", [0, 2])
def test_clean_history_rounded_to_codes_is_not_a_tone_curve(shared_data, i):
    """Region means rounded to 8-bit codes (software that averages the pixels, then reports integer codes): the
    rounding's variance step²/12 is constant in the output, which the tone test read as a γ ≈ 2 curve over shot
    noise (ΔBIC −24 and −16 on these histories; −80…−200 on the raw pipeline's). Carried into each hypothesis's
    linear light through the curve's slope, it no longer favours a curve."""
    h = hide_effect("none", TEST_CAMERAS[i % len(TEST_CAMERAS)], SEED0 + i, frames=32, patches=10)
    o = h.observations
    codes = np.round(np.clip(o.values, 0, 1) * 255) / 255
    d = diagnose(type(o)(o.frames, o.patches, codes, o.times), h.history.sensitivities, reestimate=False)
    tone = next(c for c in d.candidates if c.effect == "nonlinear_response")
    assert d.info["noise"]["step"] == pytest.approx(1 / 255)
    assert d.effect == "none" and tone.score > 0, [(c.effect, round(c.score, 1)) for c in d.candidates]


@pytest.mark.parametrize(("effect", "seed"), [("none", 3000), ("fluorescence", 3000), ("off_locus_illuminant", 3000)])
def test_raw_histories_rounded_to_codes_name_their_effect(shared_data, effect, seed):
    """The outside check's pattern (issue 16: clean, lamp-lit and fluorescent histories all read as
    ``nonlinear_response``), reproduced by the raw pipeline's ``rounded`` variant (region means rounded to 8-bit
    codes): three score histories scored ΔBIC −114, −34 and −70 for a tone curve before the rounding entered the tone
    test's noise; on these development histories no tone curve is supported and each history's own effect is named."""
    h = _raw_dev(effect, seed, variant="rounded")
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    tone = next(c for c in d.candidates if c.effect == "nonlinear_response")
    assert tone.score > -NONE_MARGIN["nonlinear_response"] / 2, tone.score
    assert d.effect == effect, [(c.effect, round(c.score, 1)) for c in d.candidates]
    if effect == "fluorescence":
        assert d.patch_index == h.patch


def test_tone_curve_whose_misfit_looks_like_lamp_light_stays_a_tone_curve(shared_data):
    """A γ ≈ 2 curve on region means rounded to codes (raw pipeline, ``rounded`` variant): the tone test supports
    it, and its misfit of the spectral model passes the off-locus margin too. Without the top off-locus frames the
    curve's weak evidence is gone, which alone named lamp light; linearised with the fitted curve the frames are
    daylight again, so the curve explains them and is named. (Development seed 3001 of the same variant is still
    named lamp light: the fix does not cover every such history.)"""
    h = _raw_dev("nonlinear_response", 3003, variant="rounded")
    assert h.parameters["tone"] == "srgb"
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    scores = {c.effect: c.score for c in d.candidates}
    assert scores["off_locus_illuminant"] < -NONE_MARGIN["off_locus_illuminant"]
    assert d.effect == "nonlinear_response", [(c.effect, round(c.score, 1)) for c in d.candidates]
    assert d.parameters["curve"] == "srgb"


def test_off_locus_light_takes_priority_over_fluorescence(shared_data):
    """A lamp-lit development history (raw pipeline, Nikon development camera, development surfaces and daylight) in
    which both spectral effects pass their margins: the lamp's misfit makes a patch look fluorescent, not the
    reverse, so the off-locus light is named. (Seed 3007 was this history until the fluorescence test's gains were
    studentised: its patch no longer passes, 1.9 against 3.0; then 9006, Nikon D50, until the emission was confined
    above its band: 3.8 against 5.0. ``benchmarks/diagnose.py --split dev``'s off-locus history 9019, Nikon D40, is
    the `rawsim` one of its 20 where both pass: 6.0 and 156.)"""
    import rawsim

    seed = 9019
    h = rawsim.hide_effect_raw("off_locus_illuminant", "Nikon_D40", seed, split="dev")
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    scores = {c.effect: c.score for c in d.candidates}
    assert scores["fluorescence"] < -NONE_MARGIN["fluorescence"]  # the fluorescence stage alone would name a patch
    assert scores["off_locus_illuminant"] < -NONE_MARGIN["off_locus_illuminant"]
    assert d.effect == "off_locus_illuminant"
    assert len(set(d.parameters["frame_indices"]) & set(h.parameters["frames"])) >= 2


def test_clean_history_with_a_tone_misfit_below_the_margin_is_clean(shared_data):
    """A clean development history of the raw pipeline (Nikon development camera, development surfaces and
    daylight) whose bilinear misfit a tone curve fits at ΔBIC −16: within the margin the tone test was given for
    exactly such histories (``NONE_MARGIN``), so nothing is reported."""
    import rawsim

    seed = 3031
    h = rawsim.hide_effect_raw("none", rawsim.DEV_CAMERAS[seed % len(rawsim.DEV_CAMERAS)], seed, split="dev")
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    tone = next(c for c in d.candidates if c.effect == "nonlinear_response")
    assert tone.score < -10.0, tone.score  # a misfit that a looser margin would report
    assert d.effect == "none", [(c.effect, round(c.score, 1)) for c in d.candidates]


def test_several_effects_at_once_lamp_frames_and_clipping(shared_data):
    """Issue 28: a history with lamp-lit frames whose brightest values are also clipped names both effects, the
    lamp-lit frames and their share of lamp light; the top-level effect is the list's first."""
    from illumon.observations import Observations

    h = hide_effect("off_locus_illuminant", "Canon_300D", 10001)
    obs = h.observations
    level = float(np.nanpercentile(obs.values, 97))
    clipped = Observations(obs.frames, obs.patches, np.minimum(obs.values, level), obs.times)
    diag = diagnose(clipped, h.history.sensitivities)
    effects = {e["effect"]: e for e in diag.effects}
    assert {"clipping", "off_locus_illuminant"} <= set(effects), diag.effects
    assert diag.effect == diag.effects[0]["effect"] and diag.parameters == diag.effects[0]["parameters"]
    changes = [e["illuminant_change_deg"] for e in diag.effects]
    assert changes == sorted(changes, reverse=True)
    off = effects["off_locus_illuminant"]["parameters"]
    truth = dict(zip(h.parameters["frames"], h.parameters["lamp_fraction"], strict=True))
    found = [obs.frames.index(fr) for fr in off["frames"]]
    assert len(set(found) & set(truth)) >= len(truth) - 1 and len(set(found) - set(truth)) <= 1
    shares = [(s, truth[i]) for i, s in zip(found, off["lamp_share"], strict=True) if i in truth and s is not None]
    assert len(shares) >= len(truth) - 2
    assert np.median([abs(s - t) for s, t in shares]) < 0.2, shares
    json = diag.to_json()
    assert json["effects"] == diag.effects and "notes" in json
    # modelling both: far better than neither, no worse than the most consequential alone (camera white, median over
    # frames; with the top effect chosen by what it changes, modelling it alone already gains most: 1.20 → 0.66°,
    # both 0.63°; in discovery order, clipping alone gave 1.29°)
    from illumon.diagnosis.correction import estimate_with_effects

    fast = {"start_offsets": (0.0,), "polish_max_frames": 0}
    truth_white = h.history.true_white
    err = {name: float(np.median(angular_error_deg(r.white, truth_white))) for name, r in (
        ("none", retrieve_illuminants(clipped, h.history.sensitivities, **fast)),
        ("first", estimate_with_effect(clipped, h.history.sensitivities, diag, **fast)),
        ("all", estimate_with_effects(clipped, h.history.sensitivities, diag, **fast)))}
    assert err["all"] < 0.6 * err["none"] and err["all"] <= err["first"] + 0.02, err


def test_shadow_is_not_put_down_to_lamp_frames_elsewhere(shared_data):
    """A development shadow (``rawsim`` 8000, Nikon D200: patch 6 shaded in frames 2–5, ΔBIC −5 406) whose frames
    also read as lamp-lit (−42). With the shaded values dropped the off-locus test still passed, by 0.3, at two other
    daylight frames (8 and 9), and the shadow was put down to lamp light; lamp light explains a shadow only in the
    shaded frames, so the shadow is named, at its patch and onset."""
    import rawsim

    h = rawsim.hide_effect_raw("shadow", "Nikon_D200", 8000, split="dev")
    d = diagnose(h.observations, h.sensitivities, reestimate=False)
    assert d.effect == "shadow"
    assert d.patch_index == h.patch and abs(d.frame_index - h.frame) <= 2
    scores = {c.effect: c.score for c in d.candidates}
    assert scores["off_locus_illuminant"] < -NONE_MARGIN["off_locus_illuminant"]  # the frames do read as lamp-lit


def test_a_channel_held_at_the_white_level_is_clipping(shared_data):
    """An auto-exposure metering the brightest region past the full well holds its green at the white level in 35 of
    36 frames (development ``rawsim`` 6019): a column constant over the frames lies in the span of the rank-4 frame
    factors, so censoring it gains nothing by ΔBIC (+3.6), yet no light makes one channel of a surface constant
    while the other two move. Held at the white level, it is clipping; the same values below the white level (a
    history scaled to 0.9) are not held there, and the ΔBIC test alone decides (none). A clean history with a few
    values at the white level is not held there either."""
    import rawsim
    from illumon.diagnosis.stages import held_at_white
    from illumon.observations import Observations

    h = rawsim.hide_effect_raw("clipping", "Nikon_D40", 6019, split="dev")
    obs = h.observations
    d = diagnose(obs, h.sensitivities, reestimate=False)
    clip = next(c for c in d.candidates if c.effect == "clipping")
    assert clip.score > -NONE_MARGIN["clipping"] and clip.parameters["held_at_white"]
    assert d.effect == "clipping" and d.parameters["clipped_values"] >= 30
    scaled = Observations(frames=obs.frames, patches=obs.patches, values=obs.values * 0.9, times=obs.times)
    assert diagnose(scaled, h.sensitivities, reestimate=False).effect == "none"
    # 6 values (0.8 %) at the white level, one channel in a fifth of its frames
    clean = rawsim.hide_effect_raw("none", "Point_Grey_Grasshopper2_14S5C", 3027, split="dev")
    y = clean.observations.values.reshape(clean.observations.values.shape[0], -1)
    at = np.isfinite(y) & (y >= np.nanmax(y) - 2e-3)
    assert np.nanmax(y) == pytest.approx(1.0) and at.sum() >= 4
    assert not held_at_white(y, at, float(np.nanmax(y)))


def test_clipping_in_patch_means_is_modelled_channel_by_channel(shared_data):
    """Modelling clipping must not throw away the channels that did not clip: development ``rawsim`` 6019 was 0.33°
    off before and 2.59° after the clipped patch was dropped in every frame its green clipped. The re-estimate
    censors the clipped channels alone (at the white level: the estimate without the effect, which censors them
    anyway); a clip level below white is censored the same way, with the patch's other channels kept."""
    import rawsim
    from illumon.diagnosis.correction import Diagnosis, corrected_observations, estimate_with_effect
    from illumon.observations import Observations

    h = rawsim.hide_effect_raw("clipping", "Nikon_D40", 6019, split="dev")
    obs, css, truth = h.observations, h.sensitivities, h.true_white
    fast = {"start_offsets": (0.0,), "polish_max_frames": 0}
    d = diagnose(obs, css, reestimate=False)

    def err(r) -> float:
        return float(np.median(angular_error_deg(r.white, truth)))

    before = err(retrieve_illuminants(obs, css, **fast))
    after = err(estimate_with_effect(obs, css, d, **fast))
    dropped = err(retrieve_illuminants(corrected_observations(obs, d), css, **fast))
    assert after == pytest.approx(before, abs=0.02) and before < 0.5
    assert dropped > before + 1.0
    # below the white level (video range): the clipped values at 0.85 are censored by the re-estimate alone
    low = Observations(obs.frames, obs.patches, obs.values * 0.85, obs.times)
    d_low = Diagnosis("clipping", None, None, {"clip_level": 0.85, "clipped_values": d.parameters["clipped_values"]},
                      [], 0.0, 0.0, None)
    assert err(estimate_with_effect(low, css, d_low, **fast)) == pytest.approx(before, abs=0.02)
    assert err(retrieve_illuminants(corrected_observations(low, d_low), css, **fast)) > before + 1.0
