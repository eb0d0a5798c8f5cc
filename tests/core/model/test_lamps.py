"""Light that is not daylight (issue 28): ``non_daylight`` per frame, lamp-lit frames' whites, ESTIMATES.csv column.

Histories: :func:`illumon.simulation.effects.hide_effect` (``off_locus_illuminant``: 3…F/5 frames lit 60–100 % by a CIE
fluorescent, high-pressure or LED lamp far from daylight) on the test cameras with seeds 10 000…, and clean measured
daylight histories; nothing in :mod:`illumon.model.lamps` was chosen on them.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from illumon.camera import angular_error_deg
from illumon.model import SceneModel, fit_scene_model
from illumon.model.lamps import lamp_posterior, non_daylight_column
from illumon.retrieval import retrieve_illuminants
from illumon.simulation import measured_daylight_history
from illumon.simulation.effects import hide_effect


def _fit(obs, css):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_scene_model(obs, css)


@pytest.mark.parametrize(("camera", "seed"), [("Canon_300D", 10001), ("Nikon_D3X", 10006)])
def test_lamp_lit_frames_are_flagged_and_their_white_follows_the_lamp(shared_data, camera, seed):
    from illumon.simulation import datasets

    css = datasets.load_camera(camera)
    h = hide_effect("off_locus_illuminant", camera, seed)
    obs, truth = h.observations, h.history.true_white
    lamp = np.array(h.parameters["frames"])
    day = np.setdiff1d(np.arange(len(obs.frames)), lamp)
    model = _fit(obs, css)
    res, extra = model.history_estimate
    nd = extra["non_daylight"]
    assert np.mean(nd[lamp] >= 0.5) >= 0.8, nd[lamp]
    assert np.all(nd[day] < 0.5), nd[day]
    err = angular_error_deg(res.white, truth)
    daylight_only = angular_error_deg(retrieve_illuminants(obs, css, start_offsets=(0.0,), polish_max_frames=0).white,
                                      truth)
    grey_world = angular_error_deg(np.nanmean(obs.values, axis=1), truth)
    # the lamp-lit frames: better than forcing them onto the daylight locus, and far better than gray-world
    assert np.median(err[lamp]) < np.median(daylight_only[lamp]), (err[lamp], daylight_only[lamp])
    assert np.median(err[lamp]) < 0.5 * np.median(grey_world[lamp]), (err[lamp], grey_world[lamp])
    # the daylight frames gain too: the lamp-lit frames are left out of the reflectance fit
    assert np.median(err[day]) < min(1.0, np.median(daylight_only[day]))
    # a saved model judges new frames the same way
    again, cols = SceneModel.from_dict(model.to_dict()).estimate(obs)
    np.testing.assert_allclose(cols["non_daylight"], nd, atol=0.05)


@pytest.mark.parametrize(("camera", "seed"), [("Canon_50D", 10003), ("Hasselblad_H2", 10004)])
def test_measured_daylight_is_not_flagged(shared_data, camera, seed):
    from illumon.simulation import datasets

    css = datasets.load_camera(camera)
    h = measured_daylight_history(camera, frames=30, patches=10, seed=seed)
    _, extra = _fit(h.observations, css).history_estimate
    assert np.max(extra["non_daylight"]) < 0.5
    assert np.all(non_daylight_column(h.observations, css) < 0.5)


def test_posterior_separates_a_sodium_lamp_from_daylight(shared_data):
    """The test itself, on whites: a grey scene under D65 and under a high-pressure sodium lamp (CIE HP1)."""
    import colour
    from illumon.simulation import datasets
    from illumon.spectra import GRID, resample_columns

    css = datasets.load_camera("Canon_300D")
    d65 = resample_columns(colour.SDS_ILLUMINANTS["D65"].wavelengths,
                           colour.SDS_ILLUMINANTS["D65"].values[:, None], GRID)[:, 0]
    hp = resample_columns(colour.SDS_ILLUMINANTS["HP1"].wavelengths,
                          colour.SDS_ILLUMINANTS["HP1"].values[:, None], GRID)[:, 0]
    means = np.array([d65 @ css, (d65 * 0.9) @ css, hp @ css]) * 0.18
    lp = lamp_posterior(means, css)
    assert lp.non_daylight[2] > 0.9 and np.all(lp.non_daylight[:2] < 0.5)
    # its general white is the lamp's, to within a degree (the daylight frames pin the scene's average)
    assert angular_error_deg(lp.white[2:], (hp @ css)[None])[0] < 1.0


def test_an_unmeasured_camera_reports_lamps_but_keeps_its_daylight_whites(shared_data):
    """A camera nobody measured: its daylight whites are the prior's, so lamp verdicts are reported, not acted on
    (on a held-out rendered camera a third of a pure-daylight history was once sent 33–36° off). The same lamp-lit
    history as above, fitted without sensitivities: the estimate equals the model's with the lamp test switched off,
    and frames are still judged."""
    h = hide_effect("off_locus_illuminant", "Canon_300D", 10001)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = fit_scene_model(h.observations, None)
    assert model.camera["calibration"] == "none" and model.lamps
    res, extra = model.history_estimate
    assert np.all(np.isfinite(extra["non_daylight"]))
    plain = SceneModel.from_dict(model.to_dict())
    plain.lamps = None
    np.testing.assert_allclose(res.white, plain.estimate(h.observations)[0].white, atol=1e-9)
