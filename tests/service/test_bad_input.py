"""Bad input and security (issue 9): every malformed upload or body is a 4xx with a clear ``detail`` and loses nothing;
a camera token reaches only its own camera; tokens are stored hashed."""

from __future__ import annotations

import json
import struct
import zlib

import cv2
import numpy as np
import pytest
from svc_helpers import SIZE, admin_headers, bearer, camera_body, encode_png, grid_regions, post_image, register


def _css() -> np.ndarray:
    wl = np.arange(400, 701, 5)
    return np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])


def _png_bomb(w: int, h: int) -> bytes:
    """A tiny PNG whose header claims ``w × h`` pixels (an all-zero stream would inflate to w·h·3 bytes)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(1 << 16))) + chunk(b"IEND", b"")


def _jpeg_bomb(w: int, h: int) -> bytes:
    """A real small JPEG with its SOF dimensions rewritten to ``w × h``."""
    data = bytearray(cv2.imencode(".jpg", np.zeros((16, 16, 3), np.uint8))[1].tobytes())
    i = data.index(b"\xff\xc0")
    data[i + 5 : i + 9] = struct.pack(">HH", h, w)
    return bytes(data)


def _tiff_bomb(w: int, h: int) -> bytes:
    """A small TIFF with its ImageWidth/ImageLength tags rewritten."""
    data = bytearray(cv2.imencode(".tif", np.zeros((16, 16, 3), np.uint8))[1].tobytes())
    off = int.from_bytes(data[4:8], "little")
    for k in range(int.from_bytes(data[off : off + 2], "little")):
        e = off + 2 + 12 * k
        tag, typ = int.from_bytes(data[e : e + 2], "little"), int.from_bytes(data[e + 2 : e + 4], "little")
        if tag in (256, 257):
            v = w if tag == 256 else h
            data[e + 2 : e + 12] = struct.pack("<HII", 4, 1, v) if typ == 4 else struct.pack("<HII", 4, 1, v)
    return bytes(data)


def _image() -> bytes:
    return encode_png(np.full((SIZE[1], SIZE[0], 3), (120, 110, 100), np.uint8))  # colour: grey frames are refused


GOOD = _image()
BAD_UPLOADS = {
    "zero bytes": (b"", "image/png", 400, "empty"),
    "corrupt png": (b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4, "image/png", 422, "decoded"),
    "truncated png": (GOOD[: len(GOOD) // 2], "image/png", 422, "decoded"),
    "truncated jpeg": (cv2.imencode(".jpg", np.full((240, 320, 3), 99, np.uint8))[1].tobytes()[:300], "image/jpeg",
                       422, "decoded"),
    "png bomb": (_png_bomb(100_000, 100_000), "image/png", 413, "pixels"),
    "jpeg bomb": (_jpeg_bomb(60_000, 60_000), "image/jpeg", 413, "pixels"),
    "tiff bomb": (_tiff_bomb(90_000, 90_000), "image/tiff", 413, "pixels"),
    "gif": (b"GIF89a" + bytes(64), "image/gif", 415, "content type"),
    "gif as png": (b"GIF89a" + bytes(64), "image/png", 415, "PNG, JPEG or TIFF"),
    "bmp": (cv2.imencode(".bmp", np.zeros((8, 8, 3), np.uint8))[1].tobytes(), "application/octet-stream", 415, "PNG"),
    "text": (b"hello, world", "text/plain", 415, "content type"),
    "float tiff": (cv2.imencode(".tif", np.zeros((240, 320, 3), np.float32))[1].tobytes(), "image/tiff", 422, "8- or 16-bit"),
    "1×1 png": (encode_png(np.full((1, 1, 3), (10, 20, 30), np.uint8)), "image/png", 422, "inside the 1×1 image"),
}


@pytest.fixture
def cam(client):
    """A camera with one stored frame."""
    cid, token = register(client, _css(), grid_regions())
    r = post_image(client, cid, token, GOOD, taken_at=None)
    assert r.status_code == 201
    return cid, token, r.json()["frame_id"]


def _frames(client, cid: int, token: str) -> list[int]:
    return [f["frame_id"] for f in client.get(f"/v1/cameras/{cid}/frames", headers=bearer(token)).json()]


@pytest.mark.parametrize("name", list(BAD_UPLOADS))
def test_bad_images_rejected_nothing_lost(client, cam, name):
    cid, token, fid = cam
    data, ctype, status, word = BAD_UPLOADS[name]
    r = post_image(client, cid, token, data, content_type=ctype)
    assert r.status_code == status, (name, r.status_code, r.text)
    assert word in r.json()["detail"], r.json()
    assert _frames(client, cid, token) == [fid]


BAD_JSON = [
    ('{"patches": {"r0": [0.1, NaN, 0.3]}}', "NaN"),
    ('{"patches": {"r0": [0.1, Infinity, 0.3]}}', "infinite"),
    ('{"patches": {"r0": [0.1, -Infinity, 0.3]}}', "-infinite"),
    ('{"patches": {"r0": [0.1, -0.2, 0.3]}}', "negative"),
    ('{"patches": {"r0": [0.1, 0.3]}}', "two values"),
    ('{"patches": {"r0": ["a", 0.2, 0.3]}}', "text"),
    ('{"patches": {}}', "no patches"),
    ('{"patches": {"r0": [0.1, 0.2, 0.3]}, "white_level": 0}', "white level 0"),
    ('{"patches": {"r0": [0.1, 0.2, 0.3]}, "taken_at": "yesterday"}', "bad time"),
    ('{"patches": {"r0": [0.1, 0.2, 0.3]}, "extra": 1}', "unknown field"),
    ('{"patches": {"r0": [1e400, 0.2, 0.3]}}', "overflow"),
    ("[1, 2, 3]", "not an object"),
    ("{", "truncated"),
    ("", "empty"),
]


@pytest.mark.parametrize(("body", "what"), BAD_JSON, ids=[w for _, w in BAD_JSON])
def test_bad_observations_rejected(client, cam, body, what):
    cid, token, fid = cam
    r = client.post(f"/v1/cameras/{cid}/observations", content=body,
                    headers={**bearer(token), "content-type": "application/json"})
    assert r.status_code == 422, (what, r.status_code, r.text)
    assert r.json()["detail"]
    assert _frames(client, cid, token) == [fid]


def test_bad_camera_bodies(client):
    good = camera_body(_css(), grid_regions())
    cases = []
    for key, value in (("x", -1), ("y", 10**30), ("width", 0), ("height", -5), ("id", "")):
        b = json.loads(json.dumps(good))
        b["regions"][0][key] = value
        cases.append((key, b))
    b = json.loads(json.dumps(good))
    b["response"] = {"encoding": "log"}
    cases.append(("encoding", b))
    b = json.loads(json.dumps(good))
    b["response"] = {"encoding": "srgb", "black_level": 100, "white_level": 50}
    cases.append(("levels", b))
    b = json.loads(json.dumps(good))
    b["sensitivities"]["g"] = [0.0] * len(b["sensitivities"]["g"])
    cases.append(("zero channel", b))
    for what, body in cases:
        r = client.post("/v1/cameras", json=body, headers=admin_headers())
        assert r.status_code == 422, (what, r.text)
        assert r.json()["detail"]


def test_region_outside_image_and_huge_query_values(client, cam):
    cid, token, fid = cam
    r = client.put(f"/v1/cameras/{cid}/regions", json={"regions": [{"id": "far", "x": 5000, "y": 0, "width": 9,
                                                                      "height": 9}]}, headers=bearer(token))
    assert r.status_code == 422 and "'far'" in r.json()["detail"] and "outside" in r.json()["detail"]
    for path in ("/frames", "/estimates"):  # outside 1…100000: refused like any bad parameter (issue 19), not clamped
        for limit in (10**30, 100_001, 0, -5):
            r = client.get(f"/v1/cameras/{cid}{path}", params={"limit": limit}, headers=bearer(token))
            assert r.status_code == 422, (path, limit, r.text)
            assert r.json()["detail"][0]["loc"] == ["query", "limit"]
        assert client.get(f"/v1/cameras/{cid}{path}", params={"limit": 1}, headers=bearer(token)).status_code == 200
    for path, params in (("/estimates", {"since": "2025-13-01"}), ("/frames", {"since": "never"}),
                         ("/wb-gains", {"v4l2_unity": 0}), ("/illuminant", {"at": "13/13/13"})):
        r = client.get(f"/v1/cameras/{cid}{path}", params=params, headers=bearer(token))
        assert r.status_code == 422, (path, r.text)
    assert client.get(f"/v1/cameras/{10**30}", headers=bearer(token)).status_code in (404, 422)
    assert _frames(client, cid, token) == [fid]


def test_camera_token_scope_and_hashing(client, tmp_path):
    a_id, a_tok = register(client, _css(), grid_regions())
    b_id, b_tok = register(client, _css(), grid_regions())
    assert post_image(client, a_id, a_tok, GOOD).status_code == 201
    job = client.post(f"/v1/cameras/{a_id}/refit", headers=bearer(a_tok)).json()["job_id"]
    # read, write and enumerate another camera: all 404, as for a camera that does not exist
    for method, path in (("get", f"/v1/cameras/{a_id}"), ("get", f"/v1/cameras/{a_id}/frames"),
                         ("get", f"/v1/cameras/{a_id}/estimates"), ("get", f"/v1/jobs/{job}"),
                         ("post", f"/v1/cameras/{a_id}/refit")):
        assert getattr(client, method)(path, headers=bearer(b_tok)).status_code == 404, path
    r = client.post(f"/v1/cameras/{a_id}/observations", json={"patches": {"r0": [0.1, 0.2, 0.3]}}, headers=bearer(b_tok))
    assert r.status_code == 404
    assert post_image(client, a_id, b_tok, GOOD).status_code == 404
    for other in range(1, 6):  # guessing ids tells nothing: every id but one's own looks the same
        if other != b_id:
            assert client.get(f"/v1/cameras/{other}", headers=bearer(b_tok)).json()["detail"] == f"unknown camera {other}"
    # the listing shows a camera token its own camera only; the admin sees both
    assert [c["id"] for c in client.get("/v1/cameras", headers=bearer(b_tok)).json()] == [b_id]
    assert [c["id"] for c in client.get("/v1/cameras", headers=admin_headers()).json()] == [a_id, b_id]
    # admin-only routes refuse camera tokens
    assert client.post("/v1/cameras", json=camera_body(_css(), grid_regions()), headers=bearer(b_tok)).status_code == 403
    # tokens are stored hashed
    raw = b"".join(p.read_bytes() for p in tmp_path.glob("illumon.sqlite3*"))
    assert a_tok.encode() not in raw and b_tok.encode() not in raw
