"""Issue 27, "the service holds": nothing accepted can break a camera (ranges and control characters refused at the
door, the refit drops what it cannot use, admin deletes, a failed refit alerts), jobs survive crashes (start-up
recovery, one transaction per refit, a SIGKILL inside the refit's commit), images bounded before decoding, no shared
temporary files, and frames posted before the regions are confirmed measured once they are."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import threading
import zlib
from datetime import timedelta
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from illumon_service.app import create_app
from illumon_service.storage import Estimate, Frame, Job, make_engine, make_session_factory, utcnow
from sqlalchemy import select
from svc_helpers import SIZE, T0, admin_headers, bearer, camera_body, grid_regions, make_settings, need_data
from test_faults import pg_url  # noqa: F401 - a throwaway PostgreSQL cluster, or skip

N = 12


@pytest.fixture(scope="module")
def history():
    """A measured camera (Nikon D5100), six regions of measured surfaces and 12 Granada daylights: linear region
    means 0…0.8."""
    need_data()
    from illumon.camera import render
    from illumon.simulation import datasets

    rng = np.random.default_rng(1)
    css = datasets.load_camera("Nikon_D5100")
    _, day = datasets.load_granada_daylight()
    _, refl = datasets.load_reflectance_set("munsell_matt_1269")
    refl = refl[rng.choice(len(refl), 6, replace=False)]
    lin = render(css, day[rng.choice(len(day), N, replace=False)], refl)
    return css, lin / lin.max() * 0.8


def _observation(lin: np.ndarray, f: int, **extra) -> dict:
    body = {"taken_at": (T0 + timedelta(minutes=30 * f)).isoformat(),
            "patches": {f"r{i}": [float(v) for v in lin[f % N, i]] for i in range(lin.shape[1])}}
    body.update(extra)
    return body


def _camera(c: TestClient, css: np.ndarray, lin: np.ndarray) -> tuple[int, str]:
    r = c.post("/v1/cameras", json=camera_body(css, grid_regions(lin.shape[1])), headers=admin_headers())
    assert r.status_code == 201, r.text
    cid, token = r.json()["id"], r.json()["token"]
    for f in range(N):
        assert c.post(f"/v1/cameras/{cid}/observations", json=_observation(lin, f), headers=bearer(token)).status_code == 201
    return cid, token


def _refit(c: TestClient, cid: int, token: str) -> dict:
    r = c.post(f"/v1/cameras/{cid}/refit", headers=bearer(token))
    assert r.status_code == 202, r.text
    return c.get(f"/v1/jobs/{r.json()['job_id']}", headers=bearer(token)).json()


def _png(w: int, h: int, depth: int = 8, kind: int = 2) -> bytes:
    """A tiny PNG whose header states ``w × h`` pixels (its data would inflate to far more)."""
    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))
    ihdr = struct.pack(">IIBBBBB", w, h, depth, kind, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(1 << 16))) + chunk(b"IEND", b"")


HOSTILE = {
    "values near 1e300": {"patches": {"r0": [1e300, 1e300, 1e300]}},
    "exposure 1e-300": {"exposure": 1e-300},
    "applied_gains 1e308": {"applied_gains": [1e308, 1, 1]},
    "value 100 × white": {"patches": {"r0": [100.0, 0.2, 0.2]}},
    "sd 1e300": {"sd": {"r0": [1e300, 1.0, 1.0]}},
}


def test_hostile_values_refused_at_the_door_and_refit_survives_stored_ones(tmp_path, history):
    """Each hostile value of the issue is a 422 naming the field; the same values stored by an older version (written
    straight into the database) are left out by the refit, which succeeds and reports each by frame id and reason."""
    css, lin = history
    app = create_app(make_settings(tmp_path))
    with TestClient(app) as c:
        cid, token = _camera(c, css, lin)
        for name, change in HOSTILE.items():
            body = _observation(lin, 0)
            for k, v in change.items():
                body[k] = {**body[k], **v} if isinstance(v, dict) and k in body else v
            r = c.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token))
            assert r.status_code == 422, (name, r.text)
            assert isinstance(r.json()["detail"], list) and r.json()["detail"], name
            text = str(r.json()["detail"])
            assert any(word in text for word in ("exposure", "applied_gains", "patches", "sd")), (name, text)
        # the multipart form of a frame: same ranges
        png = cv2.imencode(".png", np.full((SIZE[1], SIZE[0], 3), 120, np.uint8))[1].tobytes()
        for field, value in (("exposure", "1e-300"), ("applied_gains", "1e308,1,1"), ("exposure", "nan")):
            r = c.post(f"/v1/cameras/{cid}/frames", files={"image": ("f.png", png, "image/png")}, data={field: value},
                       headers=bearer(token))
            assert r.status_code == 422 and field in r.json()["detail"], (field, r.text)
        job = _refit(c, cid, token)
        assert job["state"] == "done", job
        for q in ("-1e308,1e308", "0,1e-320"):  # query numbers too: the mapping overflowed to null gains (200)
            r = c.get(f"/v1/cameras/{cid}/wb-gains", params={"onvif_range": q}, headers=bearer(token))
            assert r.status_code == 422 and "onvif_range" in r.json()["detail"], r.text
        # rows as an older version stored them
        sessions = app.state.sessions
        with sessions() as s, s.begin():
            bad = [Frame(camera_id=cid, taken_at=T0 + timedelta(hours=20 + i), patches=patches, applied_gains=gains,
                         exposure=exposure, patch_sd=sd)
                   for i, (patches, gains, exposure, sd) in enumerate([
                       ({**_observation(lin, 1)["patches"], "r0": [1e300, 1e300, 1e300]}, None, None, None),
                       (_observation(lin, 2)["patches"], None, 1e-300, None),
                       (_observation(lin, 3)["patches"], [1e308, 1.0, 1.0], None, None),
                       (_observation(lin, 4)["patches"], None, None, {"r0": [1e300, 1.0, 1.0]})])]
            s.add_all(bad)
            s.flush()
            bad_ids = sorted(f.id for f in bad)
        job = _refit(c, cid, token)
        assert job["state"] == "done", job
        summary = job["summary"]
        assert summary["dropped_frames"] == 4 and sorted(d["frame_id"] for d in summary["dropped"]) == bad_ids
        assert all(d["reason"] for d in summary["dropped"])
        assert summary["frames"] == N
        cam = c.get(f"/v1/cameras/{cid}", headers=bearer(token)).json()
        assert cam["not_estimated"] == {"invalid_values": 4}
        assert "frames_not_estimated" in [a["kind"] for a in cam["alerts"]]
        frames = {f["frame_id"]: f for f in c.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json()}
        assert {fid for fid, f in frames.items() if f["not_estimated"]} == set(bad_ids)
        # the admin deletes them; the next refit has nothing to drop
        for fid in bad_ids:
            assert c.delete(f"/v1/cameras/{cid}/frames/{fid}", headers=bearer(token)).status_code == 403
            r = c.delete(f"/v1/cameras/{cid}/frames/{fid}", headers=admin_headers())
            assert r.status_code == 200 and r.json()["deleted"]["frames"] == 1, r.text
        assert c.delete(f"/v1/cameras/{cid}/frames/{bad_ids[0]}", headers=admin_headers()).status_code == 404
        job = _refit(c, cid, token)
        assert job["state"] == "done" and job["summary"]["dropped_frames"] == 0
        assert c.get(f"/v1/cameras/{cid}", headers=bearer(token)).json()["not_estimated"] == {}


@pytest.mark.parametrize("where", ["camera name", "region id", "form field", "observation key"])
def test_control_characters_refused(client, where):
    body = camera_body(np.ones((61, 3)), grid_regions(2))
    if where == "camera name":
        body["name"] = "roof\x00east"
    elif where == "region id":
        body["regions"][0]["id"] = "wall\x1b[31m"
    r = client.post("/v1/cameras", json=body, headers=admin_headers())
    if where in ("camera name", "region id"):
        assert r.status_code == 422 and "control character" in str(r.json()["detail"]), r.text
        return
    assert r.status_code == 201
    cid, token = r.json()["id"], r.json()["token"]
    if where == "form field":
        png = cv2.imencode(".png", np.full((SIZE[1], SIZE[0], 3), 120, np.uint8))[1].tobytes()
        r = client.post(f"/v1/cameras/{cid}/frames", files={"image": ("f.png", png, "image/png")},
                        data={"taken_at": "2025-06-01T12:00:00\x00Z"}, headers=bearer(token))
    else:
        r = client.post(f"/v1/cameras/{cid}/observations", json={"patches": {"r0\x00": [0.1, 0.2, 0.3]}},
                        headers=bearer(token))
    assert r.status_code == 422, r.text
    assert client.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json() == []


def test_region_outside_the_image_is_422_on_put_and_page(client):
    """The issue's typo (x = 12800 among good regions): refused by PUT …/regions and by the regions page once the
    view's image size is known; accepted at registration (no size yet), where frames are still stored and measured."""
    regions = grid_regions(4)
    typo = [*regions, {"id": "typo", "x": 12800, "y": 30, "width": 40, "height": 40}]
    r = client.post("/v1/cameras", json=camera_body(np.ones((61, 3)), typo), headers=admin_headers())
    cid, token = r.json()["id"], r.json()["token"]
    png = cv2.imencode(".png", np.random.default_rng(0).integers(30, 220, (SIZE[1], SIZE[0], 3), dtype=np.uint8)
                       )[1].tobytes()
    r = client.post(f"/v1/cameras/{cid}/frames", files={"image": ("f.png", png, "image/png")}, headers=bearer(token))
    assert r.status_code == 201 and r.json()["regions"]["typo"] is None and r.json()["usable_regions"] == 4, r.text
    r = client.put(f"/v1/cameras/{cid}/regions", json={"regions": typo}, headers=bearer(token))
    assert r.status_code == 422 and "typo" in r.json()["detail"], r.text
    form = {"n_regions": str(len(typo)), "n_proposals": "0"}
    for i, g in enumerate(typo):
        form.update({f"r{i}_keep": "1", f"r{i}_id": g["id"], f"r{i}_x": str(g["x"]), f"r{i}_y": str(g["y"]),
                     f"r{i}_w": str(g["width"]), f"r{i}_h": str(g["height"])})
    r = client.post(f"/cameras/{cid}/regions", data=form, headers=admin_headers())
    assert r.status_code == 422 and "Not saved" in r.text and "typo" in r.text
    assert client.put(f"/v1/cameras/{cid}/regions", json={"regions": regions}, headers=bearer(token)).status_code == 200
    # with the frames' size declared at registration, the typo is refused there, and by PUT before any frame
    body = {**camera_body(np.ones((61, 3)), typo), "image_size": {"width": SIZE[0], "height": SIZE[1]}}
    r = client.post("/v1/cameras", json=body, headers=admin_headers())
    assert r.status_code == 422 and "typo" in str(r.json()["detail"]), r.text
    r = client.post("/v1/cameras", json={**body, "regions": regions}, headers=admin_headers())
    assert r.status_code == 201, r.text
    cid, token = r.json()["id"], r.json()["token"]
    r = client.put(f"/v1/cameras/{cid}/regions", json={"regions": typo}, headers=bearer(token))
    assert r.status_code == 422 and "typo" in r.json()["detail"], r.text


