"""Values clipped at the white level carry no weight (``illumon.retrieval.common.NEAR_WHITE``) in the scene model's
fit and per-frame solver and in the joint retrieval: found on the Point Grey Grasshopper2 through the independent raw
pipeline, whose blue saturates on bright patches."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from illumon.camera import angular_error_deg
from illumon.model import IdentifiabilityWarning, fit_scene_model
from illumon.observations import Observations
from illumon.priors import colourchecker_reflectances
from illumon.retrieval import common as rc
from illumon.retrieval import retrieve_illuminants
from illumon.simulation import datasets, simulate_history

pytestmark = pytest.mark.skipif(datasets.shared_data_dir() is None, reason="measured data (shared/data) not available")


@pytest.fixture(scope="module")
def clipped() -> dict:
    """A Point Grey history whose blue clips on the bright patches (exposure set so the white patch's blue reaches
    2.5 × white, a fifth of the values at white), as a saturating sensor delivers it."""
    _, granada = datasets.load_granada_daylight()
    css = datasets.load_camera("Point_Grey_Grasshopper2_14S5C")
    _, refl = colourchecker_reflectances()
    pick = [18, 19, 20, 1, 2, 5, 7, 10, 12, 13, 14, 15]  # whites and greys first, then colours
    hist = simulate_history(css, granada[:480:4], refl[pick], rng=7)
    v = hist.observations.values
    k = 2.5 / np.nanmax(v[..., 2], axis=1)  # per frame: the white patch's blue at 2.5 × white
    obs = hist.observations
    raw = Observations(obs.frames, obs.patches, np.minimum(v * k[:, None, None], 1.0), obs.times)
    assert np.mean(raw.values >= 1.0) > 0.15
    return {"obs": raw, "css": css, "white": hist.true_white, "clean": hist.observations}


def _model_error(obs: Observations, css: np.ndarray, white: np.ndarray) -> float:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        model = fit_scene_model(obs.subset(slice(0, 60)), css)
    return float(np.median(angular_error_deg(model.estimate(obs.subset(slice(60, None)))[0].white, white[60:])))


def test_scene_model_censors_values_at_white(clipped: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    """Measured: 0.87° on the unclipped history, 0.79° clipped and censored, 6.0° clipped and trusted."""
    clean = _model_error(clipped["clean"], clipped["css"], clipped["white"])
    censoring = _model_error(clipped["obs"], clipped["css"], clipped["white"])
    monkeypatch.setattr(rc, "NEAR_WHITE", np.inf)  # trust clipped values
    trusting = _model_error(clipped["obs"], clipped["css"], clipped["white"])
    assert censoring < clean + 0.2, (clean, censoring, trusting)
    assert trusting > censoring + 2.0, (clean, censoring, trusting)


def test_joint_retrieval_censors_values_at_white(clipped: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    """Measured (30 frames): 0.80° unclipped, 0.51° clipped and censored, 5.3° clipped and trusted."""
    obs = clipped["obs"].subset(slice(0, 30))

    def error() -> float:
        res = retrieve_illuminants(obs, clipped["css"], method="joint")
        return float(np.median(angular_error_deg(res.white, clipped["white"][:30])))

    censoring = error()
    monkeypatch.setattr(rc, "NEAR_WHITE", np.inf)
    trusting = error()
    assert censoring < 1.0 and trusting > censoring + 2.0, (censoring, trusting)


def test_no_clip_level_without_a_white_level() -> None:
    """Renderings on an arbitrary scale (values above 1: not divided by a white level) have no clip level."""
    assert rc.white_level(np.array([[0.2, 0.99, np.nan]])) == 1.0
    assert rc.white_level(np.array([[0.2, 300.0]])) == np.inf
    y = np.array([0.001, 0.5, 0.96])
    np.testing.assert_array_equal(rc.censored(y, 0.002, 1.0), [True, False, True])
    np.testing.assert_array_equal(rc.censored(y, 0.002, np.inf), [True, False, False])
