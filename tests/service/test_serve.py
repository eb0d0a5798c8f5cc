"""`illumon serve` as a real process on a loopback port: a committed frame survives a kill and restart."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
from illumon_service.app import admin_token
from illumon_service.process import free_port, wait_healthy
from illumon_service.settings import Settings
from svc_helpers import encode_png, grid_regions

ILLUMON = Path(sys.executable).with_name("illumon")


def _start(data_dir: Path, port: int, *extra: str, timeout: float = 30) -> subprocess.Popen:
    """``illumon serve`` (plus ``extra`` arguments) on ``port``, once it answers ``/healthz``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("ILLUMON_")}
    cmd = [str(ILLUMON), "serve", "--host", "127.0.0.1", "--port", str(port), "--data-dir", str(data_dir),
           "--log-level", "warning", *extra]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_healthy(proc, f"http://127.0.0.1:{port}", timeout=timeout, describe=lambda: proc.stderr.read())
    except RuntimeError as exc:
        raise AssertionError(str(exc)) from None
    return proc


def _kill(proc: subprocess.Popen) -> str:
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    return proc.stderr.read()


def test_serve_durable(tmp_path):
    port = free_port()
    proc = _start(tmp_path, port)
    try:
        token = (tmp_path / "admin_token").read_text().strip()
        assert oct((tmp_path / "admin_token").stat().st_mode & 0o777) == "0o600"
        base = f"http://127.0.0.1:{port}"
        http = httpx.Client(trust_env=False, timeout=30)
        admin = {"Authorization": f"Bearer {token}"}
        wl = list(range(400, 701, 10))
        ones = [1.0] * len(wl)
        body = {"name": "cam", "sensitivities": {"wavelength_nm": wl, "r": ones, "g": ones, "b": ones},
                "regions": grid_regions(), "response": {"encoding": "srgb"}}
        cam = http.post(f"{base}/v1/cameras", json=body, headers=admin).json()
        img = encode_png(np.full((240, 320, 3), (90, 80, 70), np.uint8))
        r = http.post(f"{base}/v1/cameras/{cam['id']}/frames", files={"image": ("a.png", img, "image/png")},
                       data={"taken_at": "2025-06-01T10:00:00Z"}, headers={"Authorization": f"Bearer {cam['token']}"})
        assert r.status_code == 201, r.text
        frame_id = r.json()["frame_id"]
        # A refit in the background thread: one frame is too few, so the job fails with a reason.
        cam_auth = {"Authorization": f"Bearer {cam['token']}"}
        job = http.post(f"{base}/v1/cameras/{cam['id']}/refit", headers=cam_auth)
        assert job.status_code == 202
        for _ in range(100):
            state = http.get(f"{base}/v1/jobs/{job.json()['job_id']}", headers=cam_auth).json()
            if state["state"] in ("done", "failed"):
                break
            time.sleep(0.1)
        assert state["state"] == "failed" and "two frames" in state["summary"]["error"]
    finally:
        stderr = _kill(proc)
    assert token in stderr  # printed once on first start
    proc = _start(tmp_path, port)
    try:
        r = http.get(f"{base}/v1/cameras/{cam['id']}/frames", headers={"Authorization": f"Bearer {cam['token']}"})
        assert [f["frame_id"] for f in r.json()] == [frame_id]
    finally:
        stderr = _kill(proc)
    assert token not in stderr  # not printed again


def test_admin_token_from_env_or_file(tmp_path):
    assert admin_token(Settings(data_dir=tmp_path, admin_token="abc")) == "abc"
    t = admin_token(Settings(data_dir=tmp_path))
    assert admin_token(Settings(data_dir=tmp_path)) == t


def test_serve_workers_answer_without_delayed_ack_stalls(tmp_path):
    """`illumon serve --workers 2` disables Nagle's algorithm on its connections: uvicorn's shared socket otherwise
    leaves it on, and on a keep-alive connection each answer's last segment waited for the client's delayed ACK
    (≥ 40 ms per request instead of a few)."""
    import http.client

    from illumon_service.process import stop_process

    port = free_port()
    proc = _start(tmp_path, port, "--workers", "2", timeout=60)
    try:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        # keep-alive requests on one connection (their latency, which Nagle's algorithm spoilt, is measured by
        # benchmarks/ingest.py: timings are not asserted in tests)
        for _ in range(15):
            conn.request("GET", "/healthz")
            resp = conn.getresponse()
            resp.read()
            assert resp.status == 200
        conn.close()
        # /metrics sums the workers: 404s answered by either worker (a new connection each), then every scrape,
        # whichever worker answers it, counts all of them once the workers have published (≤ 1 s).
        for _ in range(20):
            c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            c.request("GET", "/no-such-route")
            assert c.getresponse().status == 404
            c.close()
        time.sleep(1.5)
        for _ in range(6):
            text = httpx.get(f"http://127.0.0.1:{port}/metrics", timeout=10, trust_env=False,
                             headers={"Connection": "close"}).text
            line = next(ln for ln in text.splitlines() if ln.startswith('illumon_http_errors_total{status="404"}'))
            assert float(line.split()[1]) == 20, line
    finally:
        stop_process(proc)
