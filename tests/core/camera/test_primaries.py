"""The output space as part of the camera (issue 26): sRGB primaries, references of any subset, real photographs."""

import warnings

import colour
import numpy as np
import pytest
import rawsim
from illumon.camera import angular_error_deg, colourchecker_references
from illumon.camera.primaries import srgb_sensitivities, to_srgb_primaries
from illumon.camera.references import neutral_references, references_kind
from illumon.model import fit_scene_model
from illumon.observations import Observations
from illumon.retrieval.common import grey_world
from illumon.simulation import datasets
from illumon.spectra import GRID


def test_srgb_sensitivities_are_the_srgb_of_colour_science():
    """Independent truth: colour-science's own spectral → XYZ → linear sRGB of ColorChecker patches under D65."""
    c = srgb_sensitivities()
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(GRID)
    e = np.asarray(d65.values)
    white = e @ c
    assert np.allclose(white / white[1], 1.0, atol=1e-9)  # the daylight preset: D65 is grey
    assert c[:, 0].min() < -0.05  # the red negative lobe is kept
    refs = colourchecker_references()
    for pid in ("chart:01", "chart:07", "chart:13", "chart:15"):
        sd = colour.SpectralDistribution(dict(zip(GRID.wavelengths, refs[pid], strict=True)))
        xyz = colour.sd_to_XYZ(sd, illuminant=d65, shape=GRID) / 100
        lin = colour.XYZ_to_RGB(xyz, colour.models.RGB_COLOURSPACE_sRGB, apply_cctf_encoding=False)
        ours = (refs[pid] * e) @ c / white
        assert angular_error_deg(ours, lin) < 0.5, pid


def test_references_of_any_subset():
    refs = colourchecker_references()
    greys = {k: refs[k] for k in [f"chart:{i}" for i in range(19, 25)]}
    assert references_kind(greys) == "grey"  # the six greys pin channel scales, not a 3 × 3 ("Singular matrix")
    assert references_kind(refs) == "chart"
    assert references_kind({**greys, "chart:15": refs["chart:15"]}) == "grey"  # one colour: still one direction
    assert neutral_references(refs) == list(greys)


def _rendered_history(camera: str, seed: int, known: dict | None = None):
    """30 frames × 10 development surfaces under a development daylight run, seen by a *rendered* camera: its
    measured sensitivities through a daylight-preset white balance and a colour matrix to sRGB (negative values clip
    at 0, as in a real pipeline)."""
    rng = np.random.default_rng(seed)
    css = to_srgb_primaries(datasets.load_camera(camera))
    e = rawsim.daylight_run("dev", 30, rng)
    scene = rawsim.draw_reflectances("dev", 10, rng)
    refl = np.concatenate([scene, np.stack(list(known.values()))]) if known else scene
    h = rawsim.simulate_raw_history(css, e, refl, rng=rng)
    values = h.linear_output.copy()
    values[1:, 10:] = np.nan
    patches = [f"p{j}" for j in range(10)] + list(known or {})
    return Observations([f"f{i}" for i in range(30)], patches, values, [""] * 30), h.true_white


