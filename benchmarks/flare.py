"""Veiling glare in the real photographs: each frame's additive offset, read off its six grey patches.

A chart's grey patches 19–24 have known, nearly flat reflectances ``ρ`` (0.03…0.89). Without glare each channel of
a frame is ``a · ρ`` (the light times the exposure); light scattered in the lens adds the same ``o`` to every patch,
so a straight-line fit ``a · ρ + o`` per channel gives the frame's offset. ``o`` is printed as a fraction of the
frame's mean value over the 18 chromatic patches (the scene the model sees without a reference), the quantity
:func:`rawsim.flare_draw` draws (its root mean square) and :data:`illumon.camera.formation.FLARE_SD` is chosen from
(its spread from frame to frame).

A second table asks whether the chart's colour patches see the light its greys see. With each channel's offset and
slope from the greys' line, a colour patch's summed value is held against what its known reflectance gives through
the prior camera (the mean measured camera) under D65: ``log(measured / expected)`` (:func:`against_greys`). Any
camera and any light change that by a little (the camera's and the light's spectra weigh the patch's reflectance
otherwise than the prior's and D65's); the floor printed beside it is the same statistic for the development
cameras (:data:`rawsim.DEV_CAMERAS`) under ten development Granada daylights each and under five CIE lamps, rendered
without noise. Per photograph: the median and largest deviation over the 18 colour patches, and a least-squares fit
of the deviations on the patch's reflectance at 700 nm (the long-wave end of the model's grid: light the model does
not carry, past 700 nm, falls most on patches that reflect most there) and on its row in the chart (rows 1–3 above
the greys' row 4: light falling unevenly across the chart).

Data: the development photographs of ``benchmarks/real.py`` (``sony-raw``: ``../shared/data/real/sony-dolp``,
demosaicked sensor RGB) and the development cameras and daylights. Nothing is chosen on either, nor on the scoring
photographs (held by outside checks).

``python benchmarks/flare.py`` prints the tables and writes ``benchmarks/results/flare.json``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import real  # noqa: E402

LAMPS = ("A", "FL2", "FL11", "LED-B1", "LED-B3")
"""colour-science's CIE lamps for the floor of :func:`against_greys`: tungsten, two fluorescents, two LEDs."""

DAYLIGHTS_PER_CAMERA = 10
"""Development Granada daylights drawn per development camera for that floor."""


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


