"""The reference frames' veiling glare in the stated confidence of a camera nobody measured (issue 26).

A reference is fitted as the camera's own (``T``), glare included: the stated spread carries how far the glare the
history learned (``flare_sd``) would move the camera white, per history (``_glare_white_sd``)."""

import numpy as np
import pytest
from illumon.camera import colourchecker_references, grey_card_reference
from illumon.camera.calibration import (
    _d65_white,
    _glare_white_sd,
    _reference_offset_sd,
    camera_transform_Kinoshita2023,
    prior_sensitivities,
)
from illumon.camera.references import neutral_references
from illumon.daylight import CIEDaylight
from illumon.observations import Observations
from illumon.priors.scene_average import log_chroma
from illumon.simulation import datasets


def _frame0(refs: dict, scene: np.ndarray, css: np.ndarray):
    """One daylight frame of scene patches plus references (noise-free), with its observations."""
    e = CIEDaylight().spectra(np.array([[170.0, 0.002]]))
    spectra = np.stack(list(refs.values()))
    refl = np.concatenate([scene, spectra])
    values = 0.4 * np.einsum("fl,pl,lc->fpc", e, refl, css) / (e @ css)[0, 1]
    obs = Observations(["f0"], [f"p{i}" for i in range(len(refl))], values, [""])
    return e, spectra, values[:, len(scene):], obs


def _neutral(refs: dict) -> np.ndarray:
    grey = set(neutral_references(refs))
    return np.array([p in grey for p in refs])


@pytest.mark.parametrize("kind", ["grey", "chart"])
def test_glare_spread_is_the_white_shift_an_offset_of_that_size_makes(shared_data, kind):
    """``_glare_white_sd`` is the D65 white's shift (log r/g, b/g, pooled) when the reference frame gains the offset
    its prior spread describes (linearised: the central difference over ± that offset agrees to 1 % for a grey card,
    4 % for a chart), and 0 without glare."""
    css = datasets.load_camera("Nikon_D5100")
    base = prior_sensitivities()
    scene = np.random.default_rng(5).uniform(0.05, 0.8, (10, 61)) * np.linspace(1.3, 0.7, 61)  # bluish surfaces
    refs = grey_card_reference() if kind == "grey" else colourchecker_references()
    e, spectra, values, obs = _frame0(refs, scene, css)
    neutral = _neutral(refs)
    osd = _reference_offset_sd(obs, np.array([0]), 0.05)
    assert osd.shape == (1, 3) and np.all(osd > 0)
    sd = _glare_white_sd(base, spectra, e, values, kind == "grey", neutral, osd)

    def white(v):
        t, _ = camera_transform_Kinoshita2023(base, spectra, e, v, diagonal=kind == "grey", neutral=neutral)
        return log_chroma(_d65_white(base @ t))

    shift = (white(values + osd[0]) - white(values - osd[0])) / 2  # the central difference over ± one spread
    assert sd == pytest.approx(float(np.sqrt(np.sum(shift**2) / 2)), rel=0.06)
    assert sd > 1e-3  # coloured surfaces: the glare is not the references' colour
    assert _reference_offset_sd(obs, np.array([0]), 0.0) is None
    assert _glare_white_sd(base, spectra, e, values, kind == "grey", neutral, None) == 0.0


@pytest.mark.parametrize("tilt", [(0.6, 1.4), (1.3, 0.7)])
def test_glare_moves_a_grey_card_more_than_a_chart(shared_data, tilt):
    """A chart's dark and light patches tell an added light from the camera's channel scales; a grey card cannot
    (reddish surfaces: 0.013 against 0.008; bluish: 0.017 against 0.004)."""
    css = datasets.load_camera("Nikon_D5100")
    base = prior_sensitivities()
    scene = np.random.default_rng(3).uniform(0.05, 0.8, (10, 61)) * np.linspace(*tilt, 61)
    sds = {}
    for kind, refs in (("grey", grey_card_reference()), ("chart", colourchecker_references())):
        e, spectra, values, obs = _frame0(refs, scene, css)
        neutral = _neutral(refs)
        sds[kind] = _glare_white_sd(base, spectra, e, values, kind == "grey", neutral,
                                    _reference_offset_sd(obs, np.array([0]), 0.05))
    assert sds["grey"] > 1.3 * sds["chart"]


def test_a_channel_censored_at_0_stays_out_of_the_glare_derivative(shared_data):
    """A chart channel a colour matrix took below 0 (clipped to 0) is out of the fit; the step along the glare must not
    lift it in (a jump, not a derivative: 0.33 instead of 0.02 on a development history)."""
    css = datasets.load_camera("Nikon_D5100")
    base = prior_sensitivities()
    scene = np.random.default_rng(5).uniform(0.05, 0.8, (10, 61))
    refs = colourchecker_references()
    e, spectra, values, obs = _frame0(refs, scene, css)
    neutral = _neutral(refs)
    osd = _reference_offset_sd(obs, np.array([0]), 0.12)  # the largest glare spread a history learns
    clean = _glare_white_sd(base, spectra, e, values, False, neutral, osd, step=0.1)
    clipped = values.copy()
    clipped[0, [2, 13], 0] = 0.0  # blue and its neighbour: red clipped at 0
    assert clipped[0, 2, 0] + 0.1 * osd[0, 0] > 1e-3 * np.nanmax(clipped)  # the step would lift it into the fit
    got = _glare_white_sd(base, spectra, e, clipped, False, neutral, osd, step=0.1)
    assert 0.5 * clean < got < 2.0 * clean
