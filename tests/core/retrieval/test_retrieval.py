"""Multi-frame retrieval on simulated fixed cameras built from measured cameras, daylight and unseen reflectances."""

import numpy as np
import pytest
from illumon.camera import angular_error_deg
from illumon.observations import Observations
from illumon.retrieval import METHODS, retrieve_illuminants
from illumon.retrieval.joint import MIN_NOISE_SCALE
from illumon.simulation import measured_daylight_history, paper_cct, paper_protocol


def trivial_errors(h) -> tuple[np.ndarray, np.ndarray]:
    """Angular errors of gray-world on the history's patches and of a constant D65 camera white (the estimators an
    accuracy limit must fail)."""
    from illumon.daylight import cie_d_cct, daylight_locus_xy, daylight_spectrum

    gw = retrieve_illuminants(h.observations, h.sensitivities, method="gray_world").white
    d65 = h.sensitivities.T @ daylight_spectrum(daylight_locus_xy(cie_d_cct(6500)))
    return angular_error_deg(gw, h.true_white), angular_error_deg(np.tile(d65, (len(gw), 1)), h.true_white)


@pytest.mark.parametrize("camera", ["Nikon_D5100", "Point_Grey_Grasshopper2_14S5C"])
def test_joint_on_measured_daylight(shared_data, camera):
    h = measured_daylight_history(camera, frames=30, patches=10, seed=1)
    res = retrieve_illuminants(h.observations, h.sensitivities)
    err = angular_error_deg(res.white, h.true_white)
    assert np.median(err) < 1.5  # measured 0.35 (D5100), 1.12 (Point Grey)
    assert np.max(err) < 2.0  # measured 0.78, 1.42
    for trivial in trivial_errors(h):  # gray-world 3.28 / 4.78, constant D65 2.52 / 3.74 median
        assert np.median(trivial) >= 1.5
    assert res.reflectances.shape == (10, 61)
    assert res.info["reflectance_out_of_range"] < 0.05  # before the clip to 0…1


def test_joint_recovers_reflectance_shapes(shared_data):
    h = measured_daylight_history("Canon_600D", frames=30, patches=8, seed=2, noise=None)
    res = retrieve_illuminants(h.observations, h.sensitivities)
    # shapes (scale-free): correlation between recovered and true reflectance per patch
    corr = [np.corrcoef(a, b)[0, 1] for a, b in zip(res.reflectances, h.reflectances, strict=True)]
    assert np.median(corr) > 0.9


def test_joint_tolerates_missing_patches(shared_data):
    h = measured_daylight_history("Canon_600D", frames=20, patches=10, seed=3, missing_fraction=0.25)
    assert np.isnan(h.observations.values).any()
    res = retrieve_illuminants(h.observations, h.sensitivities)
    assert np.median(angular_error_deg(res.white, h.true_white)) < 1.5  # measured 0.33
    assert all(np.median(t) >= 1.5 for t in trivial_errors(h))  # gray-world 2.53, constant D65 2.04


def test_relative_illuminants_are_determined_on_paper_protocol(shared_data):
    # The common colour-temperature shift is set by the priors only (see README); the differences between
    # frames are determined by the data: check the estimated mired differences.
    h = paper_protocol("Canon_300D", (40, 60, 80, 100), (0, 1, 2, 3, 4, 5), noise=None)
    res = retrieve_illuminants(h.observations, h.sensitivities)
    true_mired = 1e6 / paper_cct((40, 60, 80, 100))
    est = 1e6 / res.cct
    assert np.max(np.abs(np.diff(est) - np.diff(true_mired))) < 6.0
    assert np.median(angular_error_deg(res.white, h.true_white)) < 3.0
    # Over the paper's four-image cases (Table 3) with camera noise, the frames' errors spread ~1 MK⁻¹ within a case
    # (measured: median sd 0.99, max 1.88) against true spreads of 40–150 MK⁻¹, while the shift common to a case is
    # the priors' (median 15.5 MK⁻¹; ``benchmarks/retrieval.py --analysis``).
    from illumon.camera import CameraNoise
    from illumon.simulation import PAPER_PATCH_SETS, PAPER_TABLES

    spread = []
    for temps in PAPER_TABLES[3]:
        for ps in PAPER_PATCH_SETS[:2]:
            h = paper_protocol("Canon_300D", temps, ps, noise=CameraNoise(exposure_jitter=0.0), seed=sum(temps))
            res = retrieve_illuminants(h.observations, h.sensitivities, method="joint")
            d = 1e6 / res.cct - 1e6 / paper_cct(temps)
            spread.append(float(np.std(d)))
    assert np.median(spread) < 1.5 and max(spread) < 3.0, spread


