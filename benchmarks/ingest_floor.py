"""How fast can any durable ingest of these frames be? The irreducible part of ``POST /frames`` without HTTP, next to
``cv2.imdecode`` alone, in one run (issue 29).

Run: ``python benchmarks/ingest_floor.py [--frames 60] [--rounds 3]``. Prints a table and writes
``benchmarks/results/ingest_floor.json``.

Issue 29 asks ingest at ≥ 0.6 × the frames/s of ``cv2.imdecode`` alone with one client, and ≥ 0.5 × decode-only on
every core with eight. This script takes the HTTP server, the upload, the routing, the estimate and the ORM away
and times, on the ingest benchmark's frames (``benchmarks/ingest.py``: 1920×1080 JPEG, 16 regions of 120×120), the
steps a frame cannot skip in the service's own functions, cumulatively, one thread, the steps interleaved round by
round:

* ``decode``: ``cv2.imdecode`` alone (the issue's floor);
* ``+ regions``: the service's decode (:func:`illumon_service.decode.decode_frame`) and its robust region statistics
  (:func:`illumon_service.regions.region_stats`) — what a frame is measured by;
* ``+ durable``: and one row written and committed to SQLite in WAL mode with ``synchronous=FULL`` (the service's
  settings: a 201 means the frame is on disk), a transaction per frame, as with one client;
* ``+ register``: and the frame's thumbnail and its phase correlation to the view's reference (the registration
  that tells a fixed camera's frame from a moved view).

Then, on its own, ``HTTP only``: the same frames posted as ``benchmarks/ingest.py`` posts them (one keep-alive
connection, a hand-assembled multipart body) to a server (``uvicorn``, one process) whose only route reads the upload
with the service's own form reader (:func:`illumon_service.api.forms.read_frame_form`) and answers 201 with an empty
JSON object — the HTTP path with no work behind it; ``cpu ms`` there is the server's and the client's CPU per frame.
The row ``+ HTTP`` adds it to ``+ register``; ``overlapped`` is that row's wall time with the region statistics and
the registration run side by side on two cores, as the service does with one client (the slower of the two counts),
computed from the rows above (its CPU is ``+ HTTP``'s).

``f/s ÷ decode`` of a row bounds, from above, the one-client ratio of any server doing that much; ``cpu ÷ decode``
(decode CPU ÷ the row's CPU per frame) bounds the all-cores ratio with eight clients, where both sides use every CPU.
Neither counts the per-frame estimate (~1.2 ms) or the ORM.
"""

from __future__ import annotations

import argparse
import json
import os
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import uvicorn
from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse
from illumon_service.api.forms import read_frame_form
from illumon_service.decode import decode_frame
from illumon_service.process import free_port, stop_process, wait_healthy
from illumon_service.proposals import make_thumbnail
from illumon_service.regions import Region, region_stats, response_for
from illumon_service.registration import _prepared_reference, phase_shift
from ingest import RESULTS, T0, FramePoster, H, W, _cpu_seconds, regions, render_frames

STEPS = ("decode", "+ regions", "+ durable", "+ register")


def serve_empty(port: int) -> None:
    """A server whose only routes read a frame upload (and answer 201 ``{}``) and answer ``/healthz``."""
    app = FastAPI()

    @app.get("/healthz")
    def healthz() -> dict:
        return {}

    @app.post("/v1/cameras/{camera_id}/frames")
    async def post_frame(camera_id: int, request: Request) -> JSONResponse:
        form = await read_frame_form(request, 50_000_000)
        return JSONResponse({"bytes": len(form.upload.image)}, status_code=201)

    uvicorn.run(app, host="127.0.0.1", port=port, log_level="warning", access_log=False)


def http_only(frames: list[bytes], rounds: int) -> tuple[list[float], list[float]]:
    """Seconds and CPU seconds (server + client) per frame of posting ``frames`` to :func:`serve_empty`, per round."""
    port = free_port()
    proc = subprocess.Popen([sys.executable, __file__, "--serve-empty", str(port)])
    wall, cpu = [], []
    try:
        wait_healthy(proc, f"http://127.0.0.1:{port}")
        post = FramePoster(port, 1, {"Authorization": "Bearer -"})
        for _ in range(rounds):
            post(frames[0], "image/jpeg", T0)  # warm
            s0, c0, t0 = _cpu_seconds(proc.pid), time.process_time(), time.perf_counter()
            for data in frames:
                post(data, "image/jpeg", T0)
            wall.append((time.perf_counter() - t0) / len(frames))
            cpu.append((_cpu_seconds(proc.pid) - s0 + time.process_time() - c0) / len(frames))
        post.close()
    finally:
        stop_process(proc, grace=5)
    return wall, cpu


