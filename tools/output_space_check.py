"""How often :func:`illumon.camera.primaries.output_space_warning` warns of histories declared sensor RGB: the
scene patches of the histories ``benchmarks/unmeasured.py`` renders (two seeds × each camera of the split × both
simulators, with and without veiling glare), per case — sensor-RGB cases should never be warned of, rendered ones
are caught where their patches spread beyond what sensor RGB gives.

    python tools/output_space_check.py [--split dev|score]

Choose on the development split; the score split is held out (run once after a choice).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import rawsim  # noqa: E402
import unmeasured  # noqa: E402
from illumon.camera.primaries import output_space_warning  # noqa: E402
from illumon.priors.scene_average import scene_average_evidence  # noqa: E402
from illumon.simulation import datasets  # noqa: E402

CASES = ("none", "grey", "pale", "raw+lamps", "none+matrix", "none+rendered", "none+awb", "grey+rendered",
         "none+lamps")
"""Sensor RGB first (``none``, ``grey``, ``pale``, ``raw+lamps``), then rendered output."""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=["dev", "score"], default="dev")
    args = ap.parse_args(argv)
    if datasets.shared_data_dir() is None:
        print("skipped: measured data (../shared/data) not available")
        return 0
    cams = rawsim.DEV_CAMERAS if args.split == "dev" else rawsim.SCORE_CAMERAS
    base = 7_000 if args.split == "dev" else 700_000  # the benchmark's seeds
    print(f"split {args.split} ({'development' if args.split == 'dev' else 'held out'}): {len(cams)} cameras × 2 seeds "
          "× 2 simulators per case")
    print(f"{'case':14} {'glare':5} {'warned':>8} {'spread median':>14} {'range':>11}")
    for case in CASES:
        for flare in (False, True):
            warned, spreads = 0, []
            for sim in ("illumon", "rawsim"):
                for i, cam in enumerate(cams):
                    for s in range(2):
                        obs, _, _ = unmeasured.render(sim, cam, case, base + 100 * i + s, flare)
                        v = obs.values[:, : unmeasured.PATCHES]
                        warned += output_space_warning(v) is not None
                        seen = np.all(np.isfinite(v) & (v > 0), axis=-1)
                        spreads.append(scene_average_evidence(np.where(seen[..., None], v, 0.0), seen).spread)
            print(f"{case:14} {'yes' if flare else 'no':5} {warned:4d}/{len(spreads):<3d} {np.median(spreads):14.2f} "
                  f"{min(spreads):5.2f}–{max(spreads):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
