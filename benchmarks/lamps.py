"""Real lamp-lit scenes: illumon's camera white without a reference against gray-world, and ``non_daylight`` per frame.

The MIMO lab set of ``../shared/data/real/mimo-lab`` (Beigpour et al. 2014): four table-top scenes, each seen by a fixed
camera under up to six combinations of two lamps (white, red or blue filters), 16-bit linear, with the illuminant's
chromaticity measured at every pixel. Per scene, static regions are chosen once from the images alone (12 × 12-pixel
blocks valid in every frame's mask, free of clipped pixels, in the brighter half, the most uniform 16 by their largest
coefficient of variation over the frames); each region's mean is an observation, its truth the mean of its
ground-truth chromaticities, a frame's truth the mean of its regions' (the two lamps light the scene unevenly, so one
white per frame is scored against the regions' average light). The scene model is fitted without sensitivities or a
reference (``--primaries srgb`` by default: raw-converted linear output; ``--primaries camera`` to read it as sensor RGB) and
every frame's camera white compared with gray-world over the same regions (angular error, degrees).

Split, fixed before any parameter was chosen: **development** ``bmug``, ``diff`` (looked at while developing),
**score** ``lion``, ``spdif`` (held out). The other side: the ``sony-dolp`` chart sets of ``benchmarks/real.py``
(development; :data:`illumon.model.lamps.LAMP_PRIOR` is the largest prior that flags none of their frames) — indoor
rooms lit through windows and by ceiling lamps, their light not measured (``../shared/data/real/README.md``). They
were once counted as daylight controls; they are not: what they check is that light the camera reads as near daylight
is not called lamp-lit, and no off-locus claim either way rests on them (printed as ``indoor, light unknown``).
``--sim N`` adds N simulated lamp-lit histories on the score cameras (:func:`simulated`).

``--diagnose`` adds the product's diagnosis as an outside user runs it (``illumon diagnose``: sensitivities the
linear-sRGB colour-matching functions clipped at 0, :func:`illumon.camera.primaries.srgb_sensitivities`, what outside
checkers pass for a camera nobody measured; values as loaded, white level 65535) on every scene, both with
``--primaries camera`` (the CLI's default) and ``srgb`` (raw-converted linear output, as the estimator's table above
reads it): the effects named, the lamp-lit frames, and whether ``off_locus_illuminant`` was named. The indoor side:
the ``sony-dolp`` chart sets — ``sony-raw`` with the mean measured camera's sensitivities (sensor RGB) and again with
the clipped sRGB functions (what an outside checker passes), the ISP sets with the clipped sRGB functions and
``--primaries srgb``. They have 3 frames, fewer than the bilinear effects need (6): the diagnosis judges them for their
light alone (:func:`illumon.diagnosis.fit._short_history`, as it does the 3-frame scene ``spdif``); the column also
gives the whole-history lamp check itself (:func:`illumon.diagnosis.fit._lamp_lit_history`).
``--split development`` runs the development scenes only, ``--split score`` the held-out ones (looked at once,
after every choice).

``python benchmarks/lamps.py`` prints the table and writes ``benchmarks/results/lamps.json``.

References
----------
.. [Beigpour2014] Beigpour, Riess, van de Weijer & Angelopoulou, IEEE TIP 2014: the MIMO lab set.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core"), str(ROOT / "service"), str(ROOT / "benchmarks")]

DEVELOPMENT = ("bmug", "diff")
SCORE = ("lion", "spdif")
BLOCK = 12
REGIONS = 16


def _read(path: Path) -> NDArray:
    import cv2

    im = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if im is None:
        raise FileNotFoundError(path)
    return im[..., ::-1] if im.ndim == 3 else im


def load_scene(folder: Path, scene: str):
    """Observations (regions × frames, linear 0…1 of 65535) and each frame's truth (F × 3, the regions' mean
    ground-truth chromaticity) of one MIMO scene."""
    from illumon.observations import Observations

    names = sorted(p.stem for p in (folder / "img").glob(f"{scene}_*.png"))
    imgs = [_read(folder / "img" / f"{n}.png").astype(float) for n in names]
    gts = [_read(folder / "groundtruth" / f"{n}.png").astype(float) for n in names]
    masks = [_read(folder / "masks" / f"{n}.png") > 0 for n in names]
    valid = np.all(masks, axis=0) & np.all([g.sum(-1) > 0 for g in gts], axis=0)
    h, w = imgs[0].shape[:2]
    cands = []
    for y in range(0, h - BLOCK + 1, BLOCK):
        for x in range(0, w - BLOCK + 1, BLOCK):
            if not valid[y:y + BLOCK, x:x + BLOCK].all():
                continue
            blocks = [im[y:y + BLOCK, x:x + BLOCK] for im in imgs]
            if any((b >= 0.98 * 65535).any() for b in blocks):
                continue
            lum = [b.sum(-1) for b in blocks]
            cands.append((min(v.mean() for v in lum), max(v.std() / max(v.mean(), 1e-9) for v in lum), y, x))
    c = np.array(cands)
    c = c[c[:, 0] >= np.median(c[:, 0])]
    c = c[np.argsort(c[:, 1])][:REGIONS]
    vals = np.empty((len(names), len(c), 3))
    truth = np.empty_like(vals)
    for j, (_, _, y, x) in enumerate(c):
        y, x = int(y), int(x)
        for f in range(len(names)):
            vals[f, j] = imgs[f][y:y + BLOCK, x:x + BLOCK].reshape(-1, 3).mean(0) / 65535.0
            g = gts[f][y:y + BLOCK, x:x + BLOCK].reshape(-1, 3)
            truth[f, j] = (g / g.sum(1, keepdims=True)).mean(0)
    obs = Observations([n.split("_", 1)[1] for n in names], [f"y{int(y)}x{int(x)}" for _, _, y, x in c], vals)
    return obs, truth.mean(axis=1)


def run(obs, primaries: str):
    """illumon's whites, ``non_daylight`` and ``confidence`` (no sensitivities, no reference)."""
    from illumon.model import fit_scene_model

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = fit_scene_model(obs, None, primaries=primaries)
    res, extra = model.history_estimate
    n = len(res.white)
    return (np.asarray(res.white, dtype=float), np.asarray(extra.get("non_daylight", np.zeros(n))),
            np.asarray(extra.get("confidence", np.full(n, np.nan)), dtype=float))