def test_delete_camera_removes_everything(tmp_path, history):
    css, lin = history
    with TestClient(create_app(make_settings(tmp_path))) as c:
        cid, token = _camera(c, css, lin)
        other, other_token = _camera(c, css, lin)
        assert _refit(c, cid, token)["state"] == "done"
        assert list((tmp_path / "models").glob(f"camera-{cid}.*.json"))
        assert c.delete(f"/v1/cameras/{cid}", headers=bearer(token)).status_code == 403
        r = c.delete(f"/v1/cameras/{cid}", headers=admin_headers())
        assert r.status_code == 200 and r.json()["deleted"]["frames"] == N and r.json()["deleted"]["estimates"] == N
        assert c.get(f"/v1/cameras/{cid}", headers=admin_headers()).status_code == 404
        assert c.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).status_code == 401  # its token is gone
        assert not list((tmp_path / "models").glob(f"camera-{cid}.*"))
        assert len(c.get(f"/v1/cameras/{other}/frames", headers=bearer(other_token)).json()) == N


def test_failed_refit_raises_an_alert(client):
    r = client.post("/v1/cameras", json=camera_body(np.ones((61, 3)), grid_regions(2)), headers=admin_headers())
    cid, token = r.json()["id"], r.json()["token"]
    job = _refit(client, cid, token)
    assert job["state"] == "failed"
    alerts = client.get(f"/v1/cameras/{cid}", headers=bearer(token)).json()["alerts"]
    (alert,) = [a for a in alerts if a["kind"] == "refit_failed"]
    assert job["job_id"] in alert["message"] and "two frames" in alert["message"]
    page = client.get(f"/cameras/{cid}", headers=admin_headers())
    assert 'data-kind="refit_failed"' in page.text


