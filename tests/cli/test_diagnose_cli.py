import csv
import json

import numpy as np
import pytest
from illumon.cli import main
from illumon.observations import write_observations
from illumon.simulation.effects import hide_effect

KEYS = {"effect", "patch", "frame", "parameters", "candidates", "residual_base", "residual_extended", "illuminant_change_deg"}
EFFECT_NAMES = {"none", "nonlinear_response", "black_offset", "clipping", "patch_change", "shadow", "off_locus_illuminant",
                "fluorescence"}


def _write_css(path, css):
    rows = ["wavelength_nm,r,g,b"] + [f"{400 + 5 * i},{a:.6f},{b:.6f},{c:.6f}" for i, (a, b, c) in enumerate(css)]
    path.write_text("\n".join(rows) + "\n")


def test_diagnose_contract(shared_data, tmp_path):
    h = hide_effect("patch_change", "Nikon_D3X", 15_000, frames=24, patches=8)
    obs, css, out = tmp_path / "o.csv", tmp_path / "c.csv", tmp_path / "r.json"
    write_observations(obs, h.observations)
    _write_css(css, h.history.sensitivities)
    assert main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert KEYS <= set(rep)
    assert rep["effect"] == "patch_change"
    assert rep["patch"] == h.observations.patches[h.patch]
    assert abs(h.observations.frames.index(rep["frame"]) - h.frame) <= 2
    assert {c["effect"] for c in rep["candidates"]} == EFFECT_NAMES - {"none"}
    assert all(c["score"] is None or isinstance(c["score"], float) for c in rep["candidates"])
    assert rep["residual_extended"] < rep["residual_base"]
    assert rep["illuminant_change_deg"] >= 0.0


def test_diagnose_white_level_and_estimate_model_effects(shared_data, tmp_path):
    h = hide_effect("black_offset", "Canon_50D", 15_001, frames=24, patches=8)
    obs, css, out, est = tmp_path / "o.csv", tmp_path / "c.csv", tmp_path / "r.json", tmp_path / "e.csv"
    write_observations(obs, h.observations, white_level=4095)
    _write_css(css, h.history.sensitivities)
    assert main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(out), "--white-level", "4095"]) == 0
    rep = json.loads(out.read_text())
    assert rep["effect"] == "black_offset"
    np.testing.assert_allclose(rep["parameters"]["offsets_value"], np.asarray(h.parameters["offsets"]) * 4095, atol=25)
    args = ["estimate", str(obs), "--sensitivities", str(css), "--out", str(est), "--white-level", "4095",
            "--model-effects", "auto"]
    assert main(args) == 0
    rows = list(csv.DictReader(est.open()))
    assert len(rows) == 24
    assert list(rows[0]) == ["frame", "time", "cct_k", "duv", "x", "y", "white_r", "white_g", "white_b", "gain_r", "gain_g",
                             "gain_b", "non_daylight"]
    assert all(float(r["non_daylight"]) < 0.5 for r in rows)  # daylight with a pedestal (issue 28)


@pytest.mark.parametrize(
    "obs_body, message",
    [
        ("frame,patch,r,g,b\na,p,1,2,3\n", "missing column"),
        ("frame,time,patch,r,g,b\na,,p,1,2,x\n", "row 2"),
        ("frame,time,patch,r,g,b\n" + "".join(f"f{i},,p{j},1,2,3\n" for i in range(8) for j in range(2)), "at least 3"),
        # every value near black for the white level given (a real 16-bit lamp-lit scene read with the wrong one
        # ended in a ZeroDivisionError traceback)
        ("frame,time,patch,r,g,b\n" + "".join(f"f{i},,p{j},1,2,{3 + j}\n" for i in range(8) for j in range(4)),
         "--white-level"),
    ],
)
def test_diagnose_bad_input_one_line_exit_2(tmp_path, capsys, obs_body, message):
    obs, css = tmp_path / "o.csv", tmp_path / "c.csv"
    obs.write_text(obs_body)
    _write_css(css, np.ones((61, 3)))
    code = main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(tmp_path / "r.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert message in err and str(obs) in err and "\n" not in err


def test_a_degenerate_fit_is_one_line_naming_cause_and_fix(tmp_path, capsys):
    # four identical patches in eight frames, a few values above black: the fit's systems are singular; the user gets
    # the cause and what to do, not "Singular matrix" (issue 26) nor a traceback
    obs, css = tmp_path / "o.csv", tmp_path / "c.csv"
    obs.write_text("frame,time,patch,r,g,b\n" + "".join(f"f{i},,p{j},1,2,{3 + i}\n" for i in range(8) for j in range(4)))
    _write_css(css, np.ones((61, 3)))
    code = main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(tmp_path / "r.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert err.startswith("illumon: error: the fit is degenerate") and "add patches of different colours" in err


def test_diagnose_rejects_short_sensitivities(tmp_path, capsys):
    obs, css = tmp_path / "o.csv", tmp_path / "c.csv"
    obs.write_text("frame,time,patch,r,g,b\n" + "".join(f"f{i},,p{j},1,2,3\n" for i in range(8) for j in range(4)))
    css.write_text("wavelength_nm,r,g,b\n420,1,1,1\n680,1,1,1\n")
    assert main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(tmp_path / "r.json")]) == 2
    assert "400–700" in capsys.readouterr().err


