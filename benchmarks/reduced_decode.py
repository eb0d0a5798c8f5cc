"""Reduced-resolution JPEG decode (``ILLUMON_JPEG_MAX_REDUCTION``) against the full decode: region means and the
resulting per-frame illuminant estimates.

Run: ``python benchmarks/reduced_decode.py [--frames 40]``. Prints a table and writes
``benchmarks/results/reduced_decode.json``.

Two kinds of 1920×1080 sRGB JPEG frames (quality 90, 4:2:0), both with 16 patches rendered from measured spectra
(Nikon D5100, Granada daylight, Munsell; synthetic spectra without ``../shared/data``), 2 % pixel noise and a passer-by
moving across the scene:

* ``bench``: the ingest benchmark's frames (uniform patches, textured background) and its 16 regions of 120×120,
  whose edges lie on the 8-pixel grid;
* ``textured``: patches with a ±15 % surface texture at 1–4 pixel scales (paving, foliage), and regions inset by odd
  margins so that their edges cut decoded pixels at every reduction (coverage weights in use).

For every frame, the service's robust region means (:func:`illumon_service.regions.region_means`) of the full decode
are compared with those of the 1/2, 1/4 and 1/8 decodes (regions of 120 pixels are 60, 30 and 15 decoded pixels wide),
on regions the passer-by does not touch. ``SE`` is the standard error of a region mean from pixel noise (σ/√n of the
full-decode pixels), ``JPEG`` the difference JPEG compression itself makes (the 8-bit frame before encoding against its
full decode). Illuminants: a scene model is fitted to the first 12 frames' full-decode means (as a refit does), then
every later frame is estimated from the full-decode means and from the reduced ones; the angle between the two camera
whites is reported over frames where the same regions are present (a region whose usable fraction crosses the 50 %
threshold under the passer-by can flip between present and missing, which changes the estimate by itself).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import warnings
from pathlib import Path

import cv2
import ingest
import numpy as np
from illumon.camera import ResponseCurve, angular_error_deg, render
from illumon_service import estimation
from illumon_service.decode import decode_image  # noqa: E402
from illumon_service.regions import Region, region_means, response_for

RESULTS = Path(__file__).with_name("results")
SCALES = (2, 4, 8)
W, H, R = ingest.W, ingest.H, ingest.REGION


def passer_by(f: int) -> tuple[int, int, int, int]:
    """(x, y, width, height) of frame ``f``'s passer-by (as in :func:`ingest.render_frames`)."""
    return (f * 97) % (W - 200), 100, 150, 600


def textured_frames(n: int) -> tuple[list[bytes], list[np.ndarray], np.ndarray]:
    """``n`` JPEG frames with textured patches, the 8-bit RGB frames before encoding, and the sensitivities."""
    css, day, refl, _ = ingest.spectra(n)
    lin = render(css, day, refl)
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    shade = (0.7 + 0.3 * xx / W)[..., None] * (0.8 + 0.2 * yy / H)[..., None]
    tex = sum(cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), s) for s in (0.7, 2.0, 4.0))
    tex = np.clip(1 + 0.15 * tex / tex.std(), 0.4, 1.6)[..., None]
    frames, raw = [], []
    for f in range(n):
        k = 0.7 / lin[f].max()
        img = (shade * (lin[f, 16] * k)).astype(np.float32)
        for r, v in zip(ingest.regions(), lin[f, :16] * k, strict=True):
            img[r["y"] : r["y"] + R, r["x"] : r["x"] + R] = v
        img *= tex
        img *= 1 + 0.02 * rng.standard_normal(img.shape, dtype=np.float32)
        x, y, w, h = passer_by(f)
        img[y : y + h, x : x + w] = [0.5, 0.1, 0.05]
        enc = np.round(ResponseCurve("srgb", white_level=255).encode(np.clip(img, 0, 1))).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", enc[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        frames.append(buf.tobytes())
        raw.append(enc)
    return frames, raw, css


def bench_frames(n: int) -> tuple[list[bytes], list[np.ndarray], np.ndarray]:
    """The ingest benchmark's JPEG frames, the 8-bit RGB frames before encoding, and the sensitivities."""
    raw: list[np.ndarray] = []
    encode = cv2.imencode

    def capture(ext: str, img: np.ndarray, *params: object) -> tuple[bool, np.ndarray]:
        raw.append(img[:, :, ::-1].copy())
        return encode(ext, img, *params)

    cv2.imencode = capture
    try:
        frames, css, _ = ingest.render_frames(n, "jpeg")
    finally:
        cv2.imencode = encode
    return frames, raw, css


def as_array(rows: list[dict], ids: list[str]) -> np.ndarray:
    """Frames × regions × 3 means, NaN where missing."""
    return np.array([[[np.nan] * 3 if row[i] is None else row[i] for i in ids] for row in rows], float)


