"""Real photographs: illumon against doing nothing, gray-world and max-RGB on the frames real cameras deliver.

The outside checks' protocol (issue 26), run on the real photographs of ``../shared/data/real``: a *set* is a few
photographs by one fixed camera of a ColorChecker; the chart's 18 colour patches (1–18) are the static scene, the truth
of each frame is the camera's own response to its grey patches 20–22 (their mean), values are linear 0…1 of the white
level. Per set, illumon runs three ways — no reference, the greys 19–24 known in frame 0, the whole chart known in
frame 0 — beside doing nothing (white = (1, 1, 1)), gray-world and max-RGB over the same 18 patches.

Sets (all *development* data: ``../shared/data/real/README.md`` says the scoring photographs are kept apart):

* ``sony-raw``: the four ``scene00N_macbeth`` shots of ``sony-dolp`` (indoor light, window and ceiling lamps),
  demosaicked sensor RGB without white balance; ``--primaries camera``.
* ``sony-isp-preset``, ``sony-isp-auto``: the same raw values through a simulated camera pipeline — a 3 × 3 colour
  matrix to linear sRGB primaries (fitted on the four charts' chromatic patches against their CIE D65 sRGB values, the
  way a maker tunes one; every frame white-balanced by its own greys before the fit, so the matrix is not told the
  frames' light) and a white balance: the daylight preset (gains that make CIE D65 grey through the camera, taken
  from the matrix fit) or automatic (each frame divided by its own gray-world over the whole image, a phone's AWB);
  ``--primaries srgb``. Real scenes and light; the pipeline simulated.
* ``sony-isp-ideal`` (only with ``--ideal-awb``): the same pipeline with a perfect automatic white balance, each frame
  divided by its own greys — doing nothing is exact, so the row shows what illumon without a reference costs a
  camera that needs no correction.

Patch values are measured with the service's own calibration code (OpenCV's ``cv2.mcc`` finds the chart; robust
means of the central half of each patch, clipped pixels left out). Errors are angular, in the camera's output RGB,
between the estimated camera white and the truth.

``python benchmarks/real.py`` prints the table and writes ``benchmarks/results/real.json``; ``--subsets`` adds parts of
the chart's greys as the reference (a white, a mid grey, three, the two darkest, the black: :data:`SUBSETS`) and
prints each reference frame's error beside the RMS error its confidence states; ``--single`` fits every
frame on its own (one photograph) and writes ``real_single.json``; ``--awb-mix 0.25,0.5,0.75`` adds cameras whose own
automatic white balance lies between the ideal one and gray-world (``sony-isp-mix<a>``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core"), str(ROOT / "service")]

SCENE = [f"chart:{i:02d}" for i in range(1, 19)]
GREYS = [f"chart:{i:02d}" for i in range(19, 25)]
TRUTH = [f"chart:{i:02d}" for i in (20, 21, 22)]
ALL = SCENE + GREYS


def shared_data() -> Path:
    """``$ILLUMON_SHARED_DATA`` or ``../shared/data`` beside the project root."""
    import os

    return Path(os.environ.get("ILLUMON_SHARED_DATA", ROOT.parent / "shared" / "data"))


@dataclass
class RealSet:
    """A camera's photographs of a chart: ``values`` F × 24 × 3 (chart order, linear, 0…1 of the white level, NaN where
    a patch is unusable), the frames' names, and which primaries the output is in."""

    name: str
    frames: list[str]
    values: NDArray[np.float64]
    primaries: str
    note: str
    image_means: NDArray[np.float64] | None = None  # F × 3: the whole image's mean (gray-world over the image)

    @property
    def truth(self) -> NDArray[np.float64]:
        """Each frame's camera white: the mean of its grey patches 20–22 (F × 3)."""
        idx = [ALL.index(p) for p in TRUTH]
        return np.nanmean(self.values[:, idx], axis=1)


MIN_PITCH = 4.0
"""Charts whose patches are closer than this (pixels) are not measured, as the service's calibration route refuses
them: ``scene003``'s chart is 3.5 pixels a patch, and ``cv2.mcc`` reads it in the wrong order."""


