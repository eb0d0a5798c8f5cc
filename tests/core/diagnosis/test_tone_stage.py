"""The tone-curve test alone (issue 29): :func:`illumon.diagnosis.stages.tone_stage` gives exactly the
``nonlinear_response`` candidate of the whole diagnosis, so the service's tone-response check, which now runs it alone,
decides as before on the diagnosis's test histories (every effect, the test cameras and seeds of
``tests/core/diagnosis/test_diagnosis.py``), and the matrix-product Gram sums of the bilinear fit equal the einsums they
replace."""

from __future__ import annotations

import numpy as np
import pytest
from illumon.diagnosis import bilinear as bl
from illumon.diagnosis.fit import NONE_MARGIN, RANK, diagnose
from illumon.diagnosis.noise import CODEC_NOISE
from illumon.diagnosis.stages import tone_stage
from illumon.diagnosis.tone import _convex_floor
from illumon.simulation.effects import EFFECTS, TEST_CAMERAS, hide_effect
from illumon_service.estimation import check_response

SEED0 = 10_000  # tests/core/diagnosis/test_diagnosis.py's histories


def _hist(effect: str, i: int):
    frames, patches = {"off_locus_illuminant": (32, 10), "fluorescence": (32, 10)}.get(effect, (24, 8))
    return hide_effect(effect, TEST_CAMERAS[i % len(TEST_CAMERAS)], SEED0 + 100 * EFFECTS.index(effect) + i,
                       frames=frames, patches=patches)