def run(kind: str, n: int) -> dict:
    """Compare the reductions on ``n`` frames of ``kind``; print and return the summary."""
    frames, raw, css = bench_frames(n) if kind == "bench" else textured_frames(n)
    regs = [Region(**r) for r in ingest.regions()]
    if kind == "textured":
        regs = [Region(r.id, r.x + 3 + i % 3, r.y + 5 - i % 2, R - 7 - i % 4, R - 9 + i % 3) for i, r in enumerate(regs)]
    ids = [r.id for r in regs]
    resp = response_for({"encoding": "srgb"}, 255.0)
    lut = resp.linearise(np.arange(256.0))
    full, before, reduced, se = [], [], {s: [] for s in SCALES}, []
    for f, data in enumerate(frames):
        img, _ = decode_image(data)
        full.append(region_means(img, regs, resp))
        before.append(region_means(raw[f], regs, resp))
        row = []
        for r in regs:
            px = lut[img[r.y : r.y + r.height, r.x : r.x + r.width].reshape(-1, 3)]
            med = np.median(px, axis=0)
            ok = np.all(np.abs(px - med) <= 0.25 * med + 1e-3, axis=1)  # the passer-by left out
            row.append(px[ok].std(axis=0) / np.sqrt(max(1, ok.sum())))
        se.append(row)
        for s in SCALES:
            small, _ = decode_image(data, reduction=s)
            reduced[s].append(region_means(small, regs, resp, scale=s, size=(W, H)))
    full_a, se_a = as_array(full, ids), np.array(se)
    clear = np.array([[not (x < r.x + r.width and x + w > r.x and y < r.y + r.height and y + h > r.y)
                       for r in regs] for x, y, w, h in map(passer_by, range(n))])

    with tempfile.TemporaryDirectory() as tmp:
        path = estimation.model_path(tmp, 1)
        path.parent.mkdir(parents=True, exist_ok=True)
        times = [f"2025-06-01T{5 + f // 6:02d}:{(f % 6) * 10:02d}:00+00:00" for f in range(n)]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            estimation.fit_model(estimation.build_observations(  # the refit's own fit
                [(str(f), times[f], full[f]) for f in range(12)], ids), css, path)

            def whites(rows: list[dict]) -> np.ndarray:
                out = []
                for f in range(12, n):
                    e = estimation.estimate_frame(tmp, 1, str(f), times[f], rows[f], ids)
                    out.append(e["white_rgb"] if e else [np.nan] * 3)
                return np.array(out)

            white_full = whites(full)
            white_before = whites(before)
            white_reduced = {s: whites(reduced[s]) for s in SCALES}

    def compare(rows: list[dict], white: np.ndarray) -> dict:
        a = as_array(rows, ids)
        rel = (a - full_a) / full_a
        flips = np.isnan(a[..., 0]) != np.isnan(full_a[..., 0])
        same = ~flips[12:].any(axis=1)
        ang = angular_error_deg(white, white_full)[same]
        c = clear & ~np.isnan(a[..., 0]) & ~np.isnan(full_a[..., 0])
        return {"rel_median_pct": 100 * float(np.median(np.abs(rel[c]))),
                "rel_p95_pct": 100 * float(np.percentile(np.abs(rel[c]), 95)),
                "rel_max_pct": 100 * float(np.max(np.abs(rel[c]))),
                "rel_mean_pct": 100 * float(np.mean(rel[c])),
                "diff_over_se_median": float(np.median(np.abs(a - full_a)[c] / se_a[c])),
                "presence_flips": int(flips.sum()),
                "white_deg_median": float(np.median(ang)), "white_deg_p95": float(np.percentile(ang, 95)),
                "white_deg_max": float(np.max(ang)), "white_frames": int(same.sum())}

    out = {"kind": kind, "frames": n, "regions": len(regs),
           "se_median_pct": 100 * float(np.median((se_a / full_a)[clear & ~np.isnan(full_a[..., 0])])),
           "jpeg": compare(before, white_before), "reduced": {str(s): compare(reduced[s], white_reduced[s])
                                                               for s in SCALES}}
    print(f"{kind}: {n} frames, {len(regs)} regions; region-mean SE from pixel noise: median "
          f"{out['se_median_pct']:.3f} % of the mean")
    for name, res in [("JPEG q90 itself", out["jpeg"])] + [(f"decode 1/{s}", out["reduced"][str(s)]) for s in SCALES]:
        print(f"  {name:>15} {res['rel_median_pct']:8.3f} {res['rel_p95_pct']:8.3f} {res['rel_max_pct']:8.3f} "
              f"{res['rel_mean_pct']:+9.3f} {res['diff_over_se_median']:7.1f} {res['presence_flips']:6d} "
              f"{res['white_deg_median']:9.4f} {res['white_deg_p95']:9.4f} {res['white_deg_max']:9.4f}")
    return out


def main() -> None:
    """Run both kinds of frames; print the table; write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="frames per kind (40; 12 fit the scene model)")
    args = parser.parse_args()
    print("region means vs the full decode (regions clear of the passer-by): |relative difference| median, p95, max "
          "and signed mean (%), median |difference| / SE, presence flips; white: angle to the full decode's "
          "estimate (degrees) median, p95, max")
    print(f"  {'':>15} {'median':>8} {'p95':>8} {'max':>8} {'mean':>9} {'÷SE':>7} {'flips':>6} "
          f"{'white°':>9} {'p95':>9} {'max':>9}")
    runs = [run(kind, args.frames) for kind in ("bench", "textured")]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "reduced_decode.json").write_text(json.dumps({"runs": runs}, indent=1) + "\n")
    print(f"wrote {RESULTS / 'reduced_decode.json'}")


if __name__ == "__main__":
    main()
