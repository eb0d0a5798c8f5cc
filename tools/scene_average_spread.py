"""Spread of a scene's average colour around the mean measured surface's (``SCENE_AVERAGE_SD`` of
``illumon.camera.calibration``), on the development split only (``benchmarks/rawsim.py``): 14 development cameras,
20 scenes each of ten surfaces from the five measured reflectance sets under development Granada runs. Also the
scenes' chromaticity spread (:attr:`illumon.priors.scene_average.SceneAverage.spread`) as sensor RGB and as rendered
output (each camera's colour matrix to sRGB primaries, as ``rawsim.rendering`` applies it):
``illumon.priors.scene_average.SURFACE_SPREAD`` and ``SCENE_SPREAD``; and their weakest channel
(:func:`illumon.camera.primaries.weakest_channel`, ``WEAKEST_CHANNEL``).

    python tools/scene_average_spread.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import rawsim  # noqa: E402
from illumon.camera.primaries import srgb_matrix_for, weakest_channel  # noqa: E402
from illumon.priors import reflectance_basis  # noqa: E402
from illumon.priors.scene_average import scene_average_evidence  # noqa: E402
from illumon.simulation import datasets  # noqa: E402


def log_chroma(w: np.ndarray) -> np.ndarray:
    return np.log(w[:, [0, 2]] / w[:, 1:2])


def main() -> None:
    rb = reflectance_basis()
    mean_surface = np.clip(rb.functions @ rb.prior_mean, 0, 1)
    out, spread, weakest = [], {"camera": [], "srgb": []}, {"camera": [], "srgb": []}
    for i, cam in enumerate(rawsim.DEV_CAMERAS):
        css = datasets.load_camera(cam)
        matrix = srgb_matrix_for(css).T  # the camera's colour matrix to sRGB, as rawsim.rendering's preset applies it
        for s in range(20):
            rng = np.random.default_rng(900 + 50 * i + s)
            e = rawsim.daylight_run("dev", 30, rng)
            r = rawsim.draw_reflectances("dev", 10, rng)
            values = np.einsum("fl,pl,lc->fpc", e, r, css)
            scene = values.mean(1)
            seen = np.ones(values.shape[:2], dtype=bool)
            rendered = np.clip(values @ matrix.T, 0.0, None)
            spread["camera"].append(scene_average_evidence(values, seen).spread)
            spread["srgb"].append(scene_average_evidence(rendered, seen).spread)
            weakest["camera"].append(weakest_channel(values))
            weakest["srgb"].append(weakest_channel(rendered))
            out.append((log_chroma(scene) - log_chroma((e * mean_surface) @ css)).mean(0))
    d = np.array(out)
    print(f"{len(d)} scenes: mean {d.mean(0).round(3)}, sd {d.std(0).round(3)} (log r/g, log b/g)")
    for space, v in spread.items():
        print(f"chromaticity spread, {space}: median {np.median(v):.3f} (10–90 %: {np.percentile(v, 10):.3f}–"
              f"{np.percentile(v, 90):.3f}; 1–99 %: {np.percentile(v, 1):.3f}–{np.percentile(v, 99):.3f}; "
              f"range {np.min(v):.3f}–{np.max(v):.3f}; log sd {np.std(np.log(v)):.3f})")
    for space, v in weakest.items():
        print(f"weakest channel, {space}: median {np.median(v):.3f} (1 %: {np.percentile(v, 1):.3f}; smallest "
              f"{np.min(v):.3f}; below 0.03: {np.sum(np.asarray(v) < 0.03)} of {len(v)})")


if __name__ == "__main__":
    main()