def _measure_chart(rgb: NDArray, full_scale: float) -> NDArray[np.float64] | None:
    """Robust linear means of the 24 patches (24 × 3, 0…1) of the chart ``cv2.mcc`` finds in ``rgb``; ``None`` when
    the chart is too small to measure (:data:`MIN_PITCH`)."""
    from illumon.camera.pipeline import ResponseCurve
    from illumon_service.calibration import chart_patch_ids, detect_colourchecker, measure_patches
    from illumon_service.regions import Region

    # Detection sees a brightened, gamma-encoded copy (these raw frames are dark); measurement the raw values.
    bright = np.clip(rgb.astype(float) / np.percentile(rgb, 99.5), 0, 1) ** (1 / 2.2)
    centres, pitch = detect_colourchecker((bright * 65535).astype(np.uint16), 65535)
    if pitch < MIN_PITCH:
        return None
    ids = chart_patch_ids()
    # The central half of each patch, at least 2 × 2 pixels (scene003's chart is 3.5 pixels a patch).
    side = max(2, int(0.5 * pitch))
    regions = [Region(pid, int(round(x - side / 2)), int(round(y - side / 2)), side, side)
               for pid, (x, y) in zip(ids, centres, strict=True)]
    patches, _ = measure_patches(rgb, regions, ResponseCurve("linear", white_level=full_scale),
                                 clip_fraction=0.98, min_fraction=0.5)
    return np.array([[np.nan] * 3 if p["r"] is None else [p["r"], p["g"], p["b"]] for p in patches])


def sony_raw(data: Path) -> RealSet:
    """The four chart shots of ``real/sony-dolp``, sensor RGB (see the module docstring)."""
    import cv2

    folder = data / "real" / "sony-dolp"
    frames, values, means = [], [], []
    for path in sorted(folder.glob("scene*_macbeth.png")):
        rgb = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
        chart = _measure_chart(rgb, 65535.0)
        if chart is None:
            continue
        frames.append(path.stem.split("_")[0])
        values.append(chart)
        img = rgb.astype(float) / 65535.0
        ok = np.all(img < 0.98, axis=-1)
        means.append(img[ok].mean(axis=0))
    return RealSet("sony-raw", frames, np.array(values), "camera",
                   "Sony polarisation sensor, demosaicked raw, indoor window/lamp light", np.array(means))


def _srgb_d65_chart() -> NDArray[np.float64]:
    """The ColorChecker's linear sRGB values under CIE D65 (24 × 3, white (1, 1, 1) for a perfect diffuser)."""
    from illumon.camera.formation import camera_white
    from illumon.camera.primaries import srgb_sensitivities
    from illumon.priors import colourchecker_reflectances

    c = srgb_sensitivities()
    from illumon.camera.calibration import _d65

    e = _d65()
    _, refl = colourchecker_reflectances("BabelColor Average")
    w = camera_white(c, e)
    return (refl * e) @ c / w


def isp_pipeline(raw: RealSet) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The simulated pipeline's colour matrix (3 × 3, ``out = x @ m``) and daylight-preset gains (3,), fitted on the
    raw chart shots (module docstring)."""
    target = _srgb_d65_chart()
    idx = [ALL.index(p) for p in SCENE]
    grey = raw.truth
    xs = np.concatenate([raw.values[f, idx] / grey[f] for f in range(len(raw.frames))])
    ys = np.concatenate([target[idx]] * len(raw.frames))
    ok = np.all(np.isfinite(xs), axis=1)
    # White-preserving least squares (Finlayson & Drew 1997): M 1 = 1, so a balanced grey stays grey.
    m = np.linalg.lstsq(xs[ok], ys[ok], rcond=None)[0]  # 3 × 3, out = x @ m
    m = m / m.sum(axis=0, keepdims=True)
    # The daylight preset: the gains that make D65 grey. The frames' own greys are not D65; the preset is the mean of
    # the four frames' balancing gains scaled to the D65 chart's white (a camera tuned in the lab under D65 would
    # know its D65 gains; here they are estimated from the set, which is the only place the sensor is known).
    return m, 1.0 / np.exp(np.mean(np.log(grey / grey[:, 1:2]), axis=0))


def auto_gains(image_mean: NDArray[np.float64]) -> NDArray[np.float64]:
    """A gray-world automatic white balance's gains for a frame whose whole image averages ``image_mean`` (3,)."""
    return 1.0 / (image_mean / image_mean[1])