def _versions(sessions, cid: int) -> set[str | None]:
    with sessions() as s:
        return set(s.scalars(select(Estimate.model).where(Estimate.camera_id == cid)).all())


def test_refit_estimates_and_model_change_together(tmp_path, history, monkeypatch):
    """A refit that dies inside its commit leaves the previous estimates and model in use, all of one version; the
    next refit switches both, and a frame posted afterwards is estimated by the new model."""
    import illumon_service.refit as refit

    css, lin = history
    app = create_app(make_settings(tmp_path))
    with TestClient(app) as c:
        cid, token = _camera(c, css, lin)
        first = _refit(c, cid, token)
        assert first["state"] == "done"
        v1 = first["summary"]["version"]
        assert _versions(app.state.sessions, cid) == {v1}

        def crash() -> None:
            raise RuntimeError("simulated crash inside the refit's transaction")

        monkeypatch.setattr(refit, "_commit_hook", crash)
        assert _refit(c, cid, token)["state"] == "failed"
        assert _versions(app.state.sessions, cid) == {v1}
        cam = c.get(f"/v1/cameras/{cid}", headers=bearer(token)).json()
        assert "refit_failed" in [a["kind"] for a in cam["alerts"]]
        r = c.post(f"/v1/cameras/{cid}/observations", json=_observation(lin, 5), headers=bearer(token))
        assert r.json()["estimate"] is not None
        monkeypatch.setattr(refit, "_commit_hook", None)
        second = _refit(c, cid, token)
        v2 = second["summary"]["version"]
        assert second["state"] == "done" and v2 != v1
        assert _versions(app.state.sessions, cid) == {v2}
        models = sorted(p.name for p in (tmp_path / "models").glob(f"camera-{cid}*.json"))
        assert models == [f"camera-{cid}.{v2}.json"]  # the old version's file is gone, and the crashed one's
        r = c.post(f"/v1/cameras/{cid}/observations", json=_observation(lin, 6), headers=bearer(token))
        assert r.json()["estimate"] is not None and _versions(app.state.sessions, cid) == {v2}
        assert "refit_failed" not in [a["kind"] for a in c.get(f"/v1/cameras/{cid}", headers=bearer(token)
                                                                ).json()["alerts"]]