def test_a_dim_16_bit_history_is_diagnosed_not_refused(shared_data, tmp_path):
    """A 16-bit linear camera whose regions sit at 0.5…2.5 % of white (thousands of codes above black, as the real
    MIMO lamp-lit scenes' do): 3 % of white censored every value and the history was refused; it is read above its
    own censoring level (``illumon.diagnosis.noise.history_dark_level``)."""
    h = hide_effect("none", "Nikon_D3X", 15_002, frames=24, patches=8)
    dim = h.observations
    dim.values = dim.values * (0.025 / np.nanpercentile(dim.values, 99))
    assert np.nanmax(dim.values) <= 0.15 and np.sum(dim.values > 0.03) < 12  # refused by the former rule
    obs, css, out = tmp_path / "o.csv", tmp_path / "c.csv", tmp_path / "r.json"
    write_observations(obs, dim, white_level=65535)
    _write_css(css, h.history.sensitivities)
    assert main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(out), "--white-level", "65535"]) == 0
    rep = json.loads(out.read_text())
    assert rep["effect"] == "none"  # a clean history, dim or not


def test_estimate_model_effects_reads_the_sensitivities_as_diagnose_does(shared_data, tmp_path, capsys, monkeypatch):
    """``estimate --primaries srgb --model-effects auto`` names what ``diagnose --primaries srgb`` names, and hands the
    diagnosis the measured sensitivities as ``diagnose`` does (its scene model carries them to sRGB primaries; they
    were carried twice)."""
    import rawsim
    import unmeasured
    from illumon.simulation import datasets

    cam = rawsim.DEV_CAMERAS[3001 % len(rawsim.DEV_CAMERAS)]
    o, _, _ = unmeasured.render("illumon", cam, "none+lamps", 3001)
    obs, css, out, est = tmp_path / "o.csv", tmp_path / "c.csv", tmp_path / "r.json", tmp_path / "e.csv"
    write_observations(obs, o, white_level=1.0)
    _write_css(css, datasets.load_camera(cam))
    common = ["--sensitivities", str(css), "--white-level", "1", "--primaries", "srgb"]
    assert main(["diagnose", str(obs), "--out", str(out), *common]) == 0
    rep = json.loads(out.read_text())
    assert rep["effect"] == "off_locus_illuminant"
    capsys.readouterr()
    import illumon.cli.diagnose as cli_diagnose

    seen = []
    real = cli_diagnose.run_diagnosis
    monkeypatch.setattr(cli_diagnose, "run_diagnosis", lambda path, o, c, **kw: seen.append(c) or real(path, o, c, **kw))
    assert main(["estimate", str(obs), "--out", str(est), "--model-effects", "auto", *common]) == 0
    said = capsys.readouterr().err
    assert f"model effects: {rep['effect']}" in said, said
    np.testing.assert_allclose(seen[0], datasets.load_camera(cam) / datasets.load_camera(cam).max(), atol=1e-6)


def test_a_single_frame_is_judged_for_its_light(shared_data, tmp_path):
    """One frame (a single photograph) is judged for its light alone, as a short history is: the first frame of a
    lamp-lit rendered history is named ``off_locus_illuminant`` (that frame), the first of a daylight one ``none``
    (``benchmarks/short_histories.py --frames 1``: 783 of 840 lamp-lit single frames named, 0 of 1 680 daylight)."""
    import unmeasured  # benchmarks/ (pytest's pythonpath)
    from illumon.camera.primaries import srgb_sensitivities

    obs, css, out = tmp_path / "o.csv", tmp_path / "c.csv", tmp_path / "r.json"
    _write_css(css, np.clip(srgb_sensitivities(), 0.0, None))
    for case, effect in (("none+lamps", "off_locus_illuminant"), ("none+rendered", "none")):
        o, _, _ = unmeasured.render("rawsim", "Nikon_D5100", case, 7)
        write_observations(obs, o.subset([0]))
        assert main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(out), "--primaries", "srgb"]) == 0
        rep = json.loads(out.read_text())
        assert rep["effect"] == effect and rep["residual_base"] is None and rep["notes"], (case, rep)
        if effect != "none":
            assert rep["parameters"]["frames"] == o.frames[:1]


def test_three_frames_of_rendered_output_are_judged_for_their_light(shared_data, tmp_path):
    """``--primaries srgb`` on three frames lit by lamps (the real MIMO scenes' case, three frames each in some scenes):
    a report naming ``off_locus_illuminant`` with its frames, and a note that nothing else was judged; the same frames
    as sensor RGB are judged for their light too (a report with the same note)."""
    import unmeasured  # benchmarks/ (pytest's pythonpath)
    from illumon.camera.primaries import srgb_sensitivities

    lit, _, _ = unmeasured.render("rawsim", "Nikon_D5100", "none+lamps", 7)
    obs, css, out = tmp_path / "o.csv", tmp_path / "c.csv", tmp_path / "r.json"
    write_observations(obs, lit.subset(np.arange(3)))
    _write_css(css, np.clip(srgb_sensitivities(), 0.0, None))
    assert main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(out), "--primaries", "srgb"]) == 0
    rep = json.loads(out.read_text())
    assert KEYS <= set(rep)
    assert rep["effect"] == "off_locus_illuminant" and rep["parameters"]["frames"] == lit.frames[:3]
    assert rep["residual_base"] is None and rep["notes"]
    assert main(["diagnose", str(obs), "--sensitivities", str(css), "--out", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["residual_base"] is None and any("judged as a whole" in n for n in rep["notes"])
