"""How often the output-space warnings fire, per case of the histories ``benchmarks/unmeasured.py`` renders.

* Declared sensor RGB (default): :func:`illumon.camera.primaries.output_space_warning` on the scene patches (two
  seeds × each camera of the split × both simulators, with and without veiling glare) — sensor-RGB cases should
  never be warned of, rendered ones are caught where their patches spread beyond what sensor RGB gives or a
  saturated patch's weakest channel was clipped away.
* ``--declared srgb``: each history fitted as rendered output without a reference (one seed × each camera × both
  simulators), counting those read as lit by lamps throughout, which :func:`illumon.camera.balance.unbalanced_warning`
  says — sensor RGB declared ``srgb`` mostly is, rendered daylight should never be.

    python tools/output_space_check.py [--split dev|score] [--declared camera|srgb]

Choose on the development split; the score split is held out (run once after a choice).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import rawsim  # noqa: E402
import unmeasured  # noqa: E402
from illumon.camera import angular_error_deg  # noqa: E402
from illumon.camera.primaries import chromaticity_spread, output_space_warning, weakest_channel  # noqa: E402
from illumon.model import fit_scene_model  # noqa: E402
from illumon.model.lamps import unbalanced_probability  # noqa: E402
from illumon.simulation import datasets  # noqa: E402

CASES = ("none", "grey", "pale", "raw+lamps", "none+matrix", "none+rendered", "none+awb", "grey+rendered",
         "none+lamps")
"""Sensor RGB first (``none``, ``grey``, ``pale``, ``raw+lamps``), then rendered output."""

SRGB_CASES = ("none", "pale", "none+rendered", "none+awb", "none+lamps")
"""``--declared srgb``: sensor RGB, rendered daylight, rendered lamp light; no reference."""


def declared_srgb(cams: list[str], base: int) -> None:
    """Each history of :data:`SRGB_CASES` fitted as ``srgb``: how many read as lit by lamps throughout (warned of),
    the median of their whites' median errors, and the share of frames called lamp-lit."""
    print(f"{'case':14} {'read lamp-lit':>13} {'white median':>12} {'frames lamp-lit':>15}")
    for case in SRGB_CASES:
        lit, errs, frames = 0, [], []
        for sim in ("illumon", "rawsim"):
            for i, cam in enumerate(cams):
                obs, white, _ = unmeasured.render(sim, cam, case, base + 100 * i)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    model = fit_scene_model(obs, None, primaries="srgb")
                res, extra = model.history_estimate
                lit += unbalanced_probability(model) > 0.5
                errs.append(float(np.median(angular_error_deg(res.white, white))))
                frames.append(float(np.mean(np.asarray(extra["non_daylight"]) >= 0.5)))
        print(f"{case:14} {lit:9d}/{len(errs):<3d} {np.median(errs):11.2f}° {np.mean(frames):15.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=["dev", "score"], default="dev")
    ap.add_argument("--declared", choices=["camera", "srgb"], default="camera",
                    help="the output space the histories are declared in")
    args = ap.parse_args(argv)
    if datasets.shared_data_dir() is None:
        print("skipped: measured data (../shared/data) not available")
        return 0
    cams = rawsim.DEV_CAMERAS if args.split == "dev" else rawsim.SCORE_CAMERAS
    base = 7_000 if args.split == "dev" else 700_000  # the benchmark's seeds
    if args.declared == "srgb":
        print(f"split {args.split} ({'development' if args.split == 'dev' else 'held out'}): {len(cams)} cameras × 1 "
              "seed × 2 simulators per case, declared srgb, no reference")
        declared_srgb(cams, base)
        return 0
    print(f"split {args.split} ({'development' if args.split == 'dev' else 'held out'}): {len(cams)} cameras × 2 seeds "
          "× 2 simulators per case, declared camera")
    print(f"{'case':14} {'glare':5} {'warned':>8} {'spread median':>14} {'range':>11} {'weakest channel median':>23}")
    for case in CASES:
        for flare in (False, True):
            warned, spreads, weakest = 0, [], []
            for sim in ("illumon", "rawsim"):
                for i, cam in enumerate(cams):
                    for s in range(2):
                        obs, _, _ = unmeasured.render(sim, cam, case, base + 100 * i + s, flare)
                        v = obs.values[:, : unmeasured.PATCHES]
                        warned += output_space_warning(v) is not None
                        spreads.append(chromaticity_spread(v))
                        weakest.append(weakest_channel(v))
            print(f"{case:14} {'yes' if flare else 'no':5} {warned:4d}/{len(spreads):<3d} {np.median(spreads):14.2f} "
                  f"{min(spreads):5.2f}–{max(spreads):.2f} {np.median(weakest):23.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
