"""/frames and /observations: ingest, robust region means, bad uploads."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from illumon_service.app import create_app
from svc_helpers import SIZE, bearer, camera_body, encode_png, grid_regions, make_settings, post_image, register


def _css() -> np.ndarray:
    wl = np.arange(400, 701, 5)
    return np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])


@pytest.fixture
def cam(client):
    return register(client, _css(), grid_regions())


def _image(value=(0.2, 0.3, 0.4)) -> bytes:
    img = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    img[:] = (np.asarray(value) * 255).astype(np.uint8)
    return encode_png(img)


def test_post_frame(client, cam):
    cid, token = cam
    r = post_image(client, cid, token, _image(), None)
    assert r.status_code == 201, r.text
    out = r.json()
    assert {"frame_id", "taken_at", "estimate"} <= set(out)
    assert out["estimate"] is None
    assert len(client.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json()) == 1


def test_jpeg_and_tiff_16bit(client, cam):
    cid, token = cam
    img = np.full((SIZE[1], SIZE[0], 3), (120, 100, 80), np.uint8)
    assert post_image(client, cid, token, encode_png(img, ".jpg"), content_type="image/jpeg").status_code == 201
    img16 = np.full((SIZE[1], SIZE[0], 3), (30000, 25000, 20000), np.uint16)
    r = post_image(client, cid, token, encode_png(img16, ".tiff"), content_type="image/tiff")
    assert r.status_code == 201, r.text
    v = r.json()["regions"]["r0"]
    assert v is not None and all(0.0 < x < 1.0 for x in v)


@pytest.mark.parametrize(
    ("data", "ctype", "status", "word"),
    [
        (b"", "image/png", 400, "empty"),
        (b"\x89PNG\r\n\x1a\n" + b"garbage" * 20, "image/png", 422, "decoded"),
        (b"GIF89a" + b"\0" * 50, "image/gif", 415, "content type"),
        (b"hello world, not an image", "application/octet-stream", 415, "PNG, JPEG or TIFF"),
    ],
)
def test_bad_uploads(client, cam, data, ctype, status, word):
    cid, token = cam
    r = post_image(client, cid, token, data, content_type=ctype)
    assert r.status_code == status, r.text
    assert word in r.json()["detail"]


def test_wrong_request_content_type(client, cam):
    cid, token = cam
    headers = {**bearer(token), "content-type": "image/png"}
    r = client.post(f"/v1/cameras/{cid}/frames", content=_image(), headers=headers)
    assert r.status_code == 415
    assert "multipart" in r.json()["detail"]


def test_oversized(tmp_path):
    with TestClient(create_app(make_settings(tmp_path, max_upload_bytes=1000))) as c:
        cid, token = register(c, _css(), grid_regions())
        noisy = np.random.default_rng(0).integers(0, 255, (SIZE[1], SIZE[0], 3), dtype=np.uint8)
        r = post_image(c, cid, token, encode_png(noisy))
        assert r.status_code == 413
        assert "limit" in r.json()["detail"]


def test_region_outside_image(client):
    """A region accepted before any image size was known (registration) never makes frames unusable: the frame is
    stored with that region missing and a warning; once the size is known, PUT …/regions refuses such a region."""
    regions = grid_regions() + [{"id": "far", "x": 1000, "y": 10, "width": 20, "height": 20}]
    cid, token = register(client, _css(), regions)
    r = post_image(client, cid, token, _image())
    assert r.status_code == 201, r.text
    j = r.json()
    assert j["regions"]["far"] is None and j["usable_regions"] == len(regions) - 1
    assert any("far" in w and "outside" in w for w in j["warnings"])
    r = client.put(f"/v1/cameras/{cid}/regions", json={"regions": regions}, headers=bearer(token))
    assert r.status_code == 422 and "'far'" in r.json()["detail"] and "outside" in r.json()["detail"]
    r = client.put(f"/v1/cameras/{cid}/regions", json={"regions": grid_regions()}, headers=bearer(token))
    assert r.status_code == 200
    assert post_image(client, cid, token, _image()).json()["usable_regions"] == len(grid_regions())


def test_bad_taken_at(client, cam):
    cid, token = cam
    r = client.post(f"/v1/cameras/{cid}/frames", files={"image": ("f.png", _image(), "image/png")},
                    data={"taken_at": "yesterday"}, headers=bearer(token))
    assert r.status_code == 422
    assert "ISO 8601" in r.json()["detail"]


def test_observations(client, cam):
    cid, token = cam
    body = {"taken_at": "2025-06-01T12:00:00Z", "patches": {"r0": [0.1, 0.2, 0.3], "r1": None}}
    r = client.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token))
    assert r.status_code == 201, r.text
    assert r.json()["taken_at"].startswith("2025-06-01T12:00:00")
    bad = json.dumps({"patches": {"r0": [0.1, 0.2, 0.3]}}).replace("0.2", "NaN")
    r = client.post(f"/v1/cameras/{cid}/observations", content=bad,
                    headers={**bearer(token), "content-type": "application/json"})
    assert r.status_code == 422
    r = client.post(f"/v1/cameras/{cid}/observations", json={"patches": {"r0": [0.1, -0.2, 0.3]}},
                    headers=bearer(token))
    assert r.status_code == 422
    r = client.post(f"/v1/cameras/{cid}/observations", json={"patches": {"zz": [0.1, 0.2, 0.3]}},
                    headers=bearer(token))
    assert r.status_code == 422 and "zz" in r.json()["detail"]


def test_keep_images(tmp_path):
    with TestClient(create_app(make_settings(tmp_path, keep_images=True))) as c:
        cid, token = register(c, _css(), grid_regions())
        assert post_image(c, cid, token, _image()).status_code == 201
        assert list((tmp_path / "images").rglob("*.png"))


def test_camera_body_roundtrip():
    body = camera_body(_css(), grid_regions())
    assert len(body["sensitivities"]["wavelength_nm"]) == 61


def test_too_many_pixels(tmp_path):
    with TestClient(create_app(make_settings(tmp_path, max_image_pixels=1000))) as c:
        cid, token = register(c, _css(), grid_regions())
        r = post_image(c, cid, token, _image())
        assert r.status_code == 413 and "pixels" in r.json()["detail"]


def test_reduced_jpeg_decode_setting(tmp_path):
    """ILLUMON_JPEG_MAX_REDUCTION: a JPEG whose regions are large enough is decoded at 1/2 size (counted in /metrics),
    with region means close to the full decode's; regions are still checked against the full-resolution size."""
    rng = np.random.default_rng(2)
    regions = grid_regions(4, size=70)
    img = np.empty((SIZE[1], SIZE[0] + 1, 3), np.uint8)  # odd width: the half-size decode is 161 pixels wide
    img[:] = (90, 140, 60)
    img = np.clip(img + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8)
    jpeg = encode_png(img, ".jpg")
    values = {}
    for reduction in (1, 8):
        with TestClient(create_app(make_settings(tmp_path / str(reduction), jpeg_max_reduction=reduction))) as c:
            cid, token = register(c, _css(), regions)
            r = post_image(c, cid, token, jpeg, content_type="image/jpeg")
            assert r.status_code == 201, r.text
            values[reduction] = r.json()["regions"]
            scale = "1/1" if reduction == 1 else "1/2"  # 70-pixel regions: 35 decoded pixels at 1/2, 17 at 1/4
            assert f'illumon_ingest_decodes_total{{scale="{scale}"}} 1' in c.get("/metrics").text
            frames = c.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json()
            assert (frames[0]["width"], frames[0]["height"]) == (SIZE[0] + 1, SIZE[1])
            outside = [{"id": "edge", "x": SIZE[0] + 1 - 69, "y": 0, "width": 70, "height": 70}]
            cid2, token2 = register(c, _css(), outside)  # one pixel beyond the right edge (inside the decoded 161)
            r = post_image(c, cid2, token2, jpeg, content_type="image/jpeg")
            assert r.status_code == 422 and "inside the 321×240 image" in r.json()["detail"], r.text
    for key, value in values[1].items():
        np.testing.assert_allclose(values[8][key], value, rtol=0.01)  # ~0.3 %: codes averaged before linearising