def main() -> None:
    """Run the rounds; print the table; write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60, help="frames per step and round (60)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds, the steps interleaved in each (3)")
    parser.add_argument("--serve-empty", type=int, metavar="PORT", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve_empty:
        serve_empty(args.serve_empty)
        return
    cv2.setNumThreads(1)
    frames, _, _ = render_frames(args.frames, "jpeg")
    boxes = regions()
    regs = [Region(**r) for r in boxes]
    response = response_for({"encoding": "srgb"}, 255.0)
    ref = make_thumbnail(decode_frame(frames[0], regs).image, response, 0.98, (W, H))
    prepared = _prepared_reference(ref, boxes)

    with tempfile.TemporaryDirectory() as tmp:
        db = sqlite3.connect(Path(tmp) / "floor.sqlite", isolation_level=None)
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        db.execute("CREATE TABLE frames (id INTEGER PRIMARY KEY, camera INTEGER, taken_at TEXT, values_json TEXT)")

        def one(step: int, data: bytes, i: int) -> None:
            if step == 0:
                assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) is not None
                return
            frame = decode_frame(data, regs)
            stats = region_stats(frame.image, regs, response)
            if step >= 2:
                db.execute("BEGIN")
                db.execute("INSERT INTO frames (camera, taken_at, values_json) VALUES (1, ?, ?)",
                           (f"2025-06-01 05:00:{i:06d}", json.dumps(stats)))
                db.execute("COMMIT")
            if step >= 3:
                thumb = make_thumbnail(frame.image, response, 0.98, frame.size)
                phase_shift(ref, thumb, boxes, prepared)

        wall = {s: [] for s in STEPS}
        cpu = {s: [] for s in STEPS}
        for _ in range(args.rounds):
            for k, name in enumerate(STEPS):
                one(k, frames[0], 0)  # warm
                c0, t0 = time.process_time(), time.perf_counter()
                for i, data in enumerate(frames):
                    one(k, data, i)
                wall[name].append((time.perf_counter() - t0) / len(frames))
                cpu[name].append((time.process_time() - c0) / len(frames))
        db.close()
    wall["HTTP only"], cpu["HTTP only"] = http_only(frames, args.rounds)
    wall["+ HTTP"] = [a + b for a, b in zip(wall["+ register"], wall["HTTP only"], strict=True)]
    cpu["+ HTTP"] = [a + b for a, b in zip(cpu["+ register"], cpu["HTTP only"], strict=True)]
    wall["overlapped"] = [h - min(r - d, g - c) for h, d, r, c, g in zip(
        wall["+ HTTP"], wall["decode"], wall["+ regions"], wall["+ durable"], wall["+ register"], strict=True)]
    cpu["overlapped"] = cpu["+ HTTP"]

    rows = []
    load = os.getloadavg()[0]
    print(f"1920×1080 JPEG ({np.mean([len(f) for f in frames]) / 1e6:.2f} MB), 16 regions of 120×120, "
          f"{args.frames} frames × {args.rounds} rounds, one thread; load {load:.1f}")
    print(f"{'step':<11} {'ms / frame':>10} {'f/s':>7} {'f/s ÷ decode':>12} {'cpu ms':>7} {'cpu ÷ decode':>12}")
    d_wall, d_cpu = float(np.median(wall["decode"])), float(np.median(cpu["decode"]))
    for name in (*STEPS, "HTTP only", "+ HTTP", "overlapped"):
        w, c = float(np.median(wall[name])), float(np.median(cpu[name]))
        rows.append({"step": name, "ms": 1e3 * w, "fps": 1 / w, "ratio_one_client": d_wall / w, "cpu_ms": 1e3 * c,
                     "ratio_all_cores": d_cpu / c, "rounds_ms": [1e3 * v for v in wall[name]]})
        print(f"{name:<11} {1e3 * w:>10.2f} {1 / w:>7.1f} {d_wall / w:>12.2f} {1e3 * c:>7.2f} {d_cpu / c:>12.2f}")
    print("targets (issue 29): one client ≥ 0.60, eight clients on every core ≥ 0.50 — each row bounds a server doing "
          "that much (HTTP only: an empty route; its cpu is the server's and the client's), before the estimate and "
          "the ORM")
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / "ingest_floor.json"
    out.write_text(json.dumps({"frames": args.frames, "rounds": args.rounds, "load": load, "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