def render_isp(x: NDArray[np.float64], gains: NDArray[np.float64], m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Raw values (… × 3) through the simulated pipeline: white-balance ``gains``, then the colour matrix ``m``; a
    pipeline clips out-of-gamut values at 0."""
    return np.clip((x * gains) @ m, 0.0, None)


def isp_sets(raw: RealSet, modes: tuple[str, ...] = ("preset", "auto")) -> list[RealSet]:
    """``raw`` through a simulated camera pipeline: colour matrix to linear sRGB and a preset or automatic white
    balance (module docstring); ``"ideal"`` in ``modes`` adds a camera whose automatic white balance is perfect (each
    frame divided by its own greys: doing nothing is exact); ``"mix<a>"`` (``--awb-mix``) a camera whose automatic
    white balance lies between the two, its gains ``ideal^(1 − a) · auto^a`` (log-linear): doing nothing is off by
    part of the light, as a phone's own balance is."""
    m, preset = isp_pipeline(raw)
    grey = raw.truth
    out = []
    for mode in modes:
        vals = np.empty_like(raw.values)
        means = np.empty((len(raw.frames), 3))
        for f in range(len(raw.frames)):
            auto, ideal = auto_gains(raw.image_means[f]), 1.0 / (grey[f] / grey[f, 1])
            if mode.startswith("mix"):
                a = float(mode[3:])
                gains = np.exp((1.0 - a) * np.log(ideal) + a * np.log(auto))
            else:
                gains = {"preset": preset, "auto": auto, "ideal": ideal}[mode]
            vals[f] = render_isp(raw.values[f], gains, m)
            means[f] = (raw.image_means[f] * gains) @ m
        scale = 0.9 / np.nanmax(vals)
        out.append(RealSet(f"sony-isp-{mode}", raw.frames, vals * scale, "srgb",
                           f"sony-raw through a colour matrix to linear sRGB, {mode} white balance", means * scale))
    return out


def angular(a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """Angle (degrees) between rows of ``a`` and ``b``."""
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    c = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


def _observations(s: RealSet, known: list[str]):
    """The 18 scene patches in every frame, and the ``known`` chart patches again as references (ids ``ref:NN``)
    in frame 0 only."""
    from illumon.observations import Observations

    idx = [ALL.index(p) for p in SCENE + known]
    vals = s.values[:, idx].copy()
    vals[1:, len(SCENE):] = np.nan
    patches = SCENE + [p.replace("chart:", "ref:") for p in known]
    return Observations(frames=list(s.frames), patches=patches, values=vals, times=[None] * len(s.frames))


SUBSETS = {"white 19": ["chart:19"], "grey 20": ["chart:20"], "greys 20-22": ["chart:20", "chart:21", "chart:22"],
           "dark greys 23-24": ["chart:23", "chart:24"], "black 24": ["chart:24"], "colour 15": ["chart:15"],
           "colours 01,13": ["chart:01", "chart:13"], "colours 02,07,14": ["chart:02", "chart:07", "chart:14"]}
"""Parts of the chart known in frame 0 (``--subsets``): a neutral reference as dark, as light or as mid as an
installer's card may be, and a few of its colours without a neutral (set aside:
:func:`illumon.camera.references.coloured_only`)."""


def run_illumon(s: RealSet, mode: str, primaries: str | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64], str]:
    """Camera whites (F × 3), their ``confidence`` and the CCT of frame 0, for ``mode`` none / grey / chart or a key
    of :data:`SUBSETS`."""
    from illumon.camera.references import colourchecker_references
    from illumon.model import fit_scene_model

    refs = colourchecker_references()
    known = {"none": [], "grey": GREYS, "chart": ALL, **SUBSETS}[mode]
    obs = _observations(s, known)
    known_refs = {p.replace("chart:", "ref:"): refs[p] for p in known}
    with warnings.catch_warnings():  # identifiability warnings: three frames under one light, as expected
        warnings.simplefilter("ignore")
        model = fit_scene_model(obs, None, known_reflectances=known_refs or None, primaries=primaries or s.primaries)
    result, extra = model.history_estimate
    whites = np.asarray(result.white, dtype=float)
    conf = np.asarray(extra.get("confidence", np.full(len(whites), np.nan)), dtype=float)
    return whites, conf, f"{result.cct[0]:.0f}"


def run_single(s: RealSet, mode: str, primaries: str | None = None
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], str]:
    """:func:`run_illumon` on each frame of ``s`` alone (a history of one photograph; the references, where ``mode``
    has them, in that frame)."""
    out = [run_illumon(RealSet(s.name, [s.frames[i]], s.values[i:i + 1], s.primaries, s.note), mode, primaries)
           for i in range(len(s.frames))]
    return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out]), out[0][2]


