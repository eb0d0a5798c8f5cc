"""Diagnosis benchmark: confusion matrix over every effect, and the illuminant error before / after extending the model.

Run: ``python benchmarks/diagnose.py [--quick] [--seeds N] [--jobs 2]``. Prints tables and writes
``benchmarks/results/diagnose.json``.

Histories come from :func:`illumon.diagnosis.effects.hide_effect` with the held-out cameras
(:data:`~illumon.diagnosis.effects.BENCHMARK_CAMERAS`, never used while developing or in the tests) and seeds from
1 000 000 on (development used 0…9 999, the tests 10 000…19 999). A history counts as correct when the effect is named
and, where reported, the patch is right and the onset frame within ±2 frames. Illuminant error: median angular error
(degrees) over frames between the camera white under the true illuminant and the estimate of the joint retrieval
(one start, no polish) on the raw history ("before") and with the diagnosed effect modelled ("after").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from illumon import datasets
from illumon.camera import angular_error_deg
from illumon.diagnosis.effects import BENCHMARK_CAMERAS, EFFECTS, LOCATED_EFFECTS, hide_effect
from illumon.diagnosis.fit import diagnose, estimate_with_effect
from illumon.retrieval import retrieve_illuminants

SEED0 = 1_000_000
FAST = {"start_offsets": (0.0,), "polish_max_frames": 0}


def one(effect: str, i: int) -> dict:
    """Diagnose one history; illuminant error before / after."""
    warnings.filterwarnings("ignore")
    cam = BENCHMARK_CAMERAS[i % len(BENCHMARK_CAMERAS)]
    seed = SEED0 + 1000 * EFFECTS.index(effect) + i
    h = hide_effect(effect, cam, seed)
    css = h.history.sensitivities
    t = time.perf_counter()
    d = diagnose(h.observations, css, reestimate=False)
    dt = time.perf_counter() - t
    ok = d.effect == effect
    if ok and "patch" in LOCATED_EFFECTS.get(effect, ()):
        ok = d.patch_index == h.patch
    if ok and "frame" in LOCATED_EFFECTS.get(effect, ()):
        ok = d.frame_index is not None and abs(d.frame_index - h.frame) <= 2
    before = retrieve_illuminants(h.observations, css, **FAST)
    after = before if d.effect == "none" else estimate_with_effect(h.observations, css, d, base_result=before, **FAST)
    truth = h.history.true_white
    return {
        "effect": effect, "camera": cam, "seed": seed, "diagnosed": d.effect, "correct": bool(ok),
        "patch": h.patch, "patch_found": d.patch_index, "frame": h.frame, "frame_found": d.frame_index,
        "frames": len(h.observations.frames), "patches": len(h.observations.patches),
        "err_before": float(np.median(angular_error_deg(before.white, truth))),
        "err_after": float(np.median(angular_error_deg(after.white, truth))),
        "seconds": dt,
    }


def main() -> int:
    warnings.filterwarnings("ignore")
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="5 seeds per effect")
    ap.add_argument("--seeds", type=int, default=20, help="histories per effect (20)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "diagnose.json"))
    args = ap.parse_args()
    if datasets.shared_data_dir() is None:
        print("measured data (../shared/data) not found: nothing to benchmark", file=sys.stderr)
        return 1
    n = 5 if args.quick else args.seeds
    jobs = [(e, i) for e in EFFECTS for i in range(n)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        rows = list(ex.map(one, *zip(*jobs, strict=True)))
    wall = time.perf_counter() - t0
    names = list(EFFECTS)
    conf = np.zeros((len(names), len(names)), dtype=int)
    for r in rows:
        conf[names.index(r["effect"]), names.index(r["diagnosed"])] += 1
    short = {e: e[:9] for e in names}
    print(f"Diagnosis on held-out cameras ({', '.join(BENCHMARK_CAMERAS)}), {n} seeds per effect, seeds ≥ {SEED0}")
    print("\nConfusion matrix (rows: hidden effect, columns: diagnosed)")
    print(f"{'hidden / diagnosed':<22}" + "".join(f"{short[e]:>10}" for e in names) + f"{'correct':>9}")
    summary = {}
    for i, e in enumerate(names):
        sel = [r for r in rows if r["effect"] == e]
        acc = float(np.mean([r["correct"] for r in sel]))
        eb = [r["err_before"] for r in sel]
        ea = [r["err_after"] for r in sel]
        summary[e] = {"accuracy": acc, "n": len(sel), "err_before_median": float(np.median(eb)),
                      "err_after_median": float(np.median(ea)), "err_before_mean": float(np.mean(eb)),
                      "err_after_mean": float(np.mean(ea))}
        print(f"{e:<22}" + "".join(f"{v:>10d}" for v in conf[i]) + f"{100 * acc:8.0f}%")
    effects = [r for r in rows if r["effect"] != "none"]
    clean = [r for r in rows if r["effect"] == "none"]
    overall = float(np.mean([r["correct"] for r in effects]))
    false_rate = float(np.mean([r["diagnosed"] != "none" for r in clean]))
    print(f"\nhidden effects named correctly (with patch / frame ±2 where reported): {100 * overall:.1f} % of {len(effects)}")
    print(f"false effects on clean histories: {100 * false_rate:.1f} % of {len(clean)}")
    print("\nIlluminant error, median over frames then over histories (degrees): before → after extending the model")
    print(f"{'hidden effect':<22}{'before':>9}{'after':>9}   (means {'before':>7} {'after':>7})")
    for e in names:
        s = summary[e]
        print(f"{e:<22}{s['err_before_median']:9.2f}{s['err_after_median']:9.2f}"
              f"   {'':7}{s['err_before_mean']:7.2f} {s['err_after_mean']:7.2f}")
    secs = [r["seconds"] for r in rows]
    print(f"\ndiagnosis time per history: median {np.median(secs):.2f} s, max {np.max(secs):.2f} s "
          f"({args.jobs} workers sharing the machine); wall {wall:.0f} s")
    out = {"cameras": list(BENCHMARK_CAMERAS), "seeds_per_effect": n, "seed_start": SEED0, "effects": names,
           "confusion": conf.tolist(), "summary": summary, "accuracy_effects": overall,
           "false_effect_rate_clean": false_rate, "rows": rows}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
