"""Veiling glare in the real photographs: each frame's additive offset, read off its six grey patches.

A chart's grey patches 19–24 have known, nearly flat reflectances ``ρ`` (0.03…0.89). Without glare each channel of
a frame is ``a · ρ`` (the light times the exposure); light scattered in the lens adds the same ``o`` to every patch,
so a straight-line fit ``a · ρ + o`` per channel gives the frame's offset. ``o`` is printed as a fraction of the
frame's mean value over the 18 chromatic patches (the scene the model sees without a reference), the quantity
:func:`rawsim.flare_draw` draws (its root mean square) and :data:`illumon.camera.formation.FLARE_SD` is chosen from
(its spread from frame to frame).

Data: the development photographs of ``benchmarks/real.py`` (``sony-raw``: ``../shared/data/real/sony-dolp``,
demosaicked sensor RGB). Nothing is chosen on the scoring photographs (held by outside checks).

``python benchmarks/flare.py`` prints the table and writes ``benchmarks/results/flare.json``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import real  # noqa: E402


def grey_offsets(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame and channel: the offset ``o`` and slope ``a`` of ``a · ρ + o`` over the grey patches 19–24
    (``values`` F × 24 × 3 in chart order), and the worst residual of that line (F × 3 each)."""
    from illumon.camera.references import colourchecker_references

    refs = colourchecker_references()
    rho = np.array([np.mean(refs[p]) for p in real.GREYS])
    design = np.c_[rho, np.ones_like(rho)]
    idx = [real.ALL.index(p) for p in real.GREYS]
    f = values.shape[0]
    off, slope, resid = (np.empty((f, 3)) for _ in range(3))
    for i in range(f):
        for c in range(3):
            y = values[i, idx, c]
            (a, o), *_ = np.linalg.lstsq(design, y, rcond=None)
            off[i, c], slope[i, c] = o, a
            resid[i, c] = np.max(np.abs(y - design @ [a, o]))
    return off, slope, resid


def main() -> int:
    data = real.shared_data()
    if not (data / "real" / "sony-dolp").is_dir():
        print(f"skipped: the real photographs ({data / 'real'}) are not available")
        return 0
    s = real.sony_raw(data)
    off, slope, resid = grey_offsets(s.values)
    level = np.nanmean(s.values[:, [real.ALL.index(p) for p in real.SCENE]], axis=1)
    frac = off / level
    print("split: development (sony-dolp, sensor RGB); the scoring photographs are held by outside checks")
    print(f"{'frame':9} {'offset r g b (of white level)':>30} {'÷ frame mean r g b':>22} {'÷ white patch':>13} "
          f"{'line resid':>10}")
    rows = []
    for i, name in enumerate(s.frames):
        white = s.values[i, real.ALL.index("chart:19"), 1]
        print(f"{name:9} {off[i, 0]:10.4f}{off[i, 1]:10.4f}{off[i, 2]:10.4f} {frac[i, 0]:7.3f}{frac[i, 1]:7.3f}{frac[i, 2]:7.3f}"
              f" {off[i, 1] / white:13.3f} {np.max(resid[i]):10.4f}")
        rows.append({"frame": name, "offset": off[i].tolist(), "of_frame_mean": frac[i].tolist(),
                     "of_white_patch_green": float(off[i, 1] / white), "line_residual_max": float(np.max(resid[i]))})
    rms = float(np.sqrt(np.mean(frac**2)))
    spread = {ddof: float(np.sqrt(np.mean(np.var(frac, axis=0, ddof=ddof)))) for ddof in (0, 1)}
    print(f"root mean square of the offset ÷ frame mean: {rms:.3f} (the glare rawsim.flare_draw draws, FLARE_RMS)")
    print(f"its spread about the frames' mean (pooled over channels): {spread[0]:.3f}, {spread[1]:.3f} with one degree "
          "of freedom taken (illumon.camera.formation.FLARE_SD: a history's mean glare is learned into its reflectances)")
    out = Path(__file__).with_name("results")
    out.mkdir(exist_ok=True)
    (out / "flare.json").write_text(json.dumps({"split": "development (sony-dolp)", "frames": rows, "rms": rms,
                                               "spread": spread[0], "spread_ddof1": spread[1]}, indent=1))
    print(f"wrote {out / 'flare.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
