"""Issue 17: reference regions an installer can set up — proposals, the regions page, shift tracking, view changes and
per-view regions, on rendered textured scenes (:class:`regions_setup.TexturedScene`, development cameras, surfaces and
daylight; the benchmark scores the held-out ones)."""

from __future__ import annotations

from datetime import timedelta

import cv2
import numpy as np
import pytest
import regions_setup as rs
from illumon_service.api.routes.pages import HEADERS
from illumon_service.proposals import KEEP_RECENT
from svc_helpers import T0, admin_headers, bearer, need_data

NO_REGIONS = {"name": "installer camera", "regions": [], "response": {"encoding": "srgb", "white_level": 255}}


@pytest.fixture(scope="module")
def tex():
    """A development scene: 640 × 480, ten textured surfaces among textured neighbours, sky, foliage, passers-by."""
    need_data()
    return rs.TexturedScene("Nikon_D3X", "dev", 5, 60)


def _post(client, cam: int, img: np.ndarray, k: int, token: str | None = None, view: str | None = None):
    data = {"taken_at": (T0 + timedelta(minutes=50 * k)).isoformat()}
    if view is not None:
        data["view"] = view
    return client.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", rs.png(img), "image/png")}, data=data,
                       headers=bearer(token) if token else admin_headers())


def _register(client, regions: list[dict] | None = None, css: np.ndarray | None = None) -> tuple[int, str]:
    body = dict(NO_REGIONS, regions=regions or [])
    if css is not None:
        wl = list(range(400, 701, 5))
        body["sensitivities"] = {"wavelength_nm": wl, "r": css[:, 0].tolist(), "g": css[:, 1].tolist(),
                                 "b": css[:, 2].tolist()}
    r = client.post("/v1/cameras", json=body, headers=admin_headers())
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["token"]


def _alerts(client, cam: int) -> list[str]:
    return [a["kind"] for a in client.get(f"/v1/cameras/{cam}", headers=admin_headers()).json()["alerts"]]


def test_proposals_from_stored_frames(client, tex) -> None:
    cam, token = _register(client)
    for k in range(4):
        r = _post(client, cam, tex.frame(k)[0], k, token)
        assert r.status_code == 201, r.text
        j = r.json()
        assert j["regions"] == {} and j["estimate"] is None
        assert j["registration"]["state"] == ("reference" if k == 0 else "ok")
        assert f"/cameras/{cam}/regions" in j["warnings"][0]
    assert "no_regions" in _alerts(client, cam)
    r = client.get(f"/v1/cameras/{cam}/region-proposals", headers=bearer(token))
    assert r.status_code == 409 and "at least 5" in r.json()["detail"]
    for k in range(4, 16):
        assert _post(client, cam, tex.frame(k)[0], k, token).status_code == 201
    r = client.get(f"/v1/cameras/{cam}/region-proposals?count=12", headers=bearer(token))
    assert r.status_code == 200, r.text
    out = r.json()
    assert 12 <= out["frames_used"] <= 16 and out["hours_covered"] >= 10  # thumbnails: 8 latest + one per hour
    props = out["proposals"]
    assert 8 <= len(props) <= 12
    got = rs.coverage(props, tex.surfaces, tex.moving_mask())
    assert got["covered"] >= 8 and got["on_moving"] == 0, got
    for i, p in enumerate(props):
        assert 0 <= p["x"] and p["x"] + p["width"] <= rs.W and 0 <= p["y"] and p["y"] + p["height"] <= rs.H
        assert 0 < p["score"] <= 1 and {"change", "drift", "texture", "clipped", "dark"} <= set(p["reasons"])
        for q in props[i + 1 :]:  # no overlaps
            assert (p["x"] + p["width"] <= q["x"] or q["x"] + q["width"] <= p["x"]
                    or p["y"] + p["height"] <= q["y"] or q["y"] + q["height"] <= p["y"])
    # bad input
    assert client.get(f"/v1/cameras/{cam}/region-proposals?count=0", headers=admin_headers()).status_code == 422
    assert client.get(f"/v1/cameras/{cam}/region-proposals?view=a%20b", headers=admin_headers()).status_code == 422
    other, other_token = _register(client)
    assert client.get(f"/v1/cameras/{cam}/region-proposals", headers=bearer(other_token)).status_code == 404
    assert client.get(f"/v1/cameras/{other}/region-proposals", headers=bearer(other_token)).status_code == 409


