"""Ingest benchmark (issue 9): frames/s and p50/p99 latency of ``POST /v1/cameras/{id}/frames`` for 1920×1080
8-bit JPEG and 16-bit PNG frames with 16 regions, next to ``cv2.imdecode`` alone on the same bytes in the same run.

Run: ``python benchmarks/ingest.py [--quick] [--frames N] [--concurrency 1,4] [--jpeg-reduction 1,2]
[--server-workers N]``. Prints a table and writes ``benchmarks/results/ingest.json``.

The service is a real ``illumon serve`` process on a free loopback port (SQLite in a temporary folder, WAL,
``synchronous=FULL``: every 201 is on disk). Each camera first gets 12 frames and a refit, then a few untimed frames
over as many connections as the most clients (every server process loads the scene model at the first frame it
estimates), so every timed frame goes through the whole path in the steady state: multipart upload, decode, robust
means of 16 regions of 120×120, per-frame estimate with the scene model, durable commit (concurrent frames share one:
group commit). Clients are threads of this process, each
posting over its own HTTP/1.1 keep-alive ``http.client`` connection with a hand-assembled multipart body (well under
a millisecond of client CPU per JPEG frame, so that the client takes little CPU from the server it measures).

What is compared, per format and concurrency ``c``: the same timed frames (the same bytes), in the same run, first
decoded by ``cv2.imdecode(…, IMREAD_UNCHANGED)`` at full size alone in ``c`` threads of this process
(``cv2.imdecode`` releases the GIL; OpenCV's own threads off, as in the service; the server idle meanwhile), then
posted by ``c`` client threads. ``ratio`` = ingest frames/s ÷ decode-only frames/s. Both sides may use every CPU of the
machine, but the ingest side also pays the HTTP client, the multipart upload, the robust region statistics, the
per-frame estimate and a durable commit (an fsync per transaction), and shares the CPUs with the client threads; so
with one client the ratio is bounded by decode ÷ (decode + the rest of the path) whatever the CPU count.

JPEG runs once per ``--jpeg-reduction`` value, each on its own server started with that
``ILLUMON_JPEG_MAX_REDUCTION`` (default ``1,2``: full size, then half size where the regions allow); the ``ingest
decode`` column is the scale the server reports having decoded at (``illumon_ingest_decodes_total``; ``?`` for a
server that does not count them), while ``decode f/s`` and ``ratio`` stay against the full-size decode.
The server's stages (``illumon_ingest_stage_seconds``, mean ms per frame) add up to ``srv ms``: ``receive`` (the
upload read and the view's regions looked up), ``decode``, ``register`` (thumbnail and registration to the view's
reference frame), ``regions`` (the wait for the region statistics after the registration: they run beside it),
``estimate``, ``commit`` (the rows written and committed, group commit). ``dec cpu`` / ``srv cpu`` / ``cli cpu`` are
CPU milliseconds per frame of the decode-only run (this process), of the server (its process and children, from
``/proc``) and of the posting client: unlike wall time they hardly depend on what else loads the machine. ``f/commit``
is the mean number of frames per durable commit. ``--server-workers N`` runs ``illumon serve --workers N`` (its
``/metrics`` sums the workers' published figures, read after a 1.2 s wait). The 1-minute load average (all processes
of the machine) is printed with each row.
Frames: a textured gradient background (JPEG ≈ 0.23 MB at quality 90), 16 patches rendered with measured spectra
(Nikon D5100, Granada daylight, Munsell) where ``../shared/data`` exists (synthetic spectra otherwise), noise and a
moving clutter rectangle. The accuracy of the reduced decode is measured by ``benchmarks/reduced_decode.py``.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timedelta, timezone
from pathlib import Path

import cv2
import httpx
import numpy as np
from illumon.camera import ResponseCurve, render
from illumon.daylight import CIEDaylight
from illumon.simulation import datasets
from illumon_service.process import free_port, stop_process, wait_healthy

RESULTS = Path(__file__).with_name("results")
W, H = 1920, 1080
REGION = 120
T0 = datetime(2025, 6, 1, 5, 0, tzinfo=timezone.utc)
ADMIN = "bench-admin-token"


def regions() -> list[dict]:
    """16 regions of 120×120 on a 4×4 grid."""
    return [{"id": f"r{i:02d}", "x": 240 + 400 * (i % 4), "y": 120 + 240 * (i // 4), "width": REGION, "height": REGION}
            for i in range(16)]


def spectra(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(sensitivities 61 × 3, n daylight spectra, 17 reflectances (16 patches + background), provenance)."""
    rng = np.random.default_rng(0)
    if datasets.shared_data_dir() is not None:
        css = datasets.load_camera("Nikon_D5100")
        _, day = datasets.load_granada_daylight()
        _, refl = datasets.load_reflectance_set("munsell_matt_1269")
        return (css, day[np.linspace(200, 2400, n).astype(int)], refl[rng.choice(len(refl), 17, replace=False)],
                "measured (Nikon D5100, Granada, Munsell)")
    wl = np.arange(400, 701, 5)
    css = np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])
    mired = np.linspace(110, 250, n)
    day = CIEDaylight().spectra(np.column_stack([mired, np.zeros_like(mired)]))
    refl = np.clip(0.2 + 0.6 * rng.random((17, 1)) * np.sin(wl / rng.uniform(40, 120, (17, 1))) ** 2, 0, 1)
    return css, day, refl, "synthetic (Gaussian sensitivities, CIE D, smooth reflectances)"


