"""Robust region statistics: clipping, passers-by, occlusion, 16-bit linear images."""

from __future__ import annotations

import numpy as np
import pytest
from illumon.camera import ResponseCurve
from illumon_service.decode import decode_image
from illumon_service.regions import Region, region_means, region_stats, response_for
from svc_helpers import encode_png


def test_linear16_with_clutter_and_clipping():
    rng = np.random.default_rng(1)
    truth = np.array([0.2, 0.35, 0.15])
    img = np.clip(truth * (1 + 0.01 * rng.standard_normal((100, 100, 3))), 0, 1)
    img[10:40, 10:40] = [0.9, 0.1, 0.1]  # a passer-by over 9 % of region a
    img[60:70, 0:100] = 1.0  # clipped streak
    data = encode_png(np.round(img * 65535).astype(np.uint16))
    arr, full = decode_image(data)
    assert arr.dtype == np.uint16 and full == 65535
    resp = response_for({"encoding": "linear"}, full)
    out = region_means(arr, [Region("a", 0, 0, 100, 100), Region("b", 0, 55, 100, 20)], resp)
    np.testing.assert_allclose(out["a"], truth, rtol=0.01)
    assert out["b"] is not None  # half clipped → just usable


def test_mostly_clipped_is_missing():
    img = np.full((50, 50, 3), 255, np.uint8)
    img[:10] = 100
    arr, full = decode_image(encode_png(img))
    out = region_means(arr, [Region("a", 0, 0, 50, 50)], ResponseCurve("srgb", white_level=255))
    assert out["a"] is None


def test_srgb8_linearised():
    img = np.full((20, 20, 3), 188, np.uint8)  # sRGB 188 ≈ 0.5 linear
    arr, full = decode_image(encode_png(img))
    out = region_means(arr, [Region("a", 0, 0, 20, 20)], response_for({"encoding": "srgb", "white_level": 255}, full))
    np.testing.assert_allclose(out["a"], 0.5, atol=0.01)


def test_vectorised_regions_match_per_region_reference(monkeypatch):
    """The OpenCV path (the default) gives the per-region numpy reference's values and misses, whatever the memory
    layout of the pixels: RGB, a reversed view of BGR (what decode_image returns), or non-contiguous pixels."""
    import illumon_service.regions as reg

    rng = np.random.default_rng(7)
    for dt, full in ((np.uint8, 255), (np.uint16, 65535)):
        for trial in range(12):
            img = (rng.normal(0.5, 0.05 + 0.1 * (trial % 3), (80, 180, 3)).clip(0, 1) * full).astype(dt)
            img[rng.random((80, 180)) < 0.05 * (trial % 4)] = full  # clipped pixels
            img[5:30, 5:25] = (0.9 * full, 0.1 * full, 0.1 * full)  # a passer-by
            layout = trial % 3
            if layout == 1:
                img = np.ascontiguousarray(img[:, :, ::-1])[:, :, ::-1]  # BGR memory, RGB view
            elif layout == 2:
                img = img[:, ::2]  # every other column: pixels not contiguous
            else:
                img = img[:, :90]
            size = 40 if trial < 9 else 8  # regions of different sizes; at the end, small ones (one median sample each)
            regions = [Region(str(i), int(rng.integers(0, 40)), int(rng.integers(0, 40)), int(rng.integers(1, size)),
                              int(rng.integers(1, size))) for i in range(6)]
            if trial % 4 == 3:  # all of one size, the usual case
                regions = [Region(str(i), int(rng.integers(0, 40)), int(rng.integers(0, 40)), 30, 25) for i in range(6)]
            resp = ResponseCurve("srgb" if trial % 2 else "linear", white_level=full)
            monkeypatch.setattr(reg, "_PER_REGION", True)
            ref = region_stats(img, regions, resp)
            monkeypatch.setattr(reg, "_PER_REGION", False)
            got = region_stats(img, regions, resp)
            assert any(v is not None for v in ref.values())
            for key, value in ref.items():
                assert (value is None) == (got[key] is None)
                if value is not None:
                    np.testing.assert_allclose(got[key][0], value[0], rtol=1e-12)  # means
                    np.testing.assert_allclose(got[key][1], value[1], rtol=1e-6, atol=1e-8)  # cv2: √ round-off if flat


