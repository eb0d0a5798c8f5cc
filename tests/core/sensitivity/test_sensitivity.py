"""Tests of illumon.sensitivity: single-chart sensitivity estimation, daylight recovery and colour correction.

Leave-one-camera-out on a subset of 6 measured cameras (the camera under test — and any other measurement of
the same
model — is never in the prior), charts rendered under measured Granada daylight with 0.2–1 % noise. The full
24-camera
table is ``benchmarks/sensitivity.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
from illumon.camera import render
from illumon.daylight import CMFS
from illumon.priors import build_camera_prior, colourchecker_reflectances
from illumon.sensitivity import (
    METHODS,
    channel_gains_Han2012,
    daylight_Han2012,
    estimate_sensitivities,
    rmse_per_channel,
    to_cie1931_Huynh2014,
)
from illumon.sensitivity.evaluate import leave_one_out
from illumon.sensitivity.han2012 import (
    fluorescent_reflectances,
    render_fluorescent_chart,
    sensitivities_Han2012,
    shipped_fluorophores,
)
from illumon.simulation import datasets

needs_data = pytest.mark.skipif(
    datasets.shared_data_dir() is None, reason="measured data (../shared/data) not available"
)

NOISE = [0.002, 0.01]


@pytest.fixture(scope="module")
def data():
    names = datasets.camera_names()
    cams = {n: datasets.load_camera(n) for n in names}
    _, gran = datasets.load_granada_daylight()
    _, refl = colourchecker_reflectances("BabelColor Average")
    rng = np.random.default_rng(1)
    daylights = gran[rng.choice(len(gran), 2, replace=False)]
    subset = names[::4]  # 6 cameras
    return cams, gran, daylights, refl, subset


@pytest.fixture(scope="module")
def loo(data):
    cams, _, daylights, refl, subset = data
    return {
        m: leave_one_out(METHODS[m], cams, daylights, refl, test_cameras=subset, noise=NOISE, seed=2, name=m)
        for m in ("default", "kinoshita2023", "jiang2013")
    }


def test_dispatcher_rejects_unknown_method():
    with pytest.raises(ValueError, match="unknown sensitivity method"):
        estimate_sensitivities(np.ones((24, 3)), np.ones((24, 61)), method="nope")


@needs_data
def test_default_loo_meets_issue_target(loo):
    """Leave-one-camera-out on 6 cameras. Issue 5's target was 0.04; issue 16 chose the prior's smooth floor
    leave-one-manufacturer-out (``SMOOTH_FLOOR`` 1e-4 → 1.6e-3), which costs ~0.002 here (24 cameras: 0.0393 →
    0.0407) and gains 0.006 leave-one-manufacturer-out (0.0533 → 0.0477); this subset measures 0.0419, blue 0.051."""
    res = loo["default"]
    assert res.overall <= 0.043, res.mean
    assert res.mean.max() <= 0.053


@needs_data
def test_default_beats_baselines(loo, data):
    """Leave-one-camera-out the default beats Jiang et al. by 0.01; Bayes is as good on this 6-camera subset
    (0.041 against 0.042), so the default is compared with it leave-one-manufacturer-out, the protocol its prior was
    chosen on (benchmark, 24 cameras: 0.048 against 0.060; leave-one-camera-out 0.041 against 0.049)."""
    from illumon.sensitivity.evaluate import camera_manufacturer

    assert loo["default"].overall < loo["jiang2013"].overall - 0.01
    cams, _, daylights, refl, subset = data
    lomo = {m: leave_one_out(METHODS[m], cams, daylights, refl, test_cameras=subset, noise=NOISE, seed=2, name=m,
                             group=camera_manufacturer) for m in ("default", "kinoshita2023")}
    assert lomo["default"].overall < lomo["kinoshita2023"].overall - 0.005, {m: r.overall for m, r in lomo.items()}


@needs_data
def test_baselines_in_expected_range(loo):
    assert 0.04 <= loo["jiang2013"].overall <= 0.09  # Jiang LOO ≈ 0.069 in the issue
    assert loo["kinoshita2023"].overall <= 0.06


@needs_data
def test_huynh2014_runs_and_is_bounded(data):
    cams, _, daylights, refl, subset = data
    res = leave_one_out(
        METHODS["huynh2014"], cams, daylights[:1], refl, test_cameras=subset[:2], noise=0.005, seed=3
    )
    assert np.all(np.isfinite(res.rmse))
    assert res.overall <= 0.2


@needs_data
def test_han2012_noiseless_fluorescent_chart(data):
    cams, gran, _, refl, _ = data
    ex, em = shipped_fluorophores()
    sfl = fluorescent_reflectances(ex)
    errs = []
    for name in ("Canon_20D", "Nikon_D700"):
        c = cams[name]
        x = render(c, gran[100], refl)
        fl = render_fluorescent_chart(c, gran[100])
        r = sensitivities_Han2012(
            x, refl, fluorescent_rgb=fl, fluorescent_emissions=em, fluorescent_reflectances=sfl
        )
        errs.append(rmse_per_channel(r.sensitivities, c).mean())
    assert np.mean(errs) <= 0.12, errs


@needs_data
def test_default_recovers_daylight(data):
    cams, gran, _, refl, _ = data
    c = cams["Nikon_D80"]
    prior = build_camera_prior([v for n, v in cams.items() if n != "Nikon_D80"])
    e = gran[500]
    res = estimate_sensitivities(render(c, e, refl), refl, camera_prior=prior)
    err = np.sqrt(np.mean((res.illuminant - e / e.mean()) ** 2))
    assert err <= 0.12, err


@needs_data
def test_daylight_recovery_han2012(data):
    cams, gran, _, refl, _ = data
    rng = np.random.default_rng(5)
    errs = {"cie": [], "measured": []}
    for i in rng.choice(len(gran), 10, replace=False):
        for name in ("Canon_50D", "Nikon_D3X"):
            x = render(cams[name], gran[i], refl)
            for basis in errs:
                est = daylight_Han2012(x, refl, cams[name], basis=basis)
                errs[basis].append(np.sqrt(np.mean((est - gran[i] / gran[i].mean()) ** 2)))
    cie, measured = np.mean(errs["cie"]), np.mean(errs["measured"])
    # Measured numbers: CIE basis ≈ 0.03–0.06, measured-daylight basis lower.
    assert cie <= 0.08, cie
    assert measured <= 0.05, measured
    assert measured < cie


@needs_data
def test_channel_gains_correct_illuminant_change(data):
    cams, gran, _, refl, _ = data
    c = cams["Canon_600D"]
    src, dst = gran[10], gran[2000]
    a, b = render(c, src, refl), render(c, dst, refl)
    g = channel_gains_Han2012(c, src, c, dst)
    before = np.abs(a / b.max() * (b.sum() / a.sum()) - b / b.max()).mean()
    after = np.abs(a * g / b.max() - b / b.max()).mean()
    assert after < 0.25 * before
    assert after <= 0.01


@needs_data
def test_transfer_to_cie1931_with_estimated_sensitivities(data):
    cams, gran, _, refl, _ = data
    name = "Nikon_D5100"
    c = cams[name]
    prior = build_camera_prior([v for n, v in cams.items() if n != name])
    e = gran[300]
    est = estimate_sensitivities(render(c, e, refl), refl, camera_prior=prior).sensitivities
    xyz = render(CMFS, e, refl)
    xyz = xyz / xyz[:, 1].max()
    rgb = render(c, e, refl)
    out_true = to_cie1931_Huynh2014(rgb, c)
    out_est = to_cie1931_Huynh2014(rgb, est)
    err_true = np.linalg.norm(out_true / out_true[:, 1].max() - xyz, axis=1).mean()
    err_est = np.linalg.norm(out_est / out_est[:, 1].max() - xyz, axis=1).mean()
    err_raw = np.linalg.norm(rgb / rgb[:, 1].max() - xyz, axis=1).mean()
    assert err_true <= 0.05 and err_est <= 0.06
    assert err_est < 0.5 * err_raw


@needs_data
def test_leave_one_manufacturer_out_holds_out_every_model_of_the_maker(data):
    from illumon.sensitivity.evaluate import camera_manufacturer

    cams, _, daylights, refl, _ = data
    seen: dict[str, int] = {}

    def spy(curves):
        seen[held[0]] = len(curves)
        return build_camera_prior(curves)

    for name in ("Canon_50D", "Nikon_D50", "Phase_One"):
        held = [name]
        leave_one_out(METHODS["kinoshita2023"], cams, daylights[:1], refl, test_cameras=[name], noise=0.005, seed=0,
                      prior_builder=spy, group=camera_manufacturer)
    makers = [camera_manufacturer(n) for n in cams]
    assert seen == {n: len(cams) - makers.count(camera_manufacturer(n)) for n in seen}
    assert seen["Canon_50D"] == 17 and seen["Nikon_D50"] == 11 and seen["Phase_One"] == 23


@needs_data
def test_default_leave_one_manufacturer_out_on_raw_pipeline_charts(data):
    """The default method and its prior floor were chosen leave-one-manufacturer-out on the development cameras; on
    score cameras (Canon, Hasselblad, Pentax, Phase One) with charts photographed through the independent raw pipeline
    it stays near the issue's 0.05 (benchmark: all 24 cameras)."""
    import rawsim
    from illumon.sensitivity.evaluate import camera_manufacturer

    cams, _, _, refl, _ = data
    day = rawsim.daylight_pool("score")[[100, 700]]
    test = ["Canon_50D", "Canon_600D", "Pentax_K-5", "Hasselblad_H2"]
    res = leave_one_out(METHODS["default"], cams, day, refl, test_cameras=test, seed=3, name="default",
                        group=camera_manufacturer, chart_renderer=rawsim.render_chart)
    assert res.overall <= 0.055, res.rmse