def test_thumbnails_kept_per_hour_and_recent(client, tex, tmp_path) -> None:
    cam, token = _register(client)
    img = tex.frame(0)[0]
    for k in range(30):  # every 50 minutes: 25 hours of the day, 30 frames
        assert _post(client, cam, img, k, token).status_code == 201
    kept = sorted((tmp_path / "thumbs" / f"camera-{cam}").glob("[0-9]*.png"))
    hours = {(T0 + timedelta(minutes=50 * k)).hour for k in range(30 - KEEP_RECENT)}
    assert KEEP_RECENT < len(kept) <= KEEP_RECENT + len(hours)
    assert len(kept) < 30
    # frames minutes apart: one thumbnail per ten minutes of frames
    for m in (1, 2, 3):
        data = {"taken_at": (T0 + timedelta(minutes=50 * 29 + m)).isoformat()}
        r = client.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", rs.png(img), "image/png")}, data=data,
                        headers=bearer(token))
        assert r.status_code == 201 and r.json()["registration"]["state"] == "ok"
    assert len(list((tmp_path / "thumbs" / f"camera-{cam}").glob("[0-9]*.png"))) == len(kept)


def _chroma(v: list[float]) -> np.ndarray:
    return np.log(np.array(v[::2]) / v[1])


def test_regions_follow_shifts_and_a_jump_is_a_view_change(client, tex) -> None:
    regions = [{"id": f"s{i}", "x": x + 4, "y": y + 4, "width": w - 8, "height": h - 8}
               for i, (x, y, w, h) in enumerate(tex.surfaces)]
    cam, token = _register(client, regions)
    r = _post(client, cam, tex.frame(0)[0], 0, token)
    assert r.json()["registration"]["state"] == "reference"
    ref = r.json()["regions"]
    for k, (dx, dy) in enumerate([(13, -9), (-20, 20), (7, 18)], start=1):
        r = _post(client, cam, tex.frame(0, dx, dy)[0], k, token)
        j = r.json()
        assert j["registration"]["state"] == "ok"
        assert j["registration"]["shift"] == pytest.approx([dx, dy], abs=1.0)
        assert sum(v is not None for v in j["regions"].values()) >= 8  # a shift may take a region out of the image
        # the same surfaces: the same chromaticity (exposure differs; dark ones carry 8-bit quantisation)
        d = [np.abs(_chroma(v) - _chroma(ref[rid])).max() for rid, v in j["regions"].items() if v is not None]
        assert max(d) < 0.05 and np.median(d) < 0.01, d
    r = _post(client, cam, tex.frame(0, 100, 0)[0], 9, token)
    j = r.json()
    assert r.status_code == 201 and j["registration"]["state"] == "view_change" and j["regions"] == {}
    assert j["estimate"] is None and "view change" in j["warnings"][0]
    assert "view_change" in _alerts(client, cam)
    page = client.get(f"/cameras/{cam}", headers=admin_headers())
    assert 'data-kind="view_change"' in page.text and f'href="/cameras/{cam}/regions"' in page.text
    frames = client.get(f"/v1/cameras/{cam}/frames", headers=admin_headers()).json()
    assert frames[-1]["registration"]["state"] == "view_change"
    r = _post(client, cam, tex.frame(0, 2, 1)[0], 10, token)
    assert r.json()["registration"]["state"] == "ok" and "view_change" not in _alerts(client, cam)
    # the camera was moved for good: the latest frame becomes the reference, regions redrawn on it
    assert _post(client, cam, tex.frame(0, 100, 0)[0], 11, token).json()["registration"]["state"] == "view_change"
    moved = [dict(r, x=r["x"] + 100) for r in regions if r["x"] + r["width"] + 100 <= rs.W]
    r = client.put(f"/v1/cameras/{cam}/regions?reference=latest", json={"regions": moved}, headers=bearer(token))
    assert r.status_code == 200, r.text
    j = _post(client, cam, tex.frame(0, 103, -2)[0], 12, token).json()
    assert j["registration"]["state"] == "ok" and j["registration"]["shift"] == pytest.approx([3, -2], abs=1.0)
    assert all(v is not None for v in j["regions"].values())