@pytest.mark.parametrize("temps", [(65, 80), (40, 90), (55, 65, 75, 95)])
def test_marguier2007_descends_to_the_minimum_of_eq3(shared_data, temps):
    """On the paper's protocol at the scale its model assumes (ε1 = 1, noise-free), the gradient descent ends at or
    below the error of eq. (3) at the true angles, and the camera whites are within 2° (benchmarks/seeds.py: median
    0.50°, max 1.7° over Tables 1–3). The fixed-rate descent it replaces stopped far above the truth's error (D65/D80:
    35.9 against 1.7) with camera-white errors up to 12°."""
    from illumon.daylight import theta_curve
    from illumon.priors import reflectance_basis
    from illumon.retrieval.common import imaging_operators
    from illumon.retrieval.marguier2007 import _d65_operator, error_Marguier2007

    h = paper_protocol("Canon_300D", temps, (0, 1, 2, 3, 4, 5), noise=None, illuminant_scale="model")
    res = retrieve_illuminants(h.observations, h.sensitivities, method="marguier2007")
    curve, rb = theta_curve(), reflectance_basis()
    y = h.observations.values / np.median(h.observations.values[..., 1])
    at_truth = error_Marguier2007(curve.theta_of(h.illuminants), y, h.observations.present,
                              imaging_operators(h.sensitivities, curve.basis, rb)[0], _d65_operator(h.sensitivities, rb))
    assert res.info["error"] <= 1.01 * at_truth, (res.info["error"], at_truth)
    assert np.all(angular_error_deg(res.white, h.true_white) < 2.0)


def test_paper_protocol_illuminant_scale(shared_data):
    from illumon.daylight import theta_curve

    h = paper_protocol("Canon_300D", (40, 100), (0, 1), noise=None, illuminant_scale="model")
    eps1 = np.linalg.lstsq(theta_curve().basis, h.illuminants.T, rcond=None)[0][0]
    assert np.allclose(eps1, 1.0)
    cie = paper_protocol("Canon_300D", (40, 100), (0, 1), noise=None)
    assert np.allclose(cie.illuminants[:, 32], 100.0, atol=0.5)  # 560 nm
    with pytest.raises(ValueError, match="illuminant_scale"):
        paper_protocol("Canon_300D", (40, 100), (0, 1), noise=None, illuminant_scale="lux")


def test_dispatcher_rejects_one_frame_and_unknown_method():
    obs = Observations(["a"], ["p", "q"], np.full((1, 2, 3), 0.5))
    with pytest.raises(ValueError, match="at least two frames"):
        retrieve_illuminants(obs, np.ones((61, 3)))
    with pytest.raises(ValueError, match="unknown method"):
        retrieve_illuminants(obs, np.ones((61, 3)), method="nope")
    assert set(METHODS) == {"joint", "marguier2007", "gray_world"}