def test_standard_error_is_pixel_noise_over_root_count():
    """A uniform region with pixel noise σ: the standard error is σ/√n (16-bit linear, 50 × 40 px), on every path —
    OpenCV, per-region reference and the coverage-weighted reduced decode; texture-free, so it is the noise itself."""
    import illumon_service.regions as reg

    rng = np.random.default_rng(3)
    sigma = np.array([0.004, 0.008, 0.016])
    img = ((np.array([0.3, 0.4, 0.5]) + sigma * rng.standard_normal((120, 160, 3))) * 65535).round().astype(np.uint16)
    r = Region("a", 20, 30, 50, 40)
    resp = ResponseCurve("linear", white_level=65535)
    expect = sigma / np.sqrt(50 * 40)
    for per_region in (False, True):
        reg._PER_REGION = per_region
        try:
            mean, se = region_stats(img, [r], resp)["a"]
        finally:
            reg._PER_REGION = False
        np.testing.assert_allclose(mean, [0.3, 0.4, 0.5], atol=3e-3)
        np.testing.assert_allclose(se, expect, rtol=0.08)  # trimming at 3.5σ removes a sliver of the tails
    # half-size decode: 2×2 averages (σ/2) over a quarter of the pixels — the same standard error of the mean
    half = img.reshape(60, 2, 80, 2, 3).mean(axis=(1, 3)).round().astype(np.uint16)
    _, se_half = region_stats(half, [Region("a", 21, 31, 50, 40)], resp, scale=2, size=(160, 120))["a"]
    np.testing.assert_allclose(se_half, expect, rtol=0.2)


def test_reduced_decode_weights_edges_by_coverage():
    """On an image whose every 2×2 block is one colour, the decoded-at-half-size path (regions cutting blocks, their
    edge pixels weighted by coverage) gives the full-resolution means exactly."""
    rng = np.random.default_rng(3)
    for trial in range(6):
        small = np.empty((60, 80, 3), np.uint8)
        # Bounded noise (no pixel beyond 3.5 robust σ: nothing trimmed at either resolution) and one clipped block.
        small[:] = rng.integers(100, 140, (60, 80, 3)) if trial % 2 else rng.integers(40, 200, (1, 1, 3))
        small += rng.integers(0, 12, (60, 80, 3), dtype=np.uint8)
        small[7, 9] = 255
        full = np.repeat(np.repeat(small, 2, axis=0), 2, axis=1)
        regions = [Region("a", 3, 5, 41, 27), Region("b", 10, 10, 60, 40), Region("c", 17, 2, 33, 90),
                   Region("d", 101, 61, 58, 58)]
        resp = ResponseCurve("srgb" if trial % 3 else "linear", white_level=255)
        ref = region_means(full, regions, resp)
        got = region_means(small, regions, resp, scale=2, size=(160, 120))
        for key, value in ref.items():
            np.testing.assert_allclose(got[key], value, rtol=1e-12)