def test_methods_are_named_after_their_paper_and_old_names_still_work(tmp_path):
    """``kinoshita2023`` and ``huynh2014`` are the names; ``bayes`` and the misdated ``huynh2016`` still select them."""
    from illumon.cli import main
    from illumon.sensitivity import ALIASES, METHODS, sensitivities_Huynh2014, sensitivities_Kinoshita2023

    assert METHODS["kinoshita2023"] is sensitivities_Kinoshita2023 and METHODS["huynh2014"] is sensitivities_Huynh2014
    assert {ALIASES[k] for k in ("bayes", "huynh2016")} <= set(METHODS)
    chart = tmp_path / "chart.csv"
    chart.write_text("patch,r,g,b\n" + "".join(f"{i},{10 + i},{20 + i},{5 + 2 * i}\n" for i in range(1, 25)))
    out = tmp_path / "s.csv"
    assert main(["sensitivity", str(chart), "--out", str(out), "--method", "bayes"]) == 0
    assert out.read_text().count("\n") > 60


@needs_data
def test_default_censors_clipped_chart_values(data):
    """A chart whose brightest patches clip in one channel (the exposure metered on green, blue saturating on the
    white patch: found on raw-pipeline charts of the Point Grey): values near the largest are taken as censored, so
    the estimate stays as good as on the unclipped chart; trusting them ruins it (measured: 0.048 unclipped, 0.046
    clipped and censored, 0.31 clipped and trusted)."""
    from illumon.sensitivity.evaluate import camera_manufacturer, simulate_chart

    cams, _, daylights, refl, _ = data
    cam = "Point_Grey_Grasshopper2_14S5C"
    prior = build_camera_prior([c for n, c in cams.items() if camera_manufacturer(n) != camera_manufacturer(cam)])
    x = simulate_chart(cams[cam], daylights[0], refl, 0.003, np.random.default_rng(4))
    clipped = np.minimum(x, 0.6)  # raw saturation: one level for every channel
    assert (clipped < x).sum() >= 3  # the white patch and its neighbours clip in blue
    est = {k: METHODS["default"](v, refl, camera_prior=prior, **kw).sensitivities
           for k, v, kw in (("clean", x, {}), ("clipped", clipped, {}), ("trusted", clipped, {"near_clip": None}))}
    err = {k: float(np.mean(rmse_per_channel(v, cams[cam]))) for k, v in est.items()}
    assert err["clipped"] < err["clean"] + 0.01, err
    assert err["trusted"] > err["clipped"] + 0.05, err
