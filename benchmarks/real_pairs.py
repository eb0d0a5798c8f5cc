"""Chart / chart-free pairs: a chart held up once, then a frame without it, on real photographs.

The installer's path on real data. ``../shared/data/real/sony-dolp`` has, per indoor scene, a shot with a ColorChecker
in view and one without it, by the same fixed camera under the same light (``scene00N_macbeth`` / ``scene00N_imean``;
things in the scene may have moved between the two, a person may have stepped in). Per scene a two-frame history:

* the scene's regions — static, uniform, unclipped, not dark, outside the chart, alike in both shots but for the
  exposure — chosen the way an installer confirms proposals (:func:`static_regions`: a grid of 16-pixel windows, the
  most distinct colours first), measured in both shots with the service's own robust means;
* the chart's patches as references in the chart shot only: the whole chart, or its six greys;
* the estimate that matters is the **chart-free** frame's camera white; its truth is the chart shot's greys 20–22
  (the same light), carried through the chart-free frame's own pipeline.

Three cameras as in ``benchmarks/real.py``: the raw sensor (``--primaries camera``), and the same raw values through a
colour matrix to sRGB with a fixed daylight preset or a per-frame gray-world auto white balance (``srgb``; the matrix
and preset of :func:`real.isp_pipeline`). Beside illumon: doing nothing, gray-world over the same regions, and over the
whole chart-free image. ``scene003``'s chart is too small to read (``real.MIN_PITCH``), so three pairs.

``python benchmarks/real_pairs.py`` prints the table and writes ``benchmarks/results/real_pairs.json``. Development
data (the scoring photographs are held by outside checks); nothing was chosen on it.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "core"), str(ROOT / "service"), str(Path(__file__).resolve().parent)]

import real  # noqa: E402

WINDOW = 16
"""Side of a candidate region (pixels of the 490 × 408 images)."""

REGIONS = 12
"""Regions kept per scene (the most distinct colours among the static, uniform ones)."""


def chart_centres(rgb16: NDArray) -> tuple[NDArray[np.float64], float]:
    """The chart's patch centres (24 × 2, chart order) and pitch that ``cv2.mcc`` finds in a brightened copy of the
    16-bit linear shot (as ``real._measure_chart`` reads the chart)."""
    from illumon_service.calibration import detect_colourchecker

    bright = np.clip(rgb16.astype(float) / np.percentile(rgb16, 99.5), 0, 1) ** (1 / 2.2)
    return detect_colourchecker((bright * 65535).astype(np.uint16), 65535)


def chart_box(rgb16: NDArray) -> tuple[int, int, int, int]:
    """The chart's box ``x, y, w, h`` (pixels): one patch pitch around its patch centres (:func:`chart_centres`)."""
    centres, pitch = chart_centres(rgb16)
    c = np.asarray(centres, dtype=float)
    x0, y0 = c.min(axis=0) - pitch
    x1, y1 = c.max(axis=0) + pitch
    return int(x0), int(y0), int(x1 - x0), int(y1 - y0)


def static_regions(a: NDArray[np.float64], b: NDArray[np.float64], box: tuple[int, int, int, int],
                   margin: int = 8) -> list[tuple[int, int]]:
    """Top-left corners of :data:`WINDOW`-pixel regions that are static between the two shots (log r/g and b/g
    within 0.02, brightness within 5 % of the two shots' median ratio: the exposure may differ), uniform (pixel
    spread under 15 % of the mean in each channel), unclipped, not dark (green above 3 % of the shot's 99th
    percentile) and clear of the chart's box by ``margin``; the :data:`REGIONS` most distinct in log chromaticity
    (farthest-point order from the brightest)."""
    x0, y0, w, h = box
    top = float(np.percentile(a, 99))
    stats = []
    for y in range(0, a.shape[0] - WINDOW + 1, WINDOW):
        for x in range(0, a.shape[1] - WINDOW + 1, WINDOW):
            if x + WINDOW > x0 - margin and x < x0 + w + margin and y + WINDOW > y0 - margin and y < y0 + h + margin:
                continue
            pa, pb = a[y:y + WINDOW, x:x + WINDOW].reshape(-1, 3), b[y:y + WINDOW, x:x + WINDOW].reshape(-1, 3)
            ma, mb = pa.mean(axis=0), pb.mean(axis=0)
            if pa.max() >= 0.98 or pb.max() >= 0.98 or ma[1] < 0.03 * top or np.any(pa.std(axis=0) > 0.15 * ma):
                continue
            stats.append((x, y, np.log(ma[[0, 2]] / ma[1]), np.log(mb[[0, 2]] / mb[1]), np.log(mb[1] / ma[1]), ma[1]))
    if not stats:
        return []
    ratio = float(np.median([s[4] for s in stats]))
    keep = [s for s in stats if np.all(np.abs(s[2] - s[3]) < 0.02) and abs(s[4] - ratio) < 0.05]
    if not keep:
        return []
    chroma = np.array([s[2] for s in keep])
    chosen = [int(np.argmax([s[5] for s in keep]))]
    dist = np.linalg.norm(chroma - chroma[chosen[0]], axis=1)
    while len(chosen) < min(REGIONS, len(keep)):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(chroma - chroma[nxt], axis=1))
    return [(keep[i][0], keep[i][1]) for i in chosen]