def diagnosis_row(obs, css: NDArray, primaries: str) -> dict:
    """The product's diagnosis of ``obs`` as ``illumon diagnose`` runs it (white level 65535), or why it refused."""
    from illumon.cli.diagnose import run_diagnosis

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = run_diagnosis("<history>", obs, css, white_level=65535.0, primaries=primaries)
    except ValueError as exc:
        return {"refused": str(exc).replace("<history>: ", ""), "off_locus": False, "effects": []}
    effects = [{"effect": e["effect"], "frames": e["parameters"].get("frames"),
                "non_daylight": e["parameters"].get("non_daylight"),
                "found_by": e["parameters"].get("found_by", "spectral" if e["effect"] == "off_locus_illuminant" else None),
                "illuminant_change_deg": e["illuminant_change_deg"]} for e in d.effects]
    return {"effect": d.effect, "effects": effects, "off_locus": any(e["effect"] == "off_locus_illuminant" for e in effects),
            "censoring_level": d.info.get("censoring_level")}


def _diagnosis_text(r: dict) -> str:
    if "refused" in r:
        return "refused (" + r["refused"].split(";")[0] + ")"
    if not r["effects"]:
        return "none"
    def frames(e: dict) -> str:
        nd = e.get("non_daylight") or [None] * len(e["frames"])
        return " [" + " ".join(f + ("" if v is None else f":{v:.2f}") for f, v in zip(e["frames"], nd, strict=True)) + "]"

    return ", ".join(e["effect"] + (frames(e) if e.get("frames") else "") for e in r["effects"])


