"""Light that is not daylight over a whole history (issue 28): a rendered camera's history lit only by lamps is named
``off_locus_illuminant`` with its lamp-lit frames, a daylight one is not; and a dim history of a high bit depth is read
above its own censoring level. Development cameras and seeds only (``benchmarks/unmeasured.py`` renders the
histories: ``none+lamps`` is the real MIMO lamp-lit scenes' case, ``none+rendered`` its daylight twin)."""

import numpy as np
import pytest
from illumon.diagnosis.fit import diagnose
from illumon.diagnosis.noise import DARK_LEVEL, history_dark_level


def _rendered(case: str, seed: int):
    import rawsim
    import unmeasured
    from illumon.simulation import datasets

    cam = rawsim.DEV_CAMERAS[seed % len(rawsim.DEV_CAMERAS)]
    obs, _, _ = unmeasured.render("illumon", cam, case, seed)
    return obs, datasets.load_camera(cam)


def test_a_history_lit_by_lamps_throughout_is_off_locus_with_its_frames(shared_data):
    """Every frame one or two CIE lamps (rawsim.lamp_run), rendered with a daylight preset: the spectral stage judges
    frames against the history's typical frame, which is lamp-lit too, so it found none; the estimator's level
    posterior judges the history as a whole and every frame lamp-lit."""
    obs, css = _rendered("none+lamps", 3001)
    d = diagnose(obs, css, primaries="srgb", reestimate=False)
    lamp = [e for e in d.effects if e["effect"] == "off_locus_illuminant"]
    assert lamp, d.effects
    par = lamp[0]["parameters"]
    assert par["found_by"] == "scene_level" and par["history_non_daylight"] > 0.5
    assert set(par["frames"]) == set(obs.frames)  # every frame is lamp-lit
    assert all(v >= 0.5 for v in par["non_daylight"])
    assert all(v is None for v in par["lamp_share"])  # no daylight frame to learn the reflectances from


def test_a_rendered_daylight_history_is_not_off_locus(shared_data):
    obs, css = _rendered("none+rendered", 3001)
    d = diagnose(obs, css, primaries="srgb", reestimate=False)
    assert "off_locus_illuminant" not in [e["effect"] for e in d.effects], d.effects


@pytest.mark.parametrize("frames", [[0, 1, 2], [10, 11], [27, 28, 29]])
def test_a_short_lamp_lit_history_is_judged_for_its_light(shared_data, frames):
    """Fewer frames than the bilinear effects need (6): rendered output is judged for its light alone — the real MIMO
    scenes have three to six frames, and three were refused."""
    obs, css = _rendered("none+lamps", 3001)
    short = obs.subset(np.array(frames))
    d = diagnose(short, css, primaries="srgb")
    assert d.effect == "off_locus_illuminant" and d.parameters["found_by"] == "scene_level"
    assert d.parameters["frames"] == short.frames
    assert d.illuminant_change_deg > 1.0  # the scene model's whites follow the lamps away from the daylight-only fit
    assert d.residual_base is None and d.residual_extended is None  # no bilinear fit on so few frames
    assert any("judged as a whole" in n for n in d.notes)


@pytest.mark.parametrize("frames", [[0, 1, 2], [10, 11], [27, 28, 29]])
def test_a_short_daylight_history_is_not_off_locus(shared_data, frames):
    obs, css = _rendered("none+rendered", 3001)
    d = diagnose(obs.subset(np.array(frames)), css, primaries="srgb")
    assert d.effect == "none" and d.effects == [] and d.illuminant_change_deg == 0.0
    assert any("need at least 6 frames" in n for n in d.notes)


def test_a_single_lamp_lit_frame_is_named(shared_data):
    """One frame of rendered output lit by lamps is judged for its light, as a short history is: named
    ``off_locus_illuminant`` with that frame, and what modelling it changes measured against the daylight-only joint
    estimate of the frame (given twice, that method's fewest frames)."""
    obs, css = _rendered("none+lamps", 3001)
    d = diagnose(obs.subset(np.arange(1)), css, primaries="srgb")
    assert d.effect == "off_locus_illuminant" and d.parameters["frames"] == obs.frames[:1], d
    assert d.illuminant_change_deg > 1.0, d.illuminant_change_deg


