"""Cameras nobody measured (issue 15): camera-white error with a grey card, a chart, or no reference, beside gray-world.

Each case is a fixed camera's history of 30 frames × 10 static patches under measured Granada daylight. The camera's
sensitivities are never given to illumon: its prior is the mean of the measured cameras of *other manufacturers*
(so a Canon is never scored with a prior that has seen a Canon). Cases:

* ``grey``         — raw (linear) output; a flat grey card visible in the first frame;
* ``chart+matrix`` — output through the camera's fixed raw → sRGB colour matrix (:func:`illumon.camera.pipeline.srgb_matrix`),
  a ColorChecker visible in the first frame;
* ``none``         — raw output, no reference;
* ``none+matrix``  — matrix output, no reference (reported, no goal);
* ``none+rendered``, ``grey+rendered`` — *rendered* output, what IP, surveillance and phone cameras deliver (issue
  26): a daylight-preset white balance and a white-preserving colour matrix to sRGB primaries
  (:func:`illumon.camera.primaries.srgb_matrix_for`), fitted with ``primaries="srgb"``;
* ``chart+rendered`` — rendered output with a ColorChecker in the first frame (the calibration an installer of a
  processed camera can do);
* ``none+awb``, ``grey+awb``, ``chart+awb`` — rendered output whose camera rebalances every frame (gray-world gains on
  the raw values before the matrix, as an auto white balance does); the truth is the output white *with* those gains;
* ``none+lamps``   — rendered output (daylight preset) of a history lit only by lamps (:func:`rawsim.lamp_run`) over a
  man-made scene of pale surfaces (:func:`rawsim.pale`), as the real lamp-lit scenes of ``benchmarks/lamps.py``:
  goal within 1.5 × gray-world (issue 28);
* ``raw+lamps``    — the same lamp-lit light and pale scene seen as raw (sensor RGB) output, fitted with the default
  ``primaries="camera"``: every sensor-RGB history had been daylight, so a camera nobody measured was assumed to show
  the daylight whites of the measured cameras, the assumption that sent the real lamp-lit scenes read as sensor RGB
  6–16° off (``python benchmarks/lamps.py --primaries camera``). Same goal;
* ``pale``         — raw output of a daylight history over pale surfaces (:func:`rawsim.pale`: walls, roads, table
  tops), no reference (reported, no goal);
* ``room``         — raw output of a daylight history over a colourful room whose surfaces average grey
  (:func:`rawsim.grey_average`, what the real chart-free photographs showed), no reference (reported, no goal);
* ``room+lamps``   — that room lit only by lamps (:func:`rawsim.lamp_run`), raw output, no reference: what the real
  chart-free rooms are (indoor light, ceiling lamps and windows: ``benchmarks/real_pairs.py``). Every simulated room
  had been daylit, every lamp-lit history a pale scene: the assumption that hid why the real rooms read their fit's
  level 0.24 (log r/g, b/g) from their scene average and were judged daylight (the level's lamp-lit probability
  0.31–0.49).
  Reported, no goal: the room averages grey by construction, so gray-world's error is no yardstick.

``--measured`` gives the camera's own sensitivities to every case without a reference and without rendering (``none``,
``none+matrix``, ``raw+lamps``, ``pale``, ``room``, ``room+lamps``; the others are skipped): the measured sensor's
figures beside the unmeasured one's.

The matrix cases model a fixed colour matrix *without* the camera's own white balance; the real photographs showed
that a processed camera's output is balanced too (``benchmarks/real.py``), which the rendered cases add.

Two independent simulators render every case: ``illumon`` (:mod:`illumon.simulation.simulate`, Gaussian noise on patch means,
log-normal auto-exposure) and ``rawsim`` (``benchmarks/rawsim.py``: photon shot noise with a conversion gain, read
noise, black level with clipping at 0, 12-bit quantisation, third-stop auto-exposure). Cameras, surfaces and
daylight come from ``rawsim``'s splits: ``--split dev`` (Nikon and Point Grey cameras, the five measured reflectance
sets, Granada 0–1299) is what anything was chosen on; ``--split score`` (Canon, Hasselblad, Pentax, Phase One;
ColorChecker and CIE TCS surfaces; Granada 1300–2599) is what the README reports. The error is the angle between
estimated and true camera white in the observations' own RGB space (what camera software applies gains to),
over every frame. ``coverage`` is the fraction of frames within 1° beside the mean ``confidence`` the estimates
claimed for it; ``CCT95`` the fraction of frames whose light's CCT (the rendered spectrum's, Ohno 2013) lies in the
estimate's 95 % interval, ``MK⁻¹`` the RMS error of the reciprocal temperature (for the lamp-lit case, the nearest
daylight's temperature against the lamps': reported, not a goal).

    python benchmarks/unmeasured.py [--split score] [--seeds 2] [--quick] [--cases grey,none]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from datetime import datetime, timedelta, timezone
from functools import lru_cache
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import rawsim  # noqa: E402
from illumon.camera import (  # noqa: E402
    angular_error_deg,
    camera_white,
    colourchecker_references,
    formation,
    grey_card_reference,
)
from illumon.camera.calibration import camera_mired_key  # noqa: E402
from illumon.camera.pipeline import srgb_matrix  # noqa: E402
from illumon.camera.primaries import to_srgb_primaries  # noqa: E402
from illumon.model import fit_scene_model  # noqa: E402
from illumon.model.intervals import mired_sd_from_interval  # noqa: E402
from illumon.observations import Observations  # noqa: E402
from illumon.priors import CameraPrior, build_camera_prior  # noqa: E402
from illumon.retrieval.common import grey_world  # noqa: E402
from illumon.simulation import (
    datasets,  # noqa: E402
    simulate_history,  # noqa: E402
)

CASES = ("grey", "chart+matrix", "none", "none+matrix", "none+rendered", "grey+rendered", "chart+rendered", "none+awb",
         "grey+awb", "chart+awb", "none+lamps", "raw+lamps", "pale", "room", "room+lamps")
GOALS = {"grey": (1.0, 3.0), "chart+matrix": (1.0, 3.0), "none": (2.5, None)}
RENDERED = ("rendered", "awb", "none+lamps")
FRAMES, PATCHES = 30, 10


@lru_cache(maxsize=8)
def camera_prior_without(camera: str, rendered: bool = False) -> CameraPrior:
    """The camera prior (:class:`illumon.priors.CameraPrior`) of the measured cameras of every other manufacturer:
    what a chart's reading of its frame's light integrates the camera over (:mod:`illumon.camera.chart_light`).
    ``rendered``: those cameras carried to sRGB primaries (:func:`illumon.camera.primaries.to_srgb_primaries`), as
    :func:`illumon.priors.rendered_camera_prior` is built."""
    own = rawsim.manufacturer(camera)
    cams = [datasets.load_camera(n) for n in datasets.camera_names() if rawsim.manufacturer(n) != own]
    return build_camera_prior([to_srgb_primaries(c) for c in cams] if rendered else cams)


def prior_mean_without(camera: str) -> np.ndarray:
    """Mean max-normalised sensitivities of the measured cameras of every other manufacturer (a copy of
    :func:`camera_prior_without`'s mean)."""
    return camera_prior_without(camera).mean.copy()


def _light(camera: str, case: str, seed: int) -> tuple[str, np.random.Generator, np.ndarray]:
    """The split of ``camera``, the history's generator and the light of its frames (F × grid): the first draw of
    ``seed``, which :func:`render` continues with the scene and the camera."""
    split = "score" if camera in rawsim.SCORE_CAMERAS else "dev"
    rng = np.random.default_rng(seed)
    e = rawsim.lamp_run(FRAMES, rng) if case.endswith("lamps") else rawsim.daylight_run(split, FRAMES, rng)
    return split, rng, e


def render(sim: str, camera: str, case: str, seed: int, flare: bool = False) -> tuple[Observations, np.ndarray, dict]:
    """Observations (scene patches + references in frame 0), the true output-space white (F × 3), references.
    ``flare``: every frame gets veiling glare (:func:`rawsim.flare_draw`, from a generator of its own: the history
    is otherwise the same)."""
    split, rng, e = _light(camera, case, seed)
    glare = rawsim.flare_draw(FRAMES, np.random.default_rng([seed, 0xF1A2E])) if flare else None
    css = datasets.load_camera(camera)
    scene = rawsim.draw_reflectances(split, PATCHES, rng)
    if case.startswith("room"):
        scene = rawsim.grey_average(scene)
    elif case.endswith("lamps") or case == "pale":
        scene = rawsim.pale(scene)
    known = grey_card_reference() if case.startswith("grey") else colourchecker_references() if case.startswith("chart") else {}
    refl = np.concatenate([scene, np.stack(list(known.values()))]) if known else scene
    matrix = srgb_matrix(css) if case.endswith("matrix") else None
    rendered = case.endswith(RENDERED)
    gains = None
    if rendered:
        matrix, gains = rawsim.rendering(css, e, scene, "auto" if case.endswith("awb") else "preset")
    if sim == "rawsim":
        prof = rawsim.camera_profile(camera, rng=rng)
        h = rawsim.simulate_raw_history(
            css, e, refl, rng=rng, bits=12, conversion_gain=prof["conversion_gain"], read_noise_e=prof["read_noise_e"],
            black_level=prof["black_level"], full_well_e=prof["full_well_e"], adc_bits=prof["adc_bits"], matrix=matrix,
            applied_gains=gains, flare=glare,
        )
        values, white = h.linear_output.copy(), h.true_white
        if gains is not None:
            white = (h.true_white_raw * gains) @ matrix.T
    else:
        h = simulate_history(css, e, refl, rng=rng)
        values = h.observations.values.copy()
        white = camera_white(css, e)
        if glare is not None:  # light scattered in the lens: a fraction of the frame's mean region in every region
            values = values + glare[:, None, None] * np.nanmean(values, axis=1, keepdims=True)
        if gains is not None:
            values, white = values * gains[:, None, :], white * gains
        if matrix is not None:  # a camera clips what its matrix makes negative
            values, white = np.clip(values @ matrix.T, 0.0, None), white @ matrix.T
    values[1:, PATCHES:] = np.nan  # references only in the first frame
    patches = [f"p{j:02d}" for j in range(PATCHES)] + list(known)
    obs = Observations([f"f{i:03d}" for i in range(FRAMES)], patches, values, [""] * FRAMES)
    return obs, white, known


def true_ccts(obs: Observations, camera: str, case: str, seed: int) -> np.ndarray:
    """Each frame's light's CCT (K), as :func:`render` lit the history (:func:`_light`)."""
    from illumon.daylight.cie import xy_from_spectrum
    from illumon.daylight.ohno2013 import cct_duv_from_xy

    e = _light(camera, case, seed)[2]
    return np.asarray(cct_duv_from_xy(xy_from_spectrum(e))[0], dtype=float)


MEASURED_CASES = ("none", "none+matrix", "raw+lamps", "pale", "room", "room+lamps")
"""Cases ``--measured`` runs with the camera's own sensitivities."""


def run_case(sim: str, camera: str, case: str, seed: int, hours: float = 0.0, measured: bool = False,
             flare: bool = False) -> dict:
    obs, white, known = render(sim, camera, case, seed, flare)
    if hours > 0:  # the frames spread evenly over that many hours (the service's histories carry their times)
        t0 = datetime(2026, 6, 1, 6, 0, tzinfo=timezone.utc)
        obs.times = [(t0 + timedelta(hours=hours * i / (FRAMES - 1))).isoformat() for i in range(FRAMES)]
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if measured:
            model = fit_scene_model(obs, datasets.load_camera(camera))
        elif case.endswith(RENDERED):  # the sRGB prior holds no measured camera
            model = fit_scene_model(obs, None, known_reflectances=known or None, primaries="srgb")
        else:
            model = fit_scene_model(obs, None, known_reflectances=known or None,  # the camera in neither prior
                                    camera_prior=camera_prior_without(camera),  # nor its mean
                                    rendered_camera_prior=camera_prior_without(camera, rendered=True))
    seconds = time.perf_counter() - t0
    res, extra = model.history_estimate
    err = angular_error_deg(res.white, white)
    gw = angular_error_deg(grey_world(obs.select_patches(model.patches)), white)
    nothing = angular_error_deg(np.ones(3), white)  # the output as it is (what a balanced camera already did)
    true_cct = true_ccts(obs, camera, case, seed)
    lo, hi = np.asarray(extra["cct_lo"], dtype=float), np.asarray(extra["cct_hi"], dtype=float)
    # an interval reaching past infinite temperature (hi = inf) holds every truth above its lower end; none (NaN) holds
    # nothing
    with np.errstate(invalid="ignore"):
        cct_in = np.where(np.isfinite(lo) & ~np.isnan(hi), (lo <= true_cct) & (true_cct <= hi), False)
    return {"sim": sim, "camera": camera, "case": case, "seed": seed, "err": err.tolist(), "gray_world": gw.tolist(),
            "nothing": nothing.tolist(), "cct_in_95": cct_in.tolist(),
            "mired_err": (1e6 / np.asarray(res.cct, dtype=float) - 1e6 / true_cct).tolist(),
            "mired_sd": mired_sd_from_interval(lo, hi).tolist(),  # the 95 % interval's stated spread, MK⁻¹
            "cct_lo": lo.tolist(), "cct_hi": hi.tolist(), "cct_true": true_cct.tolist(),
            "confidence": np.asarray(extra["confidence"]).tolist(), "seconds": seconds,
            "non_daylight": np.asarray(extra.get("non_daylight", np.zeros(len(err)))).tolist(),
            "calibration": model.camera["calibration"], "primaries": model.camera.get("primaries", "camera"),
            "mired_key": camera_mired_key(model, model.camera["calibration"], measured),
            "camera_log_gain": float(model.noise["model_error"].get("camera_log_gain", 0.0)),
            "camera_glare_log": float(model.noise["model_error"].get("camera_glare_log", 0.0)),
            "laplace_scale": float(model.noise["model_error"].get("laplace_scale", 1.0)),
            "split_mired": float(model.noise.get("split_mired", 0.0))}


def summarise(rows: list[dict]) -> list[dict]:
    out = []
    for sim in ("illumon", "rawsim"):
        for case in CASES:
            sel = [r for r in rows if r["sim"] == sim and r["case"] == case]
            if not sel:
                continue
            e = np.concatenate([r["err"] for r in sel])
            g = np.concatenate([r["gray_world"] for r in sel])
            c = np.concatenate([r["confidence"] for r in sel])
            out.append({
                "sim": sim, "case": case, "histories": len(sel), "median": float(np.median(e)),
                "p95": float(np.percentile(e, 95)), "max": float(e.max()), "gw_median": float(np.median(g)),
                "gw_max": float(g.max()), "nothing_median": float(np.median(np.concatenate([r["nothing"] for r in sel]))),
                "within_1deg": float(np.mean(e < 1.0)), "mean_confidence": float(c.mean()),
                "non_daylight_flagged": float(np.mean(np.concatenate([r["non_daylight"] for r in sel]) >= 0.5)),
                "cct_in_95": float(np.mean(np.concatenate([r["cct_in_95"] for r in sel]))),
                "mired_rms": float(np.sqrt(np.mean(np.concatenate([r["mired_err"] for r in sel]) ** 2))),
                "seconds": float(np.median([r["seconds"] for r in sel])),
            })
    return out


def main() -> int:
    global FRAMES
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=["dev", "score"], default="score")
    ap.add_argument("--seeds", type=int, default=2, help="histories per camera, case and simulator")
    ap.add_argument("--quick", action="store_true", help="three cameras, one seed")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated subset of {', '.join(CASES)}")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "unmeasured.json"))
    ap.add_argument("--hours", type=float, default=0.0,
                    help="give the frames times spread over this many hours (default: no times, as the CLI's CSVs "
                         "often have); a day lets a history whose light hardly moved be read as self-balanced")
    ap.add_argument("--measured", action="store_true",
                    help=f"give the camera's own sensitivities (cases {', '.join(MEASURED_CASES)} only)")
    ap.add_argument("--flare", action="store_true",
                    help="veiling glare in every frame (rawsim.flare_draw: what the real photographs showed)")
    ap.add_argument("--frames", type=int, default=FRAMES,
                    help=f"frames per history (default {FRAMES}; over the fit's 300 the scene is fitted on a subsample)")
    ap.add_argument("--flare-sd", type=float,
                    help=f"the model's prior on each frame's offset (default {formation.FLARE_SD}; 0: the model without it)")
    args = ap.parse_args()
    if args.flare_sd is not None:
        formation.FLARE_SD = args.flare_sd
    FRAMES = args.frames
    if datasets.shared_data_dir() is None:
        print("skipped: measured data (../shared/data) not available")
        return 0
    cams = rawsim.SCORE_CAMERAS if args.split == "score" else rawsim.DEV_CAMERAS
    seeds = range(1) if args.quick else range(args.seeds)
    cams = cams[:3] if args.quick else cams
    base = 700_000 if args.split == "score" else 7_000
    cases = [c for c in CASES if c in args.cases.split(",") and (c in MEASURED_CASES or not args.measured)]
    rows = [run_case(sim, cam, case, base + 100 * i + s, args.hours, args.measured, args.flare)
            for sim in ("illumon", "rawsim") for case in cases for i, cam in enumerate(cams) for s in seeds]
    table = summarise(rows)
    print(("veiling glare in every frame; " if args.flare else "") +
          (f"model offset prior {formation.FLARE_SD}; " if args.flare_sd is not None else "") +
          ("measured sensitivities given; " if args.measured else "sensitivities never given; ") +
          f"split {args.split} (cameras {', '.join(cams)}; rawsim's {args.split} surfaces and Granada daylight): "
          f"{len(cams)} cameras × {len(list(seeds))} seeds, {FRAMES} frames × {PATCHES} patches")
    print(f"{'simulator':9} {'case':13} {'median':>7} {'p95':>6} {'max':>6} {'gw med':>7} {'gw max':>7} "
          f"{'nothing':>7} {'<1°':>5} {'conf':>5} {'CCT95':>5} {'MK⁻¹':>5} {'s/fit':>6} {'lamp':>5}  goal")
    for t in table:
        goal = GOALS.get(t["case"])
        gtxt = "" if goal is None else f"med ≤ {goal[0]}" + (f", max ≤ {goal[1]}" if goal[1] else ", < gray-world")
        if t["case"] in ("none+lamps", "raw+lamps"):
            gtxt = "med ≤ 1.5 × gray-world, lamp ≥ 0.5"
        print(f"{t['sim']:9} {t['case']:13} {t['median']:7.2f} {t['p95']:6.2f} {t['max']:6.2f} {t['gw_median']:7.2f} "
              f"{t['gw_max']:7.2f} {t['nothing_median']:7.2f} {t['within_1deg']:5.2f} "
              f"{t['mean_confidence']:5.2f} {t['cct_in_95']:5.2f} {t['mired_rms']:5.1f} {t['seconds']:6.2f} "
              f"{t['non_daylight_flagged']:5.2f}  {gtxt}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"split": args.split, "flare": args.flare, "flare_sd": formation.FLARE_SD,
                                          "table": table, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
