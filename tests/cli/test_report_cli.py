"""``report daylight`` argparse registration and handler errors."""

import argparse

import numpy as np
import pytest
from illumon.cli.report import add_report_command, run_daylight_report
from illumon.simulation import datasets
from illumon.spectra import WAVELENGTHS, SpectralInputError, write_spectral_csv


def parser():
    p = argparse.ArgumentParser(prog="illumon")
    add_report_command(p.add_subparsers(dest="command"))
    return p


def test_parse():
    a = parser().parse_args(["report", "daylight", "--measured", "x.csv", "--out", "o/"])
    assert a.func is run_daylight_report and a.measured == "x.csv" and a.histories == 12


def test_missing_file(tmp_path):
    a = parser().parse_args(["report", "daylight", "--measured", str(tmp_path / "no.csv"), "--out", str(tmp_path)])
    with pytest.raises(SpectralInputError, match="no such spectra file"):
        run_daylight_report(a)


def test_bad_content(tmp_path):
    f = tmp_path / "bad.csv"
    f.write_text("wavelength_nm,a\n400,1\n500,x\n")
    a = parser().parse_args(["report", "daylight", "--measured", str(f), "--out", str(tmp_path / "o")])
    with pytest.raises(SpectralInputError, match="non-numeric"):
        run_daylight_report(a)
    f.write_text("wavelength_nm,a\n450,1\n500,1\n550,1\n")
    with pytest.raises(SpectralInputError, match="400"):
        run_daylight_report(a)


@pytest.mark.skipif(datasets.shared_data_dir() is None, reason="shared measured data not found")
def test_runs(tmp_path, capsys):
    _, e = datasets.load_granada_daylight()
    f = tmp_path / "s.csv"
    write_spectral_csv(f, WAVELENGTHS, {f"g{i}": e[i] for i in range(0, 2600, 50)})
    a = parser().parse_args(["report", "daylight", "--measured", str(f), "--out", str(tmp_path / "o"),
                             "--histories", "0"])
    assert run_daylight_report(a) == 0
    assert (tmp_path / "o" / "report.md").is_file() and "cie_xy_frac_gfc_999" in capsys.readouterr().out
    np.testing.assert_equal((tmp_path / "o" / "summary.json").is_file(), True)