def test_paper_protocol_table1_methods_side_by_side(shared_data):
    """Marguier & Süsstrunk's Table 1 (two images, CIE D40…D100, 6 ColorChecker patches, Canon 300D) for two patch
    choices: the joint solver beats the paper's method as written and gray-world, and stays below the paper's worst
    case (8.4°). Measured: joint median 3.0°, max 8.0°; marguier2007 median 4.4°, max 19.2°; gray-world 9.7° (see
    benchmarks/retrieval.py for all tables and patch sets)."""
    from illumon.camera import CameraNoise
    from illumon.simulation import PAPER_PATCH_SETS, PAPER_TABLES

    errors: dict[str, list[float]] = {m: [] for m in ("joint", "marguier2007", "gray_world")}
    for temps in PAPER_TABLES[1]:
        for ps in PAPER_PATCH_SETS[:2]:
            h = paper_protocol("Canon_300D", temps, ps, noise=CameraNoise(exposure_jitter=0.0), seed=sum(temps))
            for m in errors:
                res = retrieve_illuminants(h.observations, h.sensitivities, method=m)
                errors[m] += list(angular_error_deg(res.white, h.true_white))
    med = {m: float(np.median(v)) for m, v in errors.items()}
    assert med["joint"] < med["marguier2007"], med
    assert med["joint"] < med["gray_world"], med
    assert med["joint"] < 3.5, med
    assert max(errors["joint"]) < 8.4, med


def test_joint_shared_exposure_reads_brightness_on_the_paper_protocol(shared_data):
    # Locked exposure under illuminants of equal power (Marguier & Süsstrunk's assumption, model scale): the
    # frames' brightness pins the shift common to all frames that per-frame exposures leave to the priors.
    h = paper_protocol("Canon_300D", (40, 50), (0, 1, 2, 3, 4, 5), noise=None, illuminant_scale="model")
    shared = retrieve_illuminants(h.observations, h.sensitivities, exposure="shared")
    per_frame = retrieve_illuminants(h.observations, h.sensitivities)
    err_shared = angular_error_deg(shared.white, h.true_white)
    err_per_frame = angular_error_deg(per_frame.white, h.true_white)
    assert np.max(err_shared) < 1.5, err_shared
    assert np.min(err_per_frame) > 3.0, err_per_frame  # the same case without the brightness cue
    assert shared.info["exposure"] == "shared"
    with pytest.raises(ValueError, match="exposure"):
        retrieve_illuminants(h.observations, h.sensitivities, exposure="per-frame")


def test_joint_shared_weighs_noise_free_data_at_their_own_residual_level(shared_data):
    # Issue 30: noise-free renders fit far better than the noise model (2 %, set for real cameras) assumes; with one
    # shared exposure nothing is left to the priors alone, so the fit weighs the data at their residual level. Table 1
    # D80/D90, the row shared joint missed with the fixed noise model (camera RGB 1.0° / 0.9°; the paper 0.7 / 0.6 in
    # its own metric): now below 0.6°. Per-frame exposures keep the noise model (their common level is the priors').
    h = paper_protocol("Canon_300D", (80, 90), (0, 1, 2, 3, 4, 5), noise=None, illuminant_scale="model")
    shared = retrieve_illuminants(h.observations, h.sensitivities, exposure="shared")
    per_frame = retrieve_illuminants(h.observations, h.sensitivities)
    assert MIN_NOISE_SCALE <= shared.info["noise_scale"] < 0.8, shared.info["noise_scale"]
    assert per_frame.info["noise_scale"] == 1.0
    err = angular_error_deg(shared.white, h.true_white)
    assert np.max(err) < 0.6, err


