"""Short histories (issue 28): the diagnosis's whole-history light verdict on 2, 3 and 6 frames.

``illumon diagnose`` judges a history shorter than the bilinear effects need (``rank + 2`` = 6 frames)
for its light alone (:func:`illumon.diagnosis.fit._short_history`): ``off_locus_illuminant`` when the scene model's
common level says lamps light it throughout (:func:`illumon.diagnosis.fit._lamp_lit_history`), else ``none``. This
benchmark counts how often that verdict names lamp light

* on rendered **daylight** histories (``none+rendered``: a daylight-preset balance and a colour matrix to sRGB
  primaries; ``none+awb``: the camera rebalancing every frame) — every naming is a false alarm;
* on rendered **lamp-lit** histories (``none+lamps``: lamps only, over pale man-made surfaces, as the real MIMO scenes)
  — every miss is a miss,

``--primaries camera``: sensor RGB instead — ``none`` (daylight over measured surfaces), ``pale`` (daylight over pale
surfaces) and ``raw+lamps`` (the lamps of ``none+lamps`` seen as raw output), judged with ``primaries="camera"``;
``--primaries camera --rendered``: the rendered cases above judged as sensor RGB — what the real MIMO scenes are
(16-bit linear output of a raw converter, which looks raw and is what an outside check runs with the default
``camera``), a case the sensor-RGB cases, all raw, hid;

from ``benchmarks/unmeasured.py``'s renderer (both simulators, ``illumon`` and ``rawsim``), each 30-frame history cut
into disjoint windows of ``--frames`` consecutive frames (every window judged; the full 30 frames too). The diagnosis
is given the linear-sRGB colour-matching functions clipped at 0 as sensitivities, as outside checkers pass for a camera
nobody measured. Nothing was chosen on this benchmark (``SHORT_HISTORY_FRAMES`` = 1: a single frame has a common
level too, not a tuned value); ``--split dev`` (Nikon and Point Grey cameras, dev surfaces and Granada 0–1299) is the
development data, ``--split score`` (Canon, Hasselblad, Pentax, Phase One; score surfaces, Granada 1300–2599) is held
out.

    python benchmarks/short_histories.py [--split dev|score] [--seeds 2] [--frames 1,2,3,6] [--primaries camera]
        [--rendered]

Prints a table and writes ``benchmarks/results/short_histories.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import rawsim  # noqa: E402
import unmeasured  # noqa: E402
from illumon.camera.primaries import srgb_sensitivities  # noqa: E402
from illumon.diagnosis.fit import _lamp_lit_history  # noqa: E402

CASES = {"srgb": {"none+rendered": False, "none+awb": False, "none+lamps": True},
         "camera": {"none": False, "pale": False, "raw+lamps": True}}
"""Per primaries, case of ``benchmarks/unmeasured.py`` → whether its history is lit by lamps."""


def windows(n_frames: int, size: int) -> list[np.ndarray]:
    """Disjoint windows of ``size`` consecutive frame indices of a history of ``n_frames`` (the whole history when
    ``size`` ≥ ``n_frames``)."""
    if size >= n_frames:
        return [np.arange(n_frames)]
    return [np.arange(i, i + size) for i in range(0, n_frames - size + 1, size)]


def named(obs, css: np.ndarray, primaries: str = "srgb") -> bool:
    """Whether the short-history verdict names lamp light for ``obs``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return _lamp_lit_history(obs, css, [], primaries) is not None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--split", choices=["dev", "score"], default="dev")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--frames", default="1,2,3,6,30", help="window lengths, comma-separated (30: the whole history)")
    ap.add_argument("--primaries", choices=["srgb", "camera"], default="srgb",
                    help="srgb: rendered histories; camera: sensor-RGB ones")
    ap.add_argument("--rendered", action="store_true",
                    help="with --primaries camera: the rendered cases (none+rendered, none+awb, none+lamps) as sensor RGB")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "short_histories.json"))
    args = ap.parse_args(argv)
    cases = CASES["srgb" if args.rendered else args.primaries]
    sizes = [int(v) for v in args.frames.split(",")]
    cams = rawsim.SCORE_CAMERAS if args.split == "score" else rawsim.DEV_CAMERAS
    css = np.clip(srgb_sensitivities(), 0.0, None)
    counts: dict[tuple[str, int], list[int]] = {}
    for sim in ("illumon", "rawsim"):
        for cam in cams:
            for case in cases:
                for seed in range(args.seeds):
                    obs, _, _ = unmeasured.render(sim, cam, case, seed)
                    for size in sizes:
                        c = counts.setdefault((case, size), [0, 0])
                        for idx in windows(len(obs.frames), size):
                            c[0] += named(obs.subset(idx), css, args.primaries)
                            c[1] += 1
    split = ("development (dev cameras, surfaces, Granada 0–1299)" if args.split == "dev"
             else "score (held out: score cameras, surfaces, Granada 1300–2599)")
    print(f"split: {split}; {args.seeds} seed(s) × {len(cams)} cameras × 2 simulators; primaries {args.primaries}"
          + ("; rendered histories" if args.rendered else ""))
    print(f"{'case':<15} {'light':<9} " + " ".join(f"{f'{s} frames':>14}" for s in sizes))
    rows = []
    for case, lamp in cases.items():
        cells = []
        for size in sizes:
            k, n = counts[(case, size)]
            rows.append({"case": case, "lamp_lit": lamp, "frames": size, "named": k, "histories": n})
            cells.append(f"{k:>4}/{n:<4} {100 * k / n:4.0f}%")
        print(f"{case:<15} {'lamps' if lamp else 'daylight':<9} " + " ".join(f"{c:>14}" for c in cells))
    print("off_locus_illuminant named: on daylight a false alarm, on lamps a hit")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    report = {"split": args.split, "seeds": args.seeds, "primaries": args.primaries, "rendered": args.rendered,
              "rows": rows}
    Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
