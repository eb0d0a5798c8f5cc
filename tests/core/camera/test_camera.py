"""illumon.camera: output pipeline, references, and calibration of cameras nobody measured (issue 15)."""

import warnings

import numpy as np
import pytest
import rawsim
from illumon.camera import (
    CameraPipeline,
    ResponseCurve,
    angular_error_deg,
    colourchecker_references,
    grey_card_reference,
    read_known_reflectances,
    undo_applied,
)
from illumon.camera.calibration import CAMERA_WHITE_SD, camera_transform_Kinoshita2023
from illumon.camera.pipeline import srgb_matrix
from illumon.camera.references import references_kind
from illumon.daylight import CIEDaylight
from illumon.model import SceneModel, fit_scene_model
from illumon.observations import Observations
from illumon.priors import max_normalise
from illumon.retrieval.common import grey_world
from illumon.simulation import datasets
from illumon.spectra import WAVELENGTHS, SpectralInputError, write_spectral_csv


def test_tone_table_round_trip_and_validation():
    curve = ResponseCurve("table", table=tuple(np.linspace(0, 1, 17) ** 2.2), black_level=16, white_level=235)
    lin = np.array([0.0, 0.01, 0.2, 0.7, 1.0])
    assert np.allclose(curve.linearise(curve.encode(lin)), lin, atol=2e-3)
    srgb = ResponseCurve("srgb")
    assert np.allclose(srgb.linearise(srgb.encode(lin)), lin, atol=1e-12)
    with pytest.raises(ValueError, match="non-decreasing"):
        ResponseCurve("table", table=(0.0, 0.5, 0.4, 1.0))
    with pytest.raises(ValueError, match="unknown encoding"):
        ResponseCurve("log")


def test_undo_applied_gains_and_exposure():
    rng = np.random.default_rng(1)
    raw = rng.uniform(0.05, 0.5, (4, 6, 3))
    gains = rng.uniform(0.5, 2.5, (4, 3))
    k = rng.uniform(0.5, 2.0, 4)
    m = srgb_matrix(np.abs(rng.normal(1, 0.3, (61, 3))))
    out = np.einsum("ij,fpj->fpi", m, raw * gains[:, None, :] * k[:, None, None])
    back = undo_applied(out, gains, k, matrix=m)
    assert np.allclose(back, np.einsum("ij,fpj->fpi", m, raw), rtol=1e-10)
    plain = raw * gains[:, None, :]
    assert np.allclose(undo_applied(plain, gains), raw)
    with pytest.raises(ValueError, match="positive"):
        undo_applied(out, [1.0, 0.0, 1.0])
    assert np.allclose(CameraPipeline(matrix=m).output_sensitivities(np.eye(61, 3)), np.eye(61, 3) @ m.T)


def test_read_known_reflectances_checks(tmp_path):
    good = tmp_path / "k.csv"
    write_spectral_csv(good, WAVELENGTHS[::2], {"grey": np.full(31, 0.2), "red": np.linspace(0.05, 0.6, 31)})
    known = read_known_reflectances(good)
    assert set(known) == {"grey", "red"} and known["red"].shape == (61,)
    for name, cols, msg in (
        ("hi.csv", {"g": np.full(61, 1.3)}, "outside 0…1"),
        ("short.csv", None, "400–700"),
    ):
        path = tmp_path / name
        if cols is None:
            write_spectral_csv(path, WAVELENGTHS[4:], {"g": np.full(57, 0.2)})
        else:
            write_spectral_csv(path, WAVELENGTHS, cols)
        with pytest.raises(SpectralInputError, match=msg):
            read_known_reflectances(path)
    assert references_kind(grey_card_reference()) == "grey"
    assert references_kind(colourchecker_references()) == "chart"


def test_transform_posterior_recovers_a_colour_matrix(shared_data):
    """With the illuminant known, a chart gives T exactly (noise-free); a grey card only its diagonal."""
    css = datasets.load_camera("Nikon_D5100")
    m = srgb_matrix(css)
    refs = colourchecker_references()
    spectra = np.stack(list(refs.values()))
    e = CIEDaylight().spectra(np.array([[180.0, 0.0]]))
    values = 0.01 * np.einsum("fl,pl,lc->fpc", e, spectra, css @ m.T)
    t, sd = camera_transform_Kinoshita2023(css, spectra, e, values, diagonal=False, relative_error=1e-4)
    assert np.allclose(t / t[1, 1], m.T / m.T[1, 1], atol=1e-3)
    assert np.all(sd[np.eye(3, dtype=bool)] > 0)


def _history(camera, seed, case):
    """30 frames × 10 patches of a development camera (rawsim), references in frame 0, prior without the maker."""
    rng = np.random.default_rng(seed)
    css = datasets.load_camera(camera)
    e = rawsim.daylight_run("dev", 30, rng)
    scene = rawsim.draw_reflectances("dev", 10, rng)
    known = {"grey": grey_card_reference()["grey"]} if case == "grey" else colourchecker_references() if case == "chart" else {}
    refl = np.concatenate([scene, np.stack(list(known.values()))]) if known else scene
    matrix = srgb_matrix(css) if case == "chart" else None
    h = rawsim.simulate_raw_history(css, e, refl, rng=rng, matrix=matrix)
    values = h.linear_output.copy()
    values[1:, 10:] = np.nan
    obs = Observations([f"f{i}" for i in range(30)], [f"p{j}" for j in range(10)] + list(known), values, [""] * 30)
    own = rawsim.manufacturer(camera)
    prior = np.mean([max_normalise(datasets.load_camera(n)) for n in datasets.camera_names()
                     if rawsim.manufacturer(n) != own], axis=0)
    return obs, h.true_white, known, prior


