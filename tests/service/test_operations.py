"""Issue 27, operations: Idempotency-Key on frame posts (sequential and concurrent retries, in one process and across
worker processes), retention, file paths relative to the data directory (and the migration of absolute ones), the
database file's mode, ``/metrics`` settings."""

from __future__ import annotations

import os
import sqlite3
import stat
import threading
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from illumon_service.app import create_app
from illumon_service.datafiles import data_file, relative_form
from illumon_service.retention import prune
from ops_helpers import camera_body, frame_time, render_frames
from serve_helpers import start_server
from svc_helpers import ADMIN, admin_headers, bearer, make_settings


@pytest.fixture(scope="module")
def images() -> list[bytes]:
    return render_frames(12)


def _register(c: TestClient, name: str = "ops camera") -> tuple[int, dict]:
    r = c.post("/v1/cameras", json=camera_body(name), headers=admin_headers())
    assert r.status_code == 201, r.text
    return r.json()["id"], bearer(r.json()["token"])


def _post(c, cam: int, h: dict, img: bytes, k: int, key: str | None = None):  # noqa: ANN001 - TestClient or httpx
    headers = dict(h) if key is None else {**h, "Idempotency-Key": key}
    return c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", img, "image/png")},
                  data={"taken_at": frame_time(k)}, headers=headers)


def _count_frames(c, cam: int, h: dict) -> int:  # noqa: ANN001
    return len(c.get(f"/v1/cameras/{cam}/frames?limit=100000", headers=h).json())


# --- Idempotency-Key ---------------------------------------------------------------------------------------------


def test_idempotent_retry_returns_the_original_answer(tmp_path, images):
    with TestClient(create_app(make_settings(tmp_path))) as c:
        cam, h = _register(c)
        for k in range(6):
            assert _post(c, cam, h, images[k], k).status_code == 201
        assert c.post(f"/v1/cameras/{cam}/refit", headers=h).status_code == 202
        first = _post(c, cam, h, images[6], 6, key="cam-frame-0006")
        assert first.status_code == 201 and first.json()["estimate"] is not None
        assert "idempotent-replayed" not in first.headers
        n = _count_frames(c, cam, h)
        c.post(f"/v1/cameras/{cam}/refit", headers=h)  # the estimate changes; the replayed answer does not
        again = _post(c, cam, h, images[6], 6, key="cam-frame-0006")
        assert again.status_code == 201 and again.json() == first.json()
        assert again.headers["idempotent-replayed"] == "true"
        assert _count_frames(c, cam, h) == n
        # the same key for another frame: 422, nothing stored
        other = _post(c, cam, h, images[7], 7, key="cam-frame-0006")
        assert other.status_code == 422 and "already used" in other.json()["detail"]
        assert _count_frames(c, cam, h) == n
        # keys are per camera: another camera may use the same key
        cam2, h2 = _register(c, "second")
        r = _post(c, cam2, h2, images[6], 6, key="cam-frame-0006")
        assert r.status_code == 201 and r.json()["frame_id"] != first.json()["frame_id"]
        assert _count_frames(c, cam, h) == n and _count_frames(c, cam2, h2) == 1
        # observations too
        ob = {"taken_at": frame_time(50), "patches": {"p0": [0.2, 0.3, 0.4], "p1": [0.3, 0.3, 0.3]}}
        o1 = c.post(f"/v1/cameras/{cam}/observations", json=ob, headers={**h, "Idempotency-Key": "ob-1"})
        o2 = c.post(f"/v1/cameras/{cam}/observations", json=ob, headers={**h, "Idempotency-Key": "ob-1"})
        assert o1.status_code == o2.status_code == 201 and o1.json() == o2.json()
        assert _count_frames(c, cam, h) == n + 1
        # malformed keys: 422 with a JSON body
        for bad in ("", " ", "x" * 256, "clé"):
            r = c.post(f"/v1/cameras/{cam}/observations", json=ob,
                       headers={**h, "Idempotency-Key": bad.encode("utf-8")})
            assert r.status_code == 422 and "detail" in r.json(), (bad, r.text)
        assert _count_frames(c, cam, h) == n + 1


