"""Could a check cheaper than the registration tell that a frame has not moved (issue 29)? Measured on the frames
of ``benchmarks/ingest.py`` (1920×1080 JPEG, 2 % pixel noise, the daylight's colour changing from frame to frame, a
moving passer-by): how much two frames of the same view differ, against how much a shift changes them, for two cheap
signatures, and what a Lucas–Kanade fit of the shift on block means makes of known shifts.

Run: ``python benchmarks/stillness_check.py``. Prints three tables; the service does not use any of this (every frame
is registered: ``docs/service.md``, *Ingest speed*).

* sparse: the log of the green codes every 8th pixel; "one-pixel change" = median |code − its right neighbour's|;
* blocks: green sampled every 3rd pixel, averaged over 4 × 4 samples (12 × 12 pixels), logged (float, no 8-bit
  rounding); "one-pixel change" = median |block − next block| ÷ 12;
* the fit: least squares of the block differences by a shift, central-difference gradients of the first frame's
  blocks, the blocks that changed most (4 × the MAD) left out.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from ingest import render_frames


def _sparse(img: np.ndarray) -> tuple[np.ndarray, float]:
    g = np.log(img[:, :, 1].astype(np.float32) + 0.5)
    at = g[0:-1:8, 0:-1:8]
    return at, float(np.median(np.abs(g[0:-1:8, 1::8] - at)))


def _blocks(img: np.ndarray) -> tuple[np.ndarray, float]:
    g = img[::3, ::3, 1]
    h, w = (n - n % 4 for n in g.shape)
    v = np.log(cv2.resize(g[:h, :w].astype(np.float32), (w // 4, h // 4), interpolation=cv2.INTER_AREA) + 0.5)
    return v, min(float(np.median(np.abs(np.diff(v, axis=a)))) for a in (0, 1)) / 12


def _spread(a: np.ndarray, b: np.ndarray) -> float:
    d = b - a
    return float(np.median(np.abs(d - np.median(d))))


def _fit(ref: np.ndarray, now: np.ndarray) -> tuple[float, float]:
    """The shift (x, y, full-resolution pixels) that best explains ``now − ref`` on the blocks."""
    gy, gx = np.gradient(ref)
    inner = (slice(1, -1), slice(1, -1))
    d = (now - ref)[inner]
    d = d - np.median(d)
    keep = np.abs(d) <= 4 * 1.4826 * np.median(np.abs(d)) + 1e-6
    d, gx, gy = d[keep], gx[inner][keep], gy[inner][keep]
    a = np.array([[np.sum(gx * gx), np.sum(gx * gy)], [np.sum(gx * gy), np.sum(gy * gy)]])
    s = -np.linalg.solve(a, np.array([np.sum(gx * d), np.sum(gy * d)]))
    return float(s[0] * 12), float(s[1] * 12)


def _shifted(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(img, m, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def main() -> None:
    """Print the tables."""
    cv2.setNumThreads(1)
    data, _, provenance = render_frames(10, "jpeg")
    imgs = [cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_UNCHANGED) for d in data]
    t = time.perf_counter()
    for _ in range(20):
        _blocks(imgs[1])
    print(f"frames: {provenance}; block signature {1e3 * (time.perf_counter() - t) / 20:.2f} ms per frame\n")
    for name, sig in (("sparse", _sparse), ("blocks", _blocks)):
        ref, one = sig(imgs[0])
        same = [_spread(ref, sig(im)[0]) for im in imgs[1:]]
        moved = {s: _spread(ref, sig(_shifted(imgs[1], s, 0))[0]) for s in (1, 2, 5)}
        print(f"{name}: same view, 9 later frames: median |Δ| {min(same):.4f}–{max(same):.4f}; "
              f"one-pixel change {one:.4f}; frame 1 shifted 1 / 2 / 5 px: "
              + " / ".join(f"{v:.4f}" for v in moved.values()))
    ref = _blocks(imgs[0])[0]
    print("\nLucas–Kanade on the blocks, frame 1 shifted by (dx, dy) → fitted shift (px):")
    for dx, dy in ((0, 0), (0.5, 0), (1, 0), (2, 1), (5, 0), (12, 0), (100, 0)):
        fx, fy = _fit(ref, _blocks(_shifted(imgs[1], dx, dy))[0])
        print(f"  ({dx:>5}, {dy:>3}) → ({fx:+.2f}, {fy:+.2f})")


if __name__ == "__main__":
    main()