def _fit(obs, primaries, known=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_scene_model(obs, None, primaries=primaries, known_reflectances=known)


def test_rendered_output_needs_srgb_primaries(shared_data):
    """Without a reference, a rendered camera read as sensor RGB is several degrees worse than doing nothing; with
    ``primaries="srgb"`` it beats doing nothing and gray-world. Measured at commit time (median °): srgb 3.62 / 1.12 /
    2.92 (3.21 / 1.56 / 2.99 before each frame's glare offset, which these glare-free histories do not need), camera
    9.12 / 7.29 / 14.50, nothing 5.37 / 6.96 / 4.95, gray-world 3.76 / 15.39 / 24.02."""
    for camera, seed in (("Nikon_D700", 11), ("Nikon_D80", 5), ("Nikon_D5100", 2)):
        obs, truth = _rendered_history(camera, seed)
        srgb = np.median(angular_error_deg(_fit(obs, "srgb").history_estimate[0].white, truth))
        raw = np.median(angular_error_deg(_fit(obs, "camera").history_estimate[0].white, truth))
        nothing = np.median(angular_error_deg(np.ones(3), truth))
        gw = np.median(angular_error_deg(grey_world(obs), truth))
        assert srgb < 3.75 and srgb < 0.6 * raw and srgb < nothing and srgb < gw, (camera, srgb, raw, nothing, gw)


def test_reference_frame_reproduces_its_own_greys(shared_data):
    """A chart or its greys known in frame 0 of a rendered camera: that frame's white is the greys' own, within 0.5°,
    and the other frames are no worse than without the reference."""
    refs = colourchecker_references()
    for subset in (refs, {k: refs[k] for k in [f"chart:{i}" for i in range(19, 25)]}):
        obs, truth = _rendered_history("Nikon_D80", 5, subset)
        model = _fit(obs, "srgb", subset)
        white = model.history_estimate[0].white
        greys = np.nanmean(obs.values[0, [obs.patches.index(f"chart:{i}") for i in (20, 21, 22)]], axis=0)
        assert angular_error_deg(white[0], greys) < 0.5
        none = _fit(obs.select_patches([f"p{j}" for j in range(10)]), "srgb").history_estimate[0].white
        assert np.median(angular_error_deg(white[1:], truth[1:])) <= np.median(angular_error_deg(none[1:], truth[1:]))


def test_real_photographs_development_set(sony_raw):
    """The real chart photographs of ``../shared/data/real/sony-dolp`` (development data), the outside checks'
    protocol (``python benchmarks/real.py``): no reference beats doing nothing and gray-world on sensor RGB and on
    its automatically white-balanced rendering; a chart or its greys in frame 0 reproduce that frame within 0.5°."""
    import real

    raw = sony_raw
    sets = {s.name: s for s in [raw, *real.isp_sets(raw)]}
    for name in ("sony-raw", "sony-isp-auto"):
        s = sets[name]
        base = {k: np.median(real.angular(w, s.truth)) for k, w in real.baselines(s).items()}
        none = np.median(real.angular(real.run_illumon(s, "none")[0], s.truth))
        assert none < base["nothing"] and none < base["gray-world"], (name, none, base)
        for mode in ("grey", "chart"):
            assert real.angular(real.run_illumon(s, mode)[0], s.truth)[0] < 0.5, (name, mode)


def test_real_photographs_reference_never_hurts(sony_raw):
    """Issue 26's targets on every development set of real photographs: the greys known in one frame are never worse
    than no reference (median), the whole chart no worse than its greys, and no frame is made much worse by a
    reference (a reference in one frame must not throw another frame's light off: max within 3.5° of no reference's;
    measured: the preset set's third frame 7.5° without, 9.9° with the greys and 10.8° with the chart — a weakness
    left open, not a margin to grow — and a lamp-lit judgement on two daylight frames once made it 21°)."""
    import real

    raw = sony_raw
    for s in [raw, *real.isp_sets(raw)]:
        err = {m: real.angular(real.run_illumon(s, m)[0], s.truth) for m in ("none", "grey", "chart")}
        med = {m: float(np.median(e)) for m, e in err.items()}
        assert med["grey"] <= med["none"] and med["chart"] <= med["grey"], (s.name, med)
        for m in ("grey", "chart"):
            assert err[m].max() <= err["none"].max() + 3.5, (s.name, m, err)


def test_glare_reference_spread_is_relative_to_a_mid_grey():
    """:func:`illumon.camera.calibration._glare_reference_tr`: glare along a coloured frame mean moves the white read
    off a black patch most, off a white patch less (the other way), off a mid grey not at all, and no white when the
    frame's mean is neutral."""
    from illumon.camera.calibration import MID_GREY, _glare_reference_tr

    white = np.array([0.8, 1.0, 0.9])
    warm = 0.05 * np.array([1.3, 1.0, 0.6]) * white  # one standard deviation of glare along a warm scene's colour

    def tr(reflectance: float, glare: np.ndarray = warm) -> float:
        return _glare_reference_tr(white, reflectance * white, 1, glare)

    assert tr(MID_GREY) == pytest.approx(0.0, abs=1e-15)
    assert tr(0.031) > 10 * tr(0.9) > 0.0
    assert tr(0.031, 0.05 * white) == pytest.approx(0.0, abs=1e-15)
    # first order: the angle between the whites a black patch and a mid grey read under a small glare offset
    small = 0.02 * warm
    exact = angular_error_deg(0.031 * white + small, MID_GREY * white + small)
    assert np.degrees(np.sqrt(tr(0.031, small))) == pytest.approx(exact, rel=0.05)


def test_dark_reference_states_its_glare(sony_raw):
    """A reference frame read off the chart's black patch alone is 1–3° off its own mid greys on the development
    photographs (the scene's glare at the black's level) and now says so; one read off its mid greys 20–22 stays
    confident and right (``python benchmarks/real.py --subsets``)."""
    import real

    raw = sony_raw
    for s in [raw, *real.isp_sets(raw)]:
        w, conf, _ = real.run_illumon(s, "black 24")
        assert real.angular(w, s.truth)[0] > 1.0 and conf[0] < 0.5, (s.name, conf[0])
        w, conf, _ = real.run_illumon(s, "greys 20-22")
        assert real.angular(w, s.truth)[0] < 0.5 and conf[0] > 0.85, (s.name, conf[0])


def test_coloured_only_references():
    """:func:`illumon.camera.references.coloured_only`: a few colours with no neutral among them; not with a neutral,
    nor four colours spanning both chromatic directions (a chart's kind)."""
    from illumon.camera.references import coloured_only

    refs = colourchecker_references()
    assert coloured_only({p: refs[p] for p in ("chart:01", "chart:13")})
    assert not coloured_only({p: refs[p] for p in ("chart:01", "chart:21")})  # a neutral among them
    assert not coloured_only({p: refs[p] for p in ("chart:02", "chart:07", "chart:13", "chart:14")})  # a chart's kind


def test_a_few_colours_without_a_neutral_are_set_aside(sony_raw):
    """One or two of the chart's colours known without a neutral pinned a camera nobody measured through how it
    renders colours: on the development photographs the white went 5–27° off, where no reference is 0.5–5°. They are
    now set aside, named in a warning, and the history is estimated as without them; a neutral among them, or a
    camera with measured sensitivities, keeps them."""
    import real

    refs = colourchecker_references()
    raw = sony_raw
    for s in [raw, *real.isp_sets(raw)]:
        none = real.run_illumon(s, "none")[0]
        for mode in ("colour 15", "colours 01,13"):
            ids = real.SUBSETS[mode]
            obs = real._observations(s, ids)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = fit_scene_model(obs, None, primaries=s.primaries,
                                        known_reflectances={p.replace("chart:", "ref:"): refs[p] for p in ids})
            np.testing.assert_allclose(model.history_estimate[0].white, none, rtol=1e-9, err_msg=f"{s.name} {mode}")
            said = [w for w in model.identifiability["warnings"] if "set aside" in w]
            assert said and all(p.replace("chart:", "ref:") in said[0] for p in ids), model.identifiability["warnings"]
            assert model.camera["calibration"] == "none"


def test_real_photographs_through_the_command_line(sony_raw, tmp_path):
    """The outside checks drive the product through its command line, not the library: each development set of real
    photographs written as they do (``benchmarks/real.py --dump``: the 18 colour patches, linear 0…1, references in
    frame 0 with their KNOWN.csv) and run as ``illumon estimate OBS [--known-reflectances KNOWN] --white-level 1
    --primaries P``. Every run ends without an error and writes the library's own whites and confidence (to the CSV's
    six digits), so the issue-26 figures ``benchmarks/real.py`` prints are what such a check gets."""
    import csv

    import real
    from illumon.cli import main

    raw = sony_raw
    sets = [raw, *real.isp_sets(raw)]
    real.dump_sets(sets, tmp_path)
    for s in sets:
        d = tmp_path / s.name
        for mode in ("none", "grey", "chart"):
            out = d / f"ESTIMATES-{mode}.csv"
            known = [] if mode == "none" else ["--known-reflectances", str(d / f"KNOWN-{mode}.csv")]
            assert main(["estimate", str(d / f"OBSERVATIONS-{mode}.csv"), *known, "--white-level", "1",
                         "--primaries", s.primaries, "--out", str(out)]) == 0, (s.name, mode)
            rows = list(csv.DictReader(out.open()))
            assert [r["frame"] for r in rows] == list(s.frames)
            white = np.array([[float(r[f"white_{c}"]) for c in "rgb"] for r in rows])
            conf = np.array([float(r["confidence"]) for r in rows])
            lib_white, lib_conf, _ = real.run_illumon(s, mode)
            np.testing.assert_allclose(white, lib_white, rtol=1e-5, err_msg=f"{s.name} {mode}")
            np.testing.assert_allclose(conf, lib_conf, atol=1e-5, err_msg=f"{s.name} {mode}")
            if mode != "none":  # the reference frame reproduces its own greys
                assert real.angular(white, s.truth)[0] < 0.5, (s.name, mode)


def test_self_balancing_camera_is_named(shared_data):
    """A day (30 frames over 10 hours) from a camera that rebalances every frame: its light looks steady and the fit
    warns; the same day through a fixed daylight preset does not (``benchmarks/unmeasured.py`` cases). The balanced
    output no longer shows the light's colour, so the warned history's CCT intervals take the daylight prior's spread
    and hold the light's temperature (before: 5 of 30 frames held it, the estimates near D65 whatever the sky);
    the preset history's intervals stay as narrow as without times."""
    import unmeasured

    times = [f"2025-06-01T{7 + i // 3:02d}:{(i % 3) * 20:02d}:00Z" for i in range(30)]
    for case, expect in (("none+awb", True), ("none+rendered", False)):
        obs, _, _ = unmeasured.render("rawsim", "Nikon_D80", case, 5)
        truth = unmeasured.true_ccts(obs, "Nikon_D80", case, 5)
        untimed = _fit(obs, "srgb").history_estimate[1]
        obs = Observations(obs.frames, obs.patches, obs.values, times)
        model = _fit(obs, "srgb")
        said = any("white balance is automatic" in w for w in model.identifiability["warnings"])
        assert said == expect, (case, model.identifiability["warnings"])
        extra = model.history_estimate[1]
        held = np.mean((extra["cct_lo"] <= truth) & (truth <= extra["cct_hi"]))
        width = np.median(1e6 / extra["cct_lo"] - 1e6 / extra["cct_hi"])
        width0 = np.median(1e6 / untimed["cct_lo"] - 1e6 / untimed["cct_hi"])
        if expect:
            assert held >= 0.9 and width > 3 * width0, (held, width, width0)
            assert model.noise["model_error"]["balanced_mired"] == 45.0
        else:
            assert abs(width - width0) < 1e-6 * width0 and "balanced_mired" not in model.noise["model_error"]
    short = Observations(obs.frames, obs.patches, obs.values, times[:9] + [""] * 21)  # under six hours: no verdict
    from illumon.camera.balance import self_balance_warning

    assert self_balance_warning(short.times, np.full(30, 150.0)) is None
    assert self_balance_warning(times, np.full(30, 150.0)) is not None


def test_self_balanced_confidence_says_what_it_is(shared_data):
    """Rendered output with no reference from cameras that rebalance every frame (``benchmarks/unmeasured.py`` case
    ``none+awb``, ``rawsim``, the first six development cameras and their seeds), frames over 24 hours: every history
    is read as self-balanced, and its whites' confidence then carries the camera's own frame-to-frame residual
    (``SELF_BALANCED_WHITE_SD``): 0.114 stated where 11.1 % of frames are within 1°. Without the frames' times nothing
    tells such a camera from a fixed preset, and the same whites state 0.215. The history's estimate and the model's
    later estimates of the same frames state the same."""
    from datetime import datetime, timedelta, timezone

    import unmeasured
    from illumon.model.fit import SELF_BALANCED_WHITE_SD

    t0 = datetime(2026, 6, 1, 6, 0, tzinfo=timezone.utc)
    times = [(t0 + timedelta(hours=24 * i / 29)).isoformat() for i in range(30)]
    stated, untimed, within = [], [], []
    for i, camera in enumerate(rawsim.DEV_CAMERAS[:6]):
        obs, white, _ = unmeasured.render("rawsim", camera, "none+awb", 7_000 + 100 * i)
        untimed += np.asarray(_fit(obs, "srgb").history_estimate[1]["confidence"]).tolist()
        obs = Observations(obs.frames, obs.patches, obs.values, times)
        model = _fit(obs, "srgb")
        assert model.noise["model_error"]["balanced_log_gain"] == SELF_BALANCED_WHITE_SD
        res, extra = model.history_estimate
        later = model.estimate(obs)[1]
        np.testing.assert_allclose(extra["confidence"], later["confidence"], atol=1e-12)
        stated += np.asarray(extra["confidence"]).tolist()
        within += (angular_error_deg(res.white, white) < 1.0).tolist()
    assert abs(np.mean(stated) - np.mean(within)) <= 0.03, (np.mean(stated), np.mean(within))
    assert np.mean(untimed) - np.mean(within) >= 0.07, (np.mean(untimed), np.mean(within))


def test_no_reference_confidence_follows_the_scene_average(shared_data):
    """Sensor RGB of a camera nobody measured, no reference: the scene average sets its channel scales, as precisely
    as the scene reads (:func:`illumon.camera.calibration.scene_calibrated_scale`). Over pale surfaces (walls,
    roads: ``benchmarks/unmeasured.py`` case ``pale``) the whites are mostly within 1° and the confidence says so
    (0.18 stated where 84 % were, before); over measured surfaces (case ``none``) it stays what it was chosen at."""
    import unmeasured
    from illumon.camera.calibration import SCENE_AVERAGE_SD, scene_calibrated_scale

    assert scene_calibrated_scale(SCENE_AVERAGE_SD) == pytest.approx(1.0)
    assert scene_calibrated_scale(1.0) == pytest.approx(1.0)  # no better than the measured surfaces' spread
    assert 0.25 < scene_calibrated_scale(0.038) < 0.35
    stated, within = {}, {}
    for case in ("none", "pale"):
        s, w = [], []
        for camera, seed in (("Nikon_D5100", 7_800), ("Nikon_D80", 8_100)):
            obs, white, _ = unmeasured.render("illumon", camera, case, seed)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = fit_scene_model(obs, None, camera_prior_mean=unmeasured.prior_mean_without(camera))
            res, extra = model.history_estimate
            s += np.asarray(extra["confidence"]).tolist()
            w += (angular_error_deg(res.white, white) < 1.0).tolist()
        stated[case], within[case] = np.mean(s), np.mean(w)
    assert stated["none"] < 0.2 and stated["pale"] > 0.5, stated
    assert within["pale"] > 0.9, within  # these two pale histories: every frame within 1°


def test_rendered_grey_card_holds_the_level(shared_data, monkeypatch: pytest.MonkeyPatch):
    """A grey card on rendered output (``benchmarks/unmeasured.py`` cases): its ``T`` iterations hold the first
    fit's level (:func:`illumon.camera.calibration._held_level`). Chasing it instead, the balance anchor and the card
    moved each other by up to 31 MK⁻¹ an iteration with no fixed point: the ``illumon`` Nikon D300s auto-balanced day
    (``grey+awb``, seed 7 200) ended 117 MK⁻¹ from its first level with ``T``'s diagonal (0.57, 1, 1.93) and the
    whites 5.45° off (median; 0.99° held), the ``rawsim`` Nikon D80 preset day (``grey+rendered``, seed 8 101) 1.81°
    (0.15° held)."""
    import unmeasured
    from illumon.camera import calibration

    cases = (("illumon", "Nikon_D300s", "grey+awb", 7_200), ("rawsim", "Nikon_D80", "grey+rendered", 8_101))

    def run() -> tuple[list[float], list[float]]:
        medians, spread = [], []
        for sim, camera, case, seed in cases:
            obs, white, known = unmeasured.render(sim, camera, case, seed)
            model = _fit(obs, "srgb", known)
            medians.append(float(np.median(angular_error_deg(model.history_estimate[0].white, white))))
            gains = np.diag(np.asarray(model.camera["transform"]))
            spread.append(float(np.max(np.abs(np.log(gains / gains[1])))))
        return medians, spread

    medians, spread = run()
    assert medians[0] < 1.2 and medians[1] < 0.3 and max(spread) < 0.2, (medians, spread)
    monkeypatch.setattr(calibration, "_held_level", lambda *args: None)  # the level left free: the chase
    medians, spread = run()
    assert medians[0] > 4.0 and medians[1] > 1.5 and max(spread) > 0.4, (medians, spread)


def test_chart_then_chart_free_frame(sony_raw, chart_free_pairs):
    """The installer's path on real photographs (``python benchmarks/real_pairs.py``): a chart held up once, then a
    frame without it under the same light. With the chart or its greys known in the chart shot, the chart-free frame's
    white is within 0.6° of the chart's greys on the raw sensor and within 1.2° through the fixed daylight preset
    (measured 0.17–0.53° and 0.43–1.07°), and at most about half a degree further than without a reference (the
    preset's ``scene002``: 0.48° without, 0.94 / 1.07° with — its no-reference reading is near right there), on
    every pair."""
    import real
    import real_pairs

    raw = sony_raw
    m, preset = real.isp_pipeline(raw)
    found = chart_free_pairs
    assert len(found) == 3
    for p in found:
        for camera, bound in (("raw", 0.6), ("preset", 1.2)):
            scene, chart, truth = real_pairs.prepared(p, camera, m, preset)
            err = {mode: real.angular(real_pairs.estimate_free(chart, scene, real_pairs.PRIMARIES[camera], mode)[0],
                                      truth)[0] for mode in ("none", "grey", "chart")}
            assert err["grey"] <= bound and err["chart"] <= bound, (p["scene"], camera, err)
            assert err["grey"] <= err["none"] + 0.5 and err["chart"] <= err["none"] + 0.6, (p["scene"], camera, err)


def test_chart_free_rooms_without_a_reference(sony_raw, chart_free_pairs, monkeypatch: pytest.MonkeyPatch):
    """The real chart-free rooms on the raw sensor, two frames, no reference (``python benchmarks/real_pairs.py``):
    their regions average near grey under a warm light and the fit's level — the reflectance prior's warm mean
    surface — reads the light bluer. The channel scales read from the scene average are read again at each refit's
    light until they hold (:func:`illumon.camera.calibration.calibrate_scene_model`): median 3.55° (5.11, 3.55,
    0.67), where one reading gave 4.48° (6.10, 4.48, 2.07) — the refit's light had relaxed towards the daylight
    prior's once the scales took the scene's colour, leaving them short. Weighed with a measured camera's multi-frame
    spread (0.043) instead of its few-frame one (:data:`illumon.model.fit.FEW_FRAMES_FIT_LEVEL_SD`), 3.74°.
    Gray-world over the same regions is 1.42°: the colourful rooms are still open (a scene-average prior with rooms
    that average grey)."""
    import functools

    import illumon.camera.calibration as calibration
    import illumon.model.fit as fit_module
    import real
    import real_pairs

    m, preset = real.isp_pipeline(sony_raw)

    def errors() -> list[float]:
        errs = []
        for p in chart_free_pairs:
            scene, chart, truth = real_pairs.prepared(p, "raw", m, preset)
            white, _ = real_pairs.estimate_free(chart, scene, "camera", "none")
            errs.append(float(real.angular(white, truth)[0]))
        return errs

    errs = errors()
    now = float(np.median(errs))
    assert now < 3.8 and min(errs) < 1.0, errs  # scene002 under gray-world's 1.44°
    with monkeypatch.context() as mp:
        mp.setattr(fit_module, "calibrate_scene_model",
                   functools.partial(calibration.calibrate_scene_model, max_iterations=1))
        once = float(np.median(errors()))
    assert once > now + 0.7, (once, now)
    monkeypatch.setattr(fit_module, "FEW_FRAMES_FIT_LEVEL_SD", {1: fit_module.FIT_LEVEL_SD, 3: fit_module.FIT_LEVEL_SD})
    before = float(np.median(errors()))
    assert before > now + 0.1, (before, now)