def test_concurrent_retries_in_one_process(tmp_path, images):
    """Eight threads post the same frame with the same key at once: one frame stored, eight identical answers."""
    with TestClient(create_app(make_settings(tmp_path))) as c:
        cam, h = _register(c)
        answers: list = []
        barrier = threading.Barrier(8)

        def go() -> None:
            barrier.wait()
            answers.append(_post(c, cam, h, images[0], 0, key="same"))

        threads = [threading.Thread(target=go) for _ in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert all(r.status_code == 201 for r in answers), [r.text for r in answers]
        assert len({r.json()["frame_id"] for r in answers}) == 1
        assert all(r.json() == answers[0].json() for r in answers)
        assert sum(r.headers.get("idempotent-replayed") == "true" for r in answers) == 7
        assert _count_frames(c, cam, h) == 1


def test_concurrent_retries_across_worker_processes(tmp_path, images):
    """Two worker processes, 4 rounds of 8 concurrent retries each: the unique key lets one commit, the others replay."""
    import httpx

    server = start_server(tmp_path / "var", env={"ILLUMON_ADMIN_TOKEN": ADMIN}, workers=2)
    try:
        with server.client() as c:
            cam, h = _register(c)
        for rnd in range(4):
            answers: list[httpx.Response] = []
            barrier = threading.Barrier(8)

            def go(rnd: int = rnd, barrier: threading.Barrier = barrier, answers: list = answers) -> None:
                with server.client() as wc:  # a connection each: the kernel spreads them over both workers
                    barrier.wait()
                    answers.append(_post(wc, cam, h, images[rnd], rnd, key=f"round-{rnd}"))

            threads = [threading.Thread(target=go) for _ in range(8)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            assert len(answers) == 8 and all(r.status_code == 201 for r in answers), [r.text for r in answers]
            assert len({r.json()["frame_id"] for r in answers}) == 1 and all(r.json() == answers[0].json() for r in answers)
        with server.client() as c:
            assert _count_frames(c, cam, h) == 4
    finally:
        server.stop()


# --- retention ---------------------------------------------------------------------------------------------------


def test_retention_prunes_old_frames_estimates_and_files(tmp_path, images):
    now = datetime.now(timezone.utc)
    old_t = [(now - timedelta(days=40, minutes=20 * k)).isoformat() for k in range(6)]
    new_t = [(now - timedelta(days=1, minutes=20 * k)).isoformat() for k in range(6)]
    with TestClient(create_app(make_settings(tmp_path))) as c:  # default: keep everything
        assert c.app.state.settings.retain_days == 0
        cam, h = _register(c)
        ids = {}
        for k, t in enumerate(old_t + new_t):
            r = c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", images[k], "image/png")},
                       data={"taken_at": t}, headers={**h, "Idempotency-Key": f"k{k}"})
            assert r.status_code == 201, r.text
            ids[t] = r.json()["frame_id"]
        job = c.post(f"/v1/cameras/{cam}/refit", headers=h).json()["job_id"]
        assert c.get(f"/v1/jobs/{job}", headers=h).json()["state"] == "done"
        sessions = c.app.state.sessions
        assert prune(sessions, tmp_path, 0)["frames"] == 0  # retain_days 0 keeps every frame
        assert _count_frames(c, cam, h) == 12
        with sqlite3.connect(tmp_path / "illumon.sqlite3") as db:
            old_files = [tmp_path / p for (p,) in db.execute(
                f"SELECT thumb_path FROM frames WHERE thumb_path IS NOT NULL AND id IN ({','.join(str(ids[t]) for t in old_t)})")]
        assert old_files and all(f.is_file() for f in old_files)
        kept_original = tmp_path / "pending" / f"camera-{cam}" / f"{ids[old_t[0]]}.png"  # an original kept for later
        kept_original.parent.mkdir(parents=True)
        kept_original.write_bytes(images[0])
        out = prune(sessions, tmp_path, 30)
        assert out["frames"] == 6 and out["estimates"] == 6 and out["idempotency_keys"] == 6
        assert out["files"] == len(old_files) + 1 and not any(f.exists() for f in [*old_files, kept_original])
        frames = c.get(f"/v1/cameras/{cam}/frames?limit=100000", headers=h).json()
        assert sorted(f["frame_id"] for f in frames) == sorted(ids[t] for t in new_t)
        est = c.get(f"/v1/cameras/{cam}/estimates?limit=100000", headers=h).json()
        assert sorted(e["frame_id"] for e in est) == sorted(ids[t] for t in new_t)
        # a pruned frame's key is forgotten with it: the same post is a new frame
        r = c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", images[0], "image/png")},
                   data={"taken_at": old_t[0]}, headers={**h, "Idempotency-Key": "k0"})
        assert r.status_code == 201 and "idempotent-replayed" not in r.headers
        # jobs finished before the cut-off go too
        assert prune(sessions, tmp_path, 30, now=now + timedelta(days=31))["jobs"] == 1
        assert c.get(f"/v1/jobs/{job}", headers=h).status_code == 404