def test_reduced_jpeg_decode():
    """jpeg_reduction picks the largest factor keeping every region ≥ 32 decoded pixels wide; decode_image then
    decodes at that size (JPEG only) and the region means stay within a fraction of a percent of the full decode's."""
    from illumon_service.decode import jpeg_reduction

    rng = np.random.default_rng(4)
    yy, xx = np.mgrid[0:300, 0:403]
    img = np.stack([80 + 60 * np.sin(xx / 50.0), 120 + 40 * np.cos(yy / 40.0), 100 + 0 * xx], axis=2)
    img = np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8)
    jpeg, png = encode_png(img, ".jpg"), encode_png(img)
    regions = [Region("a", 10, 10, 130, 70), Region("b", 201, 150, 150, 133)]
    assert jpeg_reduction(jpeg, regions, 8) == 2  # 70 px: 35 at 1/2, 17 at 1/4
    assert jpeg_reduction(jpeg, regions, 1) == 1 and jpeg_reduction(png, regions, 8) == 1
    assert jpeg_reduction(jpeg, [Region("s", 0, 0, 63, 200)], 8) == 1
    assert jpeg_reduction(jpeg, [Region("s", 0, 0, 256, 256)], 4) == 4
    half, _ = decode_image(jpeg, reduction=2)
    assert half.shape == (150, 202, 3)
    arr, _ = decode_image(jpeg)
    resp = ResponseCurve("srgb", white_level=255)
    ref = region_means(arr, regions, resp)
    got = region_means(half, regions, resp, scale=2, size=(403, 300))
    for key, value in ref.items():
        np.testing.assert_allclose(got[key], value, rtol=0.005)
    with pytest.raises(ValueError, match="reduced|1/2"):
        decode_image(png, reduction=2)


def test_sample_medians_and_mads_are_exact():
    """The all-regions median / MAD of the median samples equal, bit for bit, a sort and a partition per region and
    channel (regions of one size and of several, 8- and 16-bit codes, sRGB and linear tables)."""
    from illumon_service.regions import _lut, _sample_stats

    rng = np.random.default_rng(11)
    for dt, full in ((np.uint8, 255), (np.uint16, 65535)):
        for enc in ("srgb", "linear"):
            lut = _lut(ResponseCurve(enc, white_level=full), full + 1)
            for sizes in ([64] * 5, [1, 2, 3, 50, 1029, 0]):
                samples = [(rng.normal(0.4, rng.uniform(0.001, 0.2), (m, 3)).clip(0, 1) * full).astype(dt) for m in sizes]
                med, mad = _sample_stats(samples, lut, full)
                for r, s in enumerate(samples):
                    if not len(s):
                        continue
                    for c in range(3):
                        v = lut[s[:, c]]
                        ref_med = np.sort(v)[len(v) // 2]
                        ref_mad = np.partition(np.abs(v - ref_med), len(v) // 2)[len(v) // 2]
                        assert med[c, r] == ref_med and mad[c, r] == ref_mad


@pytest.mark.parametrize("per_region", [False, True])
def test_sub_code_noise_keeps_the_mean_between_codes(per_region):
    """A clean, dark, linear 8-bit region whose pixel noise is below a code (σ = 0.35 codes around 10.3 codes): its
    pixels are codes 10 and 11 (and a few 9 and 12), and their mean is the region's value. Trimming at 3.5 robust σ
    from the MAD (0 codes: more than half the pixels share the median code) kept only code 10, a bias of 0.3 code —
    28 σ of the mean of 2 000 pixels; the trimming scale is now at least one code."""
    import illumon_service.regions as reg

    rng = np.random.default_rng(5)
    value = np.array([10.3, 20.6, 6.2])  # codes
    img = np.clip(np.round(value + 0.35 * rng.standard_normal((60, 60, 3))), 0, 255).astype(np.uint8)
    resp = ResponseCurve("linear", white_level=255)
    monkey = reg._PER_REGION
    reg._PER_REGION = per_region
    try:
        mean, se = region_stats(img, [Region("a", 5, 5, 50, 40)], resp)["a"]
    finally:
        reg._PER_REGION = monkey
    exact = img[5:45, 5:55].reshape(-1, 3).mean(axis=0) / 255  # the plain mean of the codes: nothing to trim
    np.testing.assert_allclose(mean, exact, atol=1e-9)
    np.testing.assert_allclose(mean, value / 255, atol=0.1 / 255)  # rounding that σ = 0.35 does not fully dither