def test_joint_problem_whitens_by_the_noise_model_and_penalises_reflectances_outside_0_1(shared_data):
    from illumon.daylight import daylight_model
    from illumon.priors import reflectance_basis
    from illumon.retrieval.common import grey_world_mired
    from illumon.retrieval.joint import JointProblem

    h = measured_daylight_history("Canon_600D", frames=4, patches=6, seed=7, noise=None)
    rb = reflectance_basis()
    prob = JointProblem(h.observations, h.sensitivities, daylight_model("cie"), rb, relative_error=0.02,
                        absolute_error=0.002, bound_weight=20.0)
    # whitening: σ = sqrt((0.02 y)² + 0.002²) on the median-normalised values; a dark channel weighs more
    y = h.observations.values / np.median(h.observations.values[..., 1])
    expected = 1.0 / np.sqrt((0.02 * y) ** 2 + 0.002**2)
    used = prob.W > 0
    assert used.mean() > 0.9
    np.testing.assert_allclose(prob.W[used], expected[used], rtol=1e-9)
    # physical bounds: push one patch's reflectance above 1 and below 0 and read the hinge residuals
    x = prob.start(grey_world_mired(h.observations, h.sensitivities))
    nfr = prob.F * prob.nf
    sigma = x[nfr:].reshape(prob.P, prob.nk).copy()
    sigma[0] *= 3.0
    sigma[1] *= -1.0
    x2 = np.concatenate([x[:nfr], sigma.ravel()])
    refl = sigma @ rb.functions.T
    assert refl[0].max() > 1.2 and refl[1].min() < -0.2
    hinge = 20.0 * (np.clip(-refl, 0, None) + np.clip(refl - 1.0, 0, None))
    r = prob.residuals(x2)
    n_day = prob.model.prior_residuals(prob.split(x2)[0]).size
    start = prob.F * prob.P * 3 + prob.P * prob.nk + n_day
    np.testing.assert_allclose(r[start : start + hinge.size], hinge.ravel(), rtol=1e-9, atol=1e-12)
    assert np.sum(r**2) > np.sum(hinge**2) > 10.0


def test_grey_world_baseline_reports_the_daylight_of_a_grey_scene(shared_data):
    # Every patch a flat grey: the patches' mean is the camera white, so the daylight reported is the true one.
    from illumon.daylight import cie_d_cct, daylight_locus_xy, daylight_spectrum
    from illumon.simulation import datasets, simulate_history

    cct = cie_d_cct(np.array([4000.0, 5500.0, 6500.0, 9000.0]))
    e = daylight_spectrum(daylight_locus_xy(cct))
    grey = np.outer([0.2, 0.4, 0.6], np.ones(61))
    h = simulate_history(datasets.load_camera("Nikon_D5100"), e, grey, noise=None)
    res = retrieve_illuminants(h.observations, h.sensitivities, method="gray_world")
    np.testing.assert_allclose(1e6 / res.cct, 1e6 / cct, atol=1.0)  # MK⁻¹ (the search grid's step is 0.5)
    assert np.max(angular_error_deg(res.white, h.true_white)) < 1e-6


def test_grey_world_mired_distances_are_the_summed_squares_bit_for_bit():
    """``grey_world_mired`` adds each frame's two squared chromaticity differences to every grid point as a sum over
    their axis did (issue 29: without the frames × grid × 2 temporary): the same grid point for every frame, frames
    with a missing, clipped or non-finite patch among them, over more frames than one chunk."""
    from illumon.daylight import daylight_locus_duv, daylight_spectrum, xy_from_cct_duv
    from illumon.observations import Observations
    from illumon.retrieval.common import grey_world, grey_world_mired

    rng = np.random.default_rng(3)
    css = np.abs(rng.normal(size=(61, 3))) + 0.1
    values = rng.uniform(0.01, 1.0, (9000, 5, 3))
    values[rng.random((9000, 5)) < 0.2] = np.nan
    values[::101, 2] = [np.inf, 0.5, 0.5]
    values[::103] = np.nan
    values[::107, :, 0] = 0.0
    obs = Observations([str(i) for i in range(9000)], [f"p{j}" for j in range(5)], values,
                       [""] * 9000)
    with np.errstate(all="ignore"):
        got = grey_world_mired(obs, css)
        grid = np.linspace(45.0, 380.0, 200)  # the function as it was
        cct = 1e6 / grid
        whites = daylight_spectrum(xy_from_cct_duv(cct, daylight_locus_duv(cct))) @ css
        chrom = np.log(whites[:, [0, 2]] / whites[:, 1:2])
        gchrom = np.log(np.clip(grey_world(obs)[:, [0, 2]], 1e-9, None))
        want = np.concatenate([grid[np.argmin(((gchrom[i:i + 8192, None, :] - chrom[None, :, :]) ** 2).sum(-1),
                                              axis=1)] for i in range(0, 9000, 8192)])
    assert np.array_equal(got, want)


