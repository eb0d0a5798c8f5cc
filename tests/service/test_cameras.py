"""/v1/cameras: registration, auth, validation."""

from __future__ import annotations

import json
import math

import numpy as np
from svc_helpers import admin_headers, bearer, camera_body, grid_regions


def _css() -> np.ndarray:
    wl = np.arange(400, 701, 5)
    return np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])


def test_register_and_get(client):
    body = camera_body(_css(), grid_regions())
    r = client.post("/v1/cameras", json=body, headers=admin_headers())
    assert r.status_code == 201
    cam = r.json()
    assert set(cam) >= {"id", "token"}
    got = client.get(f"/v1/cameras/{cam['id']}", headers=bearer(cam["token"]))
    assert got.status_code == 200
    assert got.json()["name"] == "test camera"
    assert "token" not in got.json()


def test_register_needs_admin(client):
    body = camera_body(_css(), grid_regions())
    cam = client.post("/v1/cameras", json=body, headers=admin_headers()).json()
    r = client.post("/v1/cameras", json=body, headers=bearer(cam["token"]))
    assert r.status_code == 403
    assert "admin" in r.json()["detail"]
    assert client.post("/v1/cameras", json=body).status_code == 401
    assert client.post("/v1/cameras", json=body, headers=bearer("nope")).status_code == 401


def test_cross_camera_is_404(client):
    body = camera_body(_css(), grid_regions())
    a = client.post("/v1/cameras", json=body, headers=admin_headers()).json()
    b = client.post("/v1/cameras", json=body, headers=admin_headers()).json()
    for path in ("", "/estimates", "/illuminant", "/wb-gains", "/frames"):
        r = client.get(f"/v1/cameras/{b['id']}{path}", headers=bearer(a["token"]))
        assert r.status_code == 404, path
        assert "unknown camera" in r.json()["detail"]
    r = client.post(f"/v1/cameras/{b['id']}/refit", headers=bearer(a["token"]))
    assert r.status_code == 404
    assert client.get("/v1/cameras/999", headers=admin_headers()).status_code == 404


def test_sensitivities_not_covering_400_700(client):
    body = camera_body(_css(), grid_regions())
    s = body["sensitivities"]
    for k in ("wavelength_nm", "r", "g", "b"):
        s[k] = s[k][4:]  # starts at 420 nm
    r = client.post("/v1/cameras", json=body, headers=admin_headers())
    assert r.status_code == 422
    assert "400–700" in r.json()["detail"]