def region_values(img16: NDArray, corners: list[tuple[int, int]]) -> NDArray[np.float64]:
    """The regions' robust linear means (R × 3, 0…1) with the service's own measurement."""
    from illumon.camera.pipeline import ResponseCurve
    from illumon_service.calibration import measure_patches
    from illumon_service.regions import Region

    regions = [Region(f"r{i:02d}", x, y, WINDOW, WINDOW) for i, (x, y) in enumerate(corners)]
    patches, _ = measure_patches(img16, regions, ResponseCurve("linear", white_level=65535.0),
                                 clip_fraction=0.98, min_fraction=0.5)
    return np.array([[np.nan] * 3 if p["r"] is None else [p["r"], p["g"], p["b"]] for p in patches])


def estimate_free(chart: NDArray[np.float64], scene: NDArray[np.float64], primaries: str, mode: str
                  ) -> tuple[NDArray[np.float64], float]:
    """The chart-free frame's camera white (3,) and ``confidence``: a two-frame history (the chart shot's regions and
    references, the chart-free shot's regions; ``scene`` 2 × R × 3, ``chart`` 24 × 3), ``mode`` ``none`` (regions
    only), ``grey`` (the chart's greys 19–24 known) or ``chart`` (all 24)."""
    from illumon.camera.references import colourchecker_references
    from illumon.model import fit_scene_model
    from illumon.observations import Observations

    refs = colourchecker_references()
    known = {"none": [], "grey": real.GREYS, "chart": real.ALL}[mode]
    ids = [f"r{i:02d}" for i in range(scene.shape[1])]
    vals = np.full((2, len(ids) + len(known), 3), np.nan)
    vals[:, :len(ids)] = scene
    vals[0, len(ids):] = chart[[real.ALL.index(p) for p in known]]
    obs = Observations(frames=["chart", "free"], patches=ids + [p.replace("chart:", "ref:") for p in known],
                       values=vals, times=[None, None])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = fit_scene_model(obs, None, primaries=primaries,
                                known_reflectances={p.replace("chart:", "ref:"): refs[p] for p in known} or None)
    result, extra = model.history_estimate
    return np.asarray(result.white[1], dtype=float), float(extra["confidence"][1])


def through(x: NDArray[np.float64], camera: str, m: NDArray[np.float64], preset: NDArray[np.float64],
            image_mean: NDArray[np.float64]) -> NDArray[np.float64]:
    """Raw values (… × 3) of a frame whose whole image averages ``image_mean`` as ``camera`` delivers them: as they
    are (``raw``), or through :func:`real.render_isp` with the daylight ``preset`` or the frame's own gray-world gains
    (``auto``, :func:`real.auto_gains`) and the colour matrix ``m`` (:func:`real.isp_pipeline`)."""
    if camera == "raw":
        return x
    return real.render_isp(x, preset if camera == "preset" else real.auto_gains(image_mean), m)


PRIMARIES = {"raw": "camera", "preset": "srgb", "auto": "srgb"}
"""The output space each camera of :func:`through` delivers (``--primaries``)."""


