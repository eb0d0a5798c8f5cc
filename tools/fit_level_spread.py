"""How far a daylight history's fit level sits from its light, by history length (:data:`illumon.model.fit.FIT_LEVEL_SD`,
:data:`illumon.model.fit.FEW_FRAMES_FIT_LEVEL_SD`).

The scene fit's common level (:func:`illumon.model.level.mean_log_chroma`: the mean log r/g, b/g of every frame's
daylight white through the fit's sensitivities) is what the reflectance prior makes of the scene where the frames'
light varies; over a few frames of one light it is the prior's mean surface and nothing more. This script fits
``benchmarks/unmeasured.py``'s histories with the camera's own sensitivities (its ``--measured`` runs: the fit's
sensitivities are the camera's, so the level and the truth share one space), records the fit's level where
:func:`illumon.model.level.daylight_level` weighs it, and prints its RMS error (log r/g, b/g) against the true lights'
mean white per history length and case, beside the scene average's reading and the spread it states, and the RMS
pooled over cases and simulators per length. ``--unmeasured`` fits without the sensitivities (the prior without the
camera's maker, as ``benchmarks/unmeasured.py`` does): the level then sits in the fitted camera's space, and is
weighed only over one to four frames (:data:`illumon.model.fit.FEW_FRAMES_LEVEL`). Development cameras only.

    python tools/fit_level_spread.py [--frames 1,3,6,30] [--cases none,pale] [--seeds 2] [--unmeasured]
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
import unmeasured  # noqa: E402
from illumon.model import fit as fit_module  # noqa: E402
from illumon.model import fit_scene_model  # noqa: E402
from illumon.priors.scene_average import log_chroma  # noqa: E402
from illumon.simulation import datasets  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", default="1,3,6,30")
    ap.add_argument("--cases", default="none,pale")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--sims", default="illumon,rawsim")
    ap.add_argument("--unmeasured", action="store_true", help="fit without the sensitivities (the prior without the "
                    "camera's maker, as benchmarks/unmeasured.py does); the level then sits in the fitted camera's space")
    args = ap.parse_args()
    seen: list = []
    original = fit_module.daylight_level

    def record(fit_level, fit_sd, scene, reading, unbalanced):  # noqa: ANN001, ANN202
        seen.append((np.asarray(fit_level, dtype=float), np.asarray(reading, dtype=float), float(scene.sd)))
        return original(fit_level, fit_sd, scene, reading, unbalanced)

    fit_module.daylight_level = record
    given = "not given (the prior without the camera's maker)" if args.unmeasured else "given"
    print(f"development cameras ({len(rawsim.DEV_CAMERAS)}), sensitivities {given}, {args.seeds} seeds; RMS over log "
          "r/g and b/g of the fit's level and of the scene average's reading against the true lights' mean white")
    print(f"{'frames':>6} {'case':6} {'sim':8} {'n':>4} {'fit level':>10} {'reading':>9} {'stated':>7}")

    def rms(e: list) -> float:
        return float(np.sqrt(np.mean(np.square(e)))) if len(e) else float("nan")

    for frames in [int(f) for f in args.frames.split(",")]:
        unmeasured.FRAMES = frames
        pooled: list = []
        for case in args.cases.split(","):
            for sim in args.sims.split(","):
                fit_err, read_err, stated = [], [], []
                for camera in rawsim.DEV_CAMERAS:
                    for seed in range(args.seeds):
                        obs, white, _ = unmeasured.render(sim, camera, case, seed)
                        seen.clear()
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            if args.unmeasured:
                                fit_scene_model(obs, None, camera_prior=unmeasured.camera_prior_without(camera),
                                                rendered_camera_prior=unmeasured.camera_prior_without(camera, True))
                            else:
                                fit_scene_model(obs, datasets.load_camera(camera))
                        if not seen:  # judged lamp-lit: no daylight level weighed
                            continue
                        truth = np.mean(log_chroma(white), axis=0)
                        fit_level, reading, sd = seen[-1]
                        fit_err.append(fit_level - truth)
                        read_err.append(reading - truth)
                        stated.append(sd)
                pooled += fit_err
                print(f"{frames:6d} {case:6} {sim:8} {len(fit_err):4d} {rms(fit_err):10.3f} {rms(read_err):9.3f} "
                      f"{rms(stated):7.3f}")
        print(f"{frames:6d} {'pooled':6} {'':8} {len(pooled):4d} {rms(pooled):10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