def _grey_upload(kind: str) -> tuple[bytes, str]:
    """A grey frame: a single-channel PNG or JPEG, or a grey image saved as three identical channels."""
    rng = np.random.default_rng(3)
    grey = np.clip(100 + 20 * rng.standard_normal((SIZE[1], SIZE[0])), 0, 255).astype(np.uint8)
    if kind == "rgb":
        return encode_png(np.repeat(grey[:, :, None], 3, axis=2)), "image/png"
    ok, buf = cv2.imencode(f".{kind}", grey)  # one channel
    assert ok
    return buf.tobytes(), f"image/{kind}"


@pytest.mark.parametrize("kind", ["png", "jpeg", "rgb"])
def test_grey_frame_refused(client, cam, kind):
    """Issue 19: a grey image was stored with a confident estimate; it is refused (422, why), nothing stored."""
    cid, token = cam
    data, ctype = _grey_upload(kind)
    r = post_image(client, cid, token, data, content_type=ctype)
    assert r.status_code == 422, r.text
    assert "grey" in r.json()["detail"] and "RGB" in r.json()["detail"]
    assert client.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json() == []
    assert post_image(client, cid, token, _image(), None).status_code == 201  # a colour frame still goes in


def test_observation_with_every_region_null_refused(client, cam):
    """Issue 19: an observation with every region null was stored (201, a frame with no data)."""
    cid, token = cam
    body = {"taken_at": "2025-06-01T12:00:00Z", "patches": {"r0": None, "r1": None}}
    r = client.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token))
    assert r.status_code == 422
    assert "every region is null" in r.json()["detail"]
    assert client.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json() == []
    body["patches"]["r0"] = [0.1, 0.2, 0.3]
    r = client.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token))
    assert r.status_code == 201 and r.json()["usable_regions"] == 1
    assert "only one region" in r.json()["warnings"][0]


