"""The status page through the TestClient: login and cookie, redirects, who sees which camera, table values, charts,
alerts. The browser end-to-end test is ``tests/browser/test_status_page.py``."""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from types import SimpleNamespace

import pytest
from fastapi.testclient import TestClient
from illumon_service.app import create_app
from illumon_service.charts import Series, gap_breaks, nice_ticks, time_chart, time_ticks
from illumon_service.demo import demo_cameras
from illumon_service.status import ALERT_RULES, AlertContext
from svc_helpers import ADMIN, admin_headers, bearer, make_settings


@dataclass
class Day:
    """A TestClient with the two demo cameras (12 frames each; refit by gray world to stay fast)."""

    client: TestClient
    ids: dict[str, int]
    tokens: dict[str, str]


@pytest.fixture(scope="module")
def day(tmp_path_factory) -> Day:
    tmp = tmp_path_factory.mktemp("pages")
    with TestClient(create_app(make_settings(tmp, refit_method="gray_world"))) as c:
        ids, tokens = {}, {}
        for cam in demo_cameras(frames=12):
            r = c.post("/v1/cameras", json=cam.body, headers=admin_headers())
            assert r.status_code == 201, r.text
            cid, tok = r.json()["id"], r.json()["token"]
            for i, ob in enumerate(cam.observations):
                if i == cam.refit_after:
                    assert c.post(f"/v1/cameras/{cid}/refit", headers=bearer(tok)).status_code == 202
                assert c.post(f"/v1/cameras/{cid}/observations", json=ob, headers=bearer(tok)).status_code == 201
            ids[cam.name], tokens[cam.name] = cid, tok
        yield Day(c, ids, tokens)


def expected_alerts(name: str, latest: dict) -> set[str]:
    """The alerts a demo camera's row must show: the yard's troubles, and those its latest estimate implies."""
    out = {"regions_missing", "clipping"} if name == "yard" else set()
    p = latest.get("non_daylight")
    if (p >= 0.5) if p is not None else abs(latest["duv"]) > 0.02:
        out.add("non_daylight")
    if latest["confidence"] < 0.5:
        out.add("low_confidence")
    return out


def _login(c: TestClient, token: str, next_: str = "/"):
    c.cookies.clear()
    return c.post("/login", data={"token": token, "next": next_}, follow_redirects=False)


