"""How far an unmeasured camera leaves the CCT reading off, and whether the stated 95 % intervals hold it.

A camera nobody measured is modelled as the mean measured camera times a 3 × 3 transform ``T`` that a reference (grey
card, ColorChecker) or the history pins. ``T`` pins the camera *white* of a reference frame, but not the light's
temperature: a redder camera under bluer light shows the same chart, so the CCT keeps the spread of the cameras'
whites along the daylight locus. This tool measures that spread on simulated histories (``benchmarks/rawsim.py``
splits: development or score cameras, development reflectances and Granada runs): frame 0 is lit by CIE D65 (a light
box) and shows the reference, the other frames by a Granada run; the prior is the mean of the other manufacturers'
cameras (the camera under test is never in it). Printed per case: the mired error of frame 0 and of all frames, the
stated standard deviation (from the 95 % CCT interval), the RMS of their ratio (z) and the 95 % intervals' coverage.

``python tools/camera_mired_spread.py [--split dev|score] [--seeds N] [--primaries camera|srgb] [--matrix]
[--cases chart,grey,none]`` prints the figures behind :data:`illumon.camera.calibration.CAMERA_MIRED_SD`
(``--matrix``: declared sensor RGB, rendered through the camera's colour matrix, its chart read as rendered: the
``"chart read as srgb"`` entry).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import colour
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core"), str(ROOT / "benchmarks")]

import rawsim  # noqa: E402
from confidence_calibration import extra_for_unit_z  # noqa: E402
from illumon.camera.pipeline import srgb_matrix  # noqa: E402
from illumon.camera.references import colourchecker_references, grey_card_reference  # noqa: E402
from illumon.model.fit import fit_scene_model  # noqa: E402
from illumon.model.intervals import Z95, mired_sd_from_interval  # noqa: E402
from illumon.observations import Observations  # noqa: E402
from illumon.simulation import datasets  # noqa: E402
from illumon.spectra import GRID  # noqa: E402
from unmeasured import camera_prior_without  # noqa: E402

FRAMES, PATCHES = 24, 10
D65_MIRED = 1e6 / 6504.0


def run(camera: str, case: str, seed: int, primaries: str, matrix: bool = False) -> dict:
    rng = np.random.default_rng(seed)
    css = datasets.load_camera(camera)
    e = rawsim.daylight_run("dev", FRAMES, rng)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(GRID).values
    e[0] = d65 / d65.max() * e[0].max()
    scene = rawsim.draw_reflectances("dev", PATCHES, rng)
    known = {"chart": colourchecker_references(), "grey": grey_card_reference(), "none": {}}[case]
    refl = np.concatenate([scene, np.stack(list(known.values()))]) if known else scene
    v = np.einsum("fl,pl,lc->fpc", e, refl, css)
    if primaries == "srgb":  # a rendered camera: daylight preset and its matrix to sRGB, negatives clipped
        matrix, _ = rawsim.rendering(css, e, scene, "preset")
        v = np.clip(v @ matrix.T, 0.0, None)
    elif matrix:  # declared sensor RGB but rendered through its colour matrix (a chart read as rendered)
        v = np.clip(v @ srgb_matrix(css).T, 0.0, None)
    v = v / v.max() * 0.9 * np.exp(0.1 * rng.standard_normal((FRAMES, 1, 1)))
    v = np.clip(v * (1 + 0.005 * rng.standard_normal(v.shape)), 0, 1)
    v[1:, PATCHES:] = np.nan
    ids = [f"p{j:02d}" for j in range(PATCHES)] + list(known)
    obs = Observations([f"f{i:03d}" for i in range(FRAMES)], ids, v, [""] * FRAMES)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if primaries == "srgb":
            model = fit_scene_model(obs, None, known_reflectances=known or None, primaries="srgb")
        else:
            model = fit_scene_model(obs, None, known_reflectances=known or None,  # the camera in neither prior
                                    camera_prior=camera_prior_without(camera),  # nor its mean
                                    rendered_camera_prior=camera_prior_without(camera, rendered=True))
    res, extra = model.history_estimate
    true_mired = np.array([1e6 / colour.uv_to_CCT(colour.UCS_to_uv(colour.XYZ_to_UCS(
        colour.sd_to_XYZ(colour.SpectralDistribution(s, GRID.range())))), method="Ohno 2013")[0] for s in e])
    err = 1e6 / res.cct - true_mired
    sd = mired_sd_from_interval(extra["cct_lo"], extra["cct_hi"])
    return {"err": err, "sd": sd, "true_mired": true_mired, "cct": res.cct, "cct_lo": extra["cct_lo"],
            "cct_hi": extra["cct_hi"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=("dev", "score"), default="dev")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--primaries", choices=("camera", "srgb"), default="camera")
    ap.add_argument("--matrix", action="store_true",
                    help="declared camera, rendered through its colour matrix to sRGB (its chart read as rendered)")
    ap.add_argument("--cases", default="chart,grey,none")
    a = ap.parse_args()
    cams = rawsim.DEV_CAMERAS if a.split == "dev" else rawsim.SCORE_CAMERAS
    print(f"cameras: {a.split} ({len(cams)}); reflectances and daylight: development; primaries: {a.primaries} "
          "(camera: prior without the camera's maker; srgb: rendered through its matrix, the sRGB prior)")
    print(f"{'case':6s} {'frame':6s} {'err rms':>8s} {'stated sd':>9s} {'z rms':>6s} {'in 95 %':>7s} {'extra for z=1':>13s}")
    for case in a.cases.split(","):
        rows = [run(c, case, 1000 * s + i, a.primaries, a.matrix) for s in range(a.seeds) for i, c in enumerate(cams)]
        for which, sl in (("0", slice(0, 1)), ("all", slice(None))):
            err = np.concatenate([r["err"][sl] for r in rows])
            sd = np.concatenate([r["sd"][sl] for r in rows])
            ok = np.isfinite(err) & np.isfinite(sd)
            z = err[ok] / sd[ok]
            extra = extra_for_unit_z(err[ok], sd[ok])
            print(f"{case:6s} {which:6s} {np.sqrt(np.mean(err[ok]**2)):8.2f} {np.median(sd[ok]):9.2f} "
                  f"{np.sqrt(np.mean(z**2)):6.2f} {np.mean(np.abs(z) < Z95):7.2f} {extra:13.1f}")


if __name__ == "__main__":
    main()
