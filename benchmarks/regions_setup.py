"""Reference regions an installer can set up (issue 17): proposals, shift tracking and the view-change alert.

Run: ``python benchmarks/regions_setup.py [--split score|dev] [--cameras N] [--quick]``. Prints a table and writes
``benchmarks/results/regions_setup.json``.

Scenes (:class:`TexturedScene`, 640 × 480, rendered from measured spectra through :func:`illumon.camera.render`): ten
static surfaces (reflectances of the split, a fixed ±15 % per-pixel texture, 44…90 px a side) set in a mosaic of
textured neighbours (tiles of other reflectances of the split, 6…16 px, ±15 % texture); a sky strip whose radiance
is the frame's daylight tilted to the blue and scaled by a cloud factor of its own; a patch of foliage in wind (leaves
and gaps redrawn every frame); a glossy panel whose highlight moves with the sun; and a pavement band where
three passers-by (random reflectances) walk each frame. Daylight: consecutive Granada spectra of the split with a
changing level (:func:`rawsim.daylight_run`); per-frame auto-exposure (99th percentile of the ground at 0.8), shot
and read noise, 8-bit sRGB-curve PNGs. Cameras, surfaces and daylight come from the ``score`` split of
:mod:`rawsim` for the reported figures; the thresholds of :mod:`illumon_service.proposals` and
:mod:`illumon_service.registration` were chosen on ``dev``.

Each case runs the service in process (FastAPI TestClient) as an installer would:

1. register the camera (measured sensitivities) with no regions; post 24 frames over a day;
2. ``GET /v1/cameras/{id}/region-proposals?count=12``: a true surface is *covered* when a proposal lies inside it
   (≥ 90 % of the proposal's area); a proposal *lies on a moving object* when ≥ 5 % of it is sky, foliage, the
   glossy panel's highlight path or the passers-by's band;
3. ``PUT …/regions`` with the 12 proposals (``--keep ticked``: those the regions page ticks, scoring at least half
   the best; on the dev split all 12 gave a pooled median of 0.60° and the ticked ones 0.66°); post 40 frames of
   another stretch of daylight, every one but the first shifted by a random −20…20 px in x and y (the reference is
   the first frame of the day before, and the first one after the regions were set is unshifted), then a refit: the
   camera-white angular error of every frame's estimate against the truth (``camera_white(css, daylight)``), and the
   number of frames without an estimate; as a control, a second camera with the same regions gets the same frames
   unshifted (``unshifted °``: what the scene model achieves when nothing moves);
4. post a frame jumped by 100 px: it must raise the ``view_change`` alert and stay unestimated.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import rawsim  # noqa: E402
from illumon.camera import ResponseCurve, angular_error_deg, camera_white, render  # noqa: E402
from illumon.daylight import cct_duv_from_xy, xy_from_spectrum  # noqa: E402
from illumon.spectra import WAVELENGTHS  # noqa: E402
from illumon_service.api.routes.pages import ticked_score  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
W, H = 640, 480
MARGIN = 120
"""The scene is rendered on a canvas this much larger on every side, so that shifted crops stay inside it."""
SKY = (0, 70)
PAVEMENT = (400, 480)
FOLIAGE = (520, 90, 120, 150)  # x, y, w, h
GLOSSY = (400, 300, 80, 70)
SRGB8 = ResponseCurve("srgb", white_level=255.0)


class TexturedScene:
    """One camera's scene (see module docstring); ``frame(f, dx, dy)`` renders frame ``f`` shifted by (dx, dy)."""

    def __init__(self, camera: str, split: str, seed: int, frames: int) -> None:
        from illumon.simulation import datasets

        self.rng = np.random.default_rng(seed)
        rng = self.rng
        self.css = datasets.load_camera(camera)
        self.daylight = rawsim.daylight_run(split, frames, rng)
        self.split = split
        self.surfaces_refl = rawsim.draw_reflectances(split, 10 + 60, rng)  # the score split holds 38 in all
        cw, ch = W + 2 * MARGIN, H + 2 * MARGIN
        # neighbours: a mosaic of small tiles of the other surfaces
        idx = np.full((ch, cw), 10, dtype=int)
        y = 0
        while y < ch:
            th = int(rng.integers(6, 17))
            x = 0
            while x < cw:
                tw = int(rng.integers(6, 17))
                idx[y : y + th, x : x + tw] = 10 + int(rng.integers(len(self.surfaces_refl) - 10))
                x += tw
            y += th
        # ten static surfaces, non-overlapping, between the sky and the pavement, off the foliage and glossy panel
        self.surfaces: list[tuple[int, int, int, int]] = []  # x, y, w, h in image coordinates (unshifted)
        busy = [(FOLIAGE[0] - 8, FOLIAGE[1] - 8, FOLIAGE[2] + 16, FOLIAGE[3] + 16),
                (GLOSSY[0] - 8, GLOSSY[1] - 8, GLOSSY[2] + 16, GLOSSY[3] + 16)]
        while len(self.surfaces) < 10:
            sw, sh = int(rng.integers(44, 91)), int(rng.integers(44, 81))
            sx, sy = int(rng.integers(8, W - sw - 8)), int(rng.integers(SKY[1] + 10, PAVEMENT[0] - sh - 10))
            if any(sx < bx + bw + 12 and bx < sx + sw + 12 and sy < by + bh + 12 and by < sy + sh + 12
                   for bx, by, bw, bh in self.surfaces + busy):
                continue
            self.surfaces.append((sx, sy, sw, sh))
            idx[sy + MARGIN : sy + sh + MARGIN, sx + MARGIN : sx + sw + MARGIN] = len(self.surfaces) - 1
        self.index = idx
        self.texture = 1.0 + 0.15 * rng.uniform(-1, 1, (ch, cw))
        self.sky_tilt = (WAVELENGTHS / 560.0) ** -2.5
        self.sky_level = np.exp(0.35 * rng.standard_normal(frames))
        self.leaf = np.clip(rawsim.draw_reflectances(split, 1, rng)[0] * 0.5 + 0.05 * (np.abs(WAVELENGTHS - 550) < 40),
                            0, 1)

    def moving_mask(self) -> np.ndarray:
        """H × W: pixels where something moves or changes (sky, foliage, glossy panel, pavement band)."""
        m = np.zeros((H, W), dtype=bool)
        m[SKY[0] : SKY[1]] = True
        m[PAVEMENT[0] : PAVEMENT[1]] = True
        x, y, w, h = FOLIAGE
        m[y : y + h, x : x + w] = True
        x, y, w, h = GLOSSY
        m[y : y + h, x : x + w] = True
        return m

    def frame(self, f: int, dx: int = 0, dy: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """8-bit sRGB image (H × W × 3) of frame ``f`` seen with the view shifted by (dx, dy) (scene content moves
        by (dx, dy) in the image), and the true camera white."""
        rng = self.rng
        e = self.daylight[f]
        rgb_s = render(self.css, e, self.surfaces_refl)  # P × 3
        img = rgb_s[self.index] * self.texture[..., None]
        ch, cw = self.index.shape
        # sky
        sky = render(self.css, e * self.sky_tilt * self.sky_level[f], np.ones((1, 61)))[0]
        img[: SKY[1] + MARGIN] = sky * (1 + 0.03 * rng.standard_normal((SKY[1] + MARGIN, cw, 1)))
        # foliage in wind: leaves and dark gaps redrawn every frame
        x, y, w, h = FOLIAGE
        leaves = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 3) > 0
        leaf_rgb = render(self.css, e, self.leaf[None])[0]
        img[y + MARGIN : y + h + MARGIN, x + MARGIN : x + w + MARGIN] = np.where(leaves[..., None], leaf_rgb, 0.15 * leaf_rgb)
        # glossy panel: a specular highlight (the light's own colour) moving with the sun
        x, y, w, h = GLOSSY
        yy, xx = np.mgrid[0:h, 0:w]
        cx = w * (f % 24) / 23.0
        spec = 2.5 * np.exp(-((xx - cx) ** 2 + (yy - h / 2) ** 2) / (2 * 8.0**2))
        white = render(self.css, e, np.ones((1, 61)))[0]
        img[y + MARGIN : y + h + MARGIN, x + MARGIN : x + w + MARGIN] += 0.3 * spec[..., None] * white
        # passers-by on the pavement
        for _ in range(3):
            pw, ph = int(rng.integers(16, 30)), int(rng.integers(50, 78))
            px = int(rng.integers(0, cw - pw))
            py = PAVEMENT[1] + MARGIN - ph - int(rng.integers(0, 4))
            refl = rawsim.draw_reflectances(self.split, 1, rng)[0]
            img[py : py + ph, px : px + pw] = render(self.css, e, refl[None])[0]
        crop = img[MARGIN - dy : MARGIN - dy + H, MARGIN - dx : MARGIN - dx + W]
        ground = crop[SKY[1] :]
        crop = crop * (0.8 / np.percentile(ground, 99)) * np.exp(0.05 * rng.standard_normal())
        crop = crop + np.sqrt(2e-4 * np.clip(crop, 0, None) + 1e-6) * rng.standard_normal(crop.shape)
        enc = np.round(SRGB8.encode(np.clip(crop, 0, 1))).astype(np.uint8)
        return enc, camera_white(self.css, e)