def _grey_world_nanmean(values: np.ndarray) -> np.ndarray:
    """``grey_world`` as it was written: np.nanmean of the finite values over the patches."""
    white = np.nanmean(np.where(np.isfinite(values), values, np.nan), axis=1)
    return white / white[:, 1:2]


@pytest.mark.parametrize("shape", [(20_000, 16, 3), (1, 16, 3), (3, 1, 3), (9000, 2, 3), (0, 5, 3), (7, 0, 3)])
def test_grey_world_equals_nanmean_bit_for_bit(shape):
    """``grey_world`` sums a chunk of frames one patch after another (issue 29): the whites of np.nanmean over the
    finite values bit for bit — missing patches, infinities, -0.0, 0 in green, frames without a patch, one patch,
    no frames, no patches, and a history that is not C-contiguous — and the same warning for a frame without any."""
    import warnings

    from illumon.retrieval.common import grey_world

    rng = np.random.default_rng(len(shape) + shape[0] + shape[1])
    values = rng.random(shape) * 10.0 ** rng.integers(-3, 3, shape)
    if values.size:
        values[rng.random(shape[:2]) < 0.2] = np.nan
        flat = values.reshape(-1)
        flat[rng.random(flat.size) < 0.01] = np.inf
        flat[rng.random(flat.size) < 0.01] = -np.inf
        flat[rng.random(flat.size) < 0.01] = -0.0
        flat[rng.random(flat.size) < 0.01] = 0.0
        values[0] = np.nan  # a frame without any patch
    for v in (values, np.asfortranarray(values), values[::-1]):
        with warnings.catch_warnings(record=True) as want_w:
            warnings.simplefilter("always")
            want = _grey_world_nanmean(v)
        with warnings.catch_warnings(record=True) as got_w:
            warnings.simplefilter("always")
            got = grey_world(Observations([str(i) for i in range(shape[0])], [f"p{j}" for j in range(shape[1])], v))
        assert got.shape == want.shape and np.array_equal(got.view(np.uint64), want.view(np.uint64))
        assert sorted(str(w.message) for w in got_w) == sorted(str(w.message) for w in want_w)


def test_observed_is_all_finite_channels():
    """``illumon.observations.observed``: ``np.all(np.isfinite(values), axis=-1)``, three channels or not."""
    from illumon.observations import observed

    rng = np.random.default_rng(3)
    for shape in [(50, 16, 3), (4, 3), (3,), (6, 5, 4), (0, 3), (2, 0)]:
        v = rng.random(shape)
        v[rng.random(shape) < 0.2] = rng.choice([np.nan, np.inf, -np.inf])
        assert np.array_equal(observed(v), np.all(np.isfinite(v), axis=-1))


def test_count_over_patches_is_the_sum_over_axis_one():
    """``illumon.observations.count_over_patches``: ``mask.sum(axis=1)`` in its dtype, for 2-, 3- and 4-D masks."""
    from illumon.observations import count_over_patches

    rng = np.random.default_rng(4)
    for shape in [(50, 16, 3), (7, 1, 3), (5, 0, 3), (0, 4, 3), (9, 4), (6, 5, 3, 3)]:
        m = rng.random(shape) < 0.7
        for dtype in (np.int_, np.intp):
            want = m.sum(axis=1, dtype=dtype)
            got = count_over_patches(m, dtype)
            assert got.dtype == want.dtype and np.array_equal(got, want)
    assert count_over_patches(rng.random((4, 3, 3)) < 0.5).dtype == (rng.random((4, 3, 3)) < 0.5).sum(axis=1).dtype
