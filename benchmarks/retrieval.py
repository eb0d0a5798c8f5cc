"""Multi-frame retrieval benchmark: the paper's protocol (Tables 1–3 layout) and measured-daylight histories.

Run: ``python benchmarks/retrieval.py [--quick] [--skip-paper] [--analysis] [--sims illumon,illumon-same,rawsim]``. Prints tables
and writes ``benchmarks/results/retrieval.json``. Metric: angular error (degrees) between the camera white under the true and the
estimated illuminant.

``--analysis`` adds what limits the paper protocol (issue 3): ``joint`` on the protocol exactly as published
(noise-free images), the same with the data trusted to 0.02 % (``relative_error=2e-4``) and an *oracle* reflectance
basis and prior built from the 24 ColorChecker spectra themselves (the patches' own model error is then the 8-component
truncation only), and the data term's range over a common reciprocal-temperature shift of every frame (±30 MK⁻¹,
exposures and reflectances re-fitted, reflectance prior made flat): zero range means the data cannot tell the shift.
It also splits each variant's reciprocal-temperature error into the shift common to a case's frames and the spread
within the case: the data fix the frames' differences, the priors their common level.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import rawsim
from illumon.camera import CameraNoise, angular_error_deg
from illumon.daylight import daylight_model
from illumon.priors import ReflectanceBasis, colourchecker_reflectances, reflectance_basis
from illumon.retrieval import retrieve_illuminants
from illumon.retrieval.joint import JointProblem
from illumon.simulation import (
    PAPER_PATCH_SETS,
    PAPER_TABLES,
    datasets,
    measured_daylight_history,
    paper_cct,
    paper_protocol,
    simulate_history,
)
from scipy.optimize import least_squares

METHODS = ("joint", "marguier2007", "gray_world")
CAMERAS = (
    "Canon_600D", "Nikon_D5100", "Pentax_K-5", "Point_Grey_Grasshopper2_14S5C", "Nikon_Z6_ssf", "Phase_One",
)
"""Cameras of the measured-daylight histories. Not a held-out set: Nikon D5100, Nikon Z6 and Point Grey are
development cameras (:data:`rawsim.DEV_CAMERAS`); Canon 600D, Pentax K-5 and Phase One are score cameras."""


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


def _oracle_basis() -> ReflectanceBasis:
    """8 principal components of the 24 ColorChecker spectra, with their coefficients' mean and covariance."""
    _, cc = colourchecker_reflectances("BabelColor Average")
    f = np.linalg.svd(cc, full_matrices=False)[2][:8].T
    c = cc @ f
    return ReflectanceBasis(f, c.mean(0), np.cov(c.T), {"sets": ["ColorChecker (oracle)"]})


def _shift_range(h, mired: np.ndarray, shifts: np.ndarray) -> float:
    """Range of the whitened data cost (relative error 0.1 %) over a common shift of every frame's true reciprocal
    temperature, exposures and reflectances re-fitted with a flat reflectance prior."""
    rb = reflectance_basis()
    flat = ReflectanceBasis(rb.functions, rb.prior_mean, rb.prior_covariance * 1e6, {})
    prob = JointProblem(h.observations, h.sensitivities, daylight_model("cie"), flat, relative_error=1e-3,
                        absolute_error=1e-4)
    costs = []
    for d in shifts:
        fr = prob.start(mired + d)[: prob.F * prob.nf].reshape(prob.F, prob.nf)
        par = fr[:, : prob.np]

        def data(lk: np.ndarray, par: np.ndarray = par) -> np.ndarray:
            return prob.projected_residuals(np.column_stack([par, lk]).ravel())[: prob.F * prob.P * 3]

        costs.append(float(np.sum(least_squares(data, fr[:, prob.np]).fun ** 2)))
    return float(np.ptp(costs))


def analysis(camera: str, patch_sets: list[tuple[int, ...]]) -> dict:
    """What limits the paper protocol: noise-free images, trusted data, an oracle basis; data-term range per table."""
    variants = {
        "published (noise-free)": {},
        "noise-free, data trusted": {"relative_error": 2e-4, "absolute_error": 1e-4},
        "noise-free, trusted, oracle basis": {"relative_error": 2e-4, "absolute_error": 1e-4,
                                              "reflectance": _oracle_basis()},
    }
    out: dict = {"variants": {}, "shift_range": {}, "mired_error": {}}
    shifts = np.linspace(-30.0, 30.0, 7)
    for name, kw in variants.items():
        per_table: dict[int, list[float]] = {}
        common, spread = [], []
        for table, cases in PAPER_TABLES.items():
            for temps in cases:
                for ps in patch_sets:
                    h = paper_protocol(camera, temps, ps, noise=None)
                    res = retrieve_illuminants(h.observations, h.sensitivities, method="joint", **kw)
                    per_table.setdefault(table, []).extend(angular_error_deg(res.white, h.true_white))
                    d = 1e6 / res.cct - 1e6 / paper_cct(temps)
                    common.append(float(np.mean(d)))
                    spread.append(float(np.std(d)))
        out["variants"][name] = {str(t): _stats(v) for t, v in per_table.items()}
        out["variants"][name]["all"] = _stats([e for v in per_table.values() for e in v])
        out["mired_error"][name] = {"common_abs_median": float(np.median(np.abs(common))),
                                    "common_abs_max": float(np.max(np.abs(common))),
                                    "within_case_sd_median": float(np.median(spread))}
    for table, cases in PAPER_TABLES.items():
        out["shift_range"][str(table)] = float(np.median([
            _shift_range(paper_protocol(camera, temps, patch_sets[0], noise=None), 1e6 / paper_cct(temps), shifts)
            for temps in cases
        ]))
    return out


