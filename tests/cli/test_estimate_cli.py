import csv

import numpy as np
import pytest
from illumon.camera import angular_error_deg
from illumon.cli import main
from illumon.observations import write_observations
from illumon.scenarios import measured_daylight_history


def _write_css(path, css):
    rows = ["wavelength_nm,r,g,b"] + [f"{400 + 5 * i},{a:.6f},{b:.6f},{c:.6f}" for i, (a, b, c) in enumerate(css)]
    path.write_text("\n".join(rows) + "\n")


def test_estimate_contract(shared_data, tmp_path):
    h = measured_daylight_history("Nikon_D5100", frames=12, patches=8, seed=5)
    obs, css, out, refl = tmp_path / "o.csv", tmp_path / "c.csv", tmp_path / "e.csv", tmp_path / "r.csv"
    write_observations(obs, h.observations)
    _write_css(css, h.sensitivities)
    args = ["estimate", str(obs), "--sensitivities", str(css), "--out", str(out), "--reflectances", str(refl)]
    assert main(args) == 0
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 12
    for col in ("frame", "time", "cct_k", "duv", "x", "y", "white_r", "white_g", "white_b", "gain_r", "gain_g",
                "gain_b"):
        assert col in rows[0]
    white = np.array([[float(r[f"white_{c}"]) for c in "rgb"] for r in rows])
    assert np.median(angular_error_deg(white, h.true_white)) < 1.5
    assert all(float(r["gain_g"]) == 1.0 for r in rows)
    assert refl.read_text().count("\n") > 60


@pytest.mark.parametrize(
    "obs_body, message",
    [
        ("frame,patch,r,g,b\na,p,1,2,3\n", "missing column"),
        ("frame,time,patch,r,g,b\na,,p,1,2,3\na,,q,3,2,1\n", "only one frame"),
        ("frame,time,patch,r,g,b\na,,p,1,2,x\n", "row 2"),
        ("frame,time,patch,r,g,b\na,,p,1,-2,3\n", "negative"),
    ],
)
def test_estimate_bad_input_exits_nonzero_with_one_line(tmp_path, capsys, obs_body, message):
    obs, css = tmp_path / "o.csv", tmp_path / "c.csv"
    obs.write_text(obs_body)
    _write_css(css, np.ones((61, 3)))
    code = main(["estimate", str(obs), "--sensitivities", str(css), "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert message in err and str(obs) in err and "\n" not in err


def test_estimate_rejects_short_sensitivities(tmp_path, capsys):
    obs, css = tmp_path / "o.csv", tmp_path / "c.csv"
    obs.write_text("frame,time,patch,r,g,b\na,,p,1,2,3\nb,,p,2,2,3\n")
    css.write_text("wavelength_nm,r,g,b\n420,1,1,1\n680,1,1,1\n")
    assert main(["estimate", str(obs), "--sensitivities", str(css), "--out", str(tmp_path / "e.csv")]) == 2
    assert "400–700" in capsys.readouterr().err