def test_nan_negative_and_inf_rejected(client):
    body = camera_body(_css(), grid_regions())
    body["sensitivities"]["r"][3] = -1.0
    r = client.post("/v1/cameras", json=body, headers=admin_headers())
    assert r.status_code == 422
    text = camera_body(_css(), grid_regions())
    raw = __import__("json").dumps(text).replace(str(text["sensitivities"]["g"][10]), "NaN", 1)
    r = client.post("/v1/cameras", content=raw, headers={**admin_headers(), "content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["detail"]
    raw = __import__("json").dumps(text).replace(str(text["sensitivities"]["b"][10]), "Infinity", 1)
    r = client.post("/v1/cameras", content=raw, headers={**admin_headers(), "content-type": "application/json"})
    assert r.status_code == 422
    assert not math.isnan(0.0)


def test_bad_regions(client):
    body = camera_body(_css(), grid_regions())
    body["regions"][1]["id"] = body["regions"][0]["id"]
    assert client.post("/v1/cameras", json=body, headers=admin_headers()).status_code == 422
    body = camera_body(_css(), grid_regions())
    body["regions"][0]["width"] = 0
    assert client.post("/v1/cameras", json=body, headers=admin_headers()).status_code == 422


def test_put_regions(client):
    cam = client.post("/v1/cameras", json=camera_body(_css(), grid_regions()), headers=admin_headers()).json()
    new = grid_regions(4, 20)
    r = client.put(f"/v1/cameras/{cam['id']}/regions", json={"regions": new}, headers=bearer(cam["token"]))
    assert r.status_code == 200
    assert [g["id"] for g in r.json()["regions"]] == [g["id"] for g in new]


def test_bad_sensitivity_sampling(client):
    """Too few samples, repeated wavelengths and irregular sampling are 422, never 500."""
    regions = grid_regions()
    cases = [
        ([400, 700], [1, 1]),
        ([400, 400, 500, 600, 650, 700], [1] * 6),
        ([400, 430, 470, 520, 600, 640, 700], [1, 2, 3, 2, 1, 1, 1]),
    ]
    for wl, v in cases:
        body = {"name": "x", "sensitivities": {"wavelength_nm": wl, "r": v, "g": v, "b": v}, "regions": regions}
        r = client.post("/v1/cameras", json=body, headers=admin_headers())
        assert r.status_code in (201, 422), (wl, r.text)
        if r.status_code == 422:
            assert r.json()["detail"]
    body = {"name": "x", "sensitivities": {"wavelength_nm": [400, 700], "r": [1, 1], "g": [1, 1], "b": [1, 1]},
            "regions": regions}
    assert client.post("/v1/cameras", json=body, headers=admin_headers()).status_code == 422


def test_malformed_json_and_multipart(client):
    json_headers = {**admin_headers(), "content-type": "application/json"}
    r = client.post("/v1/cameras", content=b"{not json", headers=json_headers)
    assert r.status_code == 422 and r.json()["detail"]
    cam = client.post("/v1/cameras", json=camera_body(_css(), grid_regions()), headers=admin_headers()).json()
    h = {**bearer(cam["token"]), "content-type": "multipart/form-data; boundary=xyz"}
    r = client.post(f"/v1/cameras/{cam['id']}/frames", content=b"garbage--xyz\r\nfoo", headers=h)
    assert r.status_code == 400 and r.json()["detail"]


def test_list_cameras(client):
    """Issue 19: there was no route listing cameras. The admin sees every camera, a camera token its own."""
    assert client.get("/v1/cameras", headers=admin_headers()).json() == []
    a = client.post("/v1/cameras", json=camera_body(_css(), grid_regions(), name="a"), headers=admin_headers()).json()
    b = client.post("/v1/cameras", json=camera_body(_css(), grid_regions(), name="b"), headers=admin_headers()).json()
    listed = client.get("/v1/cameras", headers=admin_headers()).json()
    assert [(c["id"], c["name"]) for c in listed] == [(a["id"], "a"), (b["id"], "b")]
    assert all("token" not in c and c["warnings"] == [] for c in listed)
    assert listed[0] == client.get(f"/v1/cameras/{a['id']}", headers=admin_headers()).json()
    assert [c["id"] for c in client.get("/v1/cameras", headers=bearer(b["token"])).json()] == [b["id"]]
    assert client.get("/v1/cameras").status_code == 401


def test_default_response_is_srgb(client):
    """Issue 19: the default tone response was ``linear``, wrong for every ordinary (sRGB JPEG) camera."""
    body = camera_body(_css(), grid_regions())
    del body["response"]
    cam = client.post("/v1/cameras", json=body, headers=admin_headers()).json()
    got = client.get(f"/v1/cameras/{cam['id']}", headers=admin_headers()).json()
    assert got["response"]["encoding"] == "srgb" and got["response"]["white_level"] is None


def test_nonlinear_history_warns(tmp_path, scene, populated):
    """Issue 19: frames sent sRGB-encoded by a camera declared ``linear`` gave wrong estimates silently. The refit's
    check of the tone response now warns in the job, the camera's JSON and the status page; the same frames with the
    right declaration (the ``populated`` camera, sRGB) raise no warning."""
    from fastapi.testclient import TestClient
    from illumon_service.app import create_app
    from svc_helpers import make_settings, post_image, register

    ok = populated.job["summary"]
    assert ok["response_check"]["checked"] and ok["response_check"]["gamma"] is None
    assert ok["warnings"] == []
    assert populated.client.get(f"/v1/cameras/{populated.camera_id}", headers=admin_headers()).json()["warnings"] == []
    with TestClient(create_app(make_settings(tmp_path))) as c:
        cid, token = register(c, scene.css, scene.regions, encoding="linear")
        for img, t in zip(scene.images, scene.times, strict=True):
            assert post_image(c, cid, token, img, t).status_code == 201
        job = c.get(f"/v1/jobs/{c.post(f'/v1/cameras/{cid}/refit', headers=bearer(token)).json()['job_id']}",
                    headers=bearer(token)).json()
        assert job["state"] == "done"
        check = job["summary"]["response_check"]
        assert check["tone_score"] < -15 and 1.8 < check["gamma"] < 3.0, check
        (warning,) = [w for w in job["summary"]["warnings"] if "tone-encoded" in w]
        assert "'linear'" in warning and "'srgb'" in warning
        # one list: the model's own warnings (identifiability) join the tone response's
        assert job["summary"]["warnings"] == list(dict.fromkeys(
            [warning] + job["summary"]["identifiability_warnings"]))
        assert c.get(f"/v1/cameras/{cid}", headers=bearer(token)).json()["warnings"] == job["summary"]["warnings"]
        page = c.get(f"/cameras/{cid}", headers=bearer(token))
        assert page.status_code == 200 and "Check set-up" in page.text


def test_unmeasured_camera_with_pipeline(client):
    """Issue 15: a camera registered without sensitivities, with its pipeline (black and white level, a tone table and
    a colour matrix): stored and shown; a frame encoded through the table is linearised by it."""
    from svc_helpers import SIZE, encode_png, post_image

    table = [(i / 16) ** 2.0 for i in range(17)]  # encoded → linear, evenly spaced codes from black to white
    matrix = [[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.0, -0.5, 1.5]]
    body = camera_body(_css(), grid_regions())
    del body["sensitivities"]
    body["response"] = {"encoding": "table", "table": table, "black_level": 16, "white_level": 240, "matrix": matrix}
    r = client.post("/v1/cameras", json=body, headers=admin_headers())
    assert r.status_code == 201, r.text
    cam = client.get(f"/v1/cameras/{r.json()['id']}", headers=admin_headers()).json()
    assert cam["sensitivities"] == "unmeasured" and cam["calibration"] == "none" and cam["calibrations"] == []
    assert cam["response"]["table"] == table and cam["response"]["matrix"] == matrix
    assert cam["response"]["black_level"] == 16 and cam["response"]["white_level"] == 240
    linear = np.array([0.25, 0.09, 0.49])  # codes 16 + 224·(0.5, 0.3, 0.7)
    img = np.full((SIZE[1], SIZE[0], 3), np.round(16 + 224 * np.sqrt(linear)), np.uint8)
    out = post_image(client, cam["id"], r.json()["token"], encode_png(img), None).json()
    np.testing.assert_allclose(out["regions"]["r0"], linear, atol=0.004)


def test_bad_pipelines_refused(client):
    for response, word in (({"encoding": "table"}, "table"), ({"encoding": "srgb", "table": [0, 1]}, "table"),
                           ({"encoding": "table", "table": [0, 0.5, 0.4, 1]}, "non-decreasing"),
                           ({"encoding": "table", "table": [0, 1.5]}, "less than or equal"),
                           ({"matrix": [[1, 2, 3], [2, 4, 6], [0, 0, 1]]}, "singular"),
                           ({"matrix": [[1, 0], [0, 1]]}, "at least 3"),
                           ({"matrix": [[1, 0, 0], [0, float("nan"), 0], [0, 0, 1]]}, "finite")):
        body = camera_body(_css(), grid_regions())
        body["response"] = response
        r = client.post("/v1/cameras", content=json.dumps(body).replace("NaN", "NaN"), headers={
            **admin_headers(), "content-type": "application/json"})
        assert r.status_code == 422, (response, r.text)
        assert word in json.dumps(r.json()["detail"]), (response, r.json())


def test_response_primaries_default_and_choice(client):
    """``response.primaries``: rendered sRGB by default for an unmeasured camera with sRGB-encoded frames, sensor RGB
    for a measured one or linear output; an explicit choice is kept; anything else is a 422."""
    unmeasured = {k: v for k, v in camera_body(_css(), grid_regions()).items() if k != "sensitivities"}
    cases = (
        (unmeasured, "srgb"),
        (camera_body(_css(), grid_regions()), "camera"),
        ({**unmeasured, "response": {"encoding": "linear"}}, "camera"),
        ({**camera_body(_css(), grid_regions()), "response": {"encoding": "srgb", "primaries": "srgb"}}, "srgb"),
    )
    for body, expect in cases:
        cam = client.post("/v1/cameras", json=body, headers=admin_headers())
        assert cam.status_code == 201, cam.json()
        got = client.get(f"/v1/cameras/{cam.json()['id']}", headers=admin_headers()).json()
        assert got["response"]["primaries"] == expect, (body.get("response"), got["response"])
    bad = {**camera_body(_css(), grid_regions()), "response": {"primaries": "adobe"}}
    r = client.post("/v1/cameras", json=bad, headers=admin_headers())
    assert r.status_code == 422 and "detail" in r.json()
