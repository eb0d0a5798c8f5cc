"""Ingest throughput: ``python -m illumon_service.bench [--frames N]``.

Posts a synthetic 1920×1080 frame (gradient background, 8 regions of 120×120, noise) as JPEG and as PNG through the
whole HTTP stack (in-process TestClient, SQLite in a temporary folder, WAL, synchronous=FULL) and compares with
``cv2.imdecode`` alone on the same bytes.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import cv2
import numpy as np


def _image(rng: np.random.Generator) -> np.ndarray:
    h, w = 1080, 1920
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.stack([60 + 80 * xx / w, 70 + 60 * yy / h, 90 + 40 * (xx + yy) / (w + h)], axis=-1)
    for i in range(8):
        x, y = 100 + 220 * i, 300 + 200 * (i % 2)
        img[y : y + 120, x : x + 120] = rng.uniform(40, 220, 3)
    img += rng.normal(0, 3, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def main() -> None:
    """Print frames/s for JPEG and PNG ingest and for cv2.imdecode alone."""
    from fastapi.testclient import TestClient

    from .app import create_app
    from .settings import Settings

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    img = _image(rng)
    regions = [{"id": f"r{i}", "x": 110 + 220 * i, "y": 310 + 200 * (i % 2), "width": 100, "height": 100}
               for i in range(8)]
    wl = list(range(400, 701, 10))
    body = {"name": "bench", "sensitivities": {"wavelength_nm": wl, "r": [1.0] * 31, "g": [1.0] * 31, "b": [1.0] * 31},
            "regions": regions, "response": {"encoding": "srgb"}}
    with tempfile.TemporaryDirectory() as tmp, TestClient(create_app(Settings(data_dir=tmp, admin_token="b"))) as c:
        cam = c.post("/v1/cameras", json=body, headers={"Authorization": "Bearer b"}).json()
        auth = {"Authorization": f"Bearer {cam['token']}"}
        for ext, ctype in ((".jpg", "image/jpeg"), (".png", "image/png")):
            data = cv2.imencode(ext, img[:, :, ::-1])[1].tobytes()
            t0 = time.perf_counter()
            for _ in range(args.frames):
                cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            decode = args.frames / (time.perf_counter() - t0)
            t0 = time.perf_counter()
            for _ in range(args.frames):
                r = c.post(f"/v1/cameras/{cam['id']}/frames", files={"image": ("f" + ext, data, ctype)}, headers=auth)
                assert r.status_code == 201, r.text
            ingest = args.frames / (time.perf_counter() - t0)
            print(f"{ext[1:]:>4} 1920x1080 {len(data) / 1e6:.2f} MB: ingest {ingest:.1f} frames/s, "
                  f"cv2.imdecode alone {decode:.1f} frames/s ({100 * ingest / decode:.0f} %)")


if __name__ == "__main__":
    main()