def test_gram_products_equal_the_einsums() -> None:
    rng = np.random.default_rng(0)
    w, u, v = rng.random((30, 21)), rng.normal(size=(30, 4)), rng.normal(size=(4, 21))
    np.testing.assert_allclose(bl._gram_cols(w, u), np.einsum("fj,fa,fb->jab", w, u, u), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(bl._gram_rows(w, v), np.einsum("fj,aj,bj->fab", w, v, v), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("effect", ["none", "nonlinear_response", "black_offset", "clipping", "shadow"])
def test_tone_stage_is_the_diagnosis_tone_candidate(effect: str) -> None:
    for i in range(2):
        h = _hist(effect, i)
        obs = h.observations
        f, p, _ = obs.values.shape
        d = diagnose(obs, h.history.sensitivities, reestimate=False)
        want = next(c for c in d.candidates if c.effect == "nonlinear_response")
        got, _ = tone_stage(obs.values.reshape(f, 3 * p), RANK)
        assert got.score == want.score and got.parameters == want.parameters
        supported = got.score < -NONE_MARGIN["nonlinear_response"]
        assert supported == (want.score < -NONE_MARGIN["nonlinear_response"])
        if d.effect == "nonlinear_response":
            assert supported  # the tone curves the diagnosis names are found


def test_check_response_decides_as_the_diagnosis() -> None:
    """Through the service's check: a tone-encoded history warns with the diagnosis's γ, a linear one does not."""
    for effect, warns in (("nonlinear_response", True), ("none", False)):
        h = _hist(effect, 0)
        obs = h.observations
        ids = [f"p{j}" for j in range(obs.values.shape[1])]
        frames = [(str(k), f"2025-06-01T{k % 24:02d}:00:00+00:00",
                   {pid: (None if not np.all(np.isfinite(obs.values[k, j])) else obs.values[k, j].tolist())
                    for j, pid in enumerate(ids)}) for k in range(obs.values.shape[0])]
        out = check_response(frames, ids, h.history.sensitivities, "linear")
        assert out["checked"] and bool(out["warnings"]) == warns, out
        assert out["effect"] == ("nonlinear_response" if warns else "none")
        if warns:
            d = diagnose(obs, h.history.sensitivities, reestimate=False)
            tone = next(c for c in d.candidates if c.effect == "nonlinear_response")
            assert out["gamma"] == float(tone.parameters["gamma"])


def test_check_response_allows_the_codec_noise_of_image_measured_frames(shared_data) -> None:
    """Frames measured from images (with standard errors): a clean camera encoding linear 8-bit JPEG is not told it
    sends tone-encoded values (its output-domain noise read as a γ ≈ 1.5 curve's, ΔBIC −160, before the codec's noise
    was learned), as the whole diagnosis decides; the image-based simulator's development history of
    ``tests/core/diagnosis/test_images.py``."""
    imgsim = pytest.importorskip("imgsim")
    rawsim = pytest.importorskip("rawsim")
    h = imgsim.hide_effect_img("none", rawsim.DEV_CAMERAS[10], 3010, split="dev")
    obs = h.observations
    assert obs.sd is not None
    out = check_response(obs, list(obs.patches), h.sensitivities, "linear")
    assert out["checked"] and out["effect"] == "none" and not out["warnings"], out
    f, p, _ = obs.values.shape
    assert tone_stage(obs.values.reshape(f, 3 * p), RANK)[0].score < -NONE_MARGIN["nonlinear_response"]


@pytest.mark.parametrize("effect", ["none", "nonlinear_response", "black_offset", "clipping", "shadow"])
def test_deciding_gives_the_whole_tests_verdict_and_gamma(effect: str) -> None:
    """``decide`` (the service's check) stops once the verdict is settled: the same verdict and γ as the whole test,
    a score on the same side of the margin (for a supported curve no lower than the whole test's; for none at most
    γ = 1's, ``log n``), with and without the codec's noise."""
    margin = NONE_MARGIN["nonlinear_response"]
    for i in range(2):
        obs = _hist(effect, i).observations
        f, p, _ = obs.values.shape
        y = obs.values.reshape(f, 3 * p)
        for codec in (0.0, CODEC_NOISE):
            whole, _ = tone_stage(y, RANK, True, codec)
            got, _ = tone_stage(y, RANK, True, codec, margin)
            assert (got.score < -margin) == (whole.score < -margin)
            if whole.score < -margin:
                assert got.score >= whole.score and got.parameters["gamma"] == whole.parameters["gamma"]
            else:
                assert got.score <= np.log(np.isfinite(y).sum()) + 1e-9 and np.isnan(got.parameters["gamma"])


def test_convex_floor_bounds_convex_functions_only() -> None:
    lo, hi = 0.0, 1.25
    rng = np.random.default_rng(3)
    for _ in range(50):
        c, a, b = rng.uniform(-0.5, 1.5), rng.uniform(0.1, 50), rng.normal()
        t = np.sort(rng.uniform(lo, hi, rng.integers(3, 9)))  # a convex parabola, its minimum anywhere
        floor = _convex_floor(t, a * (t - c) ** 2 + b, lo, hi)
        least = a * (np.clip(c, lo, hi) - c) ** 2 + b
        assert floor <= least + 1e-9
    # |x − 0.5| is reached exactly: its points on either side pin the kink
    t = np.array([0.1, 0.3, 0.7, 0.9])
    assert _convex_floor(t, np.abs(t - 0.5), lo, hi) == pytest.approx(0.0, abs=1e-12)
    # no bound from two points, or from points that are not convex
    assert _convex_floor(t[:2], t[:2], lo, hi) == -np.inf
    assert _convex_floor(t, -((t - 0.5) ** 2), lo, hi) == -np.inf


def test_gamma_one_is_the_linear_hypothesis() -> None:
    """The deciding floor takes γ = 1's value as the linear hypothesis's (issue 29): the tone test's pure γ at 1 learns
    its noise with the curve's extra variance and slope as arrays of ones times the linear hypothesis's scalars —
    the same fit, bit for bit — with and without a codec's variance."""
    from illumon.diagnosis import noise as nz

    obs = _hist("none", 0).observations
    f, p, _ = obs.values.shape
    y = np.nan_to_num(obs.values.reshape(f, 3 * p))
    yc = np.clip(y, nz.DARK_LEVEL, None)
    lit = np.isfinite(obs.values.reshape(f, 3 * p)) & (y > nz.DARK_LEVEL)
    u = bl.wals(yc, lit.astype(float), RANK).U
    q, floor = 1e-6, 1e-8
    for codec in (0.0, CODEC_NOISE):
        lin = nz.fit_learned_noise(yc, lit, RANK, u, updates=3, iters=30, floor=floor, huber=2.5, extra=q,
                                   codec_cap=codec)
        g = 1.0
        x, slope = yc**g, g * yc ** (g - 1.0)
        one = nz.fit_learned_noise(x, lit, RANK, u, updates=3, iters=30, huber=2.5,
                                   floor=floor * float(np.median(slope[lit])) ** 2, extra=q * slope**2,
                                   slope2=slope**2, codec_cap=codec)
        assert one.nll - float(np.log(slope[lit]).sum()) == lin.nll
