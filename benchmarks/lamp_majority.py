"""Scenes lit by lamps most of the time (issue 28): the diagnosis's off-locus verdict on sensor-RGB histories whose
lamp lights a minority of the frames (the simulators' case) against two thirds of them (the outside check's).

The outside check hid off-locus light in 36-frame histories with 24 frames mixed 35–80 % with a fluorescent, LED or
high-pressure lamp, and the diagnosis named it in 0 of 2. The project's simulator lit 3…F/5 frames at 60–100 %
(:data:`illumon.simulation.effects.LAMP_FRAMES` ``"minority"``): the spectral stage judges each frame's gain from a
free illuminant in units of the history's *typical* frame, which a majority of lamp-lit frames makes lamp-lit too.
``"majority"`` puts the outside check's case into the simulator. Both are rendered here with the same cameras and
seeds (:func:`illumon.simulation.effects.hide_effect`, 36 frames, measured sensitivities given, sensor RGB), and
``illumon.diagnosis.diagnose`` is scored on whether it names ``off_locus_illuminant`` and how many of the lamp-lit
frames it lists.

Development cameras and seeds only (:data:`illumon.simulation.effects.DEV_CAMERAS`, seeds 5 000…): nothing is chosen
on this benchmark; it measures a known miss.

    python benchmarks/lamp_majority.py [--histories 10]

Prints a table and writes ``benchmarks/results/lamp_majority.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core")]

from illumon.diagnosis.fit import diagnose  # noqa: E402
from illumon.simulation.effects import DEV_CAMERAS, LAMP_FRAMES, hide_effect  # noqa: E402

FRAMES = 36
SEED0 = 5000


def run(kind: str, n: int) -> list[dict]:
    """``n`` histories with lamp frames of ``kind``: named or not, and the lamp-lit frames found."""
    rows = []
    for i in range(n):
        cam = DEV_CAMERAS[i % len(DEV_CAMERAS)]
        h = hide_effect("off_locus_illuminant", cam, SEED0 + i, frames=FRAMES, lamp_frames=kind)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = diagnose(h.observations, h.history.sensitivities, reestimate=False)
        off = next((e for e in d.effects if e["effect"] == "off_locus_illuminant"), None)
        found = set(off["parameters"]["frame_indices"]) if off else set()
        truth = set(h.parameters["frames"])
        rows.append({"camera": cam, "seed": SEED0 + i, "lamp": h.parameters["lamp"], "lamp_frames": len(truth),
                     "named": off is not None, "found": len(found & truth), "daylight_listed": len(found - truth),
                     "effects": [e["effect"] for e in d.effects]})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--histories", type=int, default=10)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "lamp_majority.json"))
    args = ap.parse_args(argv)
    print(f"development cameras and seeds ({SEED0}…), {FRAMES} frames, sensor RGB, measured sensitivities given")
    print(f"{'lamp frames':<12} {'named':>9} {'lamp frames listed':>19} {'daylight frames listed':>23}")
    out = {}
    for kind in LAMP_FRAMES:
        rows = run(kind, args.histories)
        out[kind] = rows
        named = sum(r["named"] for r in rows)
        found = sum(r["found"] for r in rows)
        total = sum(r["lamp_frames"] for r in rows)
        print(f"{kind:<12} {named:>4} / {len(rows):<3} {found:>10} / {total:<6} "
              f"{sum(r['daylight_listed'] for r in rows):>16}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