def _raw(case: str, seed: int, sim: str = "rawsim"):
    """``benchmarks/unmeasured.py``'s sensor-RGB histories (``raw+lamps``: lit only by CIE lamps, :func:`rawsim.lamp_run`,
    over pale surfaces; ``pale``: its daylight twin, the same camera, seed and surfaces under Granada daylight; ``none``:
    daylight over measured surfaces), development camera ``seed % 14``, and that camera's sensitivities."""
    import rawsim
    import unmeasured
    from illumon.simulation import datasets

    cam = rawsim.DEV_CAMERAS[seed % len(rawsim.DEV_CAMERAS)]
    obs, _, _ = unmeasured.render(sim, cam, case, seed)
    return obs, datasets.load_camera(cam)


def _clipped_srgb():
    """What outside checkers pass as the sensitivities of a camera nobody measured."""
    from illumon.camera.primaries import srgb_sensitivities

    return np.clip(srgb_sensitivities(), 0.0, None)


def _off_locus(d) -> list[dict]:
    return [e for e in d.effects if e["effect"] == "off_locus_illuminant"]


@pytest.mark.parametrize("given", ["measured", "clipped sRGB"])
@pytest.mark.parametrize(("seed", "sim"), [(3007, "rawsim"), (3011, "illumon")])
def test_a_sensor_rgb_history_lit_by_lamps_throughout_is_off_locus_with_its_frames(shared_data, seed, sim, given):
    """Sensor RGB lit by lamps in every frame (Nikon D80, D3): the spectral stage's typical frame is lamp-lit, so it
    finds no outlier; the estimator's level tests — the sensitivities given as a measured camera's, and a camera
    nobody measured — both place the scene average among the lamps' whites, and every frame is named. With the
    measured sensitivities the diagnosis before named 24 (D80, the measured test alone) and 2 (D3, the spectral
    stage) of the 30 frames; the unmeasured test judges 5 of the 14 development cameras' ``raw+lamps`` histories
    (seeds 3 000–3 013) lamp-lit throughout, the others' lamps lying near the daylight locus through the camera (those
    are named from their frames' verdicts or by the spectral stage)."""
    obs, css = _raw("raw+lamps", seed, sim)
    d = diagnose(obs, css if given == "measured" else _clipped_srgb(), reestimate=False)
    lamp = _off_locus(d)
    assert lamp, d.effects
    par = lamp[0]["parameters"]
    assert par["found_by"] == "scene_level" and 0.55 < par["history_non_daylight"] <= 1.0
    assert set(par["frames"]) == set(obs.frames)
    assert min(par["non_daylight"]) >= 0.5


@pytest.mark.parametrize("given", ["measured", "clipped sRGB"])
@pytest.mark.parametrize(("case", "seed", "sim"), [("pale", 3007, "rawsim"), ("pale", 3011, "illumon"),
                                                   ("none", 3007, "rawsim"), ("pale", 3000, "rawsim")])
def test_a_sensor_rgb_daylight_history_is_not_off_locus(shared_data, case, seed, sim, given):
    """The daylight twins (the same cameras, seeds and pale surfaces under daylight; a scene of measured surfaces): no
    off-locus light. Given the clipped sRGB functions for a raw camera, the measured camera's level test alone called
    the pale ones lamp-lit throughout (every frame, history ``non_daylight`` 1.00: the stand-in's daylight whites are
    not the camera's); the unmeasured camera's test says 0.00."""
    obs, css = _raw(case, seed, sim)
    d = diagnose(obs, css if given == "measured" else _clipped_srgb(), reestimate=False)
    assert not _off_locus(d), d.effects


def test_a_measured_camera_outside_the_prior_keeps_its_own_daylight(shared_data):
    """The Point Grey machine-vision camera's daylight white lies outside the measured cameras' spread: on daylight
    over pale surfaces the unmeasured camera's level test reads lamps (0.93), its own measured test daylight (0.00).
    Both must say lamps; this history is clean. Lit by lamps throughout (same seed), both say so and every frame is
    named."""
    obs, css = _raw("pale", 3009)
    assert not _off_locus(diagnose(obs, css, reestimate=False))
    lit, css = _raw("raw+lamps", 3009)
    lamp = _off_locus(diagnose(lit, css, reestimate=False))
    assert lamp and lamp[0]["parameters"]["found_by"] == "scene_level"
    assert set(lamp[0]["parameters"]["frames"]) == set(lit.frames)


