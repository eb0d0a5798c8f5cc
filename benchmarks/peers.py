"""Single-image white-balance peers against illumon on the same rendered frames (issues 18, 30).

Run: ``python benchmarks/peers.py [--quick] [--seeds N]``. Prints a table per scene and writes
``benchmarks/results/peers.json``.

Splits (printed with every table): the score cameras are :data:`SCORE_CAMERAS` (Canon, Hasselblad, Pentax, Phase One:
:data:`rawsim.SCORE_CAMERAS`, no manufacturer of the development cameras); the static patches are the score surfaces
(ColorChecker and CIE 1995 TCS, which the reflectance basis never saw: :data:`SCORE_SURFACES`); daylight is measured
Granada spectra of :data:`rawsim.SCORE_DAYLIGHT`. The unmeasured-camera rows start from a camera prior built from the
development cameras only (:data:`rawsim.DEV_CAMERAS`), never from the camera under test. No constant was chosen on
these frames (``NEAR_WHITE``, the censoring level, was set on the Point Grey, a development camera).

Each frame of a fixed-camera history is rendered as an image: the static patches as rectangles on a textured
background of clutter (random rectangles of measured reflectances, redrawn every frame), a fixed per-pixel texture and
shading, the camera's sensitivities under the frame's daylight, auto-exposure on the 99th percentile, shot and read
noise, clipping; then encoded as an 8-bit sRGB-curve image (a camera JPEG without colour matrix) and, as a second
variant, a linear 16-bit image.

Peers, each on the whole 8-bit and 16-bit image, each plain and *snapped to the camera's daylight locus* (the CIE
daylight whose camera white is nearest in log-chromaticity, which illumon's daylight model also knows):

* gray-world (Buchsbaum 1980), max-RGB (Land's white patch), shades-of-gray with p = 6 (Finlayson & Trezzi 2004) and
  first-order gray-edge (van de Weijer, Gevers & Gijsenij 2007; Gaussian σ = 2, p = 6): a few lines of numpy (no
  maintained library provides them), on unclipped pixels of the linearised image;
* OpenCV contrib ``cv2.xphoto``: ``createGrayworldWB``, ``createSimpleWB`` and ``createLearningBasedWB`` (the wheel
  ships no trained model file: built-in defaults). Their camera white is read off the output: the per-channel median
  ratio of the linearised input to the linearised output over unclipped pixels;
* ``marguier2007`` on the static patches' region means of the scored frames (multi-frame; its descent is O(frames²)).

illumon reads the static patches' region means from the 8-bit frames as the service does (clipped pixels and outliers
dropped, a mostly clipped region missing for that frame) and runs ``joint`` on the whole history, and the learned
scene model fitted on the first half (measured sensitivities; or an unmeasured camera, with a grey card held up in the
first frame or no reference).

Scores are on the second half of every history: camera-white angular error median / p95 / max (degrees) pooled over
seeds, the median of each seed, and the ratio of the best peer's median to each method's per seed (mean and range).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from functools import lru_cache
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import colour  # noqa: E402
import cv2  # noqa: E402
import numpy as np  # noqa: E402
from illumon.camera import ResponseCurve, angular_error_deg, render  # noqa: E402
from illumon.daylight import daylight_locus_duv, daylight_spectrum, xy_from_cct_duv  # noqa: E402
from illumon.model import fit_scene_model  # noqa: E402
from illumon.observations import Observations  # noqa: E402
from illumon.priors import (
    build_camera_prior,  # noqa: E402
    unseen_reflectances,  # noqa: E402
)
from illumon.retrieval import retrieve_illuminants  # noqa: E402
from illumon.simulation import (
    datasets,  # noqa: E402
    simulate_history,  # noqa: E402
)
from illumon_service.regions import Region, region_means  # noqa: E402
from rawsim import DEV_CAMERAS, SCORE_DAYLIGHT  # noqa: E402
from rawsim import SCORE_CAMERAS as RAWSIM_SCORE_CAMERAS  # noqa: E402
from retrieval import _stats  # noqa: E402  (benchmarks/retrieval.py: median, p95, max, n)

RESULTS = Path(__file__).resolve().parent / "results"
SRGB8 = ResponseCurve(encoding="srgb", white_level=255.0)
SCORE_CAMERAS = ("Canon_600D", "Pentax_K-5", "Phase_One", "Canon_5DMarkII", "Hasselblad_H2", "Canon_50D")
"""Cameras scored here: six of :data:`rawsim.SCORE_CAMERAS` (no Nikon or Point Grey: those are development cameras)."""
assert set(SCORE_CAMERAS) <= set(RAWSIM_SCORE_CAMERAS) and not set(SCORE_CAMERAS) & set(DEV_CAMERAS)
SCORE_SURFACES = 38
"""Static patches are drawn from the first 38 of :func:`illumon.priors.unseen_reflectances` (ColorChecker and
CIE 1995 TCS, never used to build the reflectance basis; the 15 NIST VS chips after them were)."""
H, W, PATCH = 120, 160, 14
GREY_CARD = np.full(61, 0.45)
"""A flat grey card (reflectance 0.45), held up in the first frame of every history for the unmeasured-camera case."""
GREY_AT = (H - PATCH - 6, W - PATCH - 6)
CLUTTER = {"natural": ("natural_joensuu_219", "natural_vrhel"), "munsell": ("munsell_matt_1269",)}
"""Reflectance sets the clutter is drawn from: an outdoor scene's leaves, bark, soil and objects, or colourful paint
chips (the gray-world assumption's best case: random chips average to near grey)."""


class FrameRenderer:
    """Renders a history's frames as textured images with clutter (see module docstring)."""

    def __init__(self, history, rng: np.random.Generator, scene: str, clutter: int = 40) -> None:
        self.h = history
        self.rng = rng
        self.clutter = clutter
        self.pool = np.concatenate([datasets.load_reflectance_set(n)[1] for n in CLUTTER[scene]])
        p = history.reflectances.shape[0]
        cols = int(np.ceil(np.sqrt(p * W / H)))
        self.rects = []
        for j in range(p):
            r, c = divmod(j, cols)
            y0 = 8 + r * (PATCH + 10)
            x0 = 8 + c * (PATCH + 10)
            self.rects.append((y0, x0))
        yy, xx = np.mgrid[0:H, 0:W]
        self.texture = (1 + 0.08 * rng.uniform(-1, 1, (H, W))) * (0.75 + 0.25 * xx / W + 0.1 * yy / H)

    def reflectance_map(self, grey_card: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Index map (H × W) into a per-frame reflectance list, and the list; optionally a grey card held up."""
        refl = [self.pool[self.rng.integers(len(self.pool))]]
        idx = np.zeros((H, W), dtype=int)
        for _ in range(self.clutter):
            y0, x0 = self.rng.integers(0, H - 8), self.rng.integers(0, W - 8)
            hh, ww = self.rng.integers(6, 40), self.rng.integers(6, 50)
            refl.append(self.pool[self.rng.integers(len(self.pool))])
            idx[y0 : y0 + hh, x0 : x0 + ww] = len(refl) - 1
        for j, (y0, x0) in enumerate(self.rects):
            refl.append(self.h.reflectances[j])
            idx[y0 : y0 + PATCH, x0 : x0 + PATCH] = len(refl) - 1
        if grey_card:
            refl.append(GREY_CARD)
            y0, x0 = GREY_AT
            idx[y0 : y0 + PATCH, x0 : x0 + PATCH] = len(refl) - 1
        return idx, np.asarray(refl)

    def frame(self, f: int, grey_card: bool = False) -> np.ndarray:
        """Linear camera image (H × W × 3, 0…1) of frame ``f``."""
        idx, refl = self.reflectance_map(grey_card)
        rgb = render(self.h.sensitivities, self.h.illuminants[f], refl)[idx] * self.texture[..., None]
        rgb = rgb * 0.9 / np.percentile(rgb, 99)
        rgb = rgb + np.sqrt(2e-4 * np.clip(rgb, 0, None) + 1e-6) * self.rng.standard_normal(rgb.shape)
        return np.clip(rgb, 0.0, 1.0)

    def regions(self, img8: np.ndarray, grey_card: bool = False) -> np.ndarray:
        """Static patches' region means (P × 3) of an 8-bit sRGB-encoded frame, as the service measures them
        (:func:`illumon_service.regions.region_means`: clipped pixels and outliers dropped; NaN where too few
        survive)."""
        rects = self.rects + ([GREY_AT] if grey_card else [])
        regions = [Region(str(j), x0 + 1, y0 + 1, PATCH - 2, PATCH - 2) for j, (y0, x0) in enumerate(rects)]
        means = region_means(img8, regions, SRGB8)
        return np.array([means[r.id] if means[r.id] is not None else [np.nan] * 3 for r in regions])


def encode8(lin: np.ndarray) -> np.ndarray:
    return np.round(255 * colour.cctf_encoding(lin)).astype(np.uint8)


def decode8(img: np.ndarray) -> np.ndarray:
    return colour.cctf_decoding(img.astype(float) / 255)


def peer_white(algo, img: np.ndarray, bits: int) -> tuple[np.ndarray, float]:
    """Camera white implied by a peer's output on an RGB image (8-bit sRGB-encoded or 16-bit linear)."""
    t = time.perf_counter()
    src = np.ascontiguousarray(img[..., ::-1])
    if isinstance(algo, cv2.xphoto.SimpleWB) and bits == 16:
        src = src.astype(np.float32)  # SimpleWB takes 8-bit, 16-bit signed, 32-bit integer or float images
    out = algo.balanceWhite(src)[..., ::-1]
    dt = time.perf_counter() - t
    top = 255 if bits == 8 else 65535
    if bits == 8:
        lin_in, lin_out = decode8(img), decode8(out)
    else:
        lin_in, lin_out = img / top, out.astype(float) / top
    ok = np.all((img > 0.02 * top) & (img < 0.98 * top) & (out > 0.02 * top) & (out < 0.98 * top), axis=-1)
    if ok.sum() < 50:
        ok = np.all(img > 0.02 * top, axis=-1)
    gains = np.median(lin_out[ok] / lin_in[ok], axis=0)
    white = 1.0 / gains
    return white / white[1], dt


def peers() -> dict:
    simple8, simple16 = cv2.xphoto.createSimpleWB(), cv2.xphoto.createSimpleWB()
    simple16.setInputMax(65535.0)
    simple16.setOutputMax(65535.0)
    learn8 = cv2.xphoto.createLearningBasedWB()
    learn16 = cv2.xphoto.createLearningBasedWB()
    learn16.setRangeMaxVal(65535)
    learn16.setSaturationThreshold(0.98)
    return {"xphoto gray-world": (cv2.xphoto.createGrayworldWB(), cv2.xphoto.createGrayworldWB()),
            "xphoto SimpleWB": (simple8, simple16), "xphoto LearningBasedWB": (learn8, learn16)}


def score_history(camera: str, seed: int, frames: int, patches: int):
    """A fixed camera under measured Granada daylight with static patches from the score surfaces."""
    rng = np.random.default_rng(seed)
    _, day = datasets.load_granada_daylight()
    day = day[SCORE_DAYLIGHT]
    e = day[rng.choice(day.shape[0], frames, replace=False)]
    _, refl = unseen_reflectances()
    r = refl[:SCORE_SURFACES][rng.choice(SCORE_SURFACES, patches, replace=False)]
    return simulate_history(datasets.load_camera(camera), e, r, rng=rng)


@lru_cache(maxsize=1)
def dev_camera_prior_mean() -> np.ndarray:
    """Prior sensitivities of a camera nobody measured, from the development cameras only (61 × 3)."""
    return build_camera_prior([datasets.load_camera(c) for c in DEV_CAMERAS]).mean


class LocusSnap:
    """Snap a camera white to the camera's daylight locus: the CIE daylight (40…400 MK⁻¹, on the daylight locus)
    whose camera white is nearest in log(r/g), log(b/g)."""

    def __init__(self, sensitivities: np.ndarray) -> None:
        mired = np.linspace(40.0, 400.0, 1441)
        cct = 1e6 / mired
        whites = daylight_spectrum(xy_from_cct_duv(cct, daylight_locus_duv(cct))) @ sensitivities
        self.whites = whites / whites[:, 1:2]
        self.chrom = np.log(self.whites[:, [0, 2]])

    def __call__(self, white: np.ndarray) -> np.ndarray:
        w = np.asarray(white, dtype=float)
        c = np.log(np.clip(w[..., [0, 2]] / w[..., 1:2], 1e-9, None))
        k = np.argmin(((c[..., None, :] - self.chrom) ** 2).sum(-1), axis=-1)
        return self.whites[k]


def numpy_peers(lin: np.ndarray) -> dict[str, np.ndarray]:
    """Camera whites (3,) of gray-world, max-RGB, shades-of-gray (p = 6) and first-order gray-edge (σ = 2, p = 6)
    on the unclipped pixels of a linear image (H × W × 3, 0…1)."""
    ok = np.all((lin > 0.002) & (lin < 0.98), axis=-1)
    px = lin[ok]
    out = {"gray-world": px.mean(0), "max-RGB": px.max(0), "shades-of-gray p=6": (px**6).mean(0) ** (1 / 6)}
    blur = cv2.GaussianBlur(lin.astype(np.float32), (0, 0), 2.0)
    gx = cv2.Sobel(blur, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(blur, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.sqrt(gx.astype(float) ** 2 + gy.astype(float) ** 2)
    near_clip = cv2.dilate((~ok).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    out["gray-edge 1st order"] = (mag[~near_clip] ** 6).mean(0) ** (1 / 6)
    return {k: v / v[1] for k, v in out.items()}


PEERS = ("gray-world", "max-RGB", "shades-of-gray p=6", "gray-edge 1st order", "xphoto gray-world", "xphoto SimpleWB",
         "xphoto LearningBasedWB")
"""Single-image peers; each runs on the 8-bit and the 16-bit image, plain and snapped to the daylight locus."""


def run_history(camera: str, seed: int, frames: int, patches: int, scene: str) -> dict:
    h = score_history(camera, seed, frames, patches)
    rng = np.random.default_rng(1000 + seed)
    fr = FrameRenderer(h, rng, scene)
    algos = peers()
    snap = LocusSnap(h.sensitivities)
    test = np.arange(frames // 2, frames)
    errs: dict[str, list[float]] = {}
    secs: dict[str, list[float]] = {}
    values = np.empty((frames, patches, 3))
    grey = np.full((frames, 1, 3), np.nan)
    for f in range(frames):
        lin = fr.frame(f, grey_card=f == 0)
        img8 = encode8(lin)
        img16 = np.round(65535 * lin).astype(np.uint16)
        v = fr.regions(img8, grey_card=f == 0)
        values[f] = v[:patches]
        if f == 0:
            grey[0] = v[patches:]
        if f not in test:
            continue
        for label, img, bits in ((" 8-bit sRGB", img8, 8), (" 16-bit linear", img16, 16)):
            whites, dts = {}, {}
            t = time.perf_counter()
            lin_img = decode8(img) if bits == 8 else img / 65535.0
            for name, w in numpy_peers(lin_img).items():
                whites[name] = w
            dt = (time.perf_counter() - t) / 4
            dts.update({k: dt for k in whites})
            for name, pair in algos.items():
                whites[name], dts[name] = peer_white(pair[0] if bits == 8 else pair[1], img, bits)
            for name, w in whites.items():
                for suffix, ww in (("", w), (", snapped", snap(w))):
                    errs.setdefault(name + label + suffix, []).append(float(angular_error_deg(ww, h.true_white[f])))
                    secs.setdefault(name + label + suffix, []).append(dts[name])
    obs = Observations(h.observations.frames, h.observations.patches, values, h.observations.times)
    scored = Observations([obs.frames[i] for i in test], obs.patches, values[test], [obs.times[i] for i in test])
    t = time.perf_counter()
    try:
        res_m = retrieve_illuminants(scored, h.sensitivities, method="marguier2007")
        errs["marguier2007 (multi-frame, scored frames)"] = list(angular_error_deg(res_m.white, h.true_white[test]))
    except ValueError as exc:  # e.g. a patch clipped in every scored frame
        print(f"marguier2007 failed on {camera} seed {seed}: {exc}", file=sys.stderr)
        errs["marguier2007 (multi-frame, scored frames)"] = [float("nan")] * len(test)
    secs["marguier2007 (multi-frame, scored frames)"] = [(time.perf_counter() - t) / len(test)]
    t = time.perf_counter()
    res = retrieve_illuminants(obs, h.sensitivities, method="joint")
    secs["illumon joint (multi-frame)"] = [(time.perf_counter() - t) / frames]
    errs["illumon joint (multi-frame)"] = list(angular_error_deg(res.white[test], h.true_white[test]))
    # patches clipped in every training frame cannot be learned: the scene model leaves them out
    seen = np.isfinite(values[: frames // 2]).all(-1).any(0)
    names = [p for p, k in zip(obs.patches, seen, strict=True) if k]
    train = Observations(obs.frames[: frames // 2], names, values[: frames // 2][:, seen], obs.times[: frames // 2])
    held = Observations([obs.frames[i] for i in test], names, values[test][:, seen], [obs.times[i] for i in test])
    with_grey = Observations(train.frames, [*names, "grey"],
                             np.concatenate([train.values, grey[: frames // 2]], axis=1), train.times)
    variants = {"illumon scene model (measured camera)": (h.sensitivities, train, None),
                "illumon scene model (measured camera, grey card once)": (h.sensitivities, with_grey, {"grey": GREY_CARD}),
                "illumon scene model (unmeasured camera, grey card once)": (None, with_grey, {"grey": GREY_CARD}),
                "illumon scene model (unmeasured camera, no reference)": (None, train, None)}
    for name, (sens, data, known) in variants.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            prior = dev_camera_prior_mean() if sens is None else None
            model = fit_scene_model(data, sens, known_reflectances=known, camera_prior_mean=prior)
            t = time.perf_counter()
            est, _ = model.estimate(held)
        secs[name] = [(time.perf_counter() - t) / len(test)]
        errs[name] = list(angular_error_deg(est.white, h.true_white[test]))
    return {"errors": errs, "seconds": secs}


def is_peer(name: str) -> bool:
    """Whether a row is one of the peers (single-image methods and ``marguier2007``), not illumon."""
    return not name.startswith("illumon")


def main() -> int:
    warnings.filterwarnings("ignore")
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="3 cameras, 20 frames, 8 patches")
    ap.add_argument("--seeds", type=int, default=3, help="histories per camera and scene (one per seed; ≥ 3)")
    ap.add_argument("--out", default=str(RESULTS / "peers.json"))
    args = ap.parse_args()
    if datasets.shared_data_dir() is None:
        print("measured data (../shared/data) not found: nothing to benchmark", file=sys.stderr)
        return 1
    cams = SCORE_CAMERAS[:3] if args.quick else SCORE_CAMERAS
    frames, patches = (20, 8) if args.quick else (40, 10)
    seeds = list(range(args.seeds))
    split = {"score cameras": list(cams), "camera prior of the unmeasured rows": list(DEV_CAMERAS),
             "static patches": f"score surfaces: first {SCORE_SURFACES} of unseen_reflectances (ColorChecker, CIE TCS)",
             "daylight": f"Granada spectra {SCORE_DAYLIGHT.start}…{SCORE_DAYLIGHT.stop - 1} (rawsim.SCORE_DAYLIGHT, "
                         "held out of the measured-daylight model; the CIE prior's N(150, 45²) MK⁻¹ summarises all "
                         "of Granada)"}
    out: dict = {"split": split, "seeds": seeds, "frames": frames, "patches": patches, "image": [H, W], "scenes": {}}
    for scene in CLUTTER:
        per_seed: dict[int, dict[str, list[float]]] = {}
        secs: dict[str, list[float]] = {}
        for seed in seeds:
            errs: dict[str, list[float]] = {}
            for cam in cams:
                r = run_history(cam, seed, frames, patches, scene)
                for k, v in r["errors"].items():
                    errs.setdefault(k, []).extend(v)
                for k, v in r["seconds"].items():
                    secs.setdefault(k, []).extend(v)
            per_seed[seed] = errs
        names = list(per_seed[seeds[0]])
        pooled = {k: [x for s_ in seeds for x in per_seed[s_][k]] for k in names}
        summ = {k: {**_stats([x for x in v if np.isfinite(x)]), "ms_per_frame": 1e3 * float(np.median(secs[k])),
                    "seed_medians": [float(np.nanmedian(per_seed[s_][k])) for s_ in seeds]} for k, v in pooled.items()}
        best = min((k for k in names if is_peer(k)), key=lambda k: summ[k]["median"])
        for k in names:
            ratios = [summ[best]["seed_medians"][i] / summ[k]["seed_medians"][i] for i in range(len(seeds))]
            summ[k]["ratio_to_best_peer"] = {"mean": float(np.mean(ratios)), "min": float(np.min(ratios)),
                                             "max": float(np.max(ratios))}
        out["scenes"][scene] = {"best_peer": best, "methods": summ}
        print(f"\n{scene} clutter ({', '.join(CLUTTER[scene])}); {len(seeds)} seeds × {len(cams)} cameras, {frames} "
              f"frames ({frames // 2} scored), {patches} static patches, {H}×{W} frames")
        print("split: " + "; ".join(f"{k}: {v if isinstance(v, str) else ', '.join(v)}" for k, v in split.items()))
        print(f"camera-white angular error (degrees), pooled over seeds; best peer: {best}")
        print(f"{'method':<58} {'median':>7} {'p95':>6} {'max':>6} {'ms/fr':>7}  {'seed medians':<18} "
              f"{'best peer ÷ method (range)':<26}")
        for k in names:
            s_ = summ[k]
            rr = s_["ratio_to_best_peer"]
            print(f"{k:<58} {s_['median']:7.2f} {s_['p95']:6.2f} {s_['max']:6.2f} {s_['ms_per_frame']:7.2f}  "
                  f"{' '.join(f'{m:5.2f}' for m in s_['seed_medians']):<18} "
                  f"{rr['mean']:5.2f}× ({rr['min']:.2f}–{rr['max']:.2f})")
        sys.stdout.flush()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
