import numpy as np
import pytest
from illumon.spectra import GRID, SpectralInputError, read_sensitivities, resample


def test_grid_is_400_700_5nm():
    assert GRID.start == 400 and GRID.end == 700 and GRID.interval == 5


def test_resample_reproduces_smooth_function():
    wl = np.arange(380, 781, 10.0)
    f = np.exp(-((wl - 550) / 60) ** 2)
    out = resample(wl, f)
    truth = np.exp(-((np.arange(400, 701, 5.0) - 550) / 60) ** 2)
    assert np.max(np.abs(out - truth)) < 2e-3


def test_read_sensitivities_any_sampling_with_comments(tmp_path):
    p = tmp_path / "c.csv"
    wl = np.arange(390, 731, 2.0)
    rows = [f"{w:g},{np.exp(-((w-600)/40)**2):.6f},{np.exp(-((w-540)/40)**2):.6f},{np.exp(-((w-460)/30)**2):.6f}"
            for w in wl]
    p.write_text("# Camera: test\nwavelength_nm,r,g,b\n" + "\n".join(rows) + "\n")
    css = read_sensitivities(p)
    assert css.shape == (61, 3)
    assert np.argmax(css[:, 1]) == (540 - 400) // 5


@pytest.mark.parametrize(
    "body, message",
    [
        ("wavelength_nm,r,g,b\n450,1,1,1\n650,1,1,1\n", "400–700 nm are required"),
        ("wavelength_nm,r,g,b\n400,1,1,1\n500,x,1,1\n700,1,1,1\n", "row 3: non-numeric"),
        ("wavelength_nm,r,g,b\n400,1,1,1\n550,-1,1,1\n700,1,1,1\n", "negative sensitivity at 550"),
        ("wavelength_nm,r,g\n400,1,1\n700,1,1\n", "expected columns"),
    ],
)
def test_bad_sensitivities_name_the_problem(tmp_path, body, message):
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(SpectralInputError, match=message):
        read_sensitivities(p)
