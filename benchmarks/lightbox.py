"""A light booth: the CCT a chart-calibrated camera nobody measured reads, when the booth's lamps are not daylight.

The outside checks found an industrial camera in a lamp light box read a D65 frame with a ColorChecker in view as
17 000–25 000 K (issue 26: "after a chart calibration a D65 lamp reads 5900–7200 K"). This simulator puts that set-up
into the project's own data: a ColorChecker seen by a fixed sensor-RGB camera (``rawsim``, 12-bit, noise) under a light
booth's lamps — CIE FL3.15 (a D65 simulator), A, FL11 (TL84-like), FL2 (cool white), FL3.14 (a D50 simulator),
colour-science's spectra — the chart's 18 colour patches the static scene, the whole chart known in frame 0 (the D65
simulator), fitted as ``illumon fit --known … --primaries camera`` does for a camera registered without
sensitivities. Rows vary which lamps the history holds, so the cause shows: every frame the D65 simulator (control),
one tungsten frame, two fluorescent frames, the whole booth.

**Development** cameras (:data:`rawsim.DEV_CAMERAS`) by default; ``--split score`` runs the held-out cameras
(:data:`rawsim.SCORE_CAMERAS`), to score only. Nothing was chosen on this benchmark. Printed per row:
the D65-simulator frame's CCT (median over cameras, and the range), the median reciprocal-temperature error over
every frame (MK⁻¹, estimated − true: a common shift shows as the same sign on every lamp), the median camera-white
error (degrees) and whether frame 0's 95 % CCT interval holds its truth.

``python benchmarks/lightbox.py [--split dev|score] [--cameras N] [--matrix] [--primaries camera|srgb]
[--reference chart|greys]`` prints the table and writes
``benchmarks/results/lightbox[_score][_matrix][_srgb][_greys].json``. ``--matrix``: the camera's colour matrix to
sRGB on; declared sensor RGB, no sensor explains its chart, which is read with the rendered cameras' prior (the "as
srgb" column: the share of cameras whose chart was).
``--matrix --primaries srgb``: a rendering camera with a fixed D65 balance, declared so. ``--reference greys``: only
the chart's six greys known (a grey card's kind).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core"), str(Path(__file__).resolve().parent)]

import colour  # noqa: E402
import rawsim  # noqa: E402
from illumon.camera import angular_error_deg, colourchecker_references  # noqa: E402
from illumon.camera.pipeline import srgb_matrix  # noqa: E402
from illumon.daylight.cie import xy_from_spectrum  # noqa: E402
from illumon.daylight.ohno2013 import cct_duv_from_xy  # noqa: E402
from illumon.model import fit_scene_model  # noqa: E402
from illumon.observations import Observations  # noqa: E402
from illumon.simulation import datasets  # noqa: E402
from illumon.spectra import WAVELENGTHS  # noqa: E402
from unmeasured import camera_prior_without  # noqa: E402

LAMPS = {"D65 simulator": "FL3.15", "A": "A", "TL84": "FL11", "cool white": "FL2", "D50 simulator": "FL3.14"}
"""The booth's lamps: colour-science's CIE illuminant names."""

HISTORIES = {
    "D65 simulator only": ["D65 simulator"] * 6,
    "+ tungsten": ["D65 simulator", "A", "D65 simulator", "D65 simulator", "D65 simulator", "D65 simulator"],
    "+ two fluorescents": ["D65 simulator", "TL84", "cool white", "D65 simulator", "D65 simulator", "D65 simulator"],
    "the whole booth": ["D65 simulator", "A", "TL84", "cool white", "D50 simulator", "D65 simulator"],
}
"""Each history's frames (frame 0 shows the known chart under the D65 simulator)."""


def lamp(name: str) -> np.ndarray:
    """A lamp's spectrum on illumon's grid."""
    sd = colour.SDS_ILLUMINANTS[LAMPS[name]]
    return np.interp(WAVELENGTHS, sd.wavelengths, sd.values)


