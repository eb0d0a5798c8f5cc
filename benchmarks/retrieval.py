"""Multi-frame retrieval benchmark: the paper's protocol (Tables 1–3 layout) and measured-daylight histories.

Run: ``python benchmarks/retrieval.py [--quick]``. Prints tables and writes ``benchmarks/results/retrieval.json``.
Metric: angular error (degrees) between the camera white under the true and the estimated illuminant.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from illumon import datasets
from illumon.camera import angular_error_deg
from illumon.retrieval import retrieve_illuminants
from illumon.scenarios import PAPER_PATCH_SETS, PAPER_TABLES, measured_daylight_history, paper_protocol
from illumon.simulate import CameraNoise

METHODS = ("joint", "marguier2007", "gray_world")
HELD_OUT_CAMERAS = (
    "Canon_600D", "Nikon_D5100", "Pentax_K-5", "Point_Grey_Grasshopper2_14S5C", "Nikon_Z6_ssf", "Phase_One",
)


def _stats(err: list[float]) -> dict[str, float]:
    a = np.asarray(err)
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max()), "n": int(a.size)}


def paper(camera: str, patch_sets: list[tuple[int, ...]]) -> dict:
    rows, per_method = [], {m: [] for m in METHODS}
    for table, cases in PAPER_TABLES.items():
        for temps in cases:
            for ps in patch_sets:
                h = paper_protocol(camera, temps, ps, noise=CameraNoise(exposure_jitter=0.0), seed=sum(temps))
                row = {"table": table, "illuminants": [f"D{t}" for t in temps], "patches": list(ps)}
                for m in METHODS:
                    res = retrieve_illuminants(h.observations, h.sensitivities, method=m)
                    e = angular_error_deg(res.white, h.true_white)
                    row[m] = [round(float(v), 2) for v in e]
                    per_method[m] += list(e)
                rows.append(row)
    return {"camera": camera, "rows": rows, "summary": {m: _stats(v) for m, v in per_method.items()}}


MARGUIER_MAX_FRAMES = 30
"""marguier2007's finite-difference descent costs O(frames²) error evaluations; longer histories skip it."""


def measured(cameras: tuple[str, ...], seeds: int, frames: int, patches: int) -> dict:
    methods = [m for m in METHODS if m != "marguier2007" or frames <= MARGUIER_MAX_FRAMES]
    per_method = {m: [] for m in methods}
    times = {m: [] for m in methods}
    for cam in cameras:
        for seed in range(seeds):
            h = measured_daylight_history(cam, frames=frames, patches=patches, seed=seed)
            for m in methods:
                t = time.perf_counter()
                res = retrieve_illuminants(h.observations, h.sensitivities, method=m)
                times[m].append(time.perf_counter() - t)
                per_method[m] += list(angular_error_deg(res.white, h.true_white))
    return {
        "frames": frames,
        "patches": patches,
        "cameras": list(cameras),
        "summary": {m: _stats(v) for m, v in per_method.items()},
        "seconds_per_history": {m: float(np.median(v)) for m, v in times.items()},
    }


def main() -> int:
    warnings.filterwarnings("ignore")
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer cases")
    ap.add_argument("--skip-paper", action="store_true", help="only the measured-daylight histories")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "retrieval.json"))
    args = ap.parse_args()
    if datasets.shared_data_dir() is None:
        print("measured data (../shared/data) not found: nothing to benchmark", file=sys.stderr)
        return 1
    out: dict = {}
    sets = PAPER_PATCH_SETS[:2] if args.quick else PAPER_PATCH_SETS
    out["paper"] = {"rows": [], "summary": {}} if args.skip_paper else paper("Canon_300D", sets)
    print("Paper protocol (Canon 300D, ColorChecker, 6 patches, CIE D40–D100, no exposure jitter)")
    print(f"{'table':>5} {'illuminants':<22} {'patches':<20} " + " ".join(f"{m:>26}" for m in METHODS))
    for r in out["paper"]["rows"]:
        cells = " ".join(f"{' '.join(f'{v:4.1f}' for v in r[m]):>26}" for m in METHODS)
        print(f"{r['table']:>5} {'/'.join(r['illuminants']):<22} {','.join(map(str, r['patches'])):<20} {cells}")
    print("\nsummary (degrees)      " + " ".join(f"{m:>14}" for m in METHODS))
    for k in ("median", "p95", "max"):
        if out["paper"]["summary"]:
            print(f"{k:<22} " + " ".join(f"{out['paper']['summary'][m][k]:14.2f}" for m in METHODS))
    cams = HELD_OUT_CAMERAS[:3] if args.quick else HELD_OUT_CAMERAS
    seeds = 1 if args.quick else 3
    print("\nMeasured Granada daylight, unseen reflectances, noise + exposure jitter")
    print(f"{'frames×patches':<16} " + " ".join(f"{m + ' med/p95/max':>26}" for m in METHODS) + "   s/history (joint)")
    out["measured"] = []
    for frames, patches in ((10, 6), (30, 10), (100, 16)):
        if args.quick and frames > 30:
            continue
        r = measured(cams, seeds, frames, patches)
        out["measured"].append(r)
        s = r["summary"]
        cells = " ".join(
            f"{s[m]['median']:8.2f}{s[m]['p95']:8.2f}{s[m]['max']:8.2f}  " if m in s else f"{'(skipped)':>26}" for m in METHODS
        )
        print(f"{f'{frames}×{patches}':<16} {cells} {r['seconds_per_history']['joint']:8.2f}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