KILL_SCRIPT = """
import os, signal, sys
from pathlib import Path
import illumon_service.refit as refit
from illumon_service.storage import make_engine, make_session_factory
refit._commit_hook = lambda: os.kill(os.getpid(), signal.SIGKILL)
sessions = make_session_factory(make_engine(sys.argv[1]))
refit.refit_camera(sessions, int(sys.argv[2]), data_dir=Path(sys.argv[3]))
"""


def test_sigkill_inside_the_refit_commit_then_restart(tmp_path, history):
    """A process killed (SIGKILL) inside a refit's transaction, after the new model file was written: the database
    still holds the old estimates and model, all of one version; a restart marks the job the crash left ``running``
    failed, runs it again, and leaves no job running or queued."""
    css, lin = history
    settings = make_settings(tmp_path)
    app = create_app(settings)
    with TestClient(app) as c:
        cid, token = _camera(c, css, lin)
        v1 = _refit(c, cid, token)["summary"]["version"]
    proc = subprocess.run([sys.executable, "-c", KILL_SCRIPT, settings.resolved_database_url, str(cid), str(tmp_path)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    sessions = make_session_factory(make_engine(settings.resolved_database_url))
    assert _versions(sessions, cid) == {v1}
    assert len(list((tmp_path / "models").glob(f"camera-{cid}.*.json"))) == 2  # the new file, never referenced
    with sessions() as s, s.begin():  # the job row a killed service would have left
        s.add(Job(id="crashed", camera_id=cid, state="running", progress=0.8, heartbeat_at=utcnow()))
        s.add(Job(id="waiting", camera_id=cid, state="queued", progress=0.0))
    app = create_app(settings)
    with TestClient(app) as c:
        jobs = {j: c.get(f"/v1/jobs/{j}", headers=bearer(token)).json() for j in ("crashed", "waiting")}
        assert jobs["crashed"]["state"] == "failed" and jobs["crashed"]["summary"]["interrupted"]
        again = jobs["crashed"]["summary"]["requeued_as"]
        assert c.get(f"/v1/jobs/{again}", headers=bearer(token)).json()["state"] == "done"
        assert jobs["waiting"]["state"] == "done"
        with app.state.sessions() as s:
            left = s.scalars(select(Job).where(Job.state.in_(("running", "queued")))).all()
        assert left == []
        versions = _versions(app.state.sessions, cid)
        assert len(versions) == 1 and versions != {v1}
        (model,) = (tmp_path / "models").glob(f"camera-{cid}.*.json")
        assert model.name == f"camera-{cid}.{versions.pop()}.json"


def test_stale_running_job_recovered_while_other_processes_live(tmp_path, history):
    """With another service process alive (the data dir's lock held shared), a running job is recovered only once
    its heartbeat is older than ``job_stale_seconds``."""
    import fcntl

    css, lin = history
    settings = make_settings(tmp_path, job_stale_seconds=1.0)
    with TestClient(create_app(settings)) as c:
        cid, token = _camera(c, css, lin)
    fd = os.open(tmp_path / "service.lock", os.O_RDWR | os.O_CREAT, 0o600)
    fcntl.flock(fd, fcntl.LOCK_SH)  # "another process"
    try:
        sessions = make_session_factory(make_engine(settings.resolved_database_url))
        with sessions() as s, s.begin():
            s.add(Job(id="fresh", camera_id=cid, state="running", progress=0.5, heartbeat_at=utcnow()))
        app = create_app(settings)
        with TestClient(app) as c:
            assert c.get("/v1/jobs/fresh", headers=bearer(token)).json()["state"] == "running"
            import time

            out = app.state.jobs.recover()
            assert out["failed"] == []

            deadline = time.monotonic() + 120  # the sweeper (every 0.5 s here) recovers it once stale
            job = c.get("/v1/jobs/fresh", headers=bearer(token)).json()
            while job["state"] == "running" and time.monotonic() < deadline:
                time.sleep(0.2)
                job = c.get("/v1/jobs/fresh", headers=bearer(token)).json()
            assert job["state"] == "failed" and job["summary"]["interrupted"], job
            again = job["summary"]["requeued_as"]
            while c.get(f"/v1/jobs/{again}", headers=bearer(token)).json()["state"] != "done":
                assert time.monotonic() < deadline
                time.sleep(0.2)
    finally:
        os.close(fd)


def _tiff_with_late_size(w: int, h: int, unknown: int = 600) -> bytes:
    """A little-endian TIFF whose first IFD lists ``unknown`` private tags before its size tags."""
    entries = [(65000 + (i % 500), 3, 1, 0) for i in range(unknown)]
    entries += [(256, 4, 1, w), (257, 4, 1, h), (258, 3, 1, 16), (277, 3, 1, 3), (273, 4, 1, 8), (279, 4, 1, 16)]
    ifd = struct.pack("<H", len(entries))
    for tag, typ, count, value in entries:
        ifd += struct.pack("<HHI", tag, typ, count) + (struct.pack("<HH", value, 0) if typ == 3 else
                                                       struct.pack("<I", value))
    ifd += struct.pack("<I", 0)
    return b"II*\x00" + struct.pack("<I", 24) + bytes(16) + ifd


def _jpeg_stray_byte(w: int, h: int) -> bytes:
    """A real small JPEG with a stray byte after its first segment and its SOF size rewritten to ``w × h``."""
    data = bytearray(cv2.imencode(".jpg", np.full((16, 16, 3), 128, np.uint8))[1].tobytes())
    seg = int.from_bytes(data[4:6], "big")  # APP0 after SOI
    data[4 + seg : 4 + seg] = b"\x00"  # libjpeg skips it ("extraneous bytes") and decodes on
    i = data.index(b"\xff\xc0")
    data[i + 5 : i + 9] = struct.pack(">HH", h, w)
    return bytes(data)


@pytest.mark.parametrize("name", ["jpeg 12000×12000 after a stray byte", "tiff size after 600 tags",
                                  "16-bit png within the pixel limit"])
def test_images_refused_before_decoding(client, monkeypatch, name):
    import illumon_service.decode as decode

    data = {"jpeg 12000×12000 after a stray byte": _jpeg_stray_byte(12000, 12000),
            "tiff size after 600 tags": _tiff_with_late_size(12000, 12000),
            "16-bit png within the pixel limit": _png(6000, 6000, depth=16)}[name]
    fmt = decode.sniff_format(data)
    assert decode.declared_size(data, fmt) == ((6000, 6000) if "png" in name else (12000, 12000))

    def no_decode(*_a, **_k):  # noqa: ANN202
        raise AssertionError("decoded before the size check")

    monkeypatch.setattr(decode.cv2, "imdecode", no_decode)
    r = client.post("/v1/cameras", json=camera_body(np.ones((61, 3)), grid_regions(2)), headers=admin_headers())
    cid, token = r.json()["id"], r.json()["token"]
    r = client.post(f"/v1/cameras/{cid}/frames", files={"image": ("f", data, "application/octet-stream")},
                    headers=bearer(token))
    assert r.status_code == 413, r.text
    assert "limit" in r.json()["detail"]
    if "png" in name:  # 36 Mpx is within the 50 Mpx limit: the bytes (16-bit RGB: 206 MiB) are not
        assert "MiB" in r.json()["detail"]


def test_stray_byte_jpeg_within_limits_still_decodes():
    from illumon_service.decode import decode_image

    data = bytearray(cv2.imencode(".jpg", np.full((16, 24, 3), 128, np.uint8))[1].tobytes())
    seg = int.from_bytes(data[4:6], "big")
    data[4 + seg : 4 + seg] = b"\x00"
    img, full = decode_image(bytes(data))
    assert img.shape == (16, 24, 3) and full == 255


def test_concurrent_first_frames(client):
    """Frames posted at once to a new camera: every one is stored (the first frame's reference was written through
    a shared temporary file: 3 of 160 answered 500)."""
    r = client.post("/v1/cameras", json=camera_body(np.ones((61, 3)), grid_regions(4)), headers=admin_headers())
    rng = np.random.default_rng(3)
    scene = rng.integers(40, 200, (SIZE[1], SIZE[0], 3), dtype=np.uint8)
    statuses: list[int] = []
    for round_ in range(4):
        r = client.post("/v1/cameras", json=camera_body(np.ones((61, 3)), grid_regions(4)), headers=admin_headers())
        cid, token = r.json()["id"], r.json()["token"]

        def post(k: int, cid: int = cid, token: str = token) -> None:
            img = np.clip(scene.astype(int) + rng.integers(-3, 4, scene.shape), 0, 255).astype(np.uint8)
            png = cv2.imencode(".png", img)[1].tobytes()
            r = client.post(f"/v1/cameras/{cid}/frames", files={"image": ("f.png", png, "image/png")},
                            headers=bearer(token))
            statuses.append(r.status_code)

        threads = [threading.Thread(target=post, args=(k,)) for k in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        frames = client.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json()
        assert len(frames) == 8, round_
        states = [f["registration"]["state"] for f in frames]
        assert states.count("reference") >= 1 and "view_change" not in states, states
    assert statuses == [201] * 32
    leftovers = [p.name for p in Path(client.app.state.settings.data_dir).rglob("*") if "tmp" in p.name
                 or "claim" in p.name]
    assert leftovers == []


def test_frames_before_regions_are_measured_when_confirmed(tmp_path, scene):
    """Issue 26 item 6: frames posted while a camera has no regions keep their originals (at most
    ``pending_max_frames`` per view) and are measured when the regions are confirmed; the refit then estimates
    them. Frames whose original was dropped stay stored with their reason."""
    from svc_helpers import post_image

    with TestClient(create_app(make_settings(tmp_path, pending_max_frames=8))) as c:
        body = camera_body(scene.css, [])
        r = c.post("/v1/cameras", json=body, headers=admin_headers())
        cid, token = r.json()["id"], r.json()["token"]
        ids = []
        for img, t in zip(scene.images, scene.times, strict=True):
            r = post_image(c, cid, token, img, t)
            assert r.status_code == 201 and r.json()["regions"] == {}, r.text
            ids.append(r.json()["frame_id"])
        kept = sorted(int(p.stem) for p in (tmp_path / "pending" / f"camera-{cid}").iterdir())
        assert kept == ids[-8:]
        assert c.get(f"/v1/cameras/{cid}", headers=bearer(token)).json()["not_estimated"] == {"no_regions": len(ids)}
        r = c.put(f"/v1/cameras/{cid}/regions", json={"regions": scene.regions}, headers=bearer(token))
        assert r.status_code == 200, r.text
        assert not list((tmp_path / "pending" / f"camera-{cid}").iterdir())  # measured, then deleted
        frames = {f["frame_id"]: f for f in c.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json()}
        measured = [fid for fid in ids if frames[fid]["regions"]]
        assert measured == ids[-8:]
        assert all(sum(v is not None for v in frames[fid]["regions"].values()) >= 6 for fid in measured)
        job = _refit(c, cid, token)
        assert job["state"] == "done" and job["summary"]["frames"] == 8, job
        cam = c.get(f"/v1/cameras/{cid}", headers=bearer(token)).json()
        assert cam["not_estimated"] == {"no_regions": len(ids) - 8}
        assert cam["warnings"] == job["summary"]["warnings"]
        if cam["warnings"]:
            assert 'id="refit-warnings"' in c.get(f"/cameras/{cid}", headers=admin_headers()).text


def test_on_postgresql(tmp_path, history, pg_url):  # noqa: F811 - the fixture imported above
    """The same guarantees on PostgreSQL: NUL refused (it was a 500 there), a refit switching model and estimates
    together, deletes (rows of every table), recovery of a job a crash left running."""
    css, lin = history
    settings = make_settings(tmp_path, database_url=pg_url)
    app = create_app(settings)
    with TestClient(app) as c:
        body = camera_body(css, grid_regions(lin.shape[1]), name="roof\x00east")
        r = c.post("/v1/cameras", json=body, headers=admin_headers())
        assert r.status_code == 422 and "control character" in str(r.json()["detail"]), r.text
        cid, token = _camera(c, css, lin)
        v1 = _refit(c, cid, token)["summary"]["version"]
        r = c.post(f"/v1/cameras/{cid}/observations", json=_observation(lin, 3), headers=bearer(token))
        assert r.json()["estimate"] is not None and _versions(app.state.sessions, cid) == {v1}
        v2 = _refit(c, cid, token)["summary"]["version"]
        assert _versions(app.state.sessions, cid) == {v2}
        fid = r.json()["frame_id"]
        assert c.delete(f"/v1/cameras/{cid}/frames/{fid}", headers=admin_headers()).json()["deleted"] == {
            "frames": 1, "estimates": 1}
        other, _ = _camera(c, css, lin)
        with app.state.sessions() as s, s.begin():
            s.add(Job(id="orphan", camera_id=other, state="running", progress=0.3, heartbeat_at=utcnow()))
    with TestClient(create_app(settings)) as c:
        job = c.get("/v1/jobs/orphan", headers=admin_headers()).json()
        assert job["state"] == "failed" and job["summary"]["interrupted"]
        assert c.get(f"/v1/jobs/{job['summary']['requeued_as']}", headers=admin_headers()).json()["state"] == "done"
        r = c.delete(f"/v1/cameras/{cid}", headers=admin_headers())
        assert r.status_code == 200 and r.json()["deleted"]["frames"] == N, r.text
        assert [cam["id"] for cam in c.get("/v1/cameras", headers=admin_headers()).json()] == [other]


def test_kept_originals_bounded_in_bytes(tmp_path, scene):
    from svc_helpers import post_image

    budget = int(3.5 * max(len(img) for img in scene.images))
    with TestClient(create_app(make_settings(tmp_path, pending_max_bytes=budget))) as c:
        r = c.post("/v1/cameras", json=camera_body(scene.css, []), headers=admin_headers())
        cid, token = r.json()["id"], r.json()["token"]
        ids = [post_image(c, cid, token, img, t).json()["frame_id"]
               for img, t in zip(scene.images, scene.times, strict=True)]
        kept = sorted((tmp_path / "pending" / f"camera-{cid}").iterdir(), key=lambda p: int(p.stem))
        assert 3 <= len(kept) < len(ids) and [int(p.stem) for p in kept] == ids[-len(kept):]
        assert sum(p.stat().st_size for p in kept) <= budget
        assert len(c.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json()) == len(ids)  # frames all stored


@pytest.mark.parametrize("field,change", [
    ("gamma", {"response": {"encoding": "gamma", "gamma": 1e-300}}),
    ("white_level", {"response": {"encoding": "linear", "white_level": 1e300}}),
    ("matrix", {"response": {"encoding": "srgb", "matrix": [[1e300, 0, 0], [0, 1, 0], [0, 0, 1]]}}),
    ("matrix", {"response": {"encoding": "srgb", "matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1e-7]]}}),
    ("r", {"sensitivities": {"wavelength_nm": list(range(400, 701, 50)), "r": [1e300] * 7, "g": [1.0] * 7,
                             "b": [1.0] * 7}}),
    ("b", {"sensitivities": {"wavelength_nm": list(range(400, 701, 50)), "r": [1.0] * 7, "g": [1.0] * 7,
                             "b": [0.0] * 7}}),
])
def test_registration_numbers_in_range(client, field, change):
    body = {**camera_body(np.ones((61, 3)), grid_regions(2)), **change}
    r = client.post("/v1/cameras", json=body, headers=admin_headers())
    assert r.status_code == 422 and field in str(r.json()["detail"]), r.text
    assert client.get("/v1/cameras", headers=admin_headers()).json() == []


def test_refit_leaves_no_estimate_of_the_previous_model(tmp_path, history):
    """Regions replaced: the old frames keep one region of the new set, too few to estimate. Their estimates of the
    previous model go with the refit (reason ``too_few_regions``), so every estimate comes from the new model."""
    css, lin = history
    app = create_app(make_settings(tmp_path))
    with TestClient(app) as c:
        cid, token = _camera(c, css, lin)
        assert _refit(c, cid, token)["state"] == "done"
        new = [dict(g, id="r0" if i == 0 else f"n{i}") for i, g in enumerate(grid_regions(lin.shape[1]))]
        assert c.put(f"/v1/cameras/{cid}/regions", json={"regions": new}, headers=bearer(token)).status_code == 200
        for f in range(N, N + 6):
            body = _observation(lin, f)
            body["patches"] = {("r0" if k == "r0" else f"n{k[1:]}"): v for k, v in body["patches"].items()}
            assert c.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token)).status_code == 201
        job = _refit(c, cid, token)
        assert job["state"] == "done", job
        assert _versions(app.state.sessions, cid) == {job["summary"]["version"]}
        assert c.get(f"/v1/cameras/{cid}", headers=bearer(token)).json()["not_estimated"] == {"too_few_regions": N}