def effective_reflectances(css: np.ndarray, light: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """Each reflectance's value relative to a perfect white's (P × 3), through sensitivities ``css`` (61 × 3) under
    ``light`` (61,)."""
    from illumon.camera.formation import camera_white, render

    return render(css, light, spectra) / camera_white(css, light)


def against_greys(values: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """The 18 colour patches' ``log(measured / expected)`` (18,) in one photograph of the chart (``values`` 24 × 3,
    chart order): each channel less its offset and divided by its slope from the greys' line
    (:func:`grey_offsets`), summed over channels, against ``expected`` (24 × 3: :func:`effective_reflectances`
    through the prior camera under D65)."""
    off, slope, _ = grey_offsets(values[None])
    idx = [real.ALL.index(p) for p in real.SCENE]
    measured = np.clip((values[idx] - off[0]) / slope[0], 1e-6, None).sum(axis=1)
    return np.log(measured / expected[idx].sum(axis=1))


def chart_spectra() -> np.ndarray:
    """The ColorChecker's reflectances (24 × 61, in the chart's order, :data:`real.ALL`)."""
    from illumon.priors.surfaces import colourchecker_reflectances

    return colourchecker_reflectances()[1]


def _cie_light(name: str) -> np.ndarray:
    """A colour-science illuminant on the model's grid (61,)."""
    import colour
    from illumon.spectra import WAVELENGTHS

    sd = colour.SDS_ILLUMINANTS[name]
    return np.interp(np.asarray(WAVELENGTHS, dtype=float), sd.wavelengths, sd.values)


def consistency_floor(expected: np.ndarray, spectra: np.ndarray) -> dict:
    """:func:`against_greys` on noiseless charts of the development cameras: under :data:`DAYLIGHTS_PER_CAMERA`
    development daylights each, and under each of :data:`LAMPS`. Per light kind, the charts' medians (5–95 % and
    extremes) and their largest absolute deviations (median, largest)."""
    import rawsim
    from illumon.simulation import datasets

    pool = rawsim.daylight_pool("dev")
    rng = np.random.default_rng(0)
    kinds = {"daylight": [], **{lamp: [] for lamp in LAMPS}}
    lamps = {lamp: _cie_light(lamp) for lamp in LAMPS}
    for cam in rawsim.DEV_CAMERAS:
        css = datasets.load_camera(cam)
        for k in rng.choice(len(pool), DAYLIGHTS_PER_CAMERA, replace=False):
            kinds["daylight"].append(against_greys(0.8 * effective_reflectances(css, pool[k], spectra), expected))
        for lamp, light in lamps.items():
            kinds[lamp].append(against_greys(0.8 * effective_reflectances(css, light, spectra), expected))
    out = {}
    for kind, devs in kinds.items():
        d = np.array(devs)
        med, worst = np.median(d, axis=1), np.abs(d).max(axis=1)
        out[kind] = {"charts": len(d), "median_p5": float(np.percentile(med, 5)), "median_p95": float(np.percentile(med, 95)),
                     "median_min": float(med.min()), "median_max": float(med.max()),
                     "largest_median": float(np.median(worst)), "largest_max": float(worst.max())}
    return out


def trend(dev: np.ndarray, spectra: np.ndarray) -> dict:
    """Least-squares fit of the colour patches' deviations (18,) on their reflectance at 700 nm and their row in the
    chart (1–3): the coefficients and the share of the deviations' variance explained."""
    idx = [real.ALL.index(p) for p in real.SCENE]
    design = np.c_[np.ones(len(idx)), spectra[idx, -1], np.array(idx) // 6 + 1]
    coef, *_ = np.linalg.lstsq(design, dev, rcond=None)
    resid = dev - design @ coef
    return {"intercept": float(coef[0]), "per_reflectance_at_700nm": float(coef[1]), "per_row": float(coef[2]),
            "explained": float(1.0 - resid.var() / dev.var())}


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
    from illumon.camera.calibration import prior_sensitivities

    spectra = chart_spectra()
    expected = effective_reflectances(prior_sensitivities(), _cie_light("D65"), spectra)
    print()
    print("the colour patches against the greys' light: log(measured / expected), expected = the known reflectance "
          "through the prior camera under D65, each channel less its greys' offset and over its greys' slope")
    print(f"{'frame':9} {'median':>7} {'largest':>8} {'on R(700 nm)':>13} {'per row':>8} {'explained':>9}")
    consistency = []
    for i, name in enumerate(s.frames):
        dev = against_greys(s.values[i], expected)
        t = trend(dev, spectra)
        print(f"{name:9} {np.median(dev):7.2f} {np.max(np.abs(dev)):8.2f} {t['per_reflectance_at_700nm']:13.2f} "
              f"{t['per_row']:8.2f} {t['explained']:9.2f}")
        consistency.append({"frame": name, "median": float(np.median(dev)), "largest": float(np.max(np.abs(dev))),
                            "deviations": dev.tolist(), **t})
    floor = consistency_floor(expected, spectra)
    print(f"floor: noiseless charts, {floor['daylight']['charts']} development camera × daylight pairs and the "
          f"{floor[LAMPS[0]]['charts']} development cameras under each lamp (development data; nothing chosen on it)")
    print(f"{'light':9} {'median 5–95 %':>15} {'(extremes)':>15} {'largest: median, max':>21}")
    for kind, f in floor.items():
        print(f"{kind:9} {f['median_p5']:7.2f} {f['median_p95']:6.2f}  ({f['median_min']:5.2f} {f['median_max']:5.2f})"
              f" {f['largest_median']:10.2f} {f['largest_max']:6.2f}")
    out = Path(__file__).with_name("results")
    out.mkdir(exist_ok=True)
    (out / "flare.json").write_text(json.dumps({
        "split": "development (sony-dolp; development cameras and daylights for the floor)", "frames": rows,
        "rms": rms, "spread": spread[0], "spread_ddof1": spread[1], "chart_consistency": consistency,
        "chart_consistency_floor": floor}, indent=1))
    print(f"wrote {out / 'flare.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