def test_views_have_their_own_regions_reference_and_model(client, tex) -> None:
    regions = [{"id": f"s{i}", "x": x + 4, "y": y + 4, "width": w - 8, "height": h - 8}
               for i, (x, y, w, h) in enumerate(tex.surfaces)]
    cam, token = _register(client, regions, css=tex.css)
    assert _post(client, cam, tex.frame(0)[0], 0, token, view="a b").status_code == 422
    # preset "east": the scene seen 100 px further left; its own reference frame and regions
    r = _post(client, cam, tex.frame(0, -100, 0)[0], 0, token, view="east")
    assert r.json()["registration"]["state"] == "reference" and r.json()["regions"] == {}
    east = [dict(r, id=f"e{i}", x=r["x"] - 100) for i, r in enumerate(regions) if r["x"] >= 100]
    r = client.put(f"/v1/cameras/{cam}/regions?view=east", json={"regions": east}, headers=bearer(token))
    assert r.status_code == 200 and r.json()["views"] == {"east": east} and r.json()["regions"] == regions
    for k in range(12):
        for view, dx in ((None, 0), ("east", -100)):
            j = _post(client, cam, tex.frame(k, dx + (k % 3) - 1, 0)[0], k + 1, token, view=view).json()
            assert j["registration"]["state"] == ("reference" if k == 0 and view is None else "ok"), j
            assert set(j["regions"]) == {r["id"] for r in (regions if view is None else east)}
    assert "regions_missing" not in _alerts(client, cam)  # another preset's frames lack the default view's regions
    r = client.post(f"/v1/cameras/{cam}/refit", headers=bearer(token))
    assert r.status_code == 202
    job = client.get(f"/v1/jobs/{r.json()['job_id']}", headers=bearer(token)).json()
    assert job["state"] == "done", job
    est = client.get(f"/v1/cameras/{cam}/estimates", headers=bearer(token)).json()
    frames = client.get(f"/v1/cameras/{cam}/frames", headers=bearer(token)).json()
    measured = {f["frame_id"] for f in frames if f["regions"]}
    # 24, and east's first frame: posted before its regions, kept and measured once they were confirmed
    assert {e["frame_id"] for e in est} == measured and len(measured) == 25
    # a new frame of each view is estimated at ingest with that view's model
    for view, dx in ((None, 0), ("east", -100)):
        j = _post(client, cam, tex.frame(20, dx, 0)[0], 30, token, view=view).json()
        assert j["estimate"] is not None


def test_regions_page_confirms_proposals(client, tex) -> None:
    cam, token = _register(client)
    for k in range(6):
        assert _post(client, cam, tex.frame(k)[0], k, token).status_code == 201
    page = client.get(f"/cameras/{cam}/regions", headers=admin_headers())
    assert page.status_code == 200
    assert page.headers["content-security-policy"] == HEADERS["Content-Security-Policy"]
    assert "<script" not in page.text and 'id="regions-svg"' in page.text
    n = page.text.count('<g class="proposal"')
    assert n >= 5
    jpg = client.get(f"/cameras/{cam}/latest.jpg", headers=bearer(token))
    assert jpg.status_code == 200 and jpg.headers["content-type"] == "image/jpeg"
    assert cv2.imdecode(np.frombuffer(jpg.content, np.uint8), cv2.IMREAD_COLOR).shape == (240, 320, 3)
    props = client.get(f"/v1/cameras/{cam}/region-proposals", headers=admin_headers()).json()["proposals"]
    form = {"n_regions": "0", "n_proposals": str(len(props))}
    for i, p in enumerate(props):
        form.update({f"p{i}_id": f"p{i + 1}", f"p{i}_x": str(p["x"]), f"p{i}_y": str(p["y"]),
                     f"p{i}_w": str(p["width"]), f"p{i}_h": str(p["height"])})
    form.update({"p0_keep": "1", "p0_id": "wall", "p2_keep": "1", "new_id": "extra", "new_x": "10", "new_y": "100",
                 "new_w": "20", "new_h": "30"})
    r = client.post(f"/cameras/{cam}/regions", data=form, headers=admin_headers(), follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == f"/cameras/{cam}/regions?saved=1"
    want = [{"id": "wall", **{k: props[0][k] for k in ("x", "y", "width", "height")}},
            {"id": "p3", **{k: props[2][k] for k in ("x", "y", "width", "height")}},
            {"id": "extra", "x": 10, "y": 100, "width": 20, "height": 30}]
    assert client.get(f"/v1/cameras/{cam}", headers=admin_headers()).json()["regions"] == want
    # refused: another site's form, a malformed region; nothing changes
    r = client.post(f"/cameras/{cam}/regions", data=form, headers={**admin_headers(), "Origin": "http://evil.example"})
    assert r.status_code == 403
    bad = {**form, "new_w": "0"}
    r = client.post(f"/cameras/{cam}/regions", data=bad, headers=admin_headers())
    assert r.status_code == 422 and "Not saved" in r.text
    assert client.get(f"/v1/cameras/{cam}", headers=admin_headers()).json()["regions"] == want
    page = client.get(f"/cameras/{cam}/regions?saved=1", headers=admin_headers())
    assert 'id="saved"' in page.text and page.text.count('<g class="region"') == 3
    # another camera's token sees neither the page nor the frame
    _, other_token = _register(client)
    assert client.get(f"/cameras/{cam}/regions", headers=bearer(other_token)).status_code == 404
    assert client.get(f"/cameras/{cam}/latest.jpg", headers=bearer(other_token)).status_code == 404
