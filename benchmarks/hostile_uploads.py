"""Peak memory of hostile uploads (issue 27): crafted images posted to a live ``illumon serve``, the server's peak
resident memory (``VmHWM``) read before and after each, above its idle peak.

The images: a JPEG with a stray byte after its first segment and a 12000 × 12000 frame header; a TIFF whose size
tags follow 600 unknown tags (12000 × 12000, 16-bit RGB); a 16-bit PNG of 6000 × 6000 (36 Mpx: within the pixel limit,
206 MiB decoded); for comparison, a legitimate 1920 × 1080 8-bit JPEG. Each crafted image must be refused (413)
before decoding. Run: ``python benchmarks/hostile_uploads.py`` (~10 s); prints a table and writes
``benchmarks/results/hostile_uploads.json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "service"))

from illumon_service.process import free_port, stop_process, wait_healthy  # noqa: E402
from test_robustness import _jpeg_stray_byte, _png, _tiff_with_late_size  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def _hwm_mb(pid: int) -> float:
    """Peak resident memory of a process (MB)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM")


def main() -> None:
    """Start a server, post each image, print the peak memory above idle."""
    admin = "bench-admin"
    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        env = {**os.environ, "ILLUMON_ADMIN_TOKEN": admin}
        proc = subprocess.Popen([str(Path(sys.executable).with_name("illumon")), "serve", "--port", str(port),
                                 "--data-dir", tmp], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if proc.poll() is not None:
            raise RuntimeError("serve did not start")
        url = f"http://127.0.0.1:{port}"
        try:
            wait_healthy(proc, url)
            auth = {"Authorization": f"Bearer {admin}"}
            regions = [{"id": "a", "x": 10, "y": 10, "width": 40, "height": 40},
                       {"id": "b", "x": 100, "y": 10, "width": 40, "height": 40}]
            sens = {"wavelength_nm": list(range(400, 701, 50)), "r": [0.1, 0.1, 0.2, 0.5, 1, 0.5, 0.1],
                    "g": [0.1, 0.5, 1, 0.8, 0.3, 0.1, 0.05], "b": [0.6, 1, 0.4, 0.1, 0.05, 0.02, 0.01]}
            r = httpx.post(f"{url}/v1/cameras", json={"name": "bench", "regions": regions, "sensitivities": sens},
                           headers=auth, trust_env=False)
            cid = r.json()["id"]
            small = cv2.imencode(".jpg", np.random.default_rng(0).integers(0, 255, (120, 160, 3), np.uint8))[1]
            httpx.post(f"{url}/v1/cameras/{cid}/frames", files={"image": ("f.jpg", small.tobytes(), "image/jpeg")},
                       headers=auth, trust_env=False)  # warm up: imports, first decode
            idle = _hwm_mb(proc.pid)
            hd = cv2.imencode(".jpg", np.random.default_rng(1).integers(0, 255, (1080, 1920, 3), np.uint8))[1]
            cases = {
                "JPEG 12000×12000 after a stray byte": _jpeg_stray_byte(12000, 12000),
                "TIFF size tags after 600 unknown tags": _tiff_with_late_size(12000, 12000),
                "16-bit PNG 6000×6000 (36 Mpx)": _png(6000, 6000, depth=16),
                "legitimate JPEG 1920×1080 (reference)": hd.tobytes(),
            }
            rows = []
            for name, data in cases.items():
                r = httpx.post(f"{url}/v1/cameras/{cid}/frames", files={"image": ("f", data, "application/octet-stream")},
                               headers=auth, trust_env=False, timeout=120)
                rows.append({"image": name, "bytes": len(data), "status": r.status_code,
                             "peak_above_idle_mb": round(_hwm_mb(proc.pid) - idle, 1)})
        finally:
            stop_process(proc)
    print(f"server idle peak {idle:.0f} MB")
    print("| upload | bytes | status | server peak above idle (MB) |\n|---|---|---|---|")
    for row in rows:
        print(f"| {row['image']} | {row['bytes']} | {row['status']} | {row['peak_above_idle_mb']} |")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "hostile_uploads.json").write_text(json.dumps({"idle_mb": idle, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
