"""Diagnosis benchmark on two simulators side by side: confusion matrices, named / false rates, illuminant error before
and after extending the model.

Run: ``python benchmarks/diagnose.py [--quick] [--seeds N] [--jobs 2] [--sims illumon,rawsim] [--split dev]
[--variant V]``. Prints tables and writes ``benchmarks/results/diagnose[_dev][_V].json`` (with every candidate's
score per history, so margins can be studied without re-running).

``--split dev`` is the development protocol the margins are chosen on: :data:`rawsim.DEV_CAMERAS` (Nikon, Point Grey),
``rawsim``'s development surfaces and daylight, seeds 3 000…9 999. ``--variant`` renders the ``rawsim`` histories with
one of :data:`rawsim.PIPELINE_VARIANTS` (8- or 16-bit output, ISO 3200…6400, BT.709 tone curves, JPEG-like rounding,
small regions): robustness checks, not scored.

Histories, on the score cameras :data:`rawsim.SCORE_CAMERAS` (Canon, Hasselblad, Pentax, Phase One; the margins are
chosen on :data:`rawsim.DEV_CAMERAS`, Nikon and Point Grey) with seeds from 1 000 000 on (development used seeds
below 10 000):

* ``illumon``: the project's own simulator (:func:`illumon.simulation.effects.hide_effect`: patch-mean noise
  ``σ² = shot·y + read²``, log-normal exposure jitter, values to full float precision);
* ``rawsim``: the independent raw pipeline (:func:`rawsim.hide_effect_raw`: per-pixel shot noise with a per-camera
  conversion gain and ISO, read noise, black level subtracted with clipping at 0, 8/10/12-bit output, third-stop
  auto-exposure, texture; the score split's surfaces, ColorChecker and CIE TCS, and Granada daylight 1300…2599).
* ``imgsim`` (only with ``--sims``; held out, nothing is chosen on it): images rendered and measured as the service
  does (:func:`imgsim.hide_effect_img`: Bayer mosaic, OpenCV demosaicing, preset white balance, 8-bit PNG or JPEG,
  :func:`illumon_service.regions.region_stats`); same score split.

A history counts as correct when the effect is named and, where reported, the patch is right and the onset frame
within ±2 frames. Illuminant error: median angular error (degrees) over frames between the camera white under the
true light and the estimate of the joint retrieval (one start, no polish) on the raw history ("before") and with the
diagnosed effect modelled ("after").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import imgsim
import numpy as np
import rawsim
from illumon.camera import angular_error_deg
from illumon.diagnosis.correction import estimate_with_effect
from illumon.diagnosis.fit import diagnose
from illumon.retrieval import retrieve_illuminants
from illumon.simulation import datasets
from illumon.simulation.effects import EFFECTS, LOCATED_EFFECTS, hide_effect

SEED0 = 1_000_000
FAST = {"start_offsets": (0.0,), "polish_max_frames": 0}
SIMS = ("illumon", "rawsim")
ALL_SIMS = (*SIMS, "imgsim")  # imgsim: held out for scoring only (benchmarks/imgsim.py), not run by default
CAMERAS = rawsim.SCORE_CAMERAS


DEV_SEED0 = 3000
"""Development protocol (``--split dev``): :data:`rawsim.DEV_CAMERAS` (Nikon, Point Grey), development surfaces and
daylight for ``rawsim``, seeds 3 000…9 999; the margins are chosen on it."""


def history(sim: str, effect: str, i: int, cameras: tuple[str, ...] = CAMERAS, seed0: int = SEED0,
            split: str = "score", variant: str | None = None):
    """The ``i``-th history with ``effect`` of simulator ``sim``: (observations, sensitivities, true white,
    patch, frame, camera, seed). ``variant`` renders ``rawsim`` histories with one of
    :data:`rawsim.PIPELINE_VARIANTS` (robustness checks the benchmark does not score)."""
    cam = cameras[i % len(cameras)]
    seed = seed0 + 1000 * EFFECTS.index(effect) + i
    if sim == "imgsim":
        h = imgsim.hide_effect_img(effect, cam, seed, split=split)
        return h.observations, h.sensitivities, h.true_white, h.patch, h.frame, cam, seed
    if sim == "rawsim":
        h = rawsim.hide_effect_raw(effect, cam, seed, split=split, variant=variant)
        return h.observations, h.sensitivities, h.true_white, h.patch, h.frame, cam, seed
    h = hide_effect(effect, cam, seed)
    return h.observations, h.history.sensitivities, h.history.true_white, h.patch, h.frame, cam, seed


def one(sim: str, effect: str, i: int, split: str = "score", variant: str | None = None,
        primaries: str = "camera") -> dict:
    """Diagnose one history; illuminant error before / after; every candidate's score (to study margins offline)."""
    warnings.filterwarnings("ignore")
    if split == "dev":
        obs, css, truth, patch, frame, cam, seed = history(sim, effect, i, rawsim.DEV_CAMERAS, DEV_SEED0, "dev",
                                                           variant)
    else:
        obs, css, truth, patch, frame, cam, seed = history(sim, effect, i, variant=variant)
    t = time.perf_counter()
    # imgsim renders output (white-balance preset, colour matrix): with --primaries srgb it is diagnosed as such;
    # illumon and rawsim deliver sensor RGB
    d = diagnose(obs, css, reestimate=False, primaries=primaries if sim == "imgsim" else "camera")
    dt = time.perf_counter() - t
    ok = d.effect == effect
    if ok and "patch" in LOCATED_EFFECTS.get(effect, ()):
        ok = d.patch_index == patch
    if ok and "frame" in LOCATED_EFFECTS.get(effect, ()):
        ok = d.frame_index is not None and abs(d.frame_index - frame) <= 2
    before = retrieve_illuminants(obs, css, **FAST)
    after = before if d.effect == "none" else estimate_with_effect(obs, css, d, base_result=before, **FAST)
    return {
        "sim": sim, "effect": effect, "camera": cam, "seed": seed, "diagnosed": d.effect, "correct": bool(ok),
        "patch": patch, "patch_found": d.patch_index, "frame": frame, "frame_found": d.frame_index,
        "frames": len(obs.frames), "patches": len(obs.patches),
        "err_before": float(np.median(angular_error_deg(before.white, truth))),
        "err_after": float(np.median(angular_error_deg(after.white, truth))),
        "noise": d.info.get("noise"), "seconds": dt,
        "scores": {c.effect: (float(c.score) if np.isfinite(c.score) else None) for c in d.candidates},
    }


