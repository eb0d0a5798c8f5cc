"""kill -9 during refits (issue 27): a live ``illumon serve`` (SQLite) is killed at a random moment of a refit, again
and again, then restarted; after each restart every job must end (none left ``running`` or ``queued``) and the
camera's estimates must all come from one scene model, the one its row names, whose file exists.

Run: ``python benchmarks/refit_crashes.py [--kills 10] [--frames 1500]`` (~2–4 min on 2 cores); prints one line per
kill and a summary, writes ``benchmarks/results/refit_crashes.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

from illumon_service.process import free_port, stop_process, wait_healthy  # noqa: E402

ADMIN = "crash-admin"


def _start(data_dir: Path, port: int) -> subprocess.Popen:
    env = {**os.environ, "ILLUMON_ADMIN_TOKEN": ADMIN}
    proc = subprocess.Popen([str(Path(sys.executable).with_name("illumon")), "serve", "--port", str(port),
                             "--data-dir", str(data_dir)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    wait_healthy(proc, f"http://127.0.0.1:{port}")
    return proc


def _state(db: Path, cid: int) -> dict:
    con = sqlite3.connect(db)
    try:
        jobs = dict(con.execute("SELECT state, count(*) FROM jobs GROUP BY state").fetchall())
        versions = [v for (v,) in con.execute("SELECT DISTINCT model FROM estimates WHERE camera_id = ?", (cid,))]
        (models,) = con.execute("SELECT models FROM cameras WHERE id = ?", (cid,)).fetchone()
        n = con.execute("SELECT count(*) FROM estimates WHERE camera_id = ?", (cid,)).fetchone()[0]
    finally:
        con.close()
    return {"jobs": jobs, "versions": versions, "models": json.loads(models) if models else None, "estimates": n}


def main() -> None:
    """Register a camera with a history, then kill the server during refits and check after each restart."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kills", type=int, default=10)
    ap.add_argument("--frames", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    pick = random.Random(args.seed)
    auth = {"Authorization": f"Bearer {ADMIN}"}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp)
        port = free_port()
        url = f"http://127.0.0.1:{port}"
        proc = _start(data, port)
        wl = list(range(400, 701, 50))
        sens = {"wavelength_nm": wl, "r": [0.1, 0.1, 0.2, 0.5, 1, 0.5, 0.1], "g": [0.1, 0.5, 1, 0.8, 0.3, 0.1, 0.05],
                "b": [0.6, 1, 0.4, 0.1, 0.05, 0.02, 0.01]}
        regions = [{"id": f"r{i}", "x": 10 * i, "y": 0, "width": 5, "height": 5} for i in range(8)]
        cid = httpx.post(f"{url}/v1/cameras", json={"name": "crash", "regions": regions, "sensitivities": sens},
                         headers=auth, trust_env=False).json()["id"]
        refl = rng.uniform(0.1, 0.7, (8, 3))
        with httpx.Client(base_url=url, headers=auth, trust_env=False, timeout=60) as cl:
            for f in range(args.frames):
                light = np.array([1.0 + 0.3 * np.sin(f / 50), 1.0, 0.9 + 0.3 * np.cos(f / 70)])
                vals = refl * light * rng.uniform(0.5, 1.0) * (1 + 0.01 * rng.standard_normal((8, 3)))
                body = {"taken_at": f"2025-06-{1 + f // 1440:02d}T{(f // 60) % 24:02d}:{f % 60:02d}:00Z",
                        "patches": {f"r{i}": [float(v) for v in vals[i]] for i in range(8)}}
                assert cl.post(f"/v1/cameras/{cid}/observations", json=body).status_code == 201
            t0 = time.monotonic()
            job = cl.post(f"/v1/cameras/{cid}/refit").json()["job_id"]
            while cl.get(f"/v1/jobs/{job}").json()["state"] in ("queued", "running"):
                time.sleep(0.2)
            refit_s = time.monotonic() - t0
        print(f"{args.frames} frames; one refit takes {refit_s:.1f} s")
        for k in range(args.kills):
            with httpx.Client(base_url=url, headers=auth, trust_env=False, timeout=60) as cl:
                cl.post(f"/v1/cameras/{cid}/refit")
                if k % 3 == 2:  # a second one queued behind it
                    cl.post(f"/v1/cameras/{cid}/refit")
            time.sleep(pick.uniform(0.05, refit_s * 1.1))
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
            before = _state(data / "illumon.sqlite3", cid)
            proc = _start(data, port)
            deadline = time.monotonic() + 600
            while time.monotonic() < deadline:
                after = _state(data / "illumon.sqlite3", cid)
                if not after["jobs"].get("running") and not after["jobs"].get("queued"):
                    break
                time.sleep(0.5)
            (entry,) = after["models"].values() if after["models"] else (None,)
            model_ok = entry is not None and (data / "models" / entry["file"]).is_file()
            row = {"kill": k + 1, "jobs_at_kill": before["jobs"], "jobs_after": after["jobs"],
                   "versions_at_kill": len(before["versions"]), "versions_after": len(after["versions"]),
                   "version_is_cameras": entry is not None and after["versions"] == [entry["version"]],
                   "model_file": model_ok, "estimates": after["estimates"]}
            rows.append(row)
            print(row)
        stop_process(proc)
    ok = all(not r["jobs_after"].get("running") and not r["jobs_after"].get("queued") and r["versions_after"] == 1
             and r["versions_at_kill"] <= 1 and r["version_is_cameras"] and r["model_file"] for r in rows)
    print(f"{len(rows)} kills: jobs left running or queued after restart: "
          f"{sum(r['jobs_after'].get('running', 0) + r['jobs_after'].get('queued', 0) for r in rows)}; "
          f"kills leaving estimates of two models: {sum(r['versions_at_kill'] > 1 or r['versions_after'] > 1 for r in rows)}"
          f"; all checks {'pass' if ok else 'FAIL'}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "refit_crashes.json").write_text(json.dumps({"refit_s": refit_s, "rows": rows, "ok": ok}, indent=1))


if __name__ == "__main__":
    main()
