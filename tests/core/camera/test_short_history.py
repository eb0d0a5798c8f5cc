"""A short history's stated spreads (``calibration.SHORT_HISTORY_WHITE_SPREAD``, ``SHORT_HISTORY_MIRED_SD``): a
camera nobody measured, fitted on a few frames, states about the frequency of its frames within 1°, and its CCT
intervals hold the light's temperature."""

from __future__ import annotations

import types

import numpy as np
import pytest
from illumon.camera import calibration
from illumon.camera.calibration import (
    HISTORY_LENGTHS,
    SHORT_HISTORY_WHITE_SPREAD,
    SINGLE_FRAME_WHITE_SPREAD,
    STATED_WHITE_SPREAD,
    _record_camera_uncertainty,
    history_length_regime,
)


def test_history_length_regime_is_the_nearest_length_chosen_on() -> None:
    got = {f: history_length_regime(f) for f in (None, 0, 1, 2, 3, 4, 5, 6, 13, 14, 30, 100_000)}
    assert got == {None: 30, 0: 30, 1: 1, 2: 3, 3: 3, 4: 3, 5: 6, 6: 6, 13: 6, 14: 30, 30: 30, 100_000: 30}
    assert HISTORY_LENGTHS == (1, 3, 6, 30)
    # every regime a long history states has its short-history counterpart
    assert all(set(table) == set(STATED_WHITE_SPREAD) for table in SHORT_HISTORY_WHITE_SPREAD.values())


@pytest.mark.parametrize(("frames", "primaries", "kind", "expected"), [
    (30, "camera", "grey", STATED_WHITE_SPREAD[("camera", "grey")]),
    (5000, "srgb", "none", STATED_WHITE_SPREAD[("srgb", "none")]),
    (1, "camera", "none", SINGLE_FRAME_WHITE_SPREAD[("camera", "none")]),
    (1, "camera", "grey", STATED_WHITE_SPREAD[("camera", "grey")]),  # a single reference frame states its own
    (3, "camera", "grey", SHORT_HISTORY_WHITE_SPREAD[3][("camera", "grey")]),
    (10, "srgb", "chart", SHORT_HISTORY_WHITE_SPREAD[6][("srgb", "chart")]),
])
def test_the_stated_spread_follows_the_history_length(frames, primaries, kind, expected) -> None:
    model = types.SimpleNamespace(camera={}, noise={}, training={"frames": frames})
    _record_camera_uncertainty(model, kind, primaries, measured=False)
    me = model.noise["model_error"]
    assert me["laplace_scale"] == expected[0] and me["camera_log_gain"] == expected[1]
    measured = types.SimpleNamespace(camera={}, noise={}, training={"frames": frames})
    _record_camera_uncertainty(measured, kind, primaries, measured=True)  # a measured camera: its own spreads
    assert measured.noise["model_error"]["laplace_scale"] == 1.0


def _two_frame_histories(case: str, regime: int | None = None):
    """``benchmarks/unmeasured.py --frames 2`` (a length the regimes were not chosen on), ``rawsim``, the development
    cameras, first seed: (stated confidence, within 1°, CCT interval held) per frame. ``regime``: the history length
    whose spreads are stated instead of the one ``history_length_regime`` picks."""
    import unmeasured

    conf, within, held = [], [], []
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(unmeasured, "FRAMES", 2)
        if regime is not None:
            mp.setattr(calibration, "history_length_regime", lambda frames: regime)
        for i, cam in enumerate(unmeasured.rawsim.DEV_CAMERAS):
            row = unmeasured.run_case("rawsim", cam, case, 7000 + 100 * i)
            conf += row["confidence"]
            within += [e < 1.0 for e in row["err"]]
            held += row["cct_in_95"]
    return np.array(conf), np.array(within), np.array(held)


def test_two_frames_state_their_frequency(shared_data) -> None:
    """Measured (2026-11-27): a grey card on sensor RGB states 0.80 where 93 % of the frames are within 1° (the
    30-frame regime: 0.72), and its CCT intervals hold 86 % of the lights' temperatures (71 %); a chart through a
    colour matrix states 0.86 where 86 % are (0.64), its intervals holding 93 % (89 %)."""
    for case, tol in (("grey", 0.15), ("chart+matrix", 0.1)):
        conf, within, held = _two_frame_histories(case)
        before, _, held_before = _two_frame_histories(case, regime=30)
        gap, gap_before = abs(conf.mean() - within.mean()), abs(before.mean() - within.mean())
        assert gap < tol and gap + 0.05 < gap_before, (case, conf.mean(), before.mean(), within.mean())
        assert held.mean() >= 0.85, (case, held.mean())
        if case == "grey":
            assert held_before.mean() < 0.8, held_before.mean()  # the test can fail: it did before


def test_a_grey_cards_single_frame_holds_its_lights_temperature(shared_data) -> None:
    """One frame with a grey card on sensor RGB (``rawsim``, development cameras, first seed): the card's white is
    the camera's and the light's at once, so the light's temperature is read ~60 MK⁻¹ RMS off; with
    ``SINGLE_FRAME_MIRED_SD[("camera", "grey")]`` its 95 % intervals hold 13 of 14 (measured 2026-11-27; 10 of 14
    without it)."""
    import unmeasured

    def held(extra_sd: float | None) -> float:
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(unmeasured, "FRAMES", 1)
            if extra_sd is not None:
                mp.setitem(calibration.SINGLE_FRAME_MIRED_SD, ("camera", "grey"), extra_sd)
            return float(np.mean([unmeasured.run_case("rawsim", cam, "grey", 7000 + 100 * i)["cct_in_95"][0]
                                  for i, cam in enumerate(unmeasured.rawsim.DEV_CAMERAS)]))

    assert held(None) >= 0.85
    assert held(0.0) < 0.8  # the test can fail: without the spread the intervals missed


def test_camera_mired_key_names_how_a_chart_was_read() -> None:
    def model(noise: dict, camera: dict) -> types.SimpleNamespace:
        return types.SimpleNamespace(noise=noise, camera=camera)

    assert calibration.camera_mired_key(model({}, {}), "grey") == "grey"
    assert calibration.camera_mired_key(model({}, {}), "chart", measured=True) == "measured"
    assert calibration.camera_mired_key(model({}, {}), "chart") == "chart"  # its reading refused
    assert calibration.camera_mired_key(model({"chart_level": 1}, {}), "chart") == "chart read"
    read_as = model({"chart_level": 1}, {"chart_read_as": "srgb"})
    assert calibration.camera_mired_key(read_as, "chart") == "chart read as srgb"
    assert all(key in calibration.CAMERA_MIRED_SD for table in calibration.SHORT_HISTORY_MIRED_SD.values()
               for _, key in table)