def indoor_diagnosis(s) -> dict:
    """A ``sony-dolp`` indoor set (light unknown) through the diagnosis (module docstring): sony-raw with the mean
    measured camera's sensitivities, the ISP sets with the clipped sRGB functions; and the whole-history lamp check
    alone."""
    from illumon.camera.calibration import prior_sensitivities
    from illumon.camera.primaries import srgb_sensitivities
    from illumon.diagnosis.fit import _lamp_lit_history
    from real import _observations

    obs = _observations(s, [])
    clipped = np.clip(srgb_sensitivities(), 0.0, None)
    css, name = (clipped, "clipped sRGB functions") if s.primaries == "srgb" else (prior_sensitivities(),
                                                                                   "mean measured camera")
    out = {"sensitivities": name, "diagnose": diagnosis_row(obs, css, s.primaries)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lamp = _lamp_lit_history(obs, css, [], s.primaries)
    out["lamp_check"] = "off-locus" + str(lamp.parameters["frames"]) if lamp is not None else "near daylight (no off-locus)"
    out["off_locus"] = lamp is not None or out["diagnose"]["off_locus"]
    if s.primaries == "camera":  # sensor RGB as an outside checker passes it: the clipped sRGB functions
        out["diagnose_srgb_functions"] = diagnosis_row(obs, clipped, s.primaries)
        out["off_locus"] = out["off_locus"] or out["diagnose_srgb_functions"]["off_locus"]
    return out


def simulated(n: int) -> dict:
    """``n`` histories of :func:`illumon.simulation.effects.hide_effect` ``off_locus_illuminant`` (measured camera,
    Granada daylight, 3…F/5 frames lit 60–100 % by a CIE lamp) on the score cameras of ``benchmarks/rawsim.py``, seeds
    1 000 000…: lamp-lit frames flagged, daylight frames flagged, and the camera-white error of the lamp-lit and the
    daylight frames for illumon, the daylight-only joint retrieval and gray-world."""
    import rawsim
    from illumon.camera import angular_error_deg
    from illumon.model import fit_scene_model
    from illumon.retrieval import retrieve_illuminants
    from illumon.simulation import datasets
    from illumon.simulation.effects import hide_effect

    rows = []
    for i in range(n):
        cam = rawsim.SCORE_CAMERAS[i % len(rawsim.SCORE_CAMERAS)]
        css = datasets.load_camera(cam)
        h = hide_effect("off_locus_illuminant", cam, 1_000_000 + i)
        obs, truth = h.observations, h.history.true_white
        lamp = np.array(h.parameters["frames"])
        day = np.setdiff1d(np.arange(len(obs.frames)), lamp)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res, extra = fit_scene_model(obs, css).history_estimate
        nd = np.asarray(extra["non_daylight"])
        e = angular_error_deg(res.white, truth)
        ed = angular_error_deg(retrieve_illuminants(obs, css, start_offsets=(0.0,), polish_max_frames=0).white, truth)
        eg = angular_error_deg(np.nanmean(obs.values, axis=1), truth)
        rows.append({"camera": cam, "lamp": h.parameters["lamp"], "lamp_flagged": float(np.mean(nd[lamp] >= 0.5)),
                     "day_flagged": float(np.mean(nd[day] >= 0.5)),
                     "lamp_deg": [float(np.median(x[lamp])) for x in (e, ed, eg)],
                     "day_deg": [float(np.median(x[day])) for x in (e, ed, eg)]})
        r = rows[-1]
        print(f"sim {i} {cam:<14} {r['lamp']:<8} lamp frames flagged {r['lamp_flagged']:.2f}, daylight frames "
              f"{r['day_flagged']:.2f}; lamp-lit ° illumon/daylight-only/gray-world "
              + "/".join(f"{v:.2f}" for v in r["lamp_deg"]) + "; daylight ° " + "/".join(f"{v:.2f}" for v in r["day_deg"]))
    summ = {k: float(np.median([r[k] for r in rows])) for k in ("lamp_flagged", "day_flagged")}
    for k in ("lamp_deg", "day_deg"):
        summ[k] = [float(np.median([r[k][j] for r in rows])) for j in range(3)]
    print(f"simulated, median of {n}: lamp frames flagged {summ['lamp_flagged']:.2f}, daylight frames "
          f"{summ['day_flagged']:.2f}; lamp-lit ° illumon/daylight-only/gray-world "
          + "/".join(f"{v:.2f}" for v in summ["lamp_deg"]) + "; daylight ° " + "/".join(f"{v:.2f}" for v in summ["day_deg"]))
    return {"histories": rows, "median": summ}


def main(argv: list[str] | None = None) -> int:
    from real import angular, isp_sets, shared_data, sony_raw  # benchmarks/real.py

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "lamps.json"))
    ap.add_argument("--primaries", default="srgb", choices=["srgb", "camera"])
    ap.add_argument("--no-daylight", action="store_true", help="skip the sony-dolp indoor chart sets (light unknown)")
    ap.add_argument("--split", default="all", choices=["development", "score", "all"],
                    help="scenes to run: development (bmug, diff; and the sony-dolp indoor sets), score (lion, spdif), all")
    ap.add_argument("--diagnose", action="store_true",
                    help="add the product's diagnosis (clipped sRGB functions as sensitivities, white level 65535)")
    ap.add_argument("--sim", type=int, default=0,
                    help="also N simulated lamp-lit histories (score cameras, seeds 1 000 000…; 0: none)")
    args = ap.parse_args(argv)
    data = shared_data()
    folder = data / "real" / "mimo-lab"
    if not folder.is_dir():
        print(f"lamps.py: skipped: {folder} is absent (../shared/data or $ILLUMON_SHARED_DATA)")
        return 0
    report = {"development": list(DEVELOPMENT), "score": list(SCORE), "primaries": args.primaries, "scenes": {},
              "indoor_sets": {}}
    print(f"development scenes: {', '.join(DEVELOPMENT)}; score (held out): {', '.join(SCORE)}; primaries {args.primaries}")
    print(f"{'scene':<8} {'split':<12} {'illumon °':>9} {'gray-world °':>12} {'ratio':>6}  conf / <1°  "
          "non_daylight per frame")
    scenes = {"development": DEVELOPMENT, "score": SCORE, "all": DEVELOPMENT + SCORE}[args.split]
    report["split_run"] = args.split
    if args.split != "development":
        print("score scenes (lion, spdif) included: held out, to be looked at once after every choice")
    from illumon.camera.primaries import srgb_sensitivities

    css = np.clip(srgb_sensitivities(), 0.0, None)  # what outside checkers pass for a camera nobody measured
    for scene in scenes:
        obs, truth = load_scene(folder, scene)
        white, nd, conf = run(obs, args.primaries)
        gw = np.nanmean(np.asarray(obs.values), axis=1)
        e, eg = angular(white, truth), angular(gw, truth)
        split = "development" if scene in DEVELOPMENT else "score"
        report["scenes"][scene] = {
            "split": split, "frames": obs.frames, "errors_deg": e.tolist(), "gray_world_deg": eg.tolist(),
            "median_deg": float(np.median(e)), "gray_world_median_deg": float(np.median(eg)),
            "ratio": float(np.median(e) / np.median(eg)), "non_daylight": nd.tolist(),
            "flagged_fraction": float(np.mean(nd >= 0.5)),
            "confidence": conf.tolist(), "within_1deg": float(np.mean(e < 1.0)),
        }
        r = report["scenes"][scene]
        print(f"{scene:<8} {split:<12} {r['median_deg']:9.2f} {r['gray_world_median_deg']:12.2f} {r['ratio']:6.2f}  "
              f"{np.mean(conf):4.2f} / {r['within_1deg']:4.2f}  "
              + " ".join(f"{f}:{v:.2f}" for f, v in zip(obs.frames, nd, strict=True)))
        if args.diagnose:
            r["diagnosis"] = {prim: diagnosis_row(obs, css, prim) for prim in ("camera", "srgb")}
            for prim, dr in r["diagnosis"].items():
                print(f"    diagnosis --primaries {prim:<6}: off-locus {'named' if dr['off_locus'] else 'NOT named':<9}  "
                      + _diagnosis_text(dr))
    if args.diagnose:
        named = {prim: [s for s in scenes if report["scenes"][s]["diagnosis"][prim]["off_locus"]] for prim in ("camera", "srgb")}
        report["off_locus_named"] = named
        print("off-locus named (lamp-lit scenes): " + "; ".join(
            f"--primaries {prim} {len(v)} of {len(scenes)}" for prim, v in named.items()))
    if args.split != "score" and not args.no_daylight and (data / "real" / "sony-dolp").is_dir():
        raw = sony_raw(data)
        for s in [raw, *isp_sets(raw)]:
            from real import _observations

            white, nd, _ = run(_observations(s, []), s.primaries)
            e = angular(white, s.truth)
            report["indoor_sets"][s.name] = {"non_daylight": nd.tolist(), "median_deg": float(np.median(e)),
                                               "flagged_fraction": float(np.mean(nd >= 0.5))}
            print(f"{s.name:<16} indoor, light unknown (development) illumon {np.median(e):.2f}°  non_daylight "
                  + " ".join(f"{v:.2f}" for v in nd))
            if args.diagnose:
                report["indoor_sets"][s.name]["diagnosis"] = dr = indoor_diagnosis(s)
                print(f"    diagnosis ({dr['sensitivities']}, --primaries {s.primaries}): "
                      + _diagnosis_text(dr["diagnose"]) + f"; whole-history lamp check: {dr['lamp_check']}"
                      + ("; with the clipped sRGB functions: " + _diagnosis_text(dr["diagnose_srgb_functions"])
                         if "diagnose_srgb_functions" in dr else ""))
    if args.sim:
        report["simulated"] = simulated(args.sim)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