def report(sim: str, rows: list[dict]) -> dict:
    """Print one simulator's confusion matrix and illuminant errors; return its summary."""
    names = list(EFFECTS)
    conf = np.zeros((len(names), len(names)), dtype=int)
    for r in rows:
        conf[names.index(r["effect"]), names.index(r["diagnosed"])] += 1
    print(f"\n== {sim} ==  confusion matrix (rows: hidden effect, columns: diagnosed)")
    print(f"{'hidden / diagnosed':<22}" + "".join(f"{e[:9]:>10}" for e in names) + f"{'correct':>9}")
    summary = {}
    for i, e in enumerate(names):
        sel = [r for r in rows if r["effect"] == e]
        acc = float(np.mean([r["correct"] for r in sel]))
        eb = [r["err_before"] for r in sel]
        ea = [r["err_after"] for r in sel]
        summary[e] = {"accuracy": acc, "n": len(sel), "err_before_median": float(np.median(eb)),
                      "err_after_median": float(np.median(ea))}
        print(f"{e:<22}" + "".join(f"{v:>10d}" for v in conf[i]) + f"{100 * acc:8.0f}%")
    print("illuminant error (median over frames, then histories; degrees) before → after: " + ", ".join(
        f"{e[:9]} {summary[e]['err_before_median']:.2f}→{summary[e]['err_after_median']:.2f}" for e in names))
    effects = [r for r in rows if r["effect"] != "none"]
    clean = [r for r in rows if r["effect"] == "none"]
    return {"confusion": conf.tolist(), "summary": summary,
            "named": float(np.mean([r["correct"] for r in effects])), "n_effects": len(effects),
            "false_on_clean": float(np.mean([r["diagnosed"] != "none" for r in clean])), "n_clean": len(clean)}


