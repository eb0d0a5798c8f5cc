"""The OpenAPI schema documents every JSON answer (response models), and the models change no answer.

The models validate and serialise what the routes return; the answers are contracts (outside checks and camera
software read them), so :func:`test_models_change_no_answer` compares, for every answer of a session touching each JSON
route, the bytes sent with the route's own value serialised untyped (the answers before the models existed): any key
dropped or added, ``null`` filled in or number turned from integer to float fails it.
"""

from __future__ import annotations

import json
from typing import Any

import fastapi.routing
import numpy as np
import pytest
from fastapi.testclient import TestClient
from illumon_service.app import create_app
from illumon_service.storage import Camera, hash_token
from pydantic import TypeAdapter
from svc_helpers import admin_headers, bearer, camera_body, encode_png, make_settings, need_data

NON_JSON = {("get", "/metrics")}
"""Operations whose answer is not JSON (Prometheus text)."""


def _resolve(spec: dict, schema: dict) -> dict:
    while "$ref" in schema:
        schema = spec["components"]["schemas"][schema["$ref"].rsplit("/", 1)[1]]
    return schema


def test_every_json_route_documents_its_answer(client):
    spec = client.get("/openapi.json").json()
    seen = []
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            if (method, path) in NON_JSON:
                continue
            ok = {code: r for code, r in op["responses"].items() if code.startswith("2")}
            assert len(ok) == 1, (method, path, list(ok))
            (code, answer), = ok.items()
            schema = answer.get("content", {}).get("application/json", {}).get("schema")
            assert schema is not None, f"{method.upper()} {path} {code}: no JSON answer documented"
            schema = _resolve(spec, schema)
            if schema.get("type") == "array":
                schema = _resolve(spec, schema["items"])
            assert schema.get("properties"), f"{method.upper()} {path} {code}: answer is an undocumented object"
            seen.append((method.upper(), path))
    # the service's JSON routes, every one of them in the schema
    expected = {("GET", "/v1/cameras"), ("POST", "/v1/cameras"), ("GET", "/v1/cameras/{camera_id}"),
                ("PUT", "/v1/cameras/{camera_id}/regions"), ("POST", "/v1/cameras/{camera_id}/calibration"),
                ("POST", "/v1/cameras/{camera_id}/frames"), ("GET", "/v1/cameras/{camera_id}/frames"),
                ("POST", "/v1/cameras/{camera_id}/observations"), ("GET", "/v1/cameras/{camera_id}/estimates"),
                ("GET", "/v1/cameras/{camera_id}/illuminant"), ("GET", "/v1/cameras/{camera_id}/wb-gains"),
                ("POST", "/v1/cameras/{camera_id}/refit"), ("GET", "/v1/jobs/{job_id}"),
                ("GET", "/v1/cameras/{camera_id}/region-proposals"), ("GET", "/healthz")}
    assert expected <= set(seen), expected - set(seen)


def test_wb_gains_documents_both_onvif_shapes(client):
    spec = client.get("/openapi.json").json()
    onvif = spec["components"]["schemas"]["WbGainsOut"]["properties"]["onvif"]["anyOf"]
    shapes = [set(_resolve(spec, s)["properties"]) for s in onvif]
    assert {"Mode", "CrGain", "CbGain"} in shapes and {"Mode", "CrGain", "CbGain", "range"} in shapes


@pytest.fixture
def answers(monkeypatch) -> list[tuple[str, bytes, bytes]]:
    """``(model, untyped bytes, sent bytes)`` of every JSON answer serialised through a response model."""
    seen: list[tuple[str, bytes, bytes]] = []
    untyped = TypeAdapter(Any)
    serialize = fastapi.routing.serialize_response

    async def recording(**kw: Any) -> Any:
        out = await serialize(**kw)
        if kw.get("dump_json"):
            seen.append((str(kw["field"].field_info.annotation), untyped.dump_json(kw["response_content"]), out))
        return out

    monkeypatch.setattr(fastapi.routing, "serialize_response", recording)
    return seen