def test_retention_runs_in_the_service_and_from_the_cli(tmp_path, images):
    import json
    import subprocess

    from serve_helpers import ILLUMON

    old = (datetime.now(timezone.utc) - timedelta(days=10)).isoformat()
    with TestClient(create_app(make_settings(tmp_path))) as c:
        cam, h = _register(c)
        for k in range(3):
            assert c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", images[k], "image/png")},
                          data={"taken_at": old}, headers=h).status_code == 201
    with TestClient(create_app(make_settings(tmp_path, retain_days=5))) as c:  # the housekeeper prunes at start
        for _ in range(200):
            if c.app.state.housekeeper.runs:
                break
            threading.Event().wait(0.05)
        assert c.app.state.housekeeper.runs >= 1
        assert _count_frames(c, cam, h) == 0
        assert c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", images[0], "image/png")},
                      data={"taken_at": old}, headers=h).status_code == 201
    run = subprocess.run([str(ILLUMON), "prune", "--data-dir", str(tmp_path), "--retain-days", "5"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["frames"] == 1
    bad = subprocess.run([str(ILLUMON), "prune", "--data-dir", str(tmp_path / "nowhere")], capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.startswith("illumon: error:") and bad.stderr.count("\n") == 1


# --- file paths, database file mode, metrics ------------------------------------------------------------------------


def test_paths_stored_relative_and_absolute_ones_migrated(tmp_path, images):
    data = tmp_path / "var"
    with TestClient(create_app(make_settings(data, keep_images=True))) as c:
        cam, h = _register(c)
        for k in range(3):
            assert _post(c, cam, h, images[k], k).status_code == 201
    db = sqlite3.connect(data / "illumon.sqlite3")
    rows = db.execute("SELECT id, thumb_path, image_path FROM frames ORDER BY id").fetchall()
    assert all(p and not p.startswith("/") and (data / p).is_file() for r in rows for p in r[1:])
    # an older version's absolute paths: under this data dir, under a moved one, and outside any
    outside = tmp_path / "elsewhere.png"
    outside.write_bytes(b"not ours")
    db.execute("UPDATE frames SET thumb_path = ? WHERE id = ?", (str((data / rows[0][1]).resolve()), rows[0][0]))
    db.execute("UPDATE frames SET thumb_path = ? WHERE id = ?", (f"/old/host/var/{rows[1][1]}", rows[1][0]))
    db.execute("UPDATE frames SET image_path = ? WHERE id = ?", (str(outside), rows[2][0]))
    db.commit()
    with TestClient(create_app(make_settings(data))) as c:  # start-up migrates
        pass
    after = db.execute("SELECT id, thumb_path, image_path FROM frames ORDER BY id").fetchall()
    assert after[0][1] == rows[0][1] and after[1][1] == rows[1][1] and after[2][2] is None
    assert outside.read_bytes() == b"not ours"
    db.close()
    # nothing outside the data directory is ever named through the database
    assert data_file(data, "/etc/passwd") is None and data_file(data, "../x.png") is None
    assert data_file(data, "thumbs/camera-1/2.png") == data / "thumbs/camera-1/2.png"
    assert relative_form(data, "/srv/a/images/camera-4/9.jpeg") == "images/camera-4/9.jpeg"
    assert relative_form(data, "/tmp/file.png") is None


def test_database_file_readable_by_owner_only(tmp_path):
    data = tmp_path / "var"
    with TestClient(create_app(make_settings(data))) as c:
        _register(c)
    for name in ("illumon.sqlite3", "illumon.sqlite3-wal", "illumon.sqlite3-shm"):
        path = data / name
        if path.exists():
            assert stat.S_IMODE(path.stat().st_mode) == 0o600, name
    assert (data / "illumon.sqlite3").exists()
    assert stat.S_IMODE(data.stat().st_mode) == 0o700
    # an older database created world-readable is made private at start-up
    os.chmod(data / "illumon.sqlite3", 0o644)
    with TestClient(create_app(make_settings(data))):
        pass
    assert stat.S_IMODE((data / "illumon.sqlite3").stat().st_mode) == 0o600


def test_metrics_setting(tmp_path):
    with TestClient(create_app(make_settings(tmp_path / "a"))) as c:  # default: public
        assert c.get("/metrics").status_code == 200
    with TestClient(create_app(make_settings(tmp_path / "b", metrics="off"))) as c:
        r = c.get("/metrics")
        assert r.status_code == 404 and "ILLUMON_METRICS" in r.json()["detail"]
    with TestClient(create_app(make_settings(tmp_path / "c", metrics="admin"))) as c:
        _, h = _register(c)
        assert c.get("/metrics").status_code == 401
        assert c.get("/metrics", headers=h).status_code == 403
        r = c.get("/metrics", headers=admin_headers())
        assert r.status_code == 200 and "illumon_frames_ingested_total" in r.text


def test_data_file_is_path(tmp_path):
    assert isinstance(data_file(tmp_path, "a/b.png"), Path)


def test_login_session_is_not_the_token_and_ends_with_it(tmp_path):
    """The cookie holds a random id; the database holds only hashes; a changed admin token ends its sessions."""
    with TestClient(create_app(make_settings(tmp_path))) as c:
        r = c.post("/login", data={"token": ADMIN, "next": "/"}, follow_redirects=False)
        assert r.status_code == 303
        sid = c.cookies.get("illumon_session")
        assert sid and ADMIN not in sid and c.get("/", follow_redirects=False).status_code == 200
    with sqlite3.connect(tmp_path / "illumon.sqlite3") as db:
        dump = "\n".join(db.iterdump())
    assert sid not in dump and ADMIN not in dump  # hashes only
    with TestClient(create_app(make_settings(tmp_path))) as c:  # same token: the session survives a restart
        c.cookies.set("illumon_session", sid)
        assert c.get("/", follow_redirects=False).status_code == 200
    with TestClient(create_app(make_settings(tmp_path, admin_token="a-new-admin-token"))) as c:
        c.cookies.set("illumon_session", sid)
        r = c.get("/", follow_redirects=False)
        assert r.status_code == 303 and r.headers["location"].startswith("/login")