MARGUIER_MAX_FRAMES = 30
"""marguier2007's finite-difference descent costs O(frames²) error evaluations; longer histories skip it."""


def _score_scene(frames: int, patches: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.random.Generator]:
    """Score-split Granada daylight (random draw) and surfaces of ``rawsim`` for one seed: (E, R, rng)."""
    rng = np.random.default_rng(10_000 + seed)
    pool = rawsim.daylight_pool("score")
    e = pool[rng.choice(pool.shape[0], frames, replace=False)]
    return e, rawsim.draw_reflectances("score", patches, rng), rng


def same_scene_history(camera: str, frames: int, patches: int, seed: int):
    """The project's simulator (its noise and exposure jitter) on exactly the daylight and surfaces
    :func:`raw_history` draws: the two simulators compared on the same scenes."""
    e, r, _ = _score_scene(frames, patches, seed)
    css = datasets.load_camera(camera)
    h = simulate_history(css, e, r, rng=seed)
    return h.observations, css, h.true_white


def raw_history(camera: str, frames: int, patches: int, seed: int):
    """A history of the independent raw pipeline (``rawsim``): score-split Granada daylight (random draw) and surfaces,
    a body of ``camera`` at ISO 100…1600, 8/10/12-bit linear output. Returns (observations, sensitivities, truth)."""
    e, r, rng = _score_scene(frames, patches, seed)
    css = datasets.load_camera(camera)
    prof = rawsim.camera_profile(camera, rng=rng)
    h = rawsim.simulate_raw_history(css, e, r, rng=rng, bits=int(rng.choice([8, 10, 12])),
                                    conversion_gain=prof["conversion_gain"], read_noise_e=prof["read_noise_e"],
                                    black_level=prof["black_level"], full_well_e=prof["full_well_e"],
                                    adc_bits=prof["adc_bits"], texture=0.02)
    return h.observations, css, h.true_white_raw


def measured(cameras: tuple[str, ...], seeds: int, frames: int, patches: int, sim: str = "illumon") -> dict:
    methods = [m for m in METHODS if m != "marguier2007" or frames <= MARGUIER_MAX_FRAMES]
    per_method = {m: [] for m in methods}
    times = {m: [] for m in methods}
    for cam in cameras:
        for seed in range(seeds):
            if sim == "rawsim":
                obs, css, truth = raw_history(cam, frames, patches, seed)
            elif sim == "illumon-same":
                obs, css, truth = same_scene_history(cam, frames, patches, seed)
            else:
                h = measured_daylight_history(cam, frames=frames, patches=patches, seed=seed)
                obs, css, truth = h.observations, h.sensitivities, h.true_white
            for m in methods:
                t = time.perf_counter()
                res = retrieve_illuminants(obs, css, method=m)
                times[m].append(time.perf_counter() - t)
                per_method[m] += list(angular_error_deg(res.white, truth))
    return {
        "sim": sim,
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
    ap.add_argument("--analysis", action="store_true", help="what limits the paper protocol (see module docstring)")
    ap.add_argument("--sims", default="illumon,illumon-same,rawsim",
                    help="simulators of the measured-daylight histories (illumon-same: the project's simulator on "
                         "rawsim's scenes)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "retrieval.json"))
    args = ap.parse_args()
    if any(x not in ("illumon", "illumon-same", "rawsim") for x in args.sims.split(",")):
        print("illumon: error: --sims takes illumon, illumon-same and/or rawsim", file=sys.stderr)
        return 2
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
    if args.analysis:
        out["analysis"] = a = analysis("Canon_300D", sets)
        print("\nWhat limits the paper protocol: joint median / max (degrees) per table (images per case)")
        print(f"{'variant':<36} " + " ".join(f"{t + ' images':>14}" for t in ("2", "3", "4", "all")))
        for name, v in a["variants"].items():
            print(f"{name:<36} " + " ".join(
                f"{v[k]['median']:6.2f} /{v[k]['max']:5.2f}" for k in ("1", "2", "3", "all")))
        print("reciprocal-temperature error (MK⁻¹): shift common to a case |median| / |max|, spread within a case (median sd)")
        for name, v in a["mired_error"].items():
            print(f"{name:<36} {v['common_abs_median']:6.1f} / {v['common_abs_max']:5.1f}   {v['within_case_sd_median']:5.2f}")
        print("data-term range over a common ±30 MK⁻¹ shift (median over cases, χ² units at 0.1 % error): "
              + ", ".join(f"{int(t) + 1} images {r:.3g}" for t, r in a["shift_range"].items()))
    cams = CAMERAS[:3] if args.quick else CAMERAS
    seeds = 1 if args.quick else 3
    print(f"\nsplit: cameras {', '.join(cams)} (development: Nikon D5100, Nikon Z6, Point Grey; score: the rest)")
    print("Measured Granada daylight, unseen reflectances: illumon = the project's simulator (noise + exposure jitter),"
          " rawsim = the independent raw pipeline (score daylight and surfaces, per-pixel noise, 8/10/12 bits)")
    print(f"{'sim':<12} {'frames×patches':<16} " + " ".join(f"{m + ' med/p95/max':>26}" for m in METHODS)
          + "   s/history (joint)")
    out["measured"] = []
    for frames, patches in ((10, 6), (30, 10), (100, 16)):
        if args.quick and frames > 30:
            continue
        for sim in args.sims.split(","):
            r = measured(cams, seeds, frames, patches, sim)
            out["measured"].append(r)
            s = r["summary"]
            cells = " ".join(
                f"{s[m]['median']:8.2f}{s[m]['p95']:8.2f}{s[m]['max']:8.2f}  " if m in s else f"{'(skipped)':>26}"
                for m in METHODS
            )
            print(f"{sim:<12} {f'{frames}×{patches}':<16} {cells} {r['seconds_per_history']['joint']:8.2f}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
