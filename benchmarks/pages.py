"""Camera page and estimates API against the length of the history (issue 29): one SQLite database holding a small
camera (``--small`` frames, 1k) and a large one (``--large`` frames, 100k), each frame with its estimate (one in 100
without: a view change), 12 regions, one frame a minute; synthetic rows inserted in bulk (not timed).

    nice python benchmarks/pages.py [--small 1000] [--large 100000] [--rounds 15]

Timed through the app in process (FastAPI ``TestClient``, admin cookie / bearer), the two cameras interleaved in
each round so that load on the machine hits both sides alike: ``GET /cameras/{id}`` (the camera page) and
``GET /v1/cameras/{id}/estimates?limit=1000``, next to the estimates query alone in ``sqlite3`` (the floor) and the
"latest estimate" query alone. Prints a table of medians and the ratios large ÷ small, the page's drawn points,
and writes ``benchmarks/results/pages.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sqlite3
import statistics
import tempfile
import time
import warnings
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient
from illumon_service.app import create_app
from illumon_service.settings import Settings
from illumon_service.storage import Camera, Estimate, Frame, hash_token, make_engine
from sqlalchemy import insert

RESULTS = Path(__file__).with_name("results")
ADMIN = "bench-admin-token"
N_REGIONS = 12
T_END = datetime(2026, 1, 1, tzinfo=timezone.utc)


def fill(url: str, sizes: list[int], seed: int = 29) -> list[int]:
    """Store one camera per entry of ``sizes`` with that many frames and estimates; returns the camera ids.

    The cameras' frames interleave in time (every camera's last frame is at :data:`T_END`), as a fleet's would.
    """
    engine = make_engine(url)
    rng = np.random.default_rng(seed)
    regions = [{"id": f"r{i}", "x": 10 * i, "y": 0, "width": 8, "height": 8} for i in range(N_REGIONS)]
    ids = []
    fid = 0
    for c, n in enumerate(sizes):
        with engine.begin() as conn:
            conn.execute(insert(Camera), [{"id": c + 1, "name": f"cam {n}", "token_hash": hash_token(f"bench-{c}"),
                                           "sensitivities": [], "regions": regions, "response": {"encoding": "srgb"}}])
        ids.append(c + 1)
        for start in range(0, n, 10000):
            rows, ests = [], []
            for k in range(start, min(n, start + 10000)):
                fid += 1
                t = T_END - timedelta(minutes=n - 1 - k)
                v = rng.uniform(0.05, 0.9, (N_REGIONS, 3)).round(5).tolist()
                skip = k % 100 == 37
                rows.append({"id": fid, "camera_id": c + 1, "taken_at": t,
                             "patches": {f"r{i}": v[i] for i in range(N_REGIONS)}, "width": 1920, "height": 1080,
                             "not_estimated": "view_change" if skip else None})
                if skip:
                    continue
                cct = float(5500 + 1500 * np.sin(k / 300))
                ests.append({"frame_id": fid, "camera_id": c + 1, "taken_at": t, "cct_k": cct, "duv": 0.001,
                             "xy": [0.33, 0.34], "white_rgb": [0.6, 1.0, 0.7], "gains_rgb": [1.66, 1.0, 1.43],
                             "confidence": 0.9, "spectrum": [1.0] * 61, "source": "model", "model": "v1",
                             "intervals": {"cct_lo": cct - 200, "cct_hi": cct + 200, "duv_lo": -0.002,
                                           "duv_hi": 0.004, "gain_lo": [1.6, 1.0, 1.4], "gain_hi": [1.7, 1.0, 1.5]}})
            with engine.begin() as conn:
                conn.execute(insert(Frame), rows)
                conn.execute(insert(Estimate), ests)
    engine.dispose()
    return ids


def _time(fn) -> float:  # noqa: ANN001 - a callable of no argument
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def points(html: str) -> int:
    """The largest number of points of one polyline of the page (what one series draws)."""
    return max((len(m.split()) for m in re.findall(r'<polyline[^>]*points="([^"]*)"', html)), default=0)


def main() -> None:
    """Fill the database, time both cameras interleaved, print the table, write the JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", type=int, default=1000)
    ap.add_argument("--large", type=int, default=100_000)
    ap.add_argument("--rounds", type=int, default=15)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory(prefix="illumon-pages-") as tmp:
        settings = Settings(data_dir=tmp, admin_token=ADMIN, jobs_inline=True)
        url = settings.resolved_database_url
        t0 = time.perf_counter()
        small, large = fill(url, [args.small, args.large])
        fill_s = time.perf_counter() - t0
        db = sqlite3.connect(url.removeprefix("sqlite:///"))
        sql = ("SELECT * FROM estimates WHERE camera_id = ? ORDER BY taken_at, frame_id LIMIT 1000")
        sql_latest = ("SELECT * FROM estimates WHERE camera_id = ? ORDER BY taken_at DESC, frame_id DESC LIMIT 1")
        with TestClient(create_app(settings)) as c:
            c.post("/login", data={"token": ADMIN, "next": "/"}, follow_redirects=False)
            hdr = {"Authorization": f"Bearer {ADMIN}"}
            checks = {}
            for cid in (small, large):
                page = c.get(f"/cameras/{cid}")
                est = c.get(f"/v1/cameras/{cid}/estimates", params={"limit": 1000}, headers=hdr)
                assert page.status_code == 200 and est.status_code == 200, (page.status_code, est.status_code)
                checks[cid] = {"points": points(page.text), "estimates": len(est.json())}
            kinds = {
                "page": lambda cid: c.get(f"/cameras/{cid}"),
                "estimates?limit=1000": lambda cid: c.get(f"/v1/cameras/{cid}/estimates", params={"limit": 1000},
                                                          headers=hdr),
                "sqlite3 estimates": lambda cid: db.execute(sql, (cid,)).fetchall(),
                "sqlite3 latest": lambda cid: db.execute(sql_latest, (cid,)).fetchall(),
            }
            times: dict[str, dict[int, list[float]]] = {k: {small: [], large: []} for k in kinds}
            for r in range(args.rounds):
                for kind, fn in kinds.items():
                    order = (small, large) if r % 2 == 0 else (large, small)
                    for cid in order:
                        times[kind][cid].append(_time(lambda fn=fn, cid=cid: fn(cid)))
        db.close()
    rows = []
    print(f"cameras: {args.small} and {args.large} frames ({N_REGIONS} regions; 1 % without estimate); "
          f"fill {fill_s:.1f} s; {args.rounds} interleaved rounds; load {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"{'what':<22} {'small ms':>9} {'large ms':>9} {'large÷small':>12}")
    for kind, by in times.items():
        a, b = statistics.median(by[small]) * 1e3, statistics.median(by[large]) * 1e3
        rows.append({"what": kind, "small_ms": a, "large_ms": b, "ratio": b / a})
        print(f"{kind:<22} {a:9.1f} {b:9.1f} {b / a:12.2f}")
    print(f"points drawn per series: small {checks[small]['points']}, large {checks[large]['points']}; "
          f"estimates returned: {checks[small]['estimates']}, {checks[large]['estimates']}")
    RESULTS.mkdir(exist_ok=True)
    out = {"small_frames": args.small, "large_frames": args.large, "rounds": args.rounds, "rows": rows,
           "points": {"small": checks[small]["points"], "large": checks[large]["points"]},
           "load": os.getloadavg()[0], "cpus": os.cpu_count()}
    (RESULTS / "pages.json").write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {RESULTS / 'pages.json'}")


if __name__ == "__main__":
    main()
