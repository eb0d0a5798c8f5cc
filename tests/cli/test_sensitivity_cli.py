"""The ``illumon sensitivity`` handler, called directly with argparse-built arguments."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from illumon.camera import render
from illumon.cli.sensitivity import add_sensitivity_command, run
from illumon.priors import colourchecker_reflectances
from illumon.simulation import datasets
from illumon.spectra import SpectralInputError, read_sensitivities, read_spectral_csv


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="illumon")
    add_sensitivity_command(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(argv)


def write_chart(path, rgb, header="patch,r,g,b"):
    lines = [header] + [f"{i + 1},{r:.6f},{g:.6f},{b:.6f}" for i, (r, g, b) in enumerate(rgb)]
    path.write_text("\n".join(lines) + "\n")


def chart_values():
    _, refl = colourchecker_reflectances("BabelColor Average")
    if datasets.shared_data_dir() is not None:
        c = datasets.load_camera("Nikon_D80")
        _, gran = datasets.load_granada_daylight()
        e = gran[123]
    else:
        from illumon.priors import default_camera_prior, default_daylight_prior

        c, e = default_camera_prior().mean, default_daylight_prior().mean
    return 4000 * render(c, e, refl) / render(c, e, refl).max(), c


@pytest.mark.parametrize("method", ["default", "jiang2013", "kinoshita2023"])
def test_cli_writes_usable_sensitivities(tmp_path, method):
    rgb, truth = chart_values()
    chart = tmp_path / "chart.csv"
    write_chart(chart, rgb)
    out, ill = tmp_path / "css.csv", tmp_path / "ill.csv"
    args = parse(
        [
            "sensitivity",
            str(chart),
            "--chart",
            "BabelColor Average",
            "--out",
            str(out),
            "--method",
            method,
            "--illuminant-out",
            str(ill),
        ]
    )
    assert args.func(args) == 0
    css = read_sensitivities(out)  # directly usable as --sensitivities
    assert css.shape == (61, 3) and abs(css.max() - 1) < 1e-6 and css.min() >= 0
    wl, values, names = read_spectral_csv(out)
    assert names == ["r", "g", "b"] and wl[0] == 400 and wl[-1] == 700 and np.diff(wl).max() <= 10
    _, e, _ = read_spectral_csv(ill)
    assert e.shape == (61, 1) and np.all(e >= 0)
    if method == "default" and datasets.shared_data_dir() is not None:
        err = np.sqrt(np.mean((css - truth / truth.max()) ** 2, axis=0))
        assert err.mean() <= 0.06  # the shipped prior contains this camera, so this is an easy case


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("patch,r,g\n1,1,2\n", "missing column"),
        ("patch,r,g,b\n1,1,x,3\n", "row 2: non-numeric g"),
        ("patch,r,g,b\n25,1,2,3\n", "row 2: patch '25' is not in 1…24"),
        ("patch,r,g,b\n1,1,-2,3\n", "row 2: negative g"),
        ("patch,r,g,b\n" + "".join(f"{i},1,2,3\n" for i in range(1, 24)), "patch(es) 24 missing"),
        ("patch,r,g,b\n1,1,2,3\n1,1,2,3\n", "row 3: patch 1 appears twice"),
    ],
)
def test_cli_bad_chart_csv(tmp_path, content, message):
    chart = tmp_path / "bad.csv"
    chart.write_text(content)
    args = parse(["sensitivity", str(chart), "--out", str(tmp_path / "o.csv")])
    with pytest.raises(SpectralInputError) as exc:
        run(args)
    assert str(chart) in str(exc.value) and message in str(exc.value)


def test_cli_unknown_chart(tmp_path):
    rgb, _ = chart_values()
    chart = tmp_path / "chart.csv"
    write_chart(chart, rgb)
    args = parse(["sensitivity", str(chart), "--chart", "No Such Chart", "--out", str(tmp_path / "o.csv")])
    with pytest.raises(ValueError, match="unknown chart 'No Such Chart'"):
        run(args)