def png(img: np.ndarray) -> bytes:
    """RGB uint8 → PNG bytes."""
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img[:, :, ::-1]))
    assert ok
    return buf.tobytes()


def coverage(proposals: list[dict], surfaces: list[tuple[int, int, int, int]], moving: np.ndarray) -> dict:
    """Surfaces covered (a proposal ≥ 90 % inside one) and proposals on moving things (≥ 5 % of their area)."""
    covered = set()
    on_moving = 0
    for p in proposals:
        area = p["width"] * p["height"]
        for k, (sx, sy, sw, sh) in enumerate(surfaces):
            ix = max(0, min(p["x"] + p["width"], sx + sw) - max(p["x"], sx))
            iy = max(0, min(p["y"] + p["height"], sy + sh) - max(p["y"], sy))
            if ix * iy >= 0.9 * area:
                covered.add(k)
        if moving[p["y"] : p["y"] + p["height"], p["x"] : p["x"] + p["width"]].mean() >= 0.05:
            on_moving += 1
    return {"covered": len(covered), "on_moving": on_moving}


def common_shift(est: list[dict], spectra: list[np.ndarray]) -> tuple[float, float]:
    """Mean estimated minus true reciprocal temperature (MK⁻¹) and Duv over a history: the shift common to all its
    frames, which static patches determine worst (the scene model's priors set it); NaN without estimates."""
    if not est:
        return float("nan"), float("nan")
    cct, duv = cct_duv_from_xy(xy_from_spectrum(np.asarray(spectra)))
    mired = np.array([1e6 / e["cct_k"] for e in est])
    return float(np.mean(mired - 1e6 / cct)), float(np.mean(np.array([e["duv"] for e in est]) - duv))