def dump_sets(sets: list[RealSet], folder: Path) -> None:
    """Each set as ``illumon estimate`` reads it: ``<set>/OBSERVATIONS-none.csv`` (the 18 scene patches, linear 0…1:
    ``--white-level 1``), ``OBSERVATIONS-grey.csv`` / ``OBSERVATIONS-chart.csv`` with the references (ids ``ref:NN``)
    in frame 0 and their ``KNOWN-grey.csv`` / ``KNOWN-chart.csv``, and ``TRUTH.csv`` (each frame's greys 20–22)."""
    from illumon.camera.references import colourchecker_references
    from illumon.observations import write_observations
    from illumon.spectra import WAVELENGTHS, write_spectral_csv

    refs = colourchecker_references()
    for s in sets:
        d = folder / s.name
        d.mkdir(parents=True, exist_ok=True)
        write_observations(d / "OBSERVATIONS-none.csv", _observations(s, []), white_level=1.0)
        for mode, ids in (("grey", GREYS), ("chart", ALL)):
            write_observations(d / f"OBSERVATIONS-{mode}.csv", _observations(s, ids), white_level=1.0)
            write_spectral_csv(d / f"KNOWN-{mode}.csv", WAVELENGTHS, {p.replace("chart:", "ref:"): refs[p] for p in ids},
                               comments=[f"ColorChecker patches (BabelColor Average), {s.name}: references in frame 0"])
        rows = ["frame,r,g,b"] + [f"{f},{t[0]:.6g},{t[1]:.6g},{t[2]:.6g}" for f, t in zip(s.frames, s.truth, strict=True)]
        (d / "TRUTH.csv").write_text("\n".join(rows) + "\n")


def stated_rms_deg(confidence: float) -> float:
    """The RMS angular error (degrees) a frame's ``confidence`` states: ``confidence = 1 − exp(−ρ²/tr)`` with ρ = 1°
    (:mod:`illumon.model.intervals`), so ``√tr``; 0 for a confidence of 1."""
    from illumon.model.intervals import confidence_variance

    if not confidence > 0.0:
        return float("inf")
    return float(np.degrees(np.sqrt(confidence_variance(min(confidence, 1.0)))))