def render_frames(n: int, kind: str) -> tuple[list[bytes], np.ndarray, str]:
    """``n`` encoded frames (``jpeg``: 8-bit sRGB quality 90; ``png16``: 16-bit linear) and the sensitivities."""
    css, day, refl, provenance = spectra(n)
    rng = np.random.default_rng(1)
    lin = render(css, day, refl)  # n × 17 × 3
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    shade = (0.7 + 0.3 * xx / W)[..., None] * (0.8 + 0.2 * yy / H)[..., None]
    # Scene texture (foliage, paving): blurred noise at two scales, ±25 %, so that JPEG files have realistic sizes.
    tex = sum(cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), s) * a
              for s, a in ((1.0, 0.5), (6.0, 2.0)))
    shade = shade * np.clip(1 + 0.25 * tex / np.abs(tex).max(), 0.5, 1.5)[..., None]
    out = []
    for f in range(n):
        k = 0.7 / lin[f].max()
        img = (shade * (lin[f, 16] * k)).astype(np.float32)
        for r, v in zip(regions(), lin[f, :16] * k, strict=True):
            img[r["y"] : r["y"] + REGION, r["x"] : r["x"] + REGION] = v
        img *= 1 + 0.02 * rng.standard_normal(img.shape, dtype=np.float32)
        x = (f * 97) % (W - 200)
        img[100:700, x : x + 150] = [0.5, 0.1, 0.05]  # a passer-by
        img = np.clip(img, 0, 1)
        if kind == "jpeg":
            enc = np.round(ResponseCurve("srgb", white_level=255).encode(img)).astype(np.uint8)
            ok, buf = cv2.imencode(".jpg", enc[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
        else:
            ok, buf = cv2.imencode(".png", np.round(img * 65535).astype(np.uint16)[:, :, ::-1])
        assert ok
        out.append(buf.tobytes())
    return out, css, provenance


def start_server(data_dir: str, port: int, workers: int = 1, jpeg_max_reduction: int = 1) -> subprocess.Popen:
    """``illumon serve --workers workers`` on ``port`` (``ILLUMON_JPEG_MAX_REDUCTION``); returns once /healthz
    answers."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("ILLUMON_")}
    env["ILLUMON_ADMIN_TOKEN"] = ADMIN
    env["ILLUMON_JPEG_MAX_REDUCTION"] = str(jpeg_max_reduction)
    exe = Path(sys.executable).with_name("illumon")
    proc = subprocess.Popen([str(exe), "serve", "--host", "127.0.0.1", "--port", str(port), "--data-dir", data_dir,
                             "--log-level", "warning", "--workers", str(workers)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    wait_healthy(proc, f"http://127.0.0.1:{port}", timeout=60, describe=lambda: proc.stderr.read().decode())
    return proc


def register(http: httpx.Client, css: np.ndarray, encoding: str) -> tuple[int, dict]:
    """Register a camera; returns its id and auth header."""
    body = {"name": f"bench {encoding}",
            "sensitivities": {"wavelength_nm": list(range(400, 701, 5)), "r": css[:, 0].tolist(),
                              "g": css[:, 1].tolist(), "b": css[:, 2].tolist()},
            "regions": regions(), "response": {"encoding": encoding}}
    r = http.post("/v1/cameras", json=body, headers={"Authorization": f"Bearer {ADMIN}"})
    r.raise_for_status()
    return r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}


def post(http: httpx.Client, cam: int, auth: dict, data: bytes, ctype: str, t: datetime) -> float:
    """POST one frame; returns the latency in seconds."""
    t0 = time.perf_counter()
    r = http.post(f"/v1/cameras/{cam}/frames", files={"image": ("frame", data, ctype)},
                  data={"taken_at": t.isoformat()}, headers=auth)
    dt = time.perf_counter() - t0
    if r.status_code != 201:
        raise RuntimeError(f"{r.status_code}: {r.text}")
    return dt


class FramePoster:
    """``POST /frames`` over one keep-alive ``http.client`` connection per client thread.

    The multipart body is assembled by concatenation (timed with the request), so a frame costs the client a fraction
    of a millisecond of CPU where httpx's multipart encoder and request machinery cost ~4 ms: on a 2-core machine the
    client would otherwise take CPU from the server it measures. ``cli cpu`` in the table shows what it costs.
    """

    def __init__(self, port: int, cam: int, auth: dict) -> None:
        self.port, self.path, self.auth = port, f"/v1/cameras/{cam}/frames", auth["Authorization"]
        self.boundary = os.urandom(16).hex().encode()
        self.local = threading.local()
        self.connections: list[http.client.HTTPConnection] = []

    def __call__(self, data: bytes, ctype: str, t: datetime) -> float:
        """POST one frame; returns the latency in seconds."""
        conn = getattr(self.local, "conn", None)
        if conn is None:
            conn = self.local.conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=120)
            self.connections.append(conn)
        t0 = time.perf_counter()
        b = self.boundary
        body = b"".join((b"--", b, b'\r\nContent-Disposition: form-data; name="taken_at"\r\n\r\n', t.isoformat().encode(),
                         b"\r\n--", b, b'\r\nContent-Disposition: form-data; name="image"; filename="frame"\r\n'
                         b"Content-Type: ", ctype.encode(), b"\r\n\r\n", data, b"\r\n--", b, b"--\r\n"))
        conn.request("POST", self.path, body=body, headers={
            "Authorization": self.auth, "Content-Type": f"multipart/form-data; boundary={b.decode()}"})
        resp = conn.getresponse()
        text = resp.read()
        dt = time.perf_counter() - t0
        if resp.status != 201:
            raise RuntimeError(f"{resp.status}: {text[:300]!r}")
        return dt

    def close(self) -> None:
        """Close every connection."""
        for conn in self.connections:
            conn.close()


def run_parallel(fn, items: list, concurrency: int) -> tuple[float, list[float]]:
    """Apply ``fn`` to every item with ``concurrency`` threads; (wall seconds, per-item seconds)."""
    t0 = time.perf_counter()
    if concurrency == 1:
        lat = [fn(x) for x in items]
    else:
        with ThreadPoolExecutor(concurrency) as pool:
            lat = list(pool.map(fn, items))
    return time.perf_counter() - t0, lat


def decode_once(data: bytes) -> float:
    """Seconds of ``cv2.imdecode`` alone."""
    t0 = time.perf_counter()
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None
    return time.perf_counter() - t0


def main() -> None:
    """Run the benchmark; print the table; write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 frames per run")
    parser.add_argument("--frames", type=int, help="timed frames per run (60)")
    parser.add_argument("--concurrency", default="1,4", help="client threads per run, comma-separated (1,4)")
    parser.add_argument("--server-workers", type=int, default=1, help="illumon serve --workers (1)")
    parser.add_argument("--jpeg-reduction", default="1,2",
                        help="ILLUMON_JPEG_MAX_REDUCTION of the JPEG runs, comma-separated (1,2: full and half size)")
    args = parser.parse_args()
    n = args.frames or (20 if args.quick else 60)
    levels = [int(v) for v in args.concurrency.split(",")]
    reductions = [int(v) for v in args.jpeg_reduction.split(",")]
    cv2.setNumThreads(1)
    rows = []
    print(f"1920×1080, 16 regions of 120×120, {n} frames per run; CPUs: {os.cpu_count()}; "
          f"server workers: {args.server_workers}; decode f/s: cv2.imdecode at full size; "
          f"ingest decode: the size the server decoded at")
    print(f"{'format':>6} {'MB':>5} {'clients':>7} {'ingest':>6} {'ingest f/s':>10} {'decode f/s':>10} {'ratio':>6} "
          f"{'p50 ms':>7} {'p99 ms':>7} {'dec p50':>7} {'srv ms':>7} {'dec cpu':>7} {'srv cpu':>7} {'cli cpu':>7} "
          f"{'f/commit':>8} "
          f"{'load':>5}  server stages ms: "
          + " ".join(STAGES))
    print(f"{'':>6} {'':>5} {'':>7} {'decode':>6}")
    with tempfile.TemporaryDirectory() as tmp:
        servers: dict[int, tuple[subprocess.Popen, int]] = {}
        lock = threading.Lock()
        clock = [T0]

        def next_time() -> datetime:
            with lock:
                clock[0] += timedelta(seconds=10)
                return clock[0]

        def server(reduction: int) -> int:
            if reduction not in servers:
                port = free_port()
                folder = Path(tmp) / f"reduction-{reduction}"
                servers[reduction] = (start_server(str(folder), port, args.server_workers, reduction), port)
            return servers[reduction][1]

        runs = [("jpeg", "image/jpeg", "srgb", red) for red in reductions] + [("png16", "image/png", "linear", 1)]
        rendered: dict[str, tuple] = {}
        try:
            limits = httpx.Limits(max_connections=max(levels), max_keepalive_connections=max(levels))
            for kind, ctype, encoding, reduction in runs:
                port = server(reduction)
                with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=120, trust_env=False,
                                  limits=limits) as http:
                    if kind not in rendered:
                        rendered[kind] = render_frames(12 + n, kind)
                    frames, css, provenance = rendered[kind]
                    cam, auth = register(http, css, encoding)
                    for i in range(12):  # history, then a refit: later frames are estimated with the scene model
                        post(http, cam, auth, frames[i], ctype, next_time())
                    job = http.post(f"/v1/cameras/{cam}/refit", headers=auth).json()["job_id"]
                    while http.get(f"/v1/jobs/{job}", headers=auth).json()["state"] not in ("done", "failed"):
                        time.sleep(0.2)
                    # Warm-up, not timed: each server process loads the new scene model (and builds its solver) at
                    # the first frame it estimates; a few frames over as many connections as the most clients reach
                    # every worker.
                    warm = FramePoster(port, cam, auth)
                    try:
                        run_parallel(lambda d, warm=warm, ctype=ctype: warm(d, ctype, next_time()),
                                     frames[:12] if kind == "jpeg" else frames[:2 * max(levels)], max(levels))
                    finally:
                        warm.close()
                    timed = frames[12:]
                    mb = float(np.mean([len(f) for f in timed]) / 1e6)
                    for c in levels:
                        dec_cpu = time.process_time()
                        dec_wall, dec_lat = run_parallel(decode_once, timed, c)
                        dec_cpu = time.process_time() - dec_cpu
                        m0 = _server_ingest(http, args.server_workers)
                        srv_cpu, cli_cpu = _cpu_seconds(servers[reduction][0].pid), time.process_time()
                        poster = FramePoster(port, cam, auth)
                        try:
                            wall, lat = run_parallel(
                                lambda d, poster=poster, ctype=ctype: poster(d, ctype, next_time()), timed, c)
                        finally:
                            poster.close()
                        srv_cpu, cli_cpu = _cpu_seconds(servers[reduction][0].pid) - srv_cpu, time.process_time() - cli_cpu
                        m1 = _server_ingest(http, args.server_workers)
                        scales = [s for s in m1["decodes"] if m1["decodes"][s] > m0["decodes"].get(s, 0.0)]
                        row = {"format": kind, "mb": mb, "clients": c, "frames": n, "jpeg_max_reduction": reduction,
                               "ingest_decode": ",".join(sorted(scales)) or "?",
                               "ingest_fps": n / wall, "decode_fps": n / dec_wall, "ratio": dec_wall / wall,
                               "p50_ms": 1e3 * float(np.percentile(lat, 50)), "p99_ms": 1e3 * float(np.percentile(lat, 99)),
                               "decode_p50_ms": 1e3 * float(np.percentile(dec_lat, 50)),
                               "decode_p99_ms": 1e3 * float(np.percentile(dec_lat, 99)),
                               "server_mean_ms": _mean_ms(m0, m1, "total"),
                               "server_stage_ms": {st: _mean_ms(m0, m1, st) for st in STAGES},
                               "decode_cpu_ms": 1e3 * dec_cpu / n, "server_cpu_ms": 1e3 * srv_cpu / n,
                               "client_cpu_ms": 1e3 * cli_cpu / n, "load1": os.getloadavg()[0],
                               "frames_per_commit": (m1["commit_frames"][0] - m0["commit_frames"][0])
                               / max(1.0, m1["commit_frames"][1] - m0["commit_frames"][1])}
                        rows.append(row)
                        print(f"{kind:>6} {mb:5.2f} {c:7d} {row['ingest_decode']:>6} {row['ingest_fps']:10.1f} "
                              f"{row['decode_fps']:10.1f} {row['ratio']:6.2f} {row['p50_ms']:7.1f} {row['p99_ms']:7.1f} "
                              f"{row['decode_p50_ms']:7.1f} {row['server_mean_ms']:7.1f} {row['decode_cpu_ms']:7.1f} "
                              f"{row['server_cpu_ms']:7.1f} {row['client_cpu_ms']:7.1f} {row['frames_per_commit']:8.2f} "
                              f"{row['load1']:5.1f}  "
                              + " ".join(f"{row['server_stage_ms'][st]:5.1f}" for st in STAGES), flush=True)
        finally:
            for proc, _ in servers.values():
                stop_process(proc)
    RESULTS.mkdir(exist_ok=True)
    out = {"width": W, "height": H, "regions": 16, "data": provenance, "cpus": os.cpu_count(),
           "server_workers": args.server_workers, "runs": rows}
    (RESULTS / "ingest.json").write_text(json.dumps(out, indent=1) + "\n")
    print("ratio = ingest f/s ÷ decode-only f/s; srv ms = server-side mean per frame, then its stages; dec / srv / cli "
          "cpu = CPU ms per frame of decode-only (this process), of the server (all its processes) and of the posting "
          "client; f/commit = frames per durable commit (group commit)\n"
          f"wrote {RESULTS / 'ingest.json'}")


STAGES = ("receive", "decode", "register", "regions", "estimate", "commit")


def _server_ingest(http: httpx.Client, workers: int = 1) -> dict:
    """(sum, count) of the service's ``illumon_ingest_seconds`` summary (key ``total``) and of each ingest stage, and
    the count of decodes per scale (key ``decodes``: {"1/1": n, "1/2": n, …}). With several worker processes
    ``/metrics`` sums what each published, at most a second ago: wait that out first."""
    if workers > 1:
        time.sleep(1.2)
    text = http.get("/metrics").text
    vals = {ln.split()[0]: float(ln.split()[1]) for ln in text.splitlines() if ln.startswith("illumon_ingest_")}
    out: dict = {"total": (vals.get("illumon_ingest_seconds_sum", 0.0), vals.get("illumon_ingest_seconds_count", 0.0))}
    out["decodes"] = {k.split('"')[1]: v for k, v in vals.items() if k.startswith("illumon_ingest_decodes_total{")}
    out["commit_frames"] = (vals.get("illumon_ingest_commit_frames_sum", 0.0),
                            vals.get("illumon_ingest_commit_frames_count", 0.0))
    for st in STAGES:
        key = f'illumon_ingest_stage_seconds_%s{{stage="{st}"}}'
        out[st] = (vals.get(key % "sum", 0.0), vals.get(key % "count", 0.0))
    return out


def _cpu_seconds(pid: int) -> float:
    """CPU seconds (user + system) used so far by process ``pid`` and its descendants (Linux ``/proc``; NaN
    elsewhere): the server's cost per frame whatever else loads the machine."""
    tick = os.sysconf("SC_CLK_TCK")
    try:
        with open(f"/proc/{pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        total = (int(fields[11]) + int(fields[12])) / tick  # utime, stime
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as fh:
                total += sum(_cpu_seconds(int(child)) for child in fh.read().split())
        return total
    except (OSError, ValueError, IndexError):
        return float("nan")


def _mean_ms(m0: dict, m1: dict, key: str) -> float:
    """Mean milliseconds of ``key`` between two :func:`_server_ingest` snapshots."""
    return 1e3 * (m1[key][0] - m0[key][0]) / max(1.0, m1[key][1] - m0[key][1])


if __name__ == "__main__":
    main()