def test_models_change_no_answer(tmp_path, scene, answers):
    need_data()
    with TestClient(create_app(make_settings(tmp_path))) as c:
        adm = admin_headers()
        r = c.post("/v1/cameras", json=camera_body(scene.css, scene.regions), headers=adm)
        cam, auth = r.json()["id"], bearer(r.json()["token"])
        for k, (img, t) in enumerate(zip(scene.images[:6], scene.times, strict=False)):
            data = {"taken_at": t.isoformat()}
            if k == 1:
                data.update(applied_gains="2,1,1.5", exposure="2")
            assert c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", img, "image/png")}, data=data,
                          headers=auth).status_code == 201
        tiny = encode_png(np.full((8, 8, 3), 100, np.uint8))  # no region inside: 422, no model involved
        assert c.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", tiny, "image/png")},
                      headers=auth).status_code == 422
        ids = [g["id"] for g in scene.regions]
        obs = {"taken_at": "2025-06-01T18:00:00Z", "patches": {ids[0]: [1, 2, 3], ids[1]: [2, 2, 2], ids[2]: None},
               "sd": {ids[0]: [0.01, 0.01, 0.01]}, "white_level": 4, "applied_gains": [2, 1, 1], "exposure": 1}
        assert c.post(f"/v1/cameras/{cam}/observations", json=obs, headers=auth).status_code == 201
        job = c.post(f"/v1/cameras/{cam}/refit", headers=auth).json()
        assert c.get(f"/v1/jobs/{job['job_id']}", headers=auth).json()["state"] == "done"
        for path, params in (("frames", {}), ("estimates", {}), ("illuminant", {}), ("wb-gains", {}),
                             ("wb-gains", {"onvif_range": "0,255"}), ("wb-gains", {"v4l2_unity": 256})):
            assert c.get(f"/v1/cameras/{cam}/{path}", params=params, headers=auth).status_code == 200, path
        assert c.put(f"/v1/cameras/{cam}/regions", params={"view": "preset-2"}, json={"regions": scene.regions[:3]},
                     headers=auth).status_code == 200
        # an installer's camera without regions, then its proposals and a grey-card calibration
        body = {"name": "installer", "regions": [], "response": {"encoding": "srgb", "white_level": 255}}
        r = c.post("/v1/cameras", json=body, headers=adm)
        cam2, auth2 = r.json()["id"], bearer(r.json()["token"])
        for img, t in zip(scene.images, scene.times, strict=True):
            assert c.post(f"/v1/cameras/{cam2}/frames", files={"image": ("f.png", img, "image/png")},
                          data={"taken_at": t.isoformat()}, headers=auth2).status_code == 201
        assert c.get(f"/v1/cameras/{cam2}/region-proposals", params={"count": 4}, headers=auth2).status_code == 200
        g = scene.regions[0]
        grey = {"x": g["x"], "y": g["y"], "width": g["width"], "height": g["height"]}
        assert c.post(f"/v1/cameras/{cam2}/calibration", files={"image": ("c.png", scene.images[0], "image/png")},
                      data={"kind": "grey", "region": json.dumps(grey)}, headers=auth2).status_code == 201
        # a camera stored by an older version: a pipeline without most keys keeps them missing
        with c.app.state.sessions() as s:
            old = Camera(name="old", token_hash=hash_token("old-token"), sensitivities=[], regions=[],
                         response={"encoding": "srgb"})
            s.add(old)
            s.commit()
            old_id = old.id
        assert c.get(f"/v1/cameras/{old_id}", headers=adm).json()["response"] == {"encoding": "srgb"}
        for path in (f"/v1/cameras/{cam}", f"/v1/cameras/{cam2}", "/v1/cameras", "/healthz"):
            assert c.get(path, headers=adm).status_code == 200, path
    models = {m for m, _, _ in answers}
    for name in ("FrameIngestOut", "FrameOut", "EstimateOut", "IlluminantOut", "WbGainsOut", "JobRef", "JobOut",
                 "CameraOut", "CameraCreated", "ProposalsOut", "CalibrationOut", "HealthOut"):
        assert any(name in m for m in models), name
    changed = [(m, _first_difference(raw, out)) for m, raw, out in answers if raw != out]
    assert not changed, changed[:3]


def _first_difference(raw: bytes, out: bytes) -> str:
    i = next((k for k, (x, y) in enumerate(zip(raw, out, strict=False)) if x != y), min(len(raw), len(out)))
    window = slice(max(0, i - 80), i + 80)
    return f"untyped …{raw[window].decode(errors='replace')}… sent …{out[window].decode(errors='replace')}…"
