"""Online estimation benchmark (issue 4): per-frame latency, fit time vs history length, accuracy vs visible patches.

Run: ``python benchmarks/online.py [--long] [--quick]`` (``--long`` adds a 100k-frame history, ``--quick`` runs only
the shorter morning → afternoon setting). The morning → afternoon accuracy is measured on both simulators (the
project's and the independent raw pipeline ``rawsim``, issue 16), and as ``illumon-same`` with the project's simulator
on exactly rawsim's daylight runs and surfaces (the two simulators compared on the same scenes).
Writes ``benchmarks/results/online.json``.
"""

from __future__ import annotations

import json
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import rawsim  # noqa: E402
from illumon.camera import angular_error_deg  # noqa: E402
from illumon.daylight import cct_duv_from_xy, xy_from_spectrum  # noqa: E402
from illumon.model import fit_scene_model  # noqa: E402
from illumon.priors import colourchecker_reflectances  # noqa: E402
from illumon.simulation import (
    datasets,  # noqa: E402
    measured_daylight_history,  # noqa: E402
    simulate_history,  # noqa: E402
)

CAMERAS = ("Canon_600D", "Nikon_D5100", "Pentax_K-5", "Point_Grey_Grasshopper2_14S5C", "Nikon_Z6_ssf", "Phase_One")
"""Cameras of the morning → afternoon histories. Not a held-out set: Nikon D5100, Nikon Z6 and Point Grey are
development cameras (:data:`rawsim.DEV_CAMERAS`); Canon 600D, Pentax K-5 and Phase One are score cameras."""


def _score_run(camera: str, frames: int, seed: int) -> tuple[np.ndarray, dict, np.ndarray, np.random.Generator]:
    """A contiguous run of score-split Granada daylight, the camera body's profile and 10 score surfaces of ``rawsim``:
    (E, profile, R, rng)."""
    rng = np.random.default_rng(seed)
    pool = rawsim.daylight_pool("score")
    start = int(rng.integers(0, pool.shape[0] - frames))
    prof = rawsim.camera_profile(camera, rng=rng)
    return pool[start : start + frames], prof, rawsim.draw_reflectances("score", 10, rng), rng


def _same_scene_run(camera: str, frames: int, seed: int):
    """The project's simulator on exactly the daylight and surfaces of :func:`_raw_run` (the two simulators compared
    on the same scenes): (observations, css, illuminants, truth)."""
    e, _, refl, _ = _score_run(camera, frames, seed)
    css = datasets.load_camera(camera)
    h = simulate_history(css, e, refl, rng=seed)
    return h.observations, css, e, h.true_white


def _raw_run(camera: str, frames: int, seed: int):
    """A contiguous run of score-split Granada daylight through the independent raw pipeline (``rawsim``: a body of
    ``camera`` at ISO 100…1600, 8/10/12-bit linear output, score surfaces): (observations, css, illuminants, truth)."""
    e, prof, refl, rng = _score_run(camera, frames, seed)
    css = datasets.load_camera(camera)
    h = rawsim.simulate_raw_history(css, e, refl, rng=rng,
                                    bits=int(rng.choice([8, 10, 12])), conversion_gain=prof["conversion_gain"],
                                    read_noise_e=prof["read_noise_e"], black_level=prof["black_level"],
                                    full_well_e=prof["full_well_e"], adc_bits=prof["adc_bits"], texture=0.02)
    return h.observations, css, e, h.true_white_raw


def morning_afternoon(histories: int, frames: int, sim: str = "illumon") -> dict:
    """Fit on the first half of a run of Granada daylight, estimate the second half frame by frame (:data:`CAMERAS`,
    10 patches the reflectance basis never saw; the project's simulator's noise and auto-exposure jitter, or the raw
    pipeline of ``rawsim``)."""
    hits: dict[str, list] = {"cct": [], "duv": [], "gain_r": [], "gain_b": []}
    ae, fit_s = [], []
    half = frames // 2
    for i in range(histories):
        if sim == "rawsim":
            obs, css, illum, truth = _raw_run(CAMERAS[i % len(CAMERAS)], frames, 5000 + i)
        elif sim == "illumon-same":
            obs, css, illum, truth = _same_scene_run(CAMERAS[i % len(CAMERAS)], frames, 5000 + i)
        else:
            h = measured_daylight_history(CAMERAS[i % len(CAMERAS)], frames=frames, patches=10, seed=5000 + i,
                                          contiguous=True)
            obs, css, illum, truth = h.observations, h.sensitivities, h.illuminants, h.true_white
        t = time.perf_counter()
        model = fit_scene_model(obs.subset(slice(0, half)), css)
        fit_s.append(time.perf_counter() - t)
        res, extra = model.estimate(obs.subset(slice(half, None)))
        cct, duv = cct_duv_from_xy(xy_from_spectrum(illum[half:]))
        w = truth[half:]
        g = w[:, 1:2] / w
        hits["cct"] += list((cct >= extra["cct_lo"]) & (cct <= extra["cct_hi"]))
        hits["duv"] += list((duv >= extra["duv_lo"]) & (duv <= extra["duv_hi"]))
        inside = (g >= res.info["gain_lo"]) & (g <= res.info["gain_hi"])
        hits["gain_r"] += list(inside[:, 0])
        hits["gain_b"] += list(inside[:, 2])
        ae += list(angular_error_deg(res.white, w))
    a = np.asarray(ae)
    return {
        "histories": histories, "fit_frames": half, "estimated_frames": int(a.size),
        "median_deg": float(np.median(a)), "p95_deg": float(np.percentile(a, 95)), "max_deg": float(a.max()),
        "coverage": {k: float(np.mean(v)) for k, v in hits.items()}, "fit_s_median": float(np.median(fit_s)),
    }