def test_unauthenticated_pages_redirect_to_login(day: Day) -> None:
    c = day.client
    c.cookies.clear()
    r = c.get("/", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/login?next=/"
    r = c.get(f"/cameras/{day.ids['roof']}?limit=5", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == f"/login?next=/cameras/{day.ids['roof']}%3Flimit%3D5"
    r = c.get("/login?next=/cameras/1")
    assert r.status_code == 200 and 'name="token"' in r.text and 'value="/cameras/1"' in r.text
    c.cookies.set("illumon_session", "stale")
    r = c.get("/", follow_redirects=False)  # an invalid cookie is dropped
    assert r.status_code == 303 and 'illumon_session=""' in r.headers["set-cookie"]


def test_login_sets_http_only_strict_cookie(day: Day) -> None:
    c = day.client
    r = _login(c, ADMIN, f"/cameras/{day.ids['yard']}")
    assert r.status_code == 303 and r.headers["location"] == f"/cameras/{day.ids['yard']}"
    cookie = r.headers["set-cookie"]
    sid = cookie.split(";")[0].removeprefix("illumon_session=")
    assert cookie.startswith("illumon_session=") and len(sid) >= 43 and ADMIN not in cookie  # a session id, not the token
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Path=/" in cookie and "Secure" not in cookie
    assert c.get("/").status_code == 200
    r = c.post("/logout", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/login"
    assert c.get("/", follow_redirects=False).status_code == 303
    c.cookies.set("illumon_session", sid)  # the logged-out session id no longer logs in
    assert c.get("/", follow_redirects=False).status_code == 303
    c.cookies.set("illumon_session", ADMIN)  # nor does the token itself as a cookie
    assert c.get("/", follow_redirects=False).status_code == 303


def test_login_rejects_unknown_token_and_foreign_next(day: Day) -> None:
    c = day.client
    r = _login(c, "nope")
    assert r.status_code == 401 and "Unknown token." in r.text and "set-cookie" not in r.headers
    for target in ("//evil.example/", "https://evil.example/", "/\\evil.example"):
        assert _login(c, ADMIN, target).headers["location"] == "/"
    # A form posted from another site neither logs in nor out.
    c.cookies.clear()
    r = c.post("/login", data={"token": ADMIN}, headers={"Origin": "https://evil.example"}, follow_redirects=False)
    assert r.status_code == 403 and "set-cookie" not in r.headers
    r = c.post("/login", data={"token": ADMIN}, headers={"Origin": "http://testserver"}, follow_redirects=False)
    assert r.status_code == 303 and "illumon_session=" in r.headers["set-cookie"]
    assert c.post("/logout", headers={"Origin": "https://evil.example"}, follow_redirects=False).status_code == 403
    proxied = {"Origin": "https://cams.example", "X-Forwarded-Host": "cams.example"}
    assert c.post("/login", data={"token": ADMIN}, headers=proxied, follow_redirects=False).status_code == 303


def test_fleet_table_matches_api(day: Day) -> None:
    c = day.client
    _login(c, ADMIN)
    r = c.get("/")
    assert r.status_code == 200
    assert "default-src 'none'" in r.headers["content-security-policy"] and r.headers["x-frame-options"] == "DENY"
    assert 'href="/static/style.css"' in r.text and "<script" not in r.text
    for name, cid in day.ids.items():
        latest = c.get(f"/v1/cameras/{cid}/estimates", headers=admin_headers()).json()[-1]
        row = re.search(rf'<tr data-camera-id="{cid}">(.*?)</tr>', r.text, re.S).group(1)
        assert name in row
        assert f'data-value="{latest["cct_k"]}">{latest["cct_k"]:.0f} K<' in row
        assert f'>{latest["duv"]:+.4f}<' in row and f'>{latest["confidence"]:.2f}<' in row
        assert f'{latest["gains_rgb"][0]:.3f} / {latest["gains_rgb"][2]:.3f}' in row
        assert "2025-06-21 11:00 UTC" in row  # the 12th frame: 05:30 + 11 × 30 min
        kinds = set(re.findall(r'data-kind="(\w+)"', row))
        assert kinds == expected_alerts(name, latest)


def test_camera_page_has_charts_with_intervals(day: Day) -> None:
    c = day.client
    _login(c, ADMIN)
    cid = day.ids["roof"]
    r = c.get(f"/cameras/{cid}")
    assert r.status_code == 200
    n = len(c.get(f"/v1/cameras/{cid}/estimates", headers=admin_headers()).json())
    assert n == 12
    for key in ("cct", "duv", "gains"):
        for suffix in ("", "-compact"):
            svg = re.search(rf'<svg class="chart [a-z]+" id="chart-{key}{suffix}".*?</svg>', r.text, re.S).group(0)
            assert 'viewBox="0 0 ' in svg and "<polygon" in svg  # model estimates after the refit carry intervals
            lines = re.findall(r'<polyline class="[^"]*" points="([^"]*)"', svg)
            assert [len(p.split()) for p in lines] == [n] * (2 if key == "gains" else 1)
    assert "Recent estimates" in r.text and "refit:" in r.text
    assert c.get("/static/style.css").status_code == 200


def test_camera_token_sees_only_its_camera(day: Day) -> None:
    c = day.client
    roof, yard = day.ids["roof"], day.ids["yard"]
    _login(c, day.tokens["roof"])
    page = c.get("/").text
    assert f'data-camera-id="{roof}"' in page and f'data-camera-id="{yard}"' not in page and "yard" not in page
    assert c.get(f"/cameras/{roof}").status_code == 200
    r = c.get(f"/cameras/{yard}")
    assert r.status_code == 404 and "yard" not in r.text
    assert c.get("/cameras/999").status_code == 404
    c.cookies.clear()
    # The bearer header works as for the JSON API.
    assert c.get(f"/cameras/{yard}", headers=bearer(day.tokens["yard"])).status_code == 200
    assert c.get(f"/cameras/{roof}", headers=bearer(day.tokens["yard"])).status_code == 404
    assert c.get("/", headers=bearer("wrong"), follow_redirects=False).status_code == 303


def test_camera_without_estimates(client: TestClient) -> None:
    cam = demo_cameras(frames=3)[0]
    cid = client.post("/v1/cameras", json=cam.body, headers=admin_headers()).json()["id"]
    _login(client, ADMIN)
    assert "No estimate yet" not in client.get("/").text  # no frames: nothing to say
    for ob in cam.observations:
        client.post(f"/v1/cameras/{cid}/observations", json=ob, headers=admin_headers())
    page = client.get("/").text
    assert 'data-kind="no_estimate"' in page and "—" in page
    r = client.get(f"/cameras/{cid}")
    assert r.status_code == 200 and "no estimates yet" in r.text


def _ctx(duv: float = 0.0, confidence: float = 0.9, missing: int = 0) -> AlertContext:
    cam = SimpleNamespace(regions=[{"id": f"r{i}"} for i in range(4)])
    frames = [SimpleNamespace(patches={f"r{i}": (None if (i == 0 and k < missing) else [0.3, 0.3, 0.3]) for i in range(4)})
              for k in range(12)]
    latest = SimpleNamespace(duv=duv, confidence=confidence)
    return AlertContext(cam, frames, latest, make_settings("/tmp"), 12)  # type: ignore[arg-type]


def _kinds(ctx: AlertContext) -> list[str]:
    return [a.kind for rule in ALERT_RULES for a in rule(ctx)]


def test_alert_rules() -> None:
    assert _kinds(_ctx()) == []
    assert _kinds(_ctx(duv=-0.025)) == ["non_daylight"]
    assert _kinds(_ctx(duv=0.019)) == []
    # with the model's posterior (issue 28) the alert follows it, not the Duv rule
    lamp = _ctx(duv=0.001)
    lamp.latest.intervals = {"non_daylight": 0.8}
    assert _kinds(lamp) == ["non_daylight"]
    day = _ctx(duv=-0.025)
    day.latest.intervals = {"non_daylight": 0.1}
    assert _kinds(day) == []
    assert _kinds(_ctx(confidence=0.2)) == ["low_confidence"]
    assert _kinds(_ctx(missing=2)) == []  # a passer-by
    assert _kinds(_ctx(missing=3)) == ["regions_missing"]
    ctx = _ctx()
    ctx.camera.id, ctx.uncalibrated = 7, True
    (alert,) = [a for rule in ALERT_RULES for a in rule(ctx)]
    assert alert.kind == "uncalibrated" and "/v1/cameras/7/calibration" in alert.message and alert.severity == "info"


def test_time_chart() -> None:
    assert nice_ticks(0.0, 1.0, 5) == [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]
    assert nice_ticks(3812.0, 6533.0, 5) == [4000.0, 4500.0, 5000.0, 5500.0, 6000.0, 6500.0]
    t0 = datetime(2025, 6, 21, 6, tzinfo=timezone.utc)
    ts = [t0 + timedelta(hours=i) for i in range(5)]
    svg = str(time_chart([Series("<b>", ts, [1, 2, 3, 4, 5], [None, None, 2.5, 3.5, 4.5], [None, None, 3.5, 4.5, 5.5])],
                         title="T & U", unit="K"))
    assert svg.startswith("<svg") and svg.endswith("</svg>")
    assert "&lt;b&gt;" in svg and "T &amp; U (K)" in svg and "<b>" not in svg
    assert svg.count("<polygon") == 1 and ">06:00<" in svg and ">10:00<" in svg
    assert "no estimates yet" in str(time_chart([], title="CCT"))
    ticks, label = time_ticks(t0.timestamp(), (t0 + timedelta(days=1)).timestamp())
    assert [label(t) for t in ticks] == ["06:00", "12:00", "18:00", "06-22", "06:00"]  # midnight shows the date


def test_time_chart_breaks_at_gaps() -> None:
    """Issue 19: a 17-month gap between frames was bridged by one line and band; lines and bands break at gaps much
    longer than the usual spacing, and only there."""
    t0 = datetime(2024, 1, 10, 8, tzinfo=timezone.utc)
    first = [t0 + timedelta(minutes=20 * i) for i in range(6)]
    later = [first[-1] + timedelta(days=520) + timedelta(minutes=20 * i) for i in range(6)]
    ts = first + later
    vals = [5000.0 + 10 * i for i in range(12)]
    svg = str(time_chart([Series("CCT", ts, vals, [v - 100 for v in vals], [v + 100 for v in vals])], title="CCT"))
    assert svg.count("<polyline") == 2 and svg.count("<polygon") == 2
    assert gap_breaks(ts) == {6}
    steady = [t0 + timedelta(minutes=20 * i + (7 if i % 3 == 0 else 0)) for i in range(12)]  # uneven, no gap
    svg = str(time_chart([Series("CCT", steady, vals, [v - 100 for v in vals], [v + 100 for v in vals])], title="CCT"))
    assert svg.count("<polyline") == 1 and svg.count("<polygon") == 1
