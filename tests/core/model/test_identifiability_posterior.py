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


def test_information_from_its_blocks_equals_the_dense_product():
    """``_information`` builds ``JᵀJ`` (with each frame's offset columns) from the blocks that are not zero by
    construction: the dense product over every row gives the same matrix, to rounding, with and without offsets."""
    import sys

    import illumon.model  # noqa: F401 - the package's name ``identifiability`` is the function

    ident = sys.modules["illumon.model.identifiability"]
    rng = np.random.default_rng(4)
    f, n_p, nk = 5, 4, 8
    jac = np.zeros((f * n_p * 3, 3 * f + n_p * nk))
    rows = np.arange(jac.shape[0]).reshape(f, n_p, 3)
    for i in range(f):  # a frame's parameters move its rows, a patch's coefficients its rows
        jac[rows[i].ravel()[:, None], 3 * i + np.arange(3)] = rng.normal(size=(n_p * 3, 3))
    for q in range(n_p):
        jac[rows[:, q].ravel()[:, None], 3 * f + q * nk + np.arange(nk)] = rng.normal(size=(f * 3, nk))
    offsets = rng.uniform(0.1, 1.0, (f, n_p, 3))
    cols = np.zeros((jac.shape[0], 3 * f))  # an offset moves its frame's rows in its channel
    for c in range(3):
        cols[rows[:, :, c], (np.arange(f) * 3 + c)[:, None]] = offsets[:, :, c]
    full = np.concatenate([jac, cols], axis=1)
    np.testing.assert_allclose(ident._information(jac, f, nk, offsets), full.T @ full, rtol=0, atol=1e-13)
    np.testing.assert_allclose(ident._information(jac, f, nk, None), jac.T @ jac, rtol=0, atol=1e-13)