def run_case(camera: str, split: str, seed: int, history: int = 40, true_regions: bool = False,
             keep: str = "all", dump: Path | None = None) -> dict:
    """One camera through proposals, confirmation, shifted frames and a jump (module docstring). With ``dump``, the
    observations each refit fitted and the frames' true daylight are saved there (``<camera>-<shifted|still>.npz``)
    for offline study of the scene model."""
    import tempfile

    from fastapi.testclient import TestClient
    from illumon import model as scene_model
    from illumon_service.app import create_app
    from illumon_service.settings import Settings

    admin = {"Authorization": "Bearer bench-admin"}
    scene = TexturedScene(camera, split, seed, 24 + history + 1)
    t0 = datetime(2025, 6, 1, 5, 0, tzinfo=timezone.utc)
    out: dict = {"camera": camera, "seed": seed}
    with tempfile.TemporaryDirectory() as tmp, TestClient(create_app(Settings(
            data_dir=Path(tmp), admin_token="bench-admin", jobs_inline=True))) as c:
        css = scene.css
        body = {"name": camera, "regions": [], "response": {"encoding": "srgb", "white_level": 255},
                "sensitivities": {"wavelength_nm": WAVELENGTHS.tolist(), "r": css[:, 0].tolist(),
                                  "g": css[:, 1].tolist(), "b": css[:, 2].tolist()}}
        r = c.post("/v1/cameras", json=body, headers=admin)
        r.raise_for_status()
        cam = r.json()["id"]
        for f in range(24):
            img, _ = scene.frame(f)
            r = c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", png(img), "image/png")},
                       data={"taken_at": (t0 + timedelta(minutes=35 * f)).isoformat()}, headers=admin)
            r.raise_for_status()
        tp = time.perf_counter()
        r = c.get(f"/v1/cameras/{cam}/region-proposals?count=12", headers=admin)
        r.raise_for_status()
        out["proposal_s"] = round(time.perf_counter() - tp, 3)
        props = r.json()["proposals"]
        out.update(coverage(props, scene.surfaces, scene.moving_mask()))
        out["proposals"] = len(props)
        regions = [{"id": f"p{i + 1}", **{k: p[k] for k in ("x", "y", "width", "height")}} for i, p in enumerate(props)
                   if keep == "all" or p["score"] >= ticked_score(props)]
        out["regions"] = len(regions)
        if true_regions:  # a control: the true surfaces (4 px inside their edges) instead of the proposals
            regions = [{"id": f"s{i}", "x": x + 4, "y": y + 4, "width": w - 8, "height": h - 8}
                       for i, (x, y, w, h) in enumerate(scene.surfaces)]
        r = c.put(f"/v1/cameras/{cam}/regions", json={"regions": regions}, headers=admin)
        r.raise_for_status()
        # control: the same regions on a second camera whose frames are never shifted
        r = c.post("/v1/cameras", json={**body, "regions": regions}, headers=admin)
        r.raise_for_status()
        still = r.json()["id"]
        truth, truth_still, spectra = {}, {}, {}
        shifts = []
        t1 = t0 + timedelta(days=1)
        for k in range(history):
            f = 24 + k
            dx, dy = (0, 0) if k == 0 else (int(v) for v in scene.rng.integers(-20, 21, 2))
            img, white = scene.frame(f, dx, dy)
            r = c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", png(img), "image/png")},
                       data={"taken_at": (t1 + timedelta(minutes=15 * k)).isoformat()}, headers=admin)
            r.raise_for_status()
            j = r.json()
            truth[j["frame_id"]] = white
            spectra[j["frame_id"]] = scene.daylight[f]
            got = (j.get("registration") or {}).get("shift")
            if got is not None:
                shifts.append(float(np.hypot(got[0] - dx, got[1] - dy)))
            img, white = scene.frame(f)
            r = c.post(f"/v1/cameras/{still}/frames", files={"image": ("f.png", png(img), "image/png")},
                       data={"taken_at": (t1 + timedelta(minutes=15 * k)).isoformat()}, headers=admin)
            r.raise_for_status()
            truth_still[r.json()["frame_id"]] = white
            spectra[r.json()["frame_id"]] = scene.daylight[f]
        fitted: list = []
        fit = scene_model.fit_scene_model

        def recording_fit(obs, css, **kw):  # noqa: ANN001, ANN202 - records what the refit fits
            fitted.append((obs, css))
            return fit(obs, css, **kw)

        def errors(camera_id: int, truths: dict, name: str) -> tuple[list[float], tuple[float, float]]:
            scene_model.fit_scene_model = recording_fit
            try:
                r = c.post(f"/v1/cameras/{camera_id}/refit", headers=admin)
            finally:
                scene_model.fit_scene_model = fit
            r.raise_for_status()
            est = c.get(f"/v1/cameras/{camera_id}/estimates?limit=1000", headers=admin).json()
            by_frame = {e["frame_id"]: e for e in est}
            if dump is not None and fitted:
                obs, css_fit = fitted[-1]
                dump.mkdir(parents=True, exist_ok=True)
                np.savez(dump / f"{camera}-{name}.npz", values=obs.values, patches=np.array(obs.patches),
                         frames=np.array([str(f) for f in obs.frames]), css=css_fit,
                         daylight=np.array([spectra.get(int(f), np.full(len(WAVELENGTHS), np.nan))
                                            if str(f).isdigit() else np.full(len(WAVELENGTHS), np.nan)
                                            for f in obs.frames]))
            seen = [fid for fid in truths if fid in by_frame]
            return ([float(angular_error_deg(by_frame[fid]["white_rgb"], truths[fid])) for fid in seen],
                    common_shift([by_frame[fid] for fid in seen], [spectra[fid] for fid in seen]))

        errs, shift = errors(cam, truth, "shifted")
        control, _ = errors(still, truth_still, "still")
        out["common_mired"], out["common_duv"] = shift
        out["estimated"] = len(errs)
        out["frames"] = len(truth)
        out["white_median_deg"] = float(np.median(errs)) if errs else None
        out["white_max_deg"] = float(np.max(errs)) if errs else None
        out["unshifted_median_deg"] = float(np.median(control)) if control else None
        out["errors_deg"] = [round(e, 4) for e in errs]
        out["shift_error_px_max"] = float(np.max(shifts)) if shifts else None
        img, _ = scene.frame(24 + history, 100, 0)
        r = c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", png(img), "image/png")},
                   data={"taken_at": (t1 + timedelta(minutes=15 * history)).isoformat()}, headers=admin)
        r.raise_for_status()
        j = r.json()
        alerts = [a["kind"] for a in c.get(f"/v1/cameras/{cam}", headers=admin).json().get("alerts", [])]
        out["jump_alert"] = "view_change" in alerts and (j.get("registration") or {}).get("state") == "view_change"
        out["jump_estimated"] = j.get("estimate") is not None
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("score", "dev"), default="score")
    ap.add_argument("--cameras", type=int, default=4, help="cameras of the split (seeded, distinct)")
    ap.add_argument("--quick", action="store_true", help="one camera")
    ap.add_argument("--true-regions", action="store_true", help="control: confirm the true surfaces, not the proposals")
    ap.add_argument("--keep", choices=("ticked", "all"), default="all",
                    help="confirm all 12 proposals (default) or those the regions page ticks (≥ half the best score)")
    ap.add_argument("--dump", type=Path, help="save each refit's observations and the true daylight here (.npz)")
    args = ap.parse_args()
    from illumon.simulation import datasets

    if datasets.shared_data_dir() is None:
        print("regions_setup: measured data (../shared/data) not available", file=sys.stderr)
        return 2
    pool = rawsim.SCORE_CAMERAS if args.split == "score" else rawsim.DEV_CAMERAS
    n = 1 if args.quick else min(args.cameras, len(pool))
    cams = [pool[i] for i in np.random.default_rng(17).choice(len(pool), n, replace=False)]
    rows = []
    print(f"{'camera':<18} {'covered/10':>10} {'on moving':>9} {'white med °':>11} {'max °':>6} {'unshifted °':>11} "
          f"{'estimated':>9} {'shift err px':>12} {'jump alert':>10} {'proposals s':>11} {'Δmired':>7} {'ΔDuv×1e3':>8}")
    for i, cam in enumerate(cams):
        row = run_case(cam, args.split, 1000 * (args.split == "score") + i, true_regions=args.true_regions,
                       keep=args.keep, dump=args.dump)
        rows.append(row)
        def fmt(v: float | None, nd: int) -> str:
            return "—" if v is None else f"{v:.{nd}f}"

        print(f"{cam:<18} {row['covered']:>10} {row['on_moving']:>9} {fmt(row['white_median_deg'], 3):>11} "
              f"{fmt(row['white_max_deg'], 2):>6} {fmt(row['unshifted_median_deg'], 3):>11} "
              f"{row['estimated']:>4}/{row['frames']:<4} {fmt(row['shift_error_px_max'], 2):>12} "
              f"{str(row['jump_alert'] and not row['jump_estimated']):>10} {row['proposal_s']:>11} "
              f"{row['common_mired']:>7.1f} {1e3 * row['common_duv']:>8.2f}", flush=True)
    meds = [r["white_median_deg"] for r in rows if r["white_median_deg"] is not None]
    summary = {
        "split": args.split,
        "cases": len(rows),
        "covered_min": min(r["covered"] for r in rows),
        "on_moving_total": sum(r["on_moving"] for r in rows),
        "white_median_deg_worst": max(meds) if meds else None,
        "white_median_deg_pooled": float(np.median([e for r in rows for e in r["errors_deg"]])),
        "unshifted_median_deg_worst": max(r["unshifted_median_deg"] for r in rows if r["unshifted_median_deg"] is not None),
        "all_estimated": all(r["estimated"] == r["frames"] for r in rows),
        "jump_alerts": sum(bool(r["jump_alert"] and not r["jump_estimated"]) for r in rows),
    }
    print(json.dumps(summary))
    RESULTS.mkdir(exist_ok=True)
    name = "regions_setup_true.json" if args.true_regions else "regions_setup.json"
    (RESULTS / name).write_text(json.dumps({"summary": summary, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
