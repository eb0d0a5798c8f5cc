"""Single-image white-balance peers against illumon on the same rendered frames (issue 18).

Run: ``python benchmarks/peers.py [--quick]``. Prints a table and writes ``benchmarks/results/peers.json``.

Each frame of a fixed-camera history (:func:`illumon.scenarios.measured_daylight_history`: measured Granada daylight,
patches the reflectance basis never saw, held-out measured cameras) is rendered as an image: the static patches as
rectangles on a textured background of clutter (random rectangles of measured reflectances, redrawn every frame),
a fixed per-pixel texture and shading, the camera's sensitivities under the frame's daylight, auto-exposure on the
99th percentile, shot and read noise, clipping; then encoded as an 8-bit sRGB-curve image (a camera JPEG without
colour matrix) and, as a second variant, a linear 16-bit image.

Peers (OpenCV contrib ``cv2.xphoto``): gray world (``createGrayworldWB``), SimpleWB (``createSimpleWB``, per-channel
percentile stretch) and LearningBasedWB (``createLearningBasedWB``; the wheel ships no trained model file: it runs
with its built-in defaults). A peer's camera white is read off its output: the per-channel median ratio of the
linearised input to the linearised output over unclipped pixels.

illumon reads the static patches' region means from the 8-bit frames as the service does (clipped pixels and outliers
dropped, a mostly clipped region missing for that frame) and runs

* ``joint`` (multi-frame, :func:`illumon.retrieval.retrieve_illuminants`) on the whole history;
* the learned scene model (:func:`illumon.model.fit_scene_model` on the first half, ``SceneModel.estimate`` per frame)
  with the camera's measured sensitivities, and for an unmeasured camera (``sensitivities=None``) with a grey card
  held up in the first frame (``known_reflectances``) or with no reference at all.

Scores are on the second half of every history (frames the scene model never saw): camera-white angular error
median / p95 / max (degrees) and time per frame.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import colour  # noqa: E402
import cv2  # noqa: E402
import numpy as np  # noqa: E402
from illumon import datasets  # noqa: E402
from illumon.camera import ResponseCurve, angular_error_deg, render  # noqa: E402
from illumon.model import fit_scene_model  # noqa: E402
from illumon.observations import Observations  # noqa: E402
from illumon.retrieval import retrieve_illuminants  # noqa: E402
from illumon.scenarios import measured_daylight_history  # noqa: E402
from illumon_service.regions import Region, region_means  # noqa: E402
from retrieval import _stats  # noqa: E402  (benchmarks/retrieval.py: median, p95, max, n)

RESULTS = Path(__file__).resolve().parent / "results"
SRGB8 = ResponseCurve(encoding="srgb", white_level=255.0)
HELD_OUT_CAMERAS = ("Canon_600D", "Nikon_D5100", "Pentax_K-5", "Point_Grey_Grasshopper2_14S5C", "Nikon_Z6_ssf",
                    "Phase_One")
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


def run_history(camera: str, seed: int, frames: int, patches: int, scene: str) -> dict:
    h = measured_daylight_history(camera, frames=frames, patches=patches, seed=seed)
    rng = np.random.default_rng(1000 + seed)
    fr = FrameRenderer(h, rng, scene)
    algos = peers()
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
        for name, (a8, a16) in algos.items():
            for label, img, algo, bits in ((" 8-bit sRGB", img8, a8, 8), (" 16-bit linear", img16, a16, 16)):
                w, dt = peer_white(algo, img, bits)
                errs.setdefault(name + label, []).append(float(angular_error_deg(w, h.true_white[f])))
                secs.setdefault(name + label, []).append(dt)
    obs = Observations(h.observations.frames, h.observations.patches, values, h.observations.times)
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
            model = fit_scene_model(data, sens, known_reflectances=known)
            t = time.perf_counter()
            est, _ = model.estimate(held)
        secs[name] = [(time.perf_counter() - t) / len(test)]
        errs[name] = list(angular_error_deg(est.white, h.true_white[test]))
    return {"errors": errs, "seconds": secs}


def main() -> int:
    warnings.filterwarnings("ignore")
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="3 cameras, 1 history each, 20 frames")
    ap.add_argument("--out", default=str(RESULTS / "peers.json"))
    args = ap.parse_args()
    if datasets.shared_data_dir() is None:
        print("measured data (../shared/data) not found: nothing to benchmark", file=sys.stderr)
        return 1
    cams = HELD_OUT_CAMERAS[:3] if args.quick else HELD_OUT_CAMERAS
    seeds, frames, patches = (1, 20, 8) if args.quick else (2, 40, 10)
    out: dict = {"cameras": list(cams), "histories_per_camera": seeds, "frames": frames, "patches": patches,
                 "image": [H, W], "scenes": {}}
    for scene in CLUTTER:
        errs: dict[str, list[float]] = {}
        secs: dict[str, list[float]] = {}
        for cam in cams:
            for seed in range(seeds):
                r = run_history(cam, seed, frames, patches, scene)
                for k, v in r["errors"].items():
                    errs.setdefault(k, []).extend(v)
                for k, v in r["seconds"].items():
                    secs.setdefault(k, []).extend(v)
        summ = {k: {**_stats(v), "ms_per_frame": 1e3 * float(np.median(secs[k]))} for k, v in errs.items()}
        out["scenes"][scene] = summ
        best_peer = min(v["median"] for k, v in summ.items() if k.startswith("xphoto"))
        print(f"\n{scene} clutter ({', '.join(CLUTTER[scene])}). Held-out cameras {', '.join(cams)}; {seeds} "
              f"histories per camera, {frames} frames ({frames // 2} scored), {patches} static patches, {H}×{W} "
              "frames; camera-white angular error (degrees)")
        print(f"{'method':<56} {'median':>7} {'p95':>7} {'max':>7} {'ms/frame':>9} {'best peer/median':>17}")
        for k, s in summ.items():
            print(f"{k:<56} {s['median']:7.2f} {s['p95']:7.2f} {s['max']:7.2f} {s['ms_per_frame']:9.2f} "
                  f"{best_peer / s['median']:17.1f}")
        sys.stdout.flush()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
