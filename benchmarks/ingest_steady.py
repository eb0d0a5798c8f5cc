"""Steady ingest (issue 29): one ``illumon serve`` taking JPEG frames for a fixed time from ``--clients`` keep-alive
connections; prints frames/s, p50 / p99 latency, the server's CPU ms per frame and the load.

Run: ``python benchmarks/ingest_steady.py [--seconds 8] [--clients 1] [--server-workers 1]``. Short and
self-contained, for A/B rounds of two versions of the service on a shared machine: run it alternately with
``PYTHONPATH=<other tree>/service:<other tree>/core`` (the server process inherits it) and without. The frames, the
camera, the warm-up (12 frames, a refit, 8 untimed frames over as many connections) and the poster are those of
``benchmarks/ingest.py``; 40 frames are posted round-robin, each with a new time.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from datetime import timedelta

import httpx
import numpy as np
from illumon_service.process import free_port, stop_process
from ingest import T0, FramePoster, _cpu_seconds, post, register, render_frames, start_server


def main() -> None:
    """Start a server, warm it up, post for ``--seconds``; print one line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--clients", type=int, default=1)
    parser.add_argument("--server-workers", type=int, default=1, help="illumon serve --workers (1)")
    args = parser.parse_args()
    frames, css, _ = render_frames(40, "jpeg")
    clock, lock = [T0], threading.Lock()

    def next_time():  # noqa: ANN202 - a datetime
        with lock:
            clock[0] += timedelta(seconds=10)
            return clock[0]

    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        proc = start_server(tmp, port, args.server_workers)
        try:
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=120, trust_env=False) as http:
                cam, auth = register(http, css, "srgb")
                for f in frames[:12]:
                    post(http, cam, auth, f, "image/jpeg", next_time())
                job = http.post(f"/v1/cameras/{cam}/refit", headers=auth).json()["job_id"]
                while http.get(f"/v1/jobs/{job}", headers=auth).json()["state"] not in ("done", "failed"):
                    time.sleep(0.2)
            poster = FramePoster(port, cam, auth)
            warm = [threading.Thread(target=lambda f=f: poster(f, "image/jpeg", next_time())) for f in frames[:8]]
            for t in warm:  # over several connections: every server worker loads the model
                t.start()
            for t in warm:
                t.join()
            lat: list[float] = []
            stop = time.perf_counter() + args.seconds

            def client(k: int) -> None:
                i = k
                while time.perf_counter() < stop:
                    lat.append(poster(frames[i % len(frames)], "image/jpeg", next_time()))
                    i += args.clients

            threads = [threading.Thread(target=client, args=(k,)) for k in range(args.clients)]
            cpu0, t0 = _cpu_seconds(proc.pid), time.perf_counter()
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            wall, cpu = time.perf_counter() - t0, _cpu_seconds(proc.pid) - cpu0
            poster.close()
        finally:
            stop_process(proc)
    print(f"{args.clients} clients, {args.server_workers} server worker(s): {len(lat) / wall:.1f} f/s, "
          f"p50 {1e3 * np.percentile(lat, 50):.1f} ms, "
          f"p99 {1e3 * np.percentile(lat, 99):.1f} ms, server CPU {1e3 * cpu / len(lat):.1f} ms/frame, "
          f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