def main() -> None:
    warnings.simplefilter("ignore")
    out_ma = []
    print("morning → afternoon (fit on the first half, estimate the second; unseen patches)")
    print(f"split: cameras {', '.join(CAMERAS)} (development: Nikon D5100, Nikon Z6, Point Grey; score: the rest); "
          "Granada daylight runs")
    print("sim          histories  fit/est frames  median°   p95°   max°  cover CCT   Duv  gain_r gain_b  fit s")
    for n_hist, frames in ((24, 120), (12, 300)):
        for sim in ("illumon", "illumon-same", "rawsim"):
            r = morning_afternoon(n_hist, frames, sim)
            r["sim"] = sim
            out_ma.append(r)
            c = r["coverage"]
            print(f"{sim:<12} {n_hist:9d} {frames // 2:7d}/{frames // 2:<7d} {r['median_deg']:7.2f} {r['p95_deg']:6.2f} "
                  f"{r['max_deg']:6.2f}  {c['cct']:9.3f} {c['duv']:5.3f} {c['gain_r']:7.3f} {c['gain_b']:6.3f} "
                  f"{r['fit_s_median']:6.2f}")
        if "--quick" in sys.argv:
            break
    _, granada = datasets.load_granada_daylight()
    css = datasets.load_camera("Nikon_D5100")
    _, refl = colourchecker_reflectances()
    out: dict = {"fit": [], "patches": [], "morning_afternoon": out_ma}
    lengths = [1000, 10000] + ([100000] if "--long" in sys.argv else [])
    for n in lengths:
        idx = np.arange(n) % 2600
        hist = simulate_history(css, granada[idx], refl[:18], rng=0, missing_fraction=0.1)
        t = time.perf_counter()
        model = fit_scene_model(hist.observations, css)
        fit_s = time.perf_counter() - t
        t = time.perf_counter()
        res, _ = model.estimate(hist.observations)
        est_s = time.perf_counter() - t
        tw = hist.true_white / hist.true_white[:, 1:2]
        ae = angular_error_deg(res.white, tw)
        out["fit"].append({"frames": n, "fit_s": fit_s, "estimate_all_s": est_s, "median_deg": float(np.median(ae))})
        print(f"history {n:6d}: fit {fit_s:6.2f} s, estimate all {est_s:6.2f} s, median {np.median(ae):.3f}°")
    hist = simulate_history(css, granada[:600], refl[:18], rng=1, missing_fraction=0.0)
    model = fit_scene_model(hist.observations.subset(slice(0, 200)), css)
    rest = hist.observations.subset(slice(200, None))
    tw = hist.true_white[200:] / hist.true_white[200:, 1:2]
    solver = model.solver()
    y = rest.values / model.noise["scale"]
    present = np.all(np.isfinite(y), axis=-1)
    times = []
    for i in range(len(rest.frames)):
        t = time.perf_counter()
        solver.solve(y[i : i + 1], present[i : i + 1])
        times.append(time.perf_counter() - t)
    out["latency_ms"] = {"median": float(np.median(times) * 1e3), "p99": float(np.percentile(times, 99) * 1e3)}
    print(f"per-frame latency: median {out['latency_ms']['median']:.3f} ms, p99 {out['latency_ms']['p99']:.3f} ms")
    rng = np.random.default_rng(5)
    print("visible patches | median angular error (°)")
    for k in (2, 3, 4, 6, 9, 12, 18):
        vals = rest.values.copy()
        for f in range(vals.shape[0]):
            hide = rng.choice(18, 18 - k, replace=False)
            vals[f, hide] = np.nan
        rest_k = type(rest)(rest.frames, rest.patches, vals, rest.times)
        res, _ = model.estimate(rest_k)
        med = float(np.median(angular_error_deg(res.white, tw)))
        out["patches"].append({"visible": k, "median_deg": med})
        print(f"{k:15d} | {med:.3f}")
    path = Path(__file__).parent / "results" / "online.json"
    path.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
