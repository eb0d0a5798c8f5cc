"""Each history learns its own glare spread (``SceneModel.noise["flare_sd"]``, prior ``FLARE_SD``): a long history
with no glare brings it well below the prior's (so the offset costs it little), the same history with veiling glare
of the size the development photographs showed raises it above, and three frames keep about the prior's."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from illumon.camera import angular_error_deg, formation
from illumon.model import fit_scene_model
from illumon.observations import Observations
from illumon.priors import colourchecker_reflectances
from illumon.simulation import datasets, simulate_history


@pytest.fixture(scope="module")
def history():
    _, granada = datasets.load_granada_daylight()
    css = datasets.load_camera("Nikon_D5100")
    _, refl = colourchecker_reflectances()
    rng = np.random.default_rng(4)
    hist = simulate_history(css, granada[rng.choice(len(granada), 30)], refl[:12], rng=3)
    return hist, css, rng


def _with_glare(obs: Observations, rng: np.random.Generator) -> Observations:
    """Each frame gains a fraction of its mean patch value in every patch (half-normal, RMS 0.12, as measured)."""
    v = np.asarray(obs.values, dtype=float)
    frac = np.abs(rng.normal(0.0, 0.12, v.shape[0]))
    return Observations(obs.frames, obs.patches, v + frac[:, None, None] * np.nanmean(v, axis=1, keepdims=True),
                        obs.times)


def _fit(obs, css):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_scene_model(obs, css)


def test_a_history_learns_its_glare_spread(history):
    hist, css, rng = history
    prior = formation.FLARE_SD
    clean = _fit(hist.observations, css)
    glared = _fit(_with_glare(hist.observations, rng), css)
    short = _fit(hist.observations.subset(slice(0, 3)), css)
    assert clean.noise["flare_sd"] < 0.6 * prior, clean.noise["flare_sd"]
    assert glared.noise["flare_sd"] > max(1.1 * prior, 2 * clean.noise["flare_sd"]), glared.noise["flare_sd"]
    assert abs(short.noise["flare_sd"] / prior - 1) < 0.2, short.noise["flare_sd"]
    # and the glare does not move the camera white far: the offsets take it
    err = angular_error_deg(glared.history_estimate[0].white, hist.true_white)
    assert np.median(err) < 1.0, err
