"""Backup, restore and retention at scale (issue 27): a SQLite data directory holding ``--frames`` frames with their
estimates (``--cameras`` cameras, 8 regions each, one frame a minute), then ``illumon backup``, ``illumon restore``
into a fresh directory and ``illumon prune`` of the older half, timed as the commands (subprocesses) run.

    python benchmarks/operations.py --frames 100000 --cameras 10

Prints one JSON line: database size, seconds per command, rows before and after.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
from illumon_service.storage import Camera, Estimate, Frame, hash_token, make_engine, new_token
from sqlalchemy import insert


def fill(data_dir: Path, n_frames: int, n_cameras: int, seed: int = 27) -> None:
    """Write ``n_frames`` frames and estimates spread over ``n_cameras`` cameras, one frame a minute ending now."""
    engine = make_engine(f"sqlite:///{data_dir / 'illumon.sqlite3'}")
    rng = np.random.default_rng(seed)
    regions = [{"id": f"r{i}", "x": 10 * i, "y": 0, "width": 8, "height": 8} for i in range(8)]
    now = datetime.now(timezone.utc)
    with engine.begin() as conn:
        conn.execute(insert(Camera), [{"id": c + 1, "name": f"cam {c}", "token_hash": hash_token(new_token()),
                                       "sensitivities": [], "regions": regions, "response": {"encoding": "srgb"}}
                                      for c in range(n_cameras)])
    per = n_frames // n_cameras
    fid = 0
    for c in range(n_cameras):
        for start in range(0, per, 5000):
            rows, ests = [], []
            for k in range(start, min(per, start + 5000)):
                fid += 1
                t = now - timedelta(minutes=per - k)
                v = rng.uniform(0.05, 0.9, (8, 3)).round(6).tolist()
                rows.append({"id": fid, "camera_id": c + 1, "taken_at": t, "patches": {f"r{i}": v[i] for i in range(8)},
                             "patch_sd": {f"r{i}": [0.001, 0.001, 0.001] for i in range(8)}, "width": 1920, "height": 1080})
                ests.append({"frame_id": fid, "camera_id": c + 1, "taken_at": t, "cct_k": 5500.0, "duv": 0.001,
                             "xy": [0.33, 0.34], "white_rgb": [0.6, 1.0, 0.7], "gains_rgb": [1.66, 1.0, 1.43],
                             "confidence": 0.9, "spectrum": [1.0] * 61, "intervals": None, "source": "model"})
            with engine.begin() as conn:
                conn.execute(insert(Frame), rows)
                conn.execute(insert(Estimate), ests)
    engine.dispose()


def _run(*args: str) -> tuple[float, dict]:
    illumon = str(Path(sys.executable).with_name("illumon"))
    t0 = time.perf_counter()
    run = subprocess.run([illumon, *args], capture_output=True, text=True, check=True)
    return time.perf_counter() - t0, json.loads(run.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100_000)
    ap.add_argument("--cameras", type=int, default=10)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="illumon-ops-") as tmp:
        data, fresh, dest = Path(tmp) / "var", Path(tmp) / "fresh", Path(tmp) / "backup"
        data.mkdir()
        t0 = time.perf_counter()
        fill(data, args.frames, args.cameras)
        t_fill = time.perf_counter() - t0
        size = (data / "illumon.sqlite3").stat().st_size
        t_backup, manifest = _run("backup", str(dest), "--data-dir", str(data))
        t_restore, restored = _run("restore", str(dest), "--data-dir", str(fresh))
        days = args.frames // args.cameras / 1440 / 2  # the older half of each camera's frames
        t_prune, pruned = _run("prune", "--data-dir", str(fresh), "--retain-days", f"{days:.6f}")
        print(json.dumps({
            "frames": manifest["counts"]["frames"], "estimates": manifest["counts"]["estimates"],
            "cameras": args.cameras, "database_mb": round(size / 1e6, 1), "fill_s": round(t_fill, 1),
            "backup_s": round(t_backup, 2), "restore_s": round(t_restore, 2),
            "restored_frames": restored["counts"]["frames"], "prune_s": round(t_prune, 2),
            "pruned_frames": pruned["frames"], "pruned_estimates": pruned["estimates"],
        }))


if __name__ == "__main__":
    main()
