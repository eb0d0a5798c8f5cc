"""``illumon backup`` / ``illumon restore`` (issue 27): a backup taken while frames are being written, restored into a
fresh data directory (and database), answers exactly as the original for every frame acknowledged before the backup;
tokens work; file paths are the copy's own; the original is untouched. SQLite always, PostgreSQL when a throwaway
cluster can be started (``test_faults.pg_url``)."""

from __future__ import annotations

import hashlib
import json
import sqlite3
import subprocess
import threading
import time
from pathlib import Path

import httpx
from ops_helpers import camera_body, frame_time, render_frames
from serve_helpers import ILLUMON, start_server
from test_faults import pg_url  # noqa: F401 - fixture

N_FIRST = 12


def _files(folder: Path) -> dict[str, str]:
    """Relative path → SHA-256 of every file of a data directory but the live database and per-process files."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_file() and not rel.startswith(("illumon.sqlite3", "metrics/")) and not rel.endswith(".lock"):
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def _wait_job(c: httpx.Client, job: str, headers: dict) -> dict:
    for _ in range(600):
        j = c.get(f"/v1/jobs/{job}", headers=headers).json()
        if j["state"] in ("done", "failed"):
            return j
        time.sleep(0.2)
    raise AssertionError(f"job {job} did not end")


def _wait_for(condition, timeout: float = 120.0) -> None:  # noqa: ANN001 - a callable returning bool
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def _state(c: httpx.Client, cam: int, headers: dict) -> dict:
    frames = c.get(f"/v1/cameras/{cam}/frames?limit=100000", headers=headers).json()
    estimates = c.get(f"/v1/cameras/{cam}/estimates?limit=100000", headers=headers).json()
    return {"frames": {f["frame_id"]: f for f in frames}, "estimates": {e["frame_id"]: e for e in estimates},
            "camera": c.get(f"/v1/cameras/{cam}", headers=headers).json()}


def _cli(*args: str) -> dict:
    run = subprocess.run([str(ILLUMON), *args], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def _roundtrip(tmp_path: Path, database_url: str | None = None, restored_url: str | None = None) -> None:
    images = render_frames(24)
    data, fresh, dest = tmp_path / "var", tmp_path / "fresh", tmp_path / "backup"
    data.mkdir()
    server = start_server(data, database_url=database_url)
    admin = {"Authorization": f"Bearer {(data / 'admin_token').read_text().strip()}"}  # generated, kept in the data dir
    acked: dict[int, tuple[float, dict, str]] = {}
    try:
        with server.client() as c:
            r = c.post("/v1/cameras", json=camera_body(), headers=admin)
            assert r.status_code == 201, r.text
            cam, token = r.json()["id"], r.json()["token"]
            cam_h = {"Authorization": f"Bearer {token}"}
            for k in range(N_FIRST):
                r = c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", images[k], "image/png")},
                           data={"taken_at": frame_time(k)}, headers=cam_h)
                assert r.status_code == 201, r.text
            job = _wait_job(c, c.post(f"/v1/cameras/{cam}/refit", headers=cam_h).json()["job_id"], cam_h)
            assert job["state"] == "done", job

        stop = threading.Event()
        errors: list[str] = []

        def writer() -> None:  # frames keep coming while the backup runs; each acknowledged one is recorded
            k = N_FIRST
            with server.client() as wc:
                while not stop.is_set():
                    key = f"frame-{k}"
                    r = wc.post(f"/v1/cameras/{cam}/frames", data={"taken_at": frame_time(k)},
                                files={"image": ("f.png", images[k % len(images)], "image/png")},
                                headers={**cam_h, "Idempotency-Key": key})
                    if r.status_code != 201:
                        errors.append(r.text)
                        return
                    acked[r.json()["frame_id"]] = (time.monotonic(), r.json(), key)
                    k += 1

        t = threading.Thread(target=writer)
        t.start()
        _wait_for(lambda: len(acked) >= 5 or bool(errors))  # frames are being written when the backup starts
        t_backup = time.monotonic()
        args = ["backup", str(dest), "--data-dir", str(data)] + (["--database-url", database_url] if database_url else [])
        manifest = _cli(*args)
        n_after = len(acked)
        _wait_for(lambda: len(acked) >= n_after + 3 or bool(errors))  # and still after it
        stop.set()
        t.join(timeout=60)
        assert not errors, errors
        before = [fid for fid, (at, _, _) in acked.items() if at < t_backup]
        assert len(before) >= 5 and len(acked) > len(before), (len(before), len(acked))
        assert manifest["database"] == ("postgresql" if database_url else "sqlite")
        assert (dest / "manifest.json").is_file() and not dest.with_name("backup.partial").exists()
        assert (dest.stat().st_mode & 0o777) == 0o700

        with server.client() as c:
            original = _state(c, cam, admin)
        original_files = _files(data)

        rargs = ["restore", str(dest), "--data-dir", str(fresh)] + (["--database-url", restored_url] if restored_url else [])
        restored_summary = _cli(*rargs)
        assert restored_summary["files_missing"] == 0
        # a second restore onto the restored copy is refused (one line, exit 2), without --force
        again = subprocess.run([str(ILLUMON), *rargs], capture_output=True, text=True, timeout=120)
        assert again.returncode == 2 and again.stderr.count("\n") == 1 and "--force" in again.stderr, again.stderr
        server2 = start_server(fresh, database_url=restored_url)
        try:
            with server2.client() as c2:
                copy = _state(c2, cam, admin)
                # every frame acknowledged before the backup started, and its estimate, is there, the same
                for fid in before:
                    assert copy["frames"][fid] == original["frames"][fid]
                    assert copy["estimates"][fid] == original["estimates"][fid]
                # the copy holds nothing the original does not, each frame and estimate identical
                assert set(copy["frames"]) <= set(original["frames"])
                for fid, f in copy["frames"].items():
                    assert f == original["frames"][fid]
                assert set(copy["estimates"]) == set(copy["frames"])  # every frame estimated (the model file came along)
                for fid, e in copy["estimates"].items():
                    assert e == original["estimates"][fid]
                for key in ("name", "regions", "response", "sensitivities", "calibration"):
                    assert copy["camera"][key] == original["camera"][key]
                # the answers: illuminant and gains at a frame's time, with the camera's token (tokens restored)
                at = original["frames"][before[-1]]["taken_at"]
                for route in ("illuminant", "wb-gains"):
                    a = c2.get(f"/v1/cameras/{cam}/{route}", params={"at": at}, headers=cam_h)
                    with server.client() as c:
                        b = c.get(f"/v1/cameras/{cam}/{route}", params={"at": at}, headers=cam_h)
                    assert a.status_code == 200 and a.json() == b.json()
                # an acknowledged frame's retry gets its original answer from the copy, storing nothing
                fid = before[0]
                _, answer, key = acked[fid]
                k = int(key.split("-")[1])
                r = c2.post(f"/v1/cameras/{cam}/frames", data={"taken_at": frame_time(k)},
                            files={"image": ("f.png", images[k % len(images)], "image/png")},
                            headers={**cam_h, "Idempotency-Key": key})
                assert r.status_code == 201 and r.json() == answer and r.headers["idempotent-replayed"] == "true"
                # the copy keeps working in its own data directory: new frames, thumbnails written and pruned there
                n = len(copy["frames"])
                for j in range(30):
                    k = 1000 + j
                    r = c2.post(f"/v1/cameras/{cam}/frames", data={"taken_at": frame_time(k)},
                                files={"image": ("f.png", images[k % len(images)], "image/png")}, headers=cam_h)
                    assert r.status_code == 201 and r.json()["estimate"] is not None, r.text
                assert len(_state(c2, cam, admin)["frames"]) == n + 30
                props = c2.get(f"/v1/cameras/{cam}/region-proposals", headers=cam_h)
                assert props.status_code == 200 and props.json()["frames_used"] >= 5
        finally:
            server2.stop()
        # the original is untouched: same files (none pruned by the copy), same frames and estimates
        assert _files(data) == original_files
        with server.client() as c:
            assert _state(c, cam, admin) == original
        if restored_url is None:
            with sqlite3.connect(fresh / "illumon.sqlite3") as db:
                paths = [p for (p,) in db.execute("SELECT thumb_path FROM frames WHERE thumb_path IS NOT NULL")]
            assert paths and all(not p.startswith("/") and (fresh / p).is_file() for p in paths)
        print(f"\nbackup while writing ({manifest['database']}): {N_FIRST} frames, then {len(acked)} acknowledged while "
              f"writing, {len(before)} of them before the backup started, {len(copy['frames']) - N_FIRST} in the copy, "
              "every frame and estimate in the copy identical; original untouched")
    finally:
        server.stop()


def test_backup_while_writing_and_restore_sqlite(tmp_path):
    _roundtrip(tmp_path)


def test_backup_while_writing_and_restore_postgres(tmp_path, pg_url):  # noqa: F811 - fixture
    import psycopg

    plain = pg_url.replace("postgresql+psycopg://", "postgresql://")
    with psycopg.connect(plain, autocommit=True) as conn:
        conn.execute("CREATE DATABASE restored")
    _roundtrip(tmp_path, pg_url, pg_url.rsplit("/", 1)[0] + "/restored")


def test_backup_and_restore_errors(tmp_path):
    """Mistakes are one line and exit 2: no database, a non-empty destination, not a backup, the other backend."""
    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([str(ILLUMON), *args], capture_output=True, text=True, timeout=120)

    (tmp_path / "empty").mkdir()
    for args, needle in (
        (["backup", str(tmp_path / "b"), "--data-dir", str(tmp_path / "empty")], "no database"),
        (["restore", str(tmp_path / "empty"), "--data-dir", str(tmp_path / "x")], "not an illumon backup"),
    ):
        r = run(*args)
        assert r.returncode == 2 and r.stderr.startswith("illumon: error:") and needle in r.stderr, r.stderr
        assert r.stderr.count("\n") == 1
    bk = tmp_path / "bk"
    (tmp_path / "var").mkdir()
    from illumon_service.storage import make_engine

    make_engine(f"sqlite:///{tmp_path / 'var' / 'illumon.sqlite3'}").dispose()
    assert run("backup", str(bk), "--data-dir", str(tmp_path / "var")).returncode == 0
    r = run("backup", str(bk), "--data-dir", str(tmp_path / "var"))
    assert r.returncode == 2 and "not an empty folder" in r.stderr
    r = run("restore", str(bk), "--data-dir", str(tmp_path / "r"), "--database-url", "postgresql+psycopg://u@127.0.0.1:1/x")
    assert r.returncode == 2 and "cannot be restored into PostgreSQL" in r.stderr, r.stderr
    # a PostgreSQL that cannot be reached: one line, and no backup folder (not even a partial one) left behind
    r = run("backup", str(tmp_path / "pgbk"), "--data-dir", str(tmp_path / "var"), "--database-url",
            "postgresql+psycopg://u@127.0.0.1:1/x")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "pg_dump" in r.stderr, r.stderr
    assert not (tmp_path / "pgbk").exists() and not (tmp_path / "pgbk.partial").exists()
    # a database that cannot be reached, a negative retention: one line each, no traceback
    for args in (["prune", "--data-dir", str(tmp_path / "var"), "--database-url", "postgresql+psycopg://u@127.0.0.1:1/x"],
                 ["prune", "--data-dir", str(tmp_path / "var"), "--retain-days", "-1"]):
        r = run(*args)
        assert r.returncode == 2 and r.stderr.startswith("illumon: error:") and r.stderr.count("\n") == 1, r.stderr


def test_backup_forgets_what_it_could_not_copy(tmp_path):
    """A thumbnail or model file the snapshot names but the copy lacks (deleted in between) is forgotten in the copy,
    counted in the manifest; the original keeps its rows."""
    from illumon_service.backup import backup
    from illumon_service.settings import Settings
    from illumon_service.storage import make_engine

    data = tmp_path / "var"
    make_engine(f"sqlite:///{data / 'illumon.sqlite3'}").dispose()
    with sqlite3.connect(data / "illumon.sqlite3") as db:
        db.execute("INSERT INTO cameras (id, name, token_hash, sensitivities, regions, response, models, created_at) "
                   "VALUES (1, 'c', 'h', '[]', '[]', '{}', '{\"default\": {\"file\": \"camera-1.gone.json\"}}', "
                   "'2025-01-01 00:00:00')")
        db.execute("INSERT INTO frames (id, camera_id, taken_at, patches, thumb_path, created_at) VALUES "
                   "(1, 1, '2025-01-01 00:00:00', '{}', 'thumbs/camera-1/1.png', '2025-01-01 00:00:00')")
    manifest = backup(Settings(data_dir=data, admin_token="x"), tmp_path / "bk")
    assert manifest["files_missing"] == 2 and manifest["integrity_check"] == "ok"
    with sqlite3.connect(tmp_path / "bk" / "illumon.sqlite3") as db:
        assert db.execute("SELECT thumb_path FROM frames").fetchone()[0] is None
        assert db.execute("SELECT models FROM cameras").fetchone()[0] in (None, "null")
    with sqlite3.connect(data / "illumon.sqlite3") as db:
        assert db.execute("SELECT thumb_path FROM frames").fetchone()[0] == "thumbs/camera-1/1.png"
