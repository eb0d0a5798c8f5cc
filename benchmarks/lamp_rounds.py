"""The scene fit's lamp rounds with and without the borderline rule (issue 29, :data:`illumon.model.fit.BORDERLINE`).

Each history is ``benchmarks/refit.py``'s (measured Nikon D5100 sensitivities, Granada daylight in sequence, 16
Munsell reflectances, 10 % of patches missing; seeds 1…N) fitted twice with :func:`illumon.model.fit_scene_model`:
with ``BORDERLINE = 0`` (a round refits on every change of the frames left out, as before) and with the default.
Prints per history the median and p95 camera-white error against the truth, the scene fits made and how far the
whites moved between the two, then the means per size.

    nice python benchmarks/lamp_rounds.py [--sizes 1000,2000,5000] [--seeds 10]
"""

from __future__ import annotations

import argparse
import os
import warnings

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from illumon.camera import angular_error_deg  # noqa: E402
from illumon.model import fit as fit_mod  # noqa: E402
from illumon.simulation import simulate_history  # noqa: E402
from refit import spectra  # noqa: E402


def main() -> None:
    """Fit every history both ways; print the table and the means."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000,5000")
    ap.add_argument("--seeds", type=int, default=10)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    css, day, refl, provenance = spectra()
    fits = [0]
    fixed = fit_mod._fit_fixed_camera

    def counted(*a, **k):  # noqa: ANN002, ANN003, ANN202 - a pass-through
        fits[0] += 1
        return fixed(*a, **k)

    fit_mod._fit_fixed_camera = counted
    default = fit_mod.BORDERLINE
    print(f"data: {provenance}; BORDERLINE 0 → {default}")
    print(f"{'frames':>6} {'seed':>4} {'median °':>15} {'p95 °':>15} {'fits':>6} {'moved median / max °':>21}")
    rows = []
    for n in (int(v) for v in args.sizes.split(",")):
        for seed in range(1, args.seeds + 1):
            idx = (np.arange(n) * 7 + seed * 131) % len(day)
            hist = simulate_history(css, day[idx], refl, rng=seed, missing_fraction=0.1)
            got = []
            for border in (0.0, default):
                fit_mod.BORDERLINE, fits[0] = border, 0
                white = fit_mod.fit_scene_model(hist.observations, css).history_estimate[0].white
                err = angular_error_deg(white, hist.true_white)
                got.append((float(np.median(err)), float(np.percentile(err, 95)), fits[0], white))
            moved = angular_error_deg(got[0][3], got[1][3])
            rows.append((n, got[0][0], got[1][0], got[0][1], got[1][1], got[0][2], got[1][2]))
            print(f"{n:>6} {seed:>4} {got[0][0]:6.3f} → {got[1][0]:6.3f} {got[0][1]:6.3f} → {got[1][1]:6.3f} "
                  f"{got[0][2]:>2} → {got[1][2]:<2} {float(np.median(moved)):9.3f} / {float(np.max(moved)):.3f}",
                  flush=True)
    fit_mod.BORDERLINE = default
    a = np.array(rows)
    for n in dict.fromkeys(a[:, 0]):
        s = a[a[:, 0] == n]
        print(f"{int(n)} frames: mean median {s[:, 1].mean():.3f} → {s[:, 2].mean():.3f}°, mean p95 "
              f"{s[:, 3].mean():.3f} → {s[:, 4].mean():.3f}°, scene fits {int(s[:, 5].sum())} → {int(s[:, 6].sum())}")
    print(f"all: mean median {a[:, 1].mean():.3f} → {a[:, 2].mean():.3f}°, scene fits {int(a[:, 5].sum())} → "
          f"{int(a[:, 6].sum())}")


if __name__ == "__main__":
    main()