def run(camera: str, frames: list[str], seed: int = 0, matrix: bool = False, primaries: str = "camera",
        reference: str = "chart") -> dict:
    """One booth history of ``camera``: its fit's CCTs against the lamps', camera-white errors. ``matrix``: the
    camera applies its colour matrix to sRGB (:func:`illumon.camera.pipeline.srgb_matrix`, as ``rawsim`` does: negative
    values clipped), as an industrial camera with its colour correction on does, and is still
    declared sensor RGB: no sensor of the prior explains its chart (``ChartLight.misfit`` > 1), which is read with
    the rendered cameras' prior instead (``chart_read_as`` "srgb"). ``primaries``:
    as the camera is declared (``srgb`` with ``matrix``: a rendering camera with a fixed D65 balance, declared so).
    ``reference``: what is known in frame 0 — the whole ``chart``, or its six ``greys`` (a grey card's kind)."""
    css = datasets.load_camera(camera)
    refs = colourchecker_references()
    spectra = np.stack(list(refs.values()))
    e = np.stack([lamp(f) for f in frames])
    h = rawsim.simulate_raw_history(css, e, spectra, rng=np.random.default_rng(seed), bits=12,
                                    matrix=srgb_matrix(css) if matrix else None)
    values, white = h.linear_output.copy(), h.true_white
    ids = list(refs) if reference == "chart" else list(refs)[18:]  # the chart's patches 19-24 are its greys
    known = values[:, [list(refs).index(p) for p in ids]].copy()
    known[1:] = np.nan  # the references known in frame 0 only; the chart's colour patches are the scene in every frame
    refs = {p: refs[p] for p in ids}
    obs = Observations([f"f{i}" for i in range(len(frames))], [f"scene{i:02d}" for i in range(18)] + ids,
                       np.concatenate([values[:, :18], known], axis=1), [""] * len(frames))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prior = camera_prior_without(camera)  # the camera under test is never in its prior
        model = fit_scene_model(obs, None, known_reflectances=refs, camera_prior=prior,  # and its mean
                                rendered_camera_prior=camera_prior_without(camera, rendered=True),
                                primaries=primaries)
    res, extra = model.history_estimate
    true = np.array([cct_duv_from_xy(xy_from_spectrum(x[None]))[0][0] for x in e])
    cct = np.asarray(res.cct, dtype=float)
    return {"camera": camera, "frames": frames, "cct": cct.tolist(), "true_cct": true.tolist(),
            "mired_err": (1e6 / cct - 1e6 / true).tolist(),
            "white_err": angular_error_deg(res.white, white).tolist(),
            "chart_read": "chart_level" in model.noise,
            "chart_read_as": model.camera.get("chart_read_as"),
            "camera_mired": model.noise["model_error"].get("camera_mired"),
            "frame0_in_95": bool(extra["cct_lo"][0] <= true[0] <= extra["cct_hi"][0]),
            "transform_diag": np.diag(np.asarray(model.camera["transform"])).tolist()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=None, help="the split's first N cameras (all)")
    ap.add_argument("--split", choices=("dev", "score"), default="dev",
                    help="development cameras (choose on these) or the held-out ones (score only)")
    ap.add_argument("--matrix", action="store_true",
                    help="the camera applies its colour matrix to sRGB and is declared sensor RGB")
    ap.add_argument("--primaries", choices=("camera", "srgb"), default="camera",
                    help="as the camera is declared (srgb: with --matrix, a rendering camera declared so)")
    ap.add_argument("--reference", choices=("chart", "greys"), default="chart",
                    help="known in frame 0: the whole chart, or its six greys (a grey card's kind)")
    ap.add_argument("--out", default=None, help="default benchmarks/results/lightbox[_score][_matrix][_srgb][_greys].json")
    args = ap.parse_args(argv)
    tag = (("_score" if args.split == "score" else "") + ("_matrix" if args.matrix else "")
           + ("_srgb" if args.primaries == "srgb" else "") + ("_greys" if args.reference == "greys" else ""))
    out = args.out or str(ROOT / "benchmarks" / "results" / f"lightbox{tag}.json")
    cameras = list((rawsim.DEV_CAMERAS if args.split == "dev" else rawsim.SCORE_CAMERAS)[: args.cameras])
    print(f"split: {'development' if args.split == 'dev' else 'score (held out: scored, nothing chosen)'} "
          f"({len(cameras)} cameras: {', '.join(cameras)}); {args.reference} known in frame 0 "
          "(D65 simulator, "
          f"FL3.15, 6504 K); {'colour matrix to sRGB, ' if args.matrix else ''}declared "
          f"{'sensor RGB' if args.primaries == 'camera' else 'sRGB'}, no sensitivities")
    print(f"{'history':22} {'frame 0 CCT K: median (range)':32} {'MK⁻¹ err, all frames':>20} {'white °':>8} "
          f"{'f0 in 95 %':>10} {'chart read':>10} {'as srgb':>8}")
    rows = []
    for name, frames in HISTORIES.items():
        got = [run(c, frames, matrix=args.matrix, primaries=args.primaries, reference=args.reference)
               for c in cameras]
        rows.append({"history": name, "results": got})
        f0 = np.array([g["cct"][0] for g in got])
        mired = np.concatenate([g["mired_err"] for g in got])
        white = np.concatenate([g["white_err"] for g in got])
        inside = np.mean([g["frame0_in_95"] for g in got])
        read = np.mean([g["chart_read"] for g in got])
        rendered = np.mean([g["chart_read_as"] == "srgb" for g in got])
        print(f"{name:22} {np.median(f0):8.0f} ({f0.min():.0f}–{f0.max():.0f}){'':9} {np.median(mired):+20.1f} "
              f"{np.median(white):8.2f} {inside:10.2f} {read:10.2f} {rendered:8.2f}")
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps({"split": args.split, "cameras": cameras, "matrix": args.matrix,
                                     "primaries": args.primaries, "reference": args.reference, "rows": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
