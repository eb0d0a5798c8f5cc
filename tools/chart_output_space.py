"""Which output space explains a chart: a sensor's RGB or rendered output (a colour matrix to sRGB primaries).

A camera declared sensor RGB (``--primaries camera``) may still render: an industrial camera with its colour
correction on applies a matrix towards sRGB. The chart's reading of its frame's light
(:func:`illumon.camera.chart_light.chart_light_illumon`) integrates the camera over a prior of cameras; the sensors'
prior (the measured cameras) then explains no such chart and the reading is refused, and the light booth's D65 frame
read 16 900 K (``benchmarks/lightbox.py --matrix``). This tool reads the ColorChecker of each development camera
(``rawsim``, 12-bit, noise; the prior without the camera's maker) under a D65 simulator (FL3.15), CIE A and a D50
simulator (FL3.14), as sensor RGB and through the camera's own colour matrix to sRGB
(:func:`illumon.camera.pipeline.srgb_matrix`, least squares on the chart: not the matrix the rendered prior was built
with), with the sensors' prior and with the rendered cameras' prior (the same cameras carried to sRGB primaries,
:func:`illumon.camera.primaries.to_srgb_primaries`). Printed per case: the reading's error (MK⁻¹, read − true), its
stated spread, its misfit (``*``: above :data:`~illumon.camera.chart_light.MAX_MISFIT`, refused).

``python tools/chart_output_space.py [--cameras N]`` prints the figures behind
:func:`illumon.camera.calibration._chart_readings`. Development cameras only.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core"), str(ROOT / "benchmarks")]

import rawsim  # noqa: E402
from illumon.camera import chart_light, colourchecker_references  # noqa: E402
from illumon.camera.pipeline import srgb_matrix  # noqa: E402
from illumon.daylight.cie import xy_from_spectrum  # noqa: E402
from illumon.daylight.ohno2013 import cct_duv_from_xy  # noqa: E402
from illumon.simulation import datasets  # noqa: E402
from lightbox import lamp  # noqa: E402
from unmeasured import camera_prior_without  # noqa: E402

LAMPS = ("D65 simulator", "A", "D50 simulator")


def reading(values: np.ndarray, spectra: np.ndarray, prior) -> chart_light.ChartLight | None:  # noqa: ANN001
    """The chart's reading with no misfit limit (the misfit is printed, and judged, here)."""
    limit = chart_light.MAX_MISFIT
    chart_light.MAX_MISFIT = np.inf
    try:
        return chart_light.chart_light_illumon(values, spectra, prior)
    finally:
        chart_light.MAX_MISFIT = limit


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=len(rawsim.DEV_CAMERAS), help="development cameras (all)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    spectra = np.stack(list(colourchecker_references().values()))
    cameras = rawsim.DEV_CAMERAS[: args.cameras]
    print(f"split: development ({len(cameras)} cameras); each prior without the camera's maker; "
          f"'*': misfit above {chart_light.MAX_MISFIT}, refused")
    print(f"{'lamp':14} {'camera':30} " + " ".join(f"{h:>24}" for h in (
        "sensor RGB / sensors", "sensor RGB / rendered", "matrix / sensors", "matrix / rendered")))
    misfits: dict[str, list[float]] = {}
    errors: dict[str, list[float]] = {}
    for name in LAMPS:
        e = lamp(name)
        true = 1e6 / float(cct_duv_from_xy(xy_from_spectrum(e[None]))[0][0])
        for camera in cameras:
            css = datasets.load_camera(camera)
            priors = {"sensors": camera_prior_without(camera), "rendered": camera_prior_without(camera, rendered=True)}
            cells = []
            for output, matrix in (("sensor RGB", None), ("matrix", srgb_matrix(css))):
                h = rawsim.simulate_raw_history(css, e[None], spectra, rng=np.random.default_rng(0), bits=12,
                                                matrix=matrix)
                for label, prior in priors.items():
                    r = reading(h.linear_output[0], spectra, prior)
                    key = f"{output} / {label}"
                    if r is None:
                        cells.append(f"{'none':>24}")
                        continue
                    misfits.setdefault(key, []).append(r.misfit)
                    errors.setdefault(f"{name}: {key}", []).append(r.mired - true)
                    star = "*" if r.misfit > chart_light.MAX_MISFIT else " "
                    cells.append(f"{r.mired - true:+8.1f} ± {r.sd:4.1f} mf {r.misfit:4.2f}{star}")
            print(f"{name:14} {camera:30} " + " ".join(cells), flush=True)
    print("\nmisfit range per output and prior:")
    for key, v in misfits.items():
        print(f"  {key:26} {min(v):.2f}–{max(v):.2f}")
    print("reading error range (MK⁻¹) per lamp, output and prior:")
    for key, v in errors.items():
        print(f"  {key:42} {min(v):+.1f}…{max(v):+.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
