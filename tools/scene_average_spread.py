"""Spread of a scene's average colour around the mean measured surface's (``SCENE_AVERAGE_SD`` of
``illumon.camera.calibration``), on the development split only (``benchmarks/rawsim.py``): 14 development cameras,
20 scenes each of ten surfaces from the five measured reflectance sets under development Granada runs.

    python tools/scene_average_spread.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import rawsim  # noqa: E402
from illumon.priors import reflectance_basis  # noqa: E402
from illumon.simulation import datasets  # noqa: E402


def log_chroma(w: np.ndarray) -> np.ndarray:
    return np.log(w[:, [0, 2]] / w[:, 1:2])


def main() -> None:
    rb = reflectance_basis()
    mean_surface = np.clip(rb.functions @ rb.prior_mean, 0, 1)
    out = []
    for i, cam in enumerate(rawsim.DEV_CAMERAS):
        css = datasets.load_camera(cam)
        for s in range(20):
            rng = np.random.default_rng(900 + 50 * i + s)
            e = rawsim.daylight_run("dev", 30, rng)
            r = rawsim.draw_reflectances("dev", 10, rng)
            scene = np.einsum("fl,pl,lc->fpc", e, r, css).mean(1)
            out.append((log_chroma(scene) - log_chroma((e * mean_surface) @ css)).mean(0))
    d = np.array(out)
    print(f"{len(d)} scenes: mean {d.mean(0).round(3)}, sd {d.std(0).round(3)} (log r/g, log b/g)")


if __name__ == "__main__":
    main()
