"""The spread of a rendered (sRGB-primaries) camera's history-mean white around grey, from measured daylight.

A camera whose output is white-balanced for daylight (a D65 preset, or an auto white balance that neutralises the
scene's light) shows a history's light, on average, near grey. How far from grey: the geometric-mean white of a run of
consecutive Granada daylight spectra (one run ≈ one day at one site; ``illumon.simulation.datasets``) through the linear-sRGB
colour-matching functions balanced for D65 (:func:`illumon.camera.primaries.srgb_sensitivities`), in log r/g and b/g.
The development half of the runs is used (runs of 40 spectra, even-numbered runs), as for every shipped constant.

``python tools/srgb_balance_spread.py`` prints the figures behind
:data:`illumon.camera.calibration.SRGB_BALANCE_SD`.
"""

from __future__ import annotations

import numpy as np
from illumon.camera.primaries import srgb_sensitivities
from illumon.simulation.datasets import load_granada_daylight

RUN = 40


def main() -> None:
    _, spectra = load_granada_daylight()
    c = srgb_sensitivities()
    white = spectra @ c
    chroma = np.log(white[:, [0, 2]] / white[:, 1:2])
    runs = [chroma[i:i + RUN] for i in range(0, len(chroma) - RUN + 1, RUN)][::2]  # development: even runs
    means = np.array([r.mean(axis=0) for r in runs])
    within = np.concatenate([r - r.mean(axis=0) for r in runs])
    print(f"{len(runs)} development runs of {RUN} spectra")
    print(f"run-mean white, log r/g and b/g: mean {means.mean(axis=0).round(4)}, sd {means.std(axis=0).round(4)}, "
          f"rms about grey {np.sqrt((means**2).mean(axis=0)).round(4)}, pooled {np.sqrt((means**2).mean()):.4f}")
    print(f"within a run: sd {within.std(axis=0).round(4)}")
    print(f"single spectra about grey: rms {np.sqrt((chroma**2).mean(axis=0)).round(4)}")


if __name__ == "__main__":
    main()
