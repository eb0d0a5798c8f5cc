"""Leave-one-camera-out benchmark of the single-chart sensitivity estimators (issue 5).

Every measured camera (24 files; the two Nikon D50 measurements count as one camera and are held out
together) is
estimated from a BabelColor ColorChecker rendered under 3 measured Granada daylight spectra with 0.2 %, 0.5 %
and
1 % noise; priors are rebuilt without the camera under test. Prints a table of each method's mean R/G/B RMSE
of
max-normalised curves and its worst camera (like Huynh & Robles-Kelly's Tables I/II), plus daylight recovery
and
colour-correction figures, and writes ``benchmarks/results/sensitivity.json``.

Run: ``python benchmarks/sensitivity.py`` (about 3 minutes on one core).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from illumon import datasets  # noqa: E402
from illumon.camera import render  # noqa: E402
from illumon.daylight import CMFS  # noqa: E402
from illumon.reflectance import colourchecker_reflectances  # noqa: E402
from illumon.sensitivity import METHODS, channel_gains_Han2012, daylight_Han2012, to_cie1931_Huynh2016  # noqa: E402
from illumon.sensitivity.evaluate import leave_one_out  # noqa: E402
from illumon.sensitivity.han2012 import (  # noqa: E402
    fluorescent_reflectances,
    render_fluorescent_chart,
    shipped_fluorophores,
)

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
            est = to_cie1931_Huynh2016(render(c / c.max(), gran[i], refl), c)
            xyz_err.append(np.linalg.norm(est / est[:, 1].max() - xyz / xyz[:, 1].max(), axis=1).mean())
    out["correction"] = {
        "illuminant_change_mean_abs_before": float(np.mean(before)),
        "illuminant_change_mean_abs_after_gains": float(np.mean(after)),
        "cie1931_transfer_mean_xyz_error": float(np.mean(xyz_err)),
    }
    return out


def main() -> int:
    if datasets.shared_data_dir() is None:
        print("measured data not found (../shared/data); nothing to benchmark", file=sys.stderr)
        return 1
    names = datasets.camera_names()
    cams = {n: datasets.load_camera(n) for n in names}
    _, gran = datasets.load_granada_daylight()
    _, refl = colourchecker_reflectances("BabelColor Average")
    rng = np.random.default_rng(SEED)
    daylights = gran[rng.choice(len(gran), N_DAYLIGHTS, replace=False)]
    rows = {}
    for method in ("default", "bayes", "jiang2013", "huynh2016", "han2012"):
        extra = {"chart_maker": han_chart_maker(refl)} if method == "han2012" else {}
        t0 = time.perf_counter()
        res = leave_one_out(
            METHODS[method], cams, daylights, refl, noise=NOISE, seed=SEED, name=method, **extra
        )
        worst, worst_rmse = res.worst
        rows[method] = {
            "mean_rgb": res.mean.tolist(),
            "mean": res.overall,
            "worst_camera": worst,
            "worst_rmse": worst_rmse,
            "per_camera": {n: r.tolist() for n, r in zip(res.cameras, res.rmse, strict=True)},
            "seconds": time.perf_counter() - t0,
        }
        print(f"  {method}: {res.overall:.4f} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    print(f"Leave-one-camera-out, {len(names)} cameras × {N_DAYLIGHTS} Granada daylights, noise {NOISE}")
    print(f"{'method':<11} {'R':>7} {'G':>7} {'B':>7} {'mean':>7}  worst camera (mean RMSE)")
    for m, row in rows.items():
        r, g, b = row["mean_rgb"]
        print(
            f"{m:<11} {r:7.4f} {g:7.4f} {b:7.4f} {row['mean']:7.4f}  "
            f"{row['worst_camera']} ({row['worst_rmse']:.3f})"
        )
    extra = daylight_and_correction(cams, gran, refl, rng)
    print("Daylight recovery with known sensitivities (Han §6.2), RMSE of unit-mean spectra:")
    for k, v in extra["daylight_rmse"].items():
        print(f"  {k:<9} basis: {v:.4f}")
    print("Colour correction:")
    for k, v in extra["correction"].items():
        print(f"  {k}: {v:.4f}")
    out = Path(__file__).resolve().parent / "results"
    out.mkdir(exist_ok=True)
    payload = {"protocol": {"cameras": names, "daylights": N_DAYLIGHTS, "noise": NOISE, "seed": SEED}}
    payload.update(methods=rows, **extra)
    (out / "sensitivity.json").write_text(json.dumps(payload, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
