"""/refit and /v1/jobs, and the `illumon refit` batch command."""

from __future__ import annotations

import time

import numpy as np
from fastapi.testclient import TestClient
from illumon.cli import main
from illumon_service.app import create_app
from illumon_service.storage import Job
from svc_helpers import admin_headers, bearer, grid_regions, make_settings, register


def test_job_visibility(populated):
    c = populated.client
    job_id = c.post(f"/v1/cameras/{populated.camera_id}/refit", headers=admin_headers()).json()["job_id"]
    assert c.get(f"/v1/jobs/{job_id}", headers=admin_headers()).json()["state"] == "done"
    assert c.get("/v1/jobs/nope", headers=admin_headers()).status_code == 404


def test_refit_too_few_frames_fails_cleanly(client):
    cid, token = register(client, np.ones((61, 3)), grid_regions())
    job_id = client.post(f"/v1/cameras/{cid}/refit", headers=bearer(token)).json()["job_id"]
    job = client.get(f"/v1/jobs/{job_id}", headers=bearer(token)).json()
    assert job["state"] == "failed"
    assert "at least two frames" in job["summary"]["error"]


def test_refit_cli(tmp_path, scene, capsys):
    """`illumon refit --camera` on JSON observations stored by the service, and an unknown camera."""
    with TestClient(create_app(make_settings(tmp_path))) as c:
        cid, token = register(c, scene.css, scene.regions)
        rng = np.random.default_rng(3)
        for f in range(4):
            patches = {r["id"]: list(rng.uniform(0.1, 0.6, 3)) for r in scene.regions}
            body = {"taken_at": f"2025-06-01T0{f}:00:00Z", "patches": patches}
            assert c.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token)).status_code == 201
    assert main(["refit", "--camera", str(cid), "--data-dir", str(tmp_path)]) == 0
    assert '"frames": 4' in capsys.readouterr().out
    assert main(["refit", "--camera", "99", "--data-dir", str(tmp_path)]) == 2
    with TestClient(create_app(make_settings(tmp_path))) as c:
        assert len(c.get(f"/v1/cameras/{cid}/estimates", headers=bearer(token)).json()) == 4


def _two_cameras_three_frames(tmp_path, scene, seed: int) -> None:
    """Register two cameras and post three observations to each (random patch values)."""
    rng = np.random.default_rng(seed)
    with TestClient(create_app(make_settings(tmp_path))) as c:
        for _ in range(2):
            cid, token = register(c, scene.css, scene.regions)
            for f in range(3):
                patches = {r["id"]: list(rng.uniform(0.1, 0.6, 3)) for r in scene.regions}
                body = {"taken_at": f"2025-06-01T0{f}:00:00Z", "patches": patches}
                assert c.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token)).status_code == 201