@pytest.mark.parametrize("frames", [[0, 1, 2], [10, 11], [25, 26, 27, 28, 29]])
def test_a_short_sensor_rgb_history_is_judged_for_its_light(shared_data, frames):
    """Sensor RGB of 2–5 frames (the real MIMO scene ``spdif`` has 3, the sony-dolp indoor sets 3): judged for its
    light alone, as rendered output is — lamp-lit windows named with all their frames, daylight windows clean."""
    obs, css = _raw("raw+lamps", 3007)
    short = obs.subset(np.array(frames))
    d = diagnose(short, _clipped_srgb())
    assert d.effect == "off_locus_illuminant" and d.parameters["found_by"] == "scene_level"
    assert d.parameters["frames"] == short.frames
    assert d.residual_base is None and any("judged as a whole" in n for n in d.notes)
    day, css = _raw("pale", 3007)
    for given in (css, _clipped_srgb()):
        d = diagnose(day.subset(np.array(frames)), given)
        assert d.effect == "none" and d.effects == [], d.effects


@pytest.mark.parametrize(
    "brightest, white, expected",
    [
        (0.8, 255, DARK_LEVEL),  # an ordinary history: 3 % of white
        (0.02, 255, DARK_LEVEL),  # 8-bit near black: still 3 % of white (7.65 codes), refused by the CLI
        (0.8, 65535, DARK_LEVEL),
        (0.037, 65535, DARK_LEVEL * 0.037 / 0.2),  # MIMO bmug: 16-bit regions at ~2 400 codes
        (1e-4, 65535, DARK_LEVEL * 255 / 65535),  # a few codes of 16-bit: the floor
    ],
)
def test_history_dark_level(brightest, white, expected):
    v = np.linspace(0.1, 1.0, 500) * brightest
    assert history_dark_level(v, white) == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize(("camera", "seed"), [("Nikon_D3X", 10_501), ("Nikon_D7000_ssf", 10_505)])
def test_lamps_lighting_most_frames_are_named_from_the_frames_verdicts(camera, seed):
    """Sensor RGB, measured sensitivities, 24 of 36 frames mixed 35–80 % with a lamp (the outside check's case,
    ``hide_effect(…, lamp_frames="majority")``; test cameras and seeds): the spectral stage's typical frame is
    lamp-lit and finds no outlier (1 of 10 development histories named), the scene model's ``non_daylight`` judges
    each frame against daylight and lamp whites — the effect is named with frames that are lamp-lit
    (``found_by: frames``, or ``scene_level`` where the scene average places the whole history among the lamps'
    whites through the camera, :mod:`illumon.model.level`: both these high-pressure-lamp histories); the same
    camera and seed without a lamp is ``none``."""
    from illumon.simulation import datasets
    from illumon.simulation.effects import hide_effect

    css = datasets.load_camera(camera)
    h = hide_effect("off_locus_illuminant", camera, seed, frames=36, lamp_frames="majority")
    d = diagnose(h.observations, css, reestimate=False)
    lamp = [e for e in d.effects if e["effect"] == "off_locus_illuminant"]
    assert lamp, d.effects
    par = lamp[0]["parameters"]
    assert par["found_by"] in ("frames", "scene_level")
    listed = set(par["frame_indices"])
    assert len(listed) >= 4 and listed <= set(h.parameters["frames"]), (sorted(listed), h.parameters["frames"])
    assert all(v >= 0.5 for v in par["non_daylight"])
    clean = hide_effect("none", camera, seed, frames=36)
    assert diagnose(clean.observations, css, reestimate=False).effects == []


def _rendered_as_sensor_rgb(case: str, seed: int, sim: str, camera: str):
    """``benchmarks/unmeasured.py``'s rendered history (a raw converter's white balance and colour matrix) on a
    development camera, to be read as sensor RGB: what the real MIMO scenes are (16-bit linear output of a raw
    converter, run with the default ``--primaries camera``)."""
    import unmeasured

    return unmeasured.render(sim, camera, case, seed)[0]


@pytest.mark.parametrize(("case", "seed", "sim", "camera", "given_frames"), [
    ("none+rendered", 1, "illumon", "Nikon_D200", 12),
    ("none+rendered", 2, "rawsim", "Nikon_Z6_ssf", 0),
    ("none+awb", 2, "illumon", "Nikon_D200", 0),
])
def test_rendered_daylight_read_as_sensor_rgb_is_not_off_locus(shared_data, case, seed, sim, camera, given_frames):
    """Daylight through a raw converter, read as sensor RGB with the clipped sRGB functions given: the measured
    camera's test judges a day's sky changes lamps frame by frame (those functions' daylight locus is compressed:
    log r/g moves 0.20 between 11 000 and 5 600 K, 0.34 through the unclipped functions), and main named off-locus
    light from those frames (``found_by: frames``, 12, 28 and 30 of 30; in the last two the unmeasured test's
    history probability 0.52–0.55 lent every frame its value). A frame is lamp-lit only when both tests judge it so
    on its own: none is named. Since the measured test's scene-average offset is expected where measured surfaces
    average (:func:`illumon.model.lamps.expected_scene_offset`) it judges ``given_frames`` lamp-lit: 12, 0, 0."""
    from illumon.diagnosis.fit import _lamp_lit_history, _level_verdict
    from illumon.model.lamps import frame_verdicts

    obs = _rendered_as_sensor_rgb(case, seed, sim, camera)
    css = _clipped_srgb()
    given = _level_verdict(obs, css, "camera")
    unmeasured = _level_verdict(obs, None, "camera")
    assert given[1] < 0.5  # neither test calls the history lamp-lit throughout with the other
    assert int(np.sum(given[2] >= 0.5)) == pytest.approx(given_frames, abs=1)  # the failure: its frames alone
    assert int(np.sum(frame_verdicts(unmeasured[0], obs) >= 0.5)) <= 2
    assert _lamp_lit_history(obs, css, [], "camera") is None