def test_frame_with_nothing_usable_says_so(client, cam):
    """A frame whose every region is clipped is stored (it was taken) but the answer says nothing was usable."""
    cid, token = cam
    img = np.full((SIZE[1], SIZE[0], 3), (255, 250, 255), np.uint8)
    r = post_image(client, cid, token, encode_png(img), None)
    assert r.status_code == 201, r.text
    out = r.json()
    assert out["usable_regions"] == 0 and all(v is None for v in out["regions"].values())
    assert "no region was usable" in out["warnings"][0]
    good = post_image(client, cid, token, _image(), None).json()
    assert good["usable_regions"] == len(grid_regions()) and good["warnings"] == []


def test_applied_gains_and_exposure_stored(client, cam):
    """Issue 15: a frame's applied white-balance gains and exposure (form fields) are stored with it and shown."""
    cid, token = cam
    r = client.post(f"/v1/cameras/{cid}/frames", files={"image": ("f.png", _image(), "image/png")},
                    data={"applied_gains": "1.9, 1, 1.4", "exposure": "0.5"}, headers=bearer(token))
    assert r.status_code == 201, r.text
    assert r.json()["applied_gains"] == [1.9, 1.0, 1.4] and r.json()["exposure"] == 0.5
    (f,) = client.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json()
    assert f["applied_gains"] == [1.9, 1.0, 1.4] and f["exposure"] == 0.5
    body = {"patches": {"r0": [0.1, 0.2, 0.3]}, "applied_gains": [1, 2, 0], "exposure": 1}
    assert client.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token)).status_code == 422


