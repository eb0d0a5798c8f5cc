"""Daylight report on a fixed Granada subset, and the hidden-distortion detector."""

import json

import numpy as np
import pytest
from illumon.reports.daylight import daylight_report
from illumon.reports.detect import detect_band, detect_tint
from illumon.simulation import datasets
from illumon.spectra import WAVELENGTHS, write_spectral_csv

pytestmark = pytest.mark.skipif(datasets.shared_data_dir() is None, reason="shared measured data not found")


@pytest.fixture(scope="module")
def granada():
    return datasets.load_granada_daylight()[1]


@pytest.fixture(scope="module")
def subset_report(tmp_path_factory, granada):
    d = tmp_path_factory.mktemp("dr")
    idx = np.arange(0, 2600, 13)  # 200 spectra spread over the file
    write_spectral_csv(d / "sub.csv", WAVELENGTHS, {f"g{i:04d}": granada[i] for i in idx})
    return daylight_report(d / "sub.csv", d / "out", simulate=False, plots=True), d / "out"


def test_report_numbers(subset_report):
    s, out = subset_report
    assert s["input"]["n_spectra"] == 200
    assert s["models"]["cie_xy"]["frac_gfc_999"] == pytest.approx(0.60, abs=0.05)
    assert s["models"]["cie_free"]["frac_gfc_999"] >= s["models"]["cie_xy"]["frac_gfc_999"]
    ho = s["held_out"]
    assert ho["measured_xy"]["median_rmse"] < 0.8 * ho["cie_xy"]["median_rmse"]
    assert ho["measured_free"]["frac_gfc_999"] > ho["cie_free"]["frac_gfc_999"]
    assert s["cause"]["median_cct_fail"] > s["cause"]["median_cct_pass"]
    cw = s["gain"]["camera_white_at_true_chromaticity"]
    assert cw["measured"]["median_deg"] < cw["cie"]["median_deg"]
    band = s["detection"]["band"]  # natural: a few humid / low-sun spectra deepen the O2-B / H2O bands near 690 nm
    assert not band["found"] or (band["centre_nm"] >= 660 and band["n_affected"] <= 20)
    for f in ("report.md", "figures.json", "summary.json", "error_vs_cct.png", "band_scan.png"):
        assert (out / f).is_file()
    assert "error_vs_cct" in json.loads((out / "figures.json").read_text())


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_hidden_band(granada, seed):
    rng = np.random.default_rng(100 + seed)
    x = granada[rng.choice(len(granada), 300, replace=False)].copy()
    sub = rng.random(300) < rng.uniform(0.15, 0.5)
    centre, depth, fwhm = rng.uniform(420, 680), rng.uniform(0.04, 0.15), rng.uniform(10, 30)
    x[sub] *= 1 - depth * np.exp(-0.5 * ((WAVELENGTHS - centre) / (fwhm / 2.3548)) ** 2)
    r = detect_band(x)
    assert r["found"] and abs(r["centre_nm"] - centre) <= 20
    aff = np.zeros(300, bool)
    aff[r["affected"]] = True
    assert (aff & sub).sum() / aff.sum() >= 0.9 and (aff & sub).sum() / sub.sum() >= 0.9


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hidden_tint(granada, seed):
    rng = np.random.default_rng(200 + seed)
    x = granada[rng.choice(len(granada), 300, replace=False)].copy()
    sub = rng.random(300) < rng.uniform(0.2, 0.5)
    a = rng.choice([-1, 1]) * rng.uniform(0.16, 0.22)  # |ΔDuv| ≈ 0.008–0.011
    x[sub] *= 1 + a * (np.exp(-0.5 * ((WAVELENGTHS - 540) / 40) ** 2) - 0.4)
    r = detect_tint(x)
    assert r["found"] and np.sign(r["shift_duv"]) == np.sign(a)
    aff = np.zeros(300, bool)
    aff[r["affected"]] = True
    assert (aff & sub).sum() / aff.sum() >= 0.9 and (aff & sub).sum() / sub.sum() >= 0.9
