"""A chart's reading of its frame's light with the camera integrated out (:mod:`illumon.camera.chart_light`, issue 26's
light booth): it follows the light, on cameras whose maker is not in the prior, and is independent of the scale."""

from __future__ import annotations

import numpy as np
import pytest
from illumon.camera import colourchecker_references
from illumon.camera.chart_light import chart_light_illumon
from illumon.daylight import CIEDaylight
from illumon.simulation import datasets

CAMERAS = ["Nikon_D5100", "Nikon_D80", "Point_Grey_Grasshopper2_14S5C"]


@pytest.mark.parametrize("camera", CAMERAS)
def test_reads_daylight_without_the_camera(shared_data, camera: str) -> None:
    """CIE daylight at 4 000, 6 500 and 10 000 K on three development cameras (prior without their maker): each
    reading within 30 MK⁻¹ of the truth (the readings' spread on development cameras is ~12 MK⁻¹), in order, and
    its stated spread 1–20 MK⁻¹. A reading fixed at the prior's mean light would miss two of the three by 60+."""
    import unmeasured

    prior = unmeasured.camera_prior_without(camera)
    css = datasets.load_camera(camera)
    refs = colourchecker_references()
    spectra = np.stack(list(refs.values()))
    dm = CIEDaylight()
    got = []
    for mired in (250.0, 153.8, 100.0):
        e = dm.spectra(np.array([[mired, 0.0]]))[0]
        values = (spectra * e) @ css
        values = 0.9 * values / values.max()
        reading = chart_light_illumon(values, spectra, prior)
        assert reading is not None
        assert abs(reading.mired - mired) < 30, (camera, mired, reading)
        assert 1 <= reading.sd <= 20
        got.append(reading.mired)
    assert got[0] > got[1] > got[2]
    scaled = chart_light_illumon(0.5 * values, spectra, prior)
    assert scaled is not None and scaled.mired == pytest.approx(got[2], abs=1e-6)


def test_too_few_values(shared_data) -> None:
    """Fewer than six usable values (NaN, black, clipped) give no reading, not an error."""
    import unmeasured

    prior = unmeasured.camera_prior_without("Nikon_D5100")
    refs = colourchecker_references()
    spectra = np.stack(list(refs.values()))[:3]
    values = np.full((3, 3), np.nan)
    values[0] = [0.2, 0.3, 0.1]
    assert chart_light_illumon(values, spectra, prior) is None
    assert chart_light_illumon(np.zeros((3, 3)), spectra, prior) is None


def test_refused_where_no_camera_explains_the_chart(shared_data) -> None:
    """A camera that renders through its colour matrix to sRGB (declared as sensor RGB) and a TL84 lamp: misfit
    above ``MAX_MISFIT`` (1.13–1.38 on development cameras against 0.38–0.86 for sensor RGB under a D65 simulator),
    no reading — their readings were 20–60 MK⁻¹ off. The same chart without the matrix under D65 is read."""
    import lightbox
    import rawsim
    import unmeasured
    from illumon.camera.pipeline import srgb_matrix

    css = datasets.load_camera("Nikon_D5100")
    prior = unmeasured.camera_prior_without("Nikon_D5100")
    spectra = np.stack(list(colourchecker_references().values()))

    def chart(lamp: str, matrix: np.ndarray | None) -> np.ndarray:
        h = rawsim.simulate_raw_history(css, lightbox.lamp(lamp)[None], spectra, rng=np.random.default_rng(0),
                                        bits=12, matrix=matrix)
        return h.linear_output[0]

    read = chart_light_illumon(chart("D65 simulator", None), spectra, prior)
    assert read is not None and read.misfit < 0.9 and abs(read.mired - 153.7) < 25
    assert chart_light_illumon(chart("D65 simulator", srgb_matrix(css)), spectra, prior) is None
    assert chart_light_illumon(chart("TL84", None), spectra, prior) is None


@pytest.mark.parametrize("camera", ["Nikon_D5100", "Point_Grey_Grasshopper2_14S5C"])
def test_rendered_chart_read_with_the_rendered_prior(shared_data, camera: str) -> None:
    """The chart of a camera that renders through its colour matrix (declared sensor RGB) under the D65 simulator and
    CIE A: the rendered cameras' prior (the other makers' cameras carried to sRGB primaries) explains it (misfit
    below 0.95; the sensors' prior: above 1) and reads the D65 simulator within 15 MK⁻¹ (development: −8…+11) and A
    within 60 (−53…−7; the sensors' prior reads a sensor's chart under A −75…+20); it refuses the same camera's sensor
    chart (misfit above 1; development 1.05–1.41), so a sensor's chart is never read as rendered.
    ``calibration._chart_readings`` tries the sensors' prior first and says which prior read the chart."""
    import lightbox
    import rawsim
    import unmeasured
    from illumon.camera import calibration
    from illumon.camera.pipeline import srgb_matrix

    css = datasets.load_camera(camera)
    sensors = unmeasured.camera_prior_without(camera)
    rendered = unmeasured.camera_prior_without(camera, rendered=True)
    spectra = np.stack(list(colourchecker_references().values()))

    def chart(lamp: str, matrix: np.ndarray | None) -> np.ndarray:
        h = rawsim.simulate_raw_history(css, lightbox.lamp(lamp)[None], spectra, rng=np.random.default_rng(0),
                                        bits=12, matrix=matrix)
        return h.linear_output[0]

    for lamp, mired, tol in (("D65 simulator", 153.7, 15.0), ("A", 350.1, 60.0)):
        values = chart(lamp, srgb_matrix(css))
        assert chart_light_illumon(values, spectra, sensors) is None
        read = chart_light_illumon(values, spectra, rendered)
        assert read is not None and read.misfit < 0.95 and abs(read.mired - mired) < tol, (lamp, read)
        readings, space = calibration._chart_readings(values[None], np.array([0]), spectra, sensors, rendered)
        assert space == "srgb" and readings[1][0] == pytest.approx(read.mired)
    raw = chart("D65 simulator", None)
    assert chart_light_illumon(raw, spectra, rendered) is None
    readings, space = calibration._chart_readings(raw[None], np.array([0]), spectra, sensors, rendered)
    assert space == "camera" and abs(readings[1][0] - 153.7) < 30


def test_veiling_glare_integrated_out(shared_data) -> None:
    """A chart under a D65 simulator with veiling glare (an offset of 3–12 % of each channel's mean value, the
    development photographs' range): read within 8 MK⁻¹ of the glare-free reading (the offset is integrated out;
    without that term even 3 % raised the misfit above ``MAX_MISFIT`` on every development camera)."""
    import lightbox
    import rawsim
    import unmeasured

    css = datasets.load_camera("Nikon_D80")
    prior = unmeasured.camera_prior_without("Nikon_D80")
    spectra = np.stack(list(colourchecker_references().values()))
    v = rawsim.simulate_raw_history(css, lightbox.lamp("D65 simulator")[None], spectra, rng=np.random.default_rng(0),
                                    bits=12).linear_output[0]
    clean = chart_light_illumon(v, spectra, prior)
    assert clean is not None
    for k in (0.03, 0.12):
        glared = chart_light_illumon(v + k * v.mean(axis=0), spectra, prior)
        assert glared is not None and abs(glared.mired - clean.mired) < 8 and glared.misfit < 0.9
    assert chart_light_illumon(v + 0.03 * v.mean(axis=0), spectra, prior, flare_sd=0.0) is None