def test_frame_verdicts_are_each_frames_own(shared_data):
    """A camera nobody measured, a history its level test calls lamp-lit as a whole by a hair (rendered daylight read
    as sensor RGB, 0.52): the estimator lends every frame that probability; judged on its own against the history's
    offset no frame is lamp-lit. For a history judged daylight the two are the same."""
    from illumon.model import fit_scene_model
    from illumon.model.lamps import frame_verdicts

    obs = _rendered_as_sensor_rgb("none+awb", 2, "illumon", "Nikon_D200")
    model = fit_scene_model(obs, None, primaries="camera")
    assert 0.5 < model.noise["unbalanced"] < 0.6
    assert np.min(model.history_estimate[1]["non_daylight"]) >= model.noise["unbalanced"]
    assert np.max(frame_verdicts(model, obs)) < 0.5
    day = _rendered_as_sensor_rgb("none+awb", 1, "illumon", "Nikon_D200")
    model = fit_scene_model(day, None, primaries="camera")
    assert model.noise.get("unbalanced", 0.0) < 0.5
    np.testing.assert_allclose(frame_verdicts(model, day), model.history_estimate[1]["non_daylight"], atol=1e-12)


def test_rendered_lamps_read_as_sensor_rgb_are_off_locus_with_every_frame(shared_data):
    """The lamp-lit twin (every frame CIE lamps, the MIMO scenes' case as an outside check runs it): both tests call
    the history lamp-lit (0.85 and 1.00), every frame named."""
    from illumon.diagnosis.fit import _lamp_lit_history

    obs = _rendered_as_sensor_rgb("none+lamps", 0, "illumon", "Nikon_D200")
    lamp = _lamp_lit_history(obs, _clipped_srgb(), [], "camera")
    assert lamp is not None and lamp.parameters["found_by"] == "scene_level"
    assert lamp.parameters["frames"] == obs.frames and min(lamp.parameters["non_daylight"]) >= 0.5


def test_a_day_of_sun_and_blue_sky_is_not_lamp_lit(shared_data):
    """Development clean ``imgsim`` history 3049 (``benchmarks/diagnose.py --split dev --sims imgsim --effects
    none``): measured Granada daylight, direct sun (5 400–5 900 K) and blue sky (7 800–25 000 K), over a yellow scene
    rendered through a colour matrix (its average 0.25 / −0.86 log r/g, b/g from the light's white). The measured
    camera's per-frame lamp test judged its sun frames lamp-lit (17 of 26 frames ≥ 0.5, up to 0.76) and the diagnosis
    named ``off_locus_illuminant`` (found by frames): the test's scene-average offset expected grey, so the offset
    was drawn towards blue and every frame read warmer than its light — direct sun among the warm lamps. Expected
    where measured surfaces average (:func:`illumon.model.lamps.expected_scene_offset`): none, at most 0.39."""
    imgsim = pytest.importorskip("imgsim")
    rawsim = pytest.importorskip("rawsim")
    from illumon.diagnosis.fit import _level_verdict
    from illumon.model.lamps import frame_verdicts

    seed = 3049
    cam = rawsim.DEV_CAMERAS[(seed - 3000) % len(rawsim.DEV_CAMERAS)]
    h = imgsim.hide_effect_img("none", cam, seed, split="dev")
    obs, css = h.observations, h.sensitivities
    model, _, _ = _level_verdict(obs, css, "camera")
    nd = frame_verdicts(model, obs)
    assert np.max(nd) < 0.45, nd
    d = diagnose(obs, css, reestimate=False)
    assert "off_locus_illuminant" not in [e["effect"] for e in d.effects], d.effects