def test_old_database_gains_columns_added(tmp_path):
    """A database of the previous version (frames without applied_gains / exposure) is upgraded in place at start."""
    import sqlite3

    db = tmp_path / "illumon.sqlite3"
    with TestClient(create_app(make_settings(tmp_path))):
        pass
    con = sqlite3.connect(db)
    con.execute("ALTER TABLE frames DROP COLUMN applied_gains")
    con.execute("ALTER TABLE frames DROP COLUMN exposure")
    con.commit()
    con.close()
    with TestClient(create_app(make_settings(tmp_path))) as c:
        cid, token = register(c, _css(), grid_regions())
        r = c.post(f"/v1/cameras/{cid}/frames", files={"image": ("f.png", _image(), "image/png")},
                   data={"applied_gains": "1.5,1,1.2"}, headers=bearer(token))
        assert r.status_code == 201, r.text
    cols = {row[1] for row in sqlite3.connect(db).execute("PRAGMA table_info(frames)")}
    assert {"applied_gains", "exposure"} <= cols


def test_region_standard_errors_stored(tmp_path):
    """Issue 16: each region's standard error (pixel spread over √pixels, linear light) is measured at ingest and
    stored with the frame; client-measured means may carry theirs (``sd``), for known regions only."""
    import sqlite3

    rng = np.random.default_rng(2)
    regions = grid_regions()
    with TestClient(create_app(make_settings(tmp_path))) as c:
        cid, token = register(c, _css(), regions, encoding="linear")
        flat = np.broadcast_to([0.3, 0.4, 0.5], (SIZE[1], SIZE[0], 3))  # not grey: a grey frame is refused
        for sigma in (0.0, 0.02):
            img = np.clip(flat + sigma * rng.standard_normal(flat.shape), 0, 1)
            assert post_image(c, cid, token, encode_png((img * 255).round().astype(np.uint8))).status_code == 201
        body = {"patches": {"r0": [0.1, 0.2, 0.3], "r1": None}, "sd": {"r0": [0.001, 0.002, 0.003]}}
        assert c.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token)).status_code == 201
        body["sd"] = {"r5": [0.1, 0.1, 0.1]}  # a known region without a value here
        r = c.post(f"/v1/cameras/{cid}/observations", json=body, headers=bearer(token))
        assert r.status_code == 422 and "r5" in r.json()["detail"]
    rows = sqlite3.connect(tmp_path / "illumon.sqlite3").execute("SELECT patch_sd FROM frames ORDER BY id").fetchall()
    sds = [json.loads(row[0]) for row in rows]
    assert len(sds) == 3
    n = regions[0]["width"] * regions[0]["height"]
    assert max(max(v) for v in sds[0].values()) < 1e-6  # no spread, no error
    noisy = np.array([v for v in sds[1].values()])
    np.testing.assert_allclose(noisy, 0.02 / np.sqrt(n), rtol=0.15)  # σ/√n, rounding to 8 bits adds a little
    assert sds[2] == {"r0": [0.001, 0.002, 0.003]}


@pytest.mark.parametrize("mode", ["RGB", "RGBA"])
def test_decode_image_returns_rgb_in_rgb_order(mode):
    """Pixels written by Pillow (RGB order in the file, independent of OpenCV's BGR convention) come back as RGB."""
    import io

    from illumon_service.decode import decode_image
    from PIL import Image

    rgb = np.zeros((8, 12, 3), np.uint8)
    rgb[:, :4] = (200, 30, 10)  # red
    rgb[:, 4:8] = (10, 180, 40)  # green
    rgb[:, 8:] = (20, 40, 220)  # blue
    img = Image.fromarray(rgb)
    if mode == "RGBA":
        img.putalpha(255)
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    out, full = decode_image(buf.getvalue())
    assert full == 255.0
    np.testing.assert_array_equal(out, rgb)
