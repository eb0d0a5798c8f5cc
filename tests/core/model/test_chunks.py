"""A refit's estimates in bounded pieces (issue 29): the scene model's estimate of a history a chunk at a time equals
the estimate of every frame at once, and a lamp round's refit that estimates the whole history once gives the rows,
training summary and identifiability of a fit of its daylight frames alone.

History: :func:`illumon.simulation.effects.hide_effect` (``off_locus_illuminant``, seed 10 001 as in
``test_lamps.py``), so the model carries lamp verdicts and :func:`illumon.model.lamps.apply_lamps` runs.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from illumon.model import fit_scene_model, lamps, scene
from illumon.model.fit import _fit_fixed_camera
from illumon.observations import Observations
from illumon.simulation.effects import hide_effect


@pytest.fixture(scope="module")
def lamp_history(shared_data):
    from illumon.simulation import datasets

    css = datasets.load_camera("Canon_300D")
    obs = hide_effect("off_locus_illuminant", "Canon_300D", 10001).observations
    # measured standard errors too, so the chunks' extra variance is exercised
    obs = Observations(obs.frames, obs.patches, obs.values, obs.times, 0.002 * np.abs(obs.values))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = fit_scene_model(obs, css)
    return obs, css, model


def _arrays(res, cols) -> dict:
    out = {k: getattr(res, k) for k in ("spectra", "xy", "cct", "duv", "white", "gains", "exposures")}
    out.update({f"info_{k}": res.info[k] for k in scene._FRAME_INFO})
    out.update({f"col_{k}": v for k, v in cols.items()})
    return out


def test_chunked_estimate_equals_one_piece(lamp_history, monkeypatch):
    obs, _, model = lamp_history
    assert model.lamps, "the history's model judges lamps"
    whole_res, whole_cols = model.estimate(obs)
    monkeypatch.setattr(scene, "ESTIMATE_CHUNK", 7)
    monkeypatch.setattr(lamps, "_MEANS_CHUNK", 5)
    res, cols = model.estimate(obs)
    assert len(obs.frames) > 3 * 7
    assert res.frames == whole_res.frames and res.times == whole_res.times
    assert set(cols) == set(whole_cols) and "non_daylight" in cols
    a, b = _arrays(res, cols), _arrays(whole_res, whole_cols)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    np.testing.assert_array_equal(res.reflectances, whole_res.reflectances)


def test_a_refit_estimating_every_frame_equals_the_fit_of_its_frames(lamp_history):
    obs, css, _ = lamp_history
    rows = np.arange(0, len(obs.frames), 3)
    part = obs.subset(rows)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        alone, _ = _fit_fixed_camera(part, css)
        every, theta = _fit_fixed_camera(part, css, estimate=obs, rows=rows)
    assert theta.shape == (len(obs.frames), 3)
    assert every.training.pop("fit_seconds") >= 0 and alone.training.pop("fit_seconds") >= 0
    assert every.training == alone.training and every.identifiability == alone.identifiability
    np.testing.assert_array_equal(every.coefficients, alone.coefficients)
    res, cols = every.history_estimate
    assert res.frames == obs.frames
    a = _arrays(*alone.history_estimate)
    b = {k: v[rows] for k, v in _arrays(res, cols).items()}
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