def baselines(s: RealSet) -> dict[str, NDArray[np.float64]]:
    """Doing nothing, gray-world and max-RGB over the 18 scene patches, and gray-world over the whole image."""
    idx = [ALL.index(p) for p in SCENE]
    v = s.values[:, idx]
    out = {
        "nothing": np.ones((len(s.frames), 3)),
        "gray-world": np.nanmean(v, axis=1),
        "max-RGB": np.nanmax(v, axis=1),
    }
    if s.image_means is not None:
        out["gray-world (image)"] = s.image_means
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "real.json"))
    ap.add_argument("--dump", help="also write each set as the CLI's files (OBSERVATIONS.csv, KNOWN.csv) under this folder")
    ap.add_argument("--primaries", choices=["camera", "srgb"],
                    help="run every set with these primaries instead of its own (what the option buys)")
    ap.add_argument("--ideal-awb", action="store_true",
                    help="add sony-isp-ideal: the ISP output with a perfect automatic white balance (each frame "
                         "balanced by its own greys), what illumon without a reference costs on a camera that needs "
                         "no correction")
    ap.add_argument("--awb-mix", default="",
                    help="add sets whose automatic white balance lies between the ideal one and gray-world over the "
                         "image: comma-separated shares of gray-world's gains (0…1), e.g. 0.25,0.5,0.75")
    ap.add_argument("--single", action="store_true",
                    help="fit every frame on its own (one photograph, as an installer's first try) instead of the set "
                         "as a history; default --out benchmarks/results/real_single.json")
    ap.add_argument("--subsets", action="store_true",
                    help="also run each set with parts of the chart's greys known in frame 0 (a white, a mid grey, "
                         "three, the two darkest, the black): the reference frame's error beside what it states")
    args = ap.parse_args(argv)
    if args.single and args.out == ap.get_default("out"):
        args.out = str(ROOT / "benchmarks" / "results" / "real_single.json")
    data = shared_data()
    if not (data / "real" / "sony-dolp").is_dir():
        print(f"real.py: skipped: {data / 'real' / 'sony-dolp'} is absent (../shared/data or $ILLUMON_SHARED_DATA)")
        return 0
    raw = sony_raw(data)
    mixes = tuple(f"mix{float(a):g}" for a in args.awb_mix.split(",") if a.strip())
    sets = [raw, *isp_sets(raw, ("preset", "auto", *(("ideal",) if args.ideal_awb else ()), *mixes))]
    rows, report = [], {"split": "development (../shared/data/real: sony-dolp); scoring photographs are held by outside checks",
                        "sets": {}}
    if args.dump:
        dump_sets(sets, Path(args.dump))
    for s in sets:
        truth = s.truth
        entry = {"frames": s.frames, "primaries": s.primaries, "note": s.note, "methods": {}}
        spread = float(np.nanmax(angular(truth, truth.mean(axis=0)))) if len(truth) > 1 else 0.0
        for name, w in baselines(s).items():
            e = angular(w, truth)
            entry["methods"][name] = {"errors_deg": e.tolist(), "median_deg": float(np.median(e))}
        for mode in ("none", "grey", "chart", *(SUBSETS if args.subsets else ())):
            t0 = time.perf_counter()
            try:
                w, conf, cct0 = (run_single(s, mode, args.primaries) if args.single
                                 else run_illumon(s, mode, args.primaries))
                e = angular(w, truth)
                entry["methods"][f"illumon {mode}"] = {
                    "errors_deg": e.tolist(), "median_deg": float(np.median(e)), "frame0_deg": float(e[0]),
                    "confidence": conf.tolist(), "within_1deg": float(np.mean(e < 1.0)), "cct_frame0": cct0,
                    "frame0_stated_rms_deg": stated_rms_deg(float(conf[0])),
                    "seconds": time.perf_counter() - t0,
                }
            except Exception as exc:  # noqa: BLE001 - a benchmark row records the failure
                entry["methods"][f"illumon {mode}"] = {"error": f"{type(exc).__name__}: {exc}"}
        entry["greys_spread_deg"] = spread
        report["sets"][s.name] = entry
        for name, m in entry["methods"].items():
            if "error" in m:
                rows.append((s.name, name, "ERROR " + m["error"][:60], "", "", ""))
            else:
                rows.append((s.name, name, f"{m['median_deg']:.2f}", f"{max(m['errors_deg']):.2f}",
                             f"{m.get('frame0_deg', float('nan')):.2f}" if "frame0_deg" in m else "",
                             f"{np.mean(m['confidence']):.2f} / {m['within_1deg']:.2f}" if "confidence" in m else ""))
    print(f"split: {report['split']}")
    print(f"{'set':<17} {'method':<25} {'median °':>9} {'max °':>7} {'frame 0 °':>9}  conf / within 1°")
    for r in rows:
        print(f"{r[0]:<17} {r[1]:<25} {r[2]:>9} {r[3]:>7} {r[4]:>9}  {r[5]}")
    if args.subsets:
        print("\nreference frame (frame 0), parts of the chart's greys known: its error beside the RMS error its "
              "confidence states (°)")
        for name, entry in report["sets"].items():
            print(f"{name:<17} " + "  ".join(
                f"{mode}: {m['frame0_deg']:.2f} / {m['frame0_stated_rms_deg']:.2f}"
                for mode in SUBSETS if "frame0_deg" in (m := entry["methods"].get(f"illumon {mode}", {}))))
    write_report(args.out, report)
    return 0


def write_report(out: str | Path, report: dict) -> None:
    """Write a benchmark's JSON report (its folder made as needed) and say where."""
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(report, indent=1, default=float))
    print(f"wrote {out}")


if __name__ == "__main__":
    raise SystemExit(main())