def prepared(p: dict, camera: str, m: NDArray[np.float64], preset: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A pair of :func:`pairs` as ``camera`` delivers it: the regions of both shots (2 × R × 3) and the chart (24 × 3)
    scaled together so the brightest value is 0.9, and the truth — the chart shot's greys 20–22 (the same light) as
    the chart-free frame's pipeline renders them (3,)."""
    scene = np.stack([through(p["values"][f], camera, m, preset, p["image_means"][f]) for f in range(2)])
    chart = through(p["chart"], camera, m, preset, p["image_means"][0])
    scale = 0.9 / np.nanmax(np.concatenate([scene.reshape(-1, 3), chart]))
    truth_raw = np.nanmean(p["chart"][[real.ALL.index(t) for t in real.TRUTH]], axis=0)
    return scene * scale, chart * scale, through(truth_raw, camera, m, preset, p["image_means"][1])


def pairs(data: Path) -> list[dict]:
    """Each readable scene's chart shot and chart-free shot: raw chart values, regions, image means."""
    import cv2

    folder = data / "real" / "sony-dolp"
    out = []
    for path in sorted(folder.glob("scene*_macbeth.png")):
        name = path.stem.split("_")[0]
        a16 = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
        b16 = cv2.imread(str(folder / f"{name}_imean.png"), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
        chart = real._measure_chart(a16, 65535.0)
        if chart is None:
            continue
        a, b = a16.astype(float) / 65535.0, b16.astype(float) / 65535.0
        corners = static_regions(a, b, chart_box(a16))
        if len(corners) < 2:
            continue
        scene = np.stack([region_values(a16, corners), region_values(b16, corners)])
        means = [img[np.all(img < 0.98, axis=-1)].mean(axis=0) for img in (a, b)]
        out.append({"scene": name, "chart": chart, "regions": corners, "values": scene, "image_means": np.array(means)})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "real_pairs.json"))
    args = ap.parse_args(argv)
    data = real.shared_data()
    if not (data / "real" / "sony-dolp").is_dir():
        print(f"real_pairs.py: skipped: {data / 'real' / 'sony-dolp'} is absent (../shared/data or $ILLUMON_SHARED_DATA)")
        return 0
    raw = real.sony_raw(data)
    m, preset = real.isp_pipeline(raw)
    report = {"split": "development (../shared/data/real: sony-dolp chart / chart-free pairs); scoring photographs "
                       "are held by outside checks", "cameras": {}}
    found = pairs(data)
    for camera in ("raw", "preset", "auto"):
        rows = []
        for p in found:
            scene, chart, truth = prepared(p, camera, m, preset)
            row = {"scene": p["scene"], "regions": len(p["regions"]),
                   "nothing": float(real.angular(np.ones(3), truth)[0]),
                   "gray-world": float(real.angular(np.nanmean(scene[1], axis=0), truth)[0]),
                   "gray-world (image)": float(real.angular(
                       through(p["image_means"][1], camera, m, preset, p["image_means"][1]), truth)[0])}
            for mode in ("none", "grey", "chart"):
                white, conf = estimate_free(chart, scene, PRIMARIES[camera], mode)
                row[f"illumon {mode}"] = float(real.angular(white, truth)[0])
                row[f"confidence {mode}"] = conf
            rows.append(row)
        report["cameras"][camera] = rows
    cols = ["nothing", "gray-world", "gray-world (image)", "illumon none", "illumon grey", "illumon chart"]
    print(f"split: {report['split']}")
    print("the chart-free frame's camera white, degrees from the chart shot's greys 20–22 (confidence stated)")
    print(f"{'camera':8} {'scene':9} {'regions':>7} " + " ".join(f"{c:>18}" for c in cols))
    for camera, rows in report["cameras"].items():
        for r in rows:
            cells = [f"{r[c]:18.2f}" if not c.startswith("illumon") else
                     f"{r[c]:11.2f} ({r['confidence ' + c.split()[1]]:.2f})" for c in cols]
            print(f"{camera:8} {r['scene']:9} {r['regions']:7d} " + " ".join(f"{c:>18}" for c in cells))
        med = {c: float(np.median([r[c] for r in rows])) for c in cols}
        print(f"{camera:8} {'median':9} {'':7} " + " ".join(f"{med[c]:18.2f}" for c in cols))
    real.write_report(args.out, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
