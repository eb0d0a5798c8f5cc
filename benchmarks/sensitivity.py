"""Benchmark of the single-chart sensitivity estimators (issues 5 and 16) under three protocols.

Every measured camera (24 files; the two Nikon D50 measurements count as one camera) is estimated from a BabelColor
ColorChecker and the camera prior is rebuilt without

* ``camera``: the camera under test (leave-one-camera-out); charts rendered by the linear model under 3 measured
  Granada daylights with 0.2 %, 0.5 % and 1 % Gaussian noise (:func:`illumon.sensitivity.evaluate.simulate_chart`);
* ``manufacturer``: every camera of its manufacturer (leave-one-manufacturer-out, issue 16: a prior that has seen a
  Canon 60D should not score a Canon 50D); the same charts;
* ``rawsim``: leave-one-manufacturer-out on charts photographed through the independent raw pipeline
  (:func:`rawsim.render_chart`: shot noise with the body's gain at ISO 100…1600, read noise, black clipping, 8/10/12-bit
  output) under 3 daylights of the score half of Granada (:data:`rawsim.SCORE_DAYLIGHT`).

Prints each method's mean R/G/B RMSE of max-normalised curves and its worst camera (like Huynh & Robles-Kelly's
Tables I/II) per protocol, plus daylight recovery and colour-correction figures, and writes
``benchmarks/results/sensitivity.json``.

Run: ``python benchmarks/sensitivity.py [--protocols camera,manufacturer,rawsim] [--methods default,bayes,…]``
(about 3 minutes per protocol on one core).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import rawsim  # noqa: E402
from illumon.camera import render  # noqa: E402
from illumon.daylight import CMFS  # noqa: E402
from illumon.priors import colourchecker_reflectances  # noqa: E402
from illumon.sensitivity import METHODS, channel_gains_Han2012, daylight_Han2012, to_cie1931_Huynh2014  # noqa: E402
from illumon.sensitivity.evaluate import camera_manufacturer, camera_model, leave_one_out, simulate_chart  # noqa: E402
from illumon.sensitivity.han2012 import (  # noqa: E402
    fluorescent_reflectances,
    render_fluorescent_chart,
    shipped_fluorophores,
)
from illumon.simulation import datasets  # noqa: E402

NOISE = [0.002, 0.005, 0.01]
N_DAYLIGHTS = 3
SEED = 0


def han_chart_maker(reflectances: np.ndarray, noise: float = 0.005):
    """Extra inputs of Han et al.: a simulated fluorescent chart in the same frame (same exposure) as the
    chart."""
    ex, em = shipped_fluorophores()
    sfl = fluorescent_reflectances(ex)

    def make(camera: np.ndarray, illuminant: np.ndarray, rng: np.random.Generator) -> dict:
        scale = render(camera, illuminant, reflectances).max()
        v = render_fluorescent_chart(camera, illuminant) / scale
        v = np.clip(v + noise * rng.standard_normal(v.shape), 0.0, None)
        return {"fluorescent_rgb": v, "fluorescent_emissions": em, "fluorescent_reflectances": sfl}

    return make


def spectrum_rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a / a.mean() - b / b.mean()) ** 2)))


def daylight_and_correction(cams: dict, gran: np.ndarray, refl: np.ndarray, rng: np.random.Generator) -> dict:
    """Han §6.2 daylight recovery and eq. (20) / Huynh §IV correction with known sensitivities."""
    idx = rng.choice(len(gran), 50, replace=False)
    out: dict = {"daylight_rmse": {}, "correction": {}}
    for basis in ("cie", "measured"):
        errs = []
        for _name, c in cams.items():
            for i in idx[:5]:
                x = render(c, gran[i], refl)
                errs.append(spectrum_rmse(daylight_Han2012(x, refl, c, basis=basis), gran[i]))
        out["daylight_rmse"][basis] = float(np.mean(errs))
    before, after, xyz_err = [], [], []
    for c in cams.values():
        for i, j in zip(idx[:10], idx[10:20], strict=True):
            src, dst = render(c, gran[i], refl), render(c, gran[j], refl)
            g = channel_gains_Han2012(c, gran[i], c, gran[j])
            before.append(np.abs(src / src.max() - dst / dst.max()).mean())
            after.append(np.abs(src * g / dst.max() - dst / dst.max()).mean())
            xyz = render(CMFS, gran[i], refl)
            est = to_cie1931_Huynh2014(render(c / c.max(), gran[i], refl), c)
            xyz_err.append(np.linalg.norm(est / est[:, 1].max() - xyz / xyz[:, 1].max(), axis=1).mean())
    out["correction"] = {
        "illuminant_change_mean_abs_before": float(np.mean(before)),
        "illuminant_change_mean_abs_after_gains": float(np.mean(after)),
        "cie1931_transfer_mean_xyz_error": float(np.mean(xyz_err)),
    }
    return out


PROTOCOLS = ("camera", "manufacturer", "rawsim")
ALL_METHODS = ("default", "kinoshita2023", "jiang2013", "huynh2014", "han2012")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--protocols", default=",".join(PROTOCOLS), help="comma-separated: camera,manufacturer,rawsim")
    ap.add_argument("--methods", default=",".join(ALL_METHODS), help="comma-separated methods")
    args = ap.parse_args()
    protocols = [p for p in args.protocols.split(",") if p]
    methods = [m for m in args.methods.split(",") if m]
    if any(p not in PROTOCOLS for p in protocols) or any(m not in ALL_METHODS for m in methods):
        print(f"illumon: error: protocols are {', '.join(PROTOCOLS)}; methods {', '.join(ALL_METHODS)}", file=sys.stderr)
        return 2
    if datasets.shared_data_dir() is None:
        print("measured data not found (../shared/data); nothing to benchmark", file=sys.stderr)
        return 1
    names = datasets.camera_names()
    cams = {n: datasets.load_camera(n) for n in names}
    _, gran = datasets.load_granada_daylight()
    _, refl = colourchecker_reflectances("BabelColor Average")
    rng = np.random.default_rng(SEED)
    daylights = gran[rng.choice(len(gran), N_DAYLIGHTS, replace=False)]
    score_day = rawsim.daylight_pool("score")
    setups = {
        "camera": {"group": camera_model, "chart_renderer": simulate_chart, "illuminants": daylights},
        "manufacturer": {"group": camera_manufacturer, "chart_renderer": simulate_chart, "illuminants": daylights},
        "rawsim": {"group": camera_manufacturer, "chart_renderer": rawsim.render_chart,
                   "illuminants": score_day[np.random.default_rng(SEED + 1).choice(len(score_day), N_DAYLIGHTS,
                                                                                    replace=False)]},
    }
    rows: dict = {p: {} for p in protocols}
    for p in protocols:
        st = setups[p]
        for method in methods:
            extra = {"chart_maker": han_chart_maker(refl)} if method == "han2012" else {}
            t0 = time.perf_counter()
            res = leave_one_out(METHODS[method], cams, st["illuminants"], refl, noise=NOISE, seed=SEED, name=method,
                                group=st["group"], chart_renderer=st["chart_renderer"], **extra)
            worst, worst_rmse = res.worst
            rows[p][method] = {
                "mean_rgb": res.mean.tolist(), "mean": res.overall, "worst_camera": worst, "worst_rmse": worst_rmse,
                "per_camera": {n: r.tolist() for n, r in zip(res.cameras, res.rmse, strict=True)},
                "seconds": time.perf_counter() - t0,
            }
            print(f"  {p} {method}: {res.overall:.4f} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    titles = {"camera": "Leave-one-camera-out, linear-model charts",
              "manufacturer": "Leave-one-manufacturer-out, linear-model charts",
              "rawsim": "Leave-one-manufacturer-out, charts through the raw pipeline (rawsim, score daylight)"}
    for p in protocols:
        print(f"\n{titles[p]}: {len(names)} cameras × {N_DAYLIGHTS} Granada daylights"
              + (f", noise {NOISE}" if p != "rawsim" else ""))
        print(f"split: {titles[p].split(',')[0].lower()} (the camera or manufacturer scored is in no prior)")
        print(f"{'method':<11} {'R':>7} {'G':>7} {'B':>7} {'mean':>7}  worst camera (mean RMSE)")
        for m, row in rows[p].items():
            r, g, b = row["mean_rgb"]
            print(f"{m:<11} {r:7.4f} {g:7.4f} {b:7.4f} {row['mean']:7.4f}  {row['worst_camera']} ({row['worst_rmse']:.3f})")
    print("\nMean RMSE side by side")
    print(f"{'method':<11}" + "".join(f"{p:>14}" for p in protocols))
    for m in methods:
        print(f"{m:<11}" + "".join(f"{rows[p][m]['mean']:14.4f}" for p in protocols))
    extra = daylight_and_correction(cams, gran, refl, rng)
    print("Daylight recovery with known sensitivities (Han §6.2), RMSE of unit-mean spectra:")
    for k, v in extra["daylight_rmse"].items():
        print(f"  {k:<9} basis: {v:.4f}")
    print("Colour correction:")
    for k, v in extra["correction"].items():
        print(f"  {k}: {v:.4f}")
    out = Path(__file__).resolve().parent / "results"
    out.mkdir(exist_ok=True)
    payload = {"protocol": {"cameras": names, "daylights": N_DAYLIGHTS, "noise": NOISE, "seed": SEED,
                            "protocols": protocols}}
    payload.update(methods=rows, **extra)
    (out / "sensitivity.json").write_text(json.dumps(payload, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