def main() -> int:
    warnings.filterwarnings("ignore")
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="5 seeds per effect")
    ap.add_argument("--seeds", type=int, default=20, help="histories per effect and simulator (20)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    ap.add_argument("--sims", default=",".join(SIMS), help="simulators, comma-separated (illumon,rawsim; imgsim too)")
    ap.add_argument("--split", choices=("score", "dev"), default="score",
                    help="score protocol (default) or the development one the margins are chosen on")
    ap.add_argument("--variant", choices=tuple(rawsim.PIPELINE_VARIANTS), default=None,
                    help="render rawsim histories with a pipeline variant (robustness check, not scored)")
    ap.add_argument("--primaries", choices=("camera", "srgb"), default="camera",
                    help="output space the imgsim histories (rendered output) are diagnosed in (camera)")
    ap.add_argument("--effects", default=",".join(EFFECTS),
                    help="hidden effects to run, comma-separated (all); the named rate is over those run")
    ap.add_argument("--out", default=None, help="JSON (default benchmarks/results/diagnose[_dev][_VARIANT].json)")
    args = ap.parse_args()
    if args.out is None:
        tag = ("_dev" if args.split == "dev" else "") + (f"_{args.variant}" if args.variant else "")
        args.out = str(Path(__file__).parent / "results" / f"diagnose{tag}.json")
    if datasets.shared_data_dir() is None:
        print("measured data (../shared/data) not found: nothing to benchmark", file=sys.stderr)
        return 1
    sims = [s for s in args.sims.split(",") if s]
    if any(s not in ALL_SIMS for s in sims):
        print(f"illumon: error: --sims must name {' or '.join(ALL_SIMS)}", file=sys.stderr)
        return 2
    n = 5 if args.quick else args.seeds
    effects = [e for e in args.effects.split(",") if e]
    if any(e not in EFFECTS for e in effects):
        print(f"illumon: error: --effects must name some of {', '.join(EFFECTS)}", file=sys.stderr)
        return 2
    jobs = [(s, e, i, args.split, args.variant, args.primaries) for s in sims for e in effects for i in range(n)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        rows = list(ex.map(one, *zip(*jobs, strict=True)))
    wall = time.perf_counter() - t0
    cams, seed0 = (rawsim.DEV_CAMERAS, DEV_SEED0) if args.split == "dev" else (CAMERAS, SEED0)
    print(f"Diagnosis on {args.split} cameras ({', '.join(cams)}), {n} seeds per effect and simulator, seeds ≥ {seed0}"
          + (f"; rawsim variant {args.variant!r}: {rawsim.PIPELINE_VARIANTS[args.variant]}" if args.variant else ""))
    out: dict = {"split": args.split, "variant": args.variant, "cameras": list(cams), "seeds_per_effect": n,
                 "seed_start": seed0, "effects": list(EFFECTS), "sims": {}}
    for s in sims:
        out["sims"][s] = report(s, [r for r in rows if r["sim"] == s])
    print("\nSide by side (goal: ≥ 95 % named, ≤ 5 % false effects on clean histories)")
    print(f"{'':<34}" + "".join(f"{s:>12}" for s in sims))
    print(f"{'hidden effects named (patch, ±2 frames)':<34}" + "".join(f"{100 * out['sims'][s]['named']:11.1f}%" for s in sims))
    print(f"{'false effects on clean histories':<34}" + "".join(f"{100 * out['sims'][s]['false_on_clean']:11.1f}%" for s in sims))
    for e in EFFECTS:
        print(f"{'  ' + e:<34}" + "".join(f"{100 * out['sims'][s]['summary'][e]['accuracy']:11.0f}%" for s in sims))
    secs = [r["seconds"] for r in rows]
    print(f"\ndiagnosis time per history: median {np.median(secs):.2f} s, max {np.max(secs):.2f} s "
          f"({args.jobs} workers sharing the machine); wall {wall:.0f} s")
    out["rows"] = rows
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1, default=float))
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