def test_refit_all_with_dask(tmp_path, scene, capsys):
    """`illumon refit --all` fans two cameras out over a Dask LocalCluster."""
    _two_cameras_three_frames(tmp_path, scene, seed=4)
    assert main(["refit", "--all", "--data-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count('"frames": 3') == 2


def test_scheduled_refit(tmp_path):
    """With refit_every_hours set, the service queues refits of every camera by itself."""
    settings = make_settings(tmp_path, refit_every_hours=0.5 / 3600)  # every 0.5 s
    with TestClient(create_app(settings)) as c:
        cid, token = register(c, np.ones((61, 3)), grid_regions())
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            with c.app.state.sessions() as s:
                jobs = s.query(Job).filter(Job.camera_id == cid).all()
            if jobs and jobs[0].state in ("done", "failed"):
                break
            time.sleep(0.1)
        assert jobs and jobs[0].state == "failed"  # no frames: fails with a reason, the schedule keeps running


def test_refit_all_one_worker_runs_serially(tmp_path, scene, capsys):
    """`illumon refit --all --workers 1` refits without Dask and says so."""
    _two_cameras_three_frames(tmp_path, scene, seed=5)
    assert main(["refit", "--all", "--workers", "1", "--data-dir", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    assert captured.out.count('"frames": 3') == 2
    assert "serially without Dask" in captured.err


def test_only_one_process_runs_the_schedule(tmp_path):
    """Service processes sharing a data dir (serve --workers N): the schedule lock lets one of them run it."""
    from illumon_service.jobs import JobRunner
    from illumon_service.metrics import Metrics

    settings = make_settings(tmp_path, refit_every_hours=1.0)
    first, second = (JobRunner(None, settings, Metrics()) for _ in range(2))  # sessions unused until a refit is due
    first.start_schedule()
    second.start_schedule()
    assert first._scheduler is not None and second._scheduler is None
    first.shutdown()
    second.start_schedule()  # the lock is released with the first runner
    assert second._scheduler is not None
    second.shutdown()


def test_admin_token_generated_once_under_races(tmp_path):
    """Concurrent first starts agree on one admin token (hard link into place; losers read the winner's)."""
    from concurrent.futures import ThreadPoolExecutor

    from illumon_service.app import admin_token

    settings = make_settings(tmp_path, admin_token=None)
    with ThreadPoolExecutor(8) as pool:
        tokens = set(pool.map(lambda _i: admin_token(settings), range(16)))
    assert len(tokens) == 1 and (tmp_path / "admin_token").read_text().strip() in tokens
    assert (tmp_path / "admin_token").stat().st_mode & 0o777 == 0o600
    assert not list(tmp_path.glob(".admin_token-*"))


def test_refit_without_frames_logs_one_line(client, caplog):
    """Issue 19: a refit of a camera without frames (an ordinary user error) printed a full traceback; one line now."""
    cid, token = register(client, np.ones((61, 3)), grid_regions())
    caplog.clear()
    with caplog.at_level("INFO", logger="illumon_service"):
        job_id = client.post(f"/v1/cameras/{cid}/refit", headers=bearer(token)).json()["job_id"]
    job = client.get(f"/v1/jobs/{job_id}", headers=bearer(token)).json()
    assert job["state"] == "failed" and "0 stored" in job["summary"]["error"]
    mine = [r for r in caplog.records if r.name.startswith("illumon_service")]
    assert len(mine) == 1, [r.getMessage() for r in mine]
    assert mine[0].levelname == "WARNING" and mine[0].exc_info is None
    assert f"refit of camera {cid} failed" in mine[0].getMessage() and "\n" not in mine[0].getMessage()


def test_dask_workers_start_without_the_malloc_trim_threshold():
    """The LocalCluster's workers get Dask's one-thread BLAS/OpenMP settings but not its MALLOC_TRIM_THRESHOLD_ (which
    made every refit's arrays above 128 KiB be mapped and faulted in anew: 1.4–2 × slower, issue 29)."""
    from illumon_service.jobs import worker_config

    config = worker_config()
    env = config["distributed.nanny.pre-spawn-environ"]
    assert config["distributed.worker.profile.enabled"] is False
    assert "MALLOC_TRIM_THRESHOLD_" not in env
    assert {k: int(env[k]) for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")} == {
        "OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}


_FORKED_BATCH = """
import json, os, sys, threading, warnings
warnings.simplefilter("ignore")
from illumon_service import jobs
from illumon_service.settings import Settings
forked = []
fork = jobs.fork_workers
def spy(n, prepare=None):
    forked.append(threading.active_count())
    def marked():  # in each worker: its engine opened before it joins (pid, engines it then holds)
        prepare()
        with open(os.path.join(sys.argv[1], "prepared"), "a") as f:
            f.write(f"{os.getpid()} {len(jobs._ENGINES)}\\n")
    out = fork(n, prepare=marked if prepare else None)
    forked.append(len(out))
    return out
jobs.fork_workers = spy
workers = int(sys.argv[2])
results = jobs.run_batch(Settings(data_dir=sys.argv[1], admin_token="x"), None, n_workers=workers, progress=False)
print(json.dumps({"forked": forked, "results": results}))
"""


def _store_cameras(tmp_path, n: int, frames: int) -> None:
    """``n`` cameras of ``frames`` simulated daylight frames each (8 regions, some missing), stored directly."""
    from datetime import datetime, timedelta, timezone

    from illumon.daylight import CIEDaylight
    from illumon.simulation import simulate_history
    from illumon_service.storage import Camera, Frame, make_engine, make_session_factory
    from sqlalchemy import insert

    wl = np.arange(400, 701, 5)
    css = np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])
    engine = make_engine(make_settings(tmp_path).resolved_database_url)
    with make_session_factory(engine)() as s, s.begin():
        for k in range(n):
            rng = np.random.default_rng(k)
            refl = np.clip(0.2 + 0.6 * rng.random((8, 1)) * np.sin(wl / rng.uniform(40, 120, (8, 1))) ** 2, 0, 1)
            mired = np.linspace(110, 250, frames)
            hist = simulate_history(css, CIEDaylight().spectra(np.column_stack([mired, np.zeros(frames)])), refl,
                                    rng=k, missing_fraction=0.1)
            cam = Camera(name=f"c{k}", token_hash=f"{k:064x}", sensitivities=css.tolist(),
                         regions=[{"id": f"p{j}", "x": 0, "y": 0, "width": 1, "height": 1} for j in range(8)],
                         response={"encoding": "linear"})
            s.add(cam)
            s.flush()
            t0 = datetime(2025, 6, 1, tzinfo=timezone.utc)
            s.execute(insert(Frame), [{"camera_id": cam.id, "taken_at": t0 + timedelta(minutes=f), "patches": {
                f"p{j}": None if not np.isfinite(v[j, 0]) else v[j].tolist() for j in range(8)}}
                for f, v in enumerate(hist.observations.values)])
    engine.dispose()


def _stored_estimates(tmp_path) -> list[tuple]:
    """Every stored estimate but the columns a refit's time and version set."""
    import sqlite3

    con = sqlite3.connect(make_settings(tmp_path).resolved_database_url.removeprefix("sqlite:///"))
    try:
        return con.execute("SELECT frame_id, camera_id, taken_at, cct_k, duv, xy, white_rgb, gains_rgb, confidence, "
                           "spectrum, intervals, source FROM estimates ORDER BY frame_id").fetchall()
    finally:
        con.close()


def test_refit_all_in_forked_workers_equals_serial(tmp_path):
    """`run_batch` in a process with one thread forks its Dask workers (``jobs.fork_workers``, no spawned interpreter
    to start): the estimates they write and their summaries equal those of a serial refit, bit for bit. The serial
    refit runs in a fresh process too: this one has built tables (daylight, locus) with two BLAS threads, whose sums
    round differently (5e-11 relative in the estimates once each frame's glare offset is solved densely)."""
    import json
    import os
    import subprocess
    import sys

    _store_cameras(tmp_path, 3, 40)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}

    def batch(workers: int) -> dict:
        out = subprocess.run([sys.executable, "-c", _FORKED_BATCH, str(tmp_path), str(workers)], capture_output=True,
                             text=True, env=env, timeout=300, check=True).stdout
        return json.loads(out.strip().splitlines()[-1])

    got = batch(2)
    assert got["forked"] == [1, 2]  # one thread when it forked, two workers forked
    prepared = [line.split() for line in (tmp_path / "prepared").read_text().splitlines()]
    assert len({pid for pid, _ in prepared}) == 2 and all(n == "1" for _, n in prepared)  # each opened its engine
    forked_rows = _stored_estimates(tmp_path)
    serial = batch(1)["results"]
    assert len(forked_rows) == 120 and forked_rows == _stored_estimates(tmp_path)
    timing = {"seconds", "read_s", "fit_s", "write_s", "response_check_s", "version"}

    def same(results: list[dict]) -> list[dict]:
        return sorted(({k: v for k, v in r.items() if k not in timing} for r in results), key=lambda r: r["camera_id"])

    assert same(got["results"]) == same(serial)


def test_no_fork_beside_other_threads():
    """``jobs.fork_workers`` forks nothing while another thread runs (its lock could be held forever in a child)."""
    import threading

    from illumon_service.jobs import fork_workers

    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert fork_workers(2) == []
    finally:
        stop.set()
        other.join()
