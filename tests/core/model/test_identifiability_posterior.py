"""The identifiability warning asks the model as fitted (priors, and each frame's offset where the model has one)
how well the data fix the frames' reciprocal temperatures relative to each other: a six-patch history with varied
daylight is determined, with and without the glare offset, while the same history whose stated noise swamps its
illuminant changes is not (and its estimates are then indeed worse)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from illumon.camera import angular_error_deg, formation
from illumon.model import IdentifiabilityWarning, fit_scene_model
from illumon.priors import colourchecker_reflectances
from illumon.simulation import datasets, simulate_history


def _history():
    _, granada = datasets.load_granada_daylight()
    css = datasets.load_camera("Nikon_D5100")
    _, refl = colourchecker_reflectances()
    ill = granada[np.random.default_rng(0).choice(len(granada), 17)]
    return simulate_history(css, ill, refl[18:24], rng=2), css


@pytest.mark.parametrize("flare_sd", [0.0, 0.05])
def test_six_varied_patches_determine_their_illuminants(monkeypatch, flare_sd):
    monkeypatch.setattr(formation, "FLARE_SD", flare_sd)
    hist, css = _history()
    with warnings.catch_warnings():
        warnings.simplefilter("error", IdentifiabilityWarning)
        model = fit_scene_model(hist.observations, css)
    ident = model.identifiability
    assert ident["determined"] and ident["warnings"] == []
    # the data narrow the frames' relative temperatures to a few MK⁻¹ (prior: ±45)
    assert 1.0 < ident["relative_mired_sd"] < 6.0, ident
    res, _ = model.estimate(hist.observations)
    assert np.median(angular_error_deg(res.white, hist.true_white)) < 0.8


def test_noise_that_swamps_the_changes_is_reported(monkeypatch):
    monkeypatch.setattr(formation, "FLARE_SD", 0.05)
    hist, css = _history()
    with pytest.warns(IdentifiabilityWarning, match="ill-conditioned"):
        model = fit_scene_model(hist.observations, css, relative_error=1.0)
    ident = model.identifiability
    assert not ident["determined"] and ident["relative_mired_sd"] > 22.5, ident
    res, _ = model.estimate(hist.observations)
    assert np.median(angular_error_deg(res.white, hist.true_white)) > 1.0