def _fit(obs, known, prior):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_scene_model(obs, None, known_reflectances=known or None, camera_prior_mean=prior)


@pytest.mark.slow
def test_unmeasured_camera_calibrations(shared_data):
    """Three development histories (Nikon D700, D80, D5100; prior from other makers), every frame pooled: a grey card
    in one frame brings the camera white within a degree; a chart in one frame undoes an unknown colour matrix; with
    no reference the error stays below gray-world and the confidence says the estimate is not to be trusted.
    Measured at commit time (median / max): grey 0.13 / 1.13, chart 0.76 / 3.10, none 4.54 / 5.10 (gray-world
    median 8.36). Confidence means what it says (``STATED_WHITE_SPREAD``, chosen on the development split over
    histories with and without veiling glare, half each): these glare-free histories are where it understates —
    pooled over the three, stated / within 1°: grey 0.85 / 1.00 (0.88 before the reference frames' glare term, which
    these histories' learned glare spread of 0.025 cannot rule out: 0.99, 0.87 and 0.70 by history, the last a card
    among surfaces whose mean is far from grey; 0.965 / 0.99 when it was chosen on glare-free histories alone),
    chart 0.87 / 0.84, none 0.17 / 0.17 — so a grey card may state up to 0.2 less than it delivers here, never more
    than 0.05 above it."""
    err: dict[str, list] = {"grey": [], "chart": [], "none": []}
    gw, conf = [], {k: [] for k in err}
    for camera, seed in (("Nikon_D700", 11), ("Nikon_D80", 5), ("Nikon_D5100", 2)):
        for case in err:
            obs, white, known, prior = _history(camera, seed, case)
            model = _fit(obs, known, prior)
            assert model.camera["calibration"] == case
            res, extra = model.history_estimate
            err[case].append(angular_error_deg(res.white, white))
            conf[case].append(extra["confidence"])
            if case == "none":
                gw.append(angular_error_deg(grey_world(obs.select_patches(model.patches)), white))
    e = {k: np.concatenate(v) for k, v in err.items()}
    c = {k: float(np.mean(np.concatenate(v))) for k, v in conf.items()}
    assert np.median(e["grey"]) < 0.3 and e["grey"].max() < 1.5
    assert np.median(e["chart"]) < 1.0 and e["chart"].max() < 3.5
    assert np.median(e["none"]) < np.median(np.concatenate(gw))
    # honest confidence: what a reference pins shows in it, and the stated probability is the frequency
    assert c["none"] < min(c["chart"], c["grey"])
    assert -0.2 < c["grey"] - np.mean(e["grey"] < 1.0) < 0.05
    assert abs(c["chart"] - np.mean(e["chart"] < 1.0)) < 0.1
    assert abs(c["none"] - np.mean(e["none"] < 1.0)) < 0.1
    assert CAMERA_WHITE_SD["none"] > CAMERA_WHITE_SD["chart"] > CAMERA_WHITE_SD["grey"]


def test_calibrated_model_round_trips_and_needs_scene_in_reference_frame(shared_data, tmp_path):
    obs, white, known, prior = _history("Nikon_D80", 3, "grey")
    model = _fit(obs, known, prior)
    path = tmp_path / "m.json"
    model.save(path)
    again = SceneModel.load(path)
    assert again.camera == model.camera and "grey" not in again.patches
    res, _ = again.estimate(obs)
    ref = np.all(np.isfinite(obs.values[:, obs.patches.index("grey")]), axis=-1)  # the card's frame
    assert ref.sum() == 1
    assert np.allclose(res.white[~ref], model.history_estimate[0].white[~ref], atol=1e-9)
    # the card's frame takes its white from the card (history estimate), within a hair of the model's own
    card = obs.values[ref, obs.patches.index("grey")][0]
    assert angular_error_deg(model.history_estimate[0].white[ref][0], card / card[1]) < 0.05
    assert angular_error_deg(res.white[ref][0], model.history_estimate[0].white[ref][0]) < 0.5
    lonely = obs.values.copy()
    lonely[0, :10] = np.nan  # the grey card's frame shows no scene patch
    with pytest.raises(ValueError, match="at least two scene patches"):
        _fit(Observations(obs.frames, obs.patches, lonely, obs.times), known, prior)
    with pytest.raises(ValueError, match="never observed"):
        _fit(obs, {"elsewhere": np.full(61, 0.5)}, prior)


def test_angular_error_is_in_degrees():
    from illumon.camera import angular_error_deg

    a = [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 2.0, 2.0]]
    got = angular_error_deg(a, [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    np.testing.assert_allclose(got, [90.0, 45.0, 0.0], atol=1e-6)
