"""The status page end to end: a real ``illumon serve`` process, two cameras with a simulated day, headless Chromium.

Chromium is Debian's package (``make browser`` installs it as root; ``make test`` runs that first), driven by the
Python ``playwright`` package over its own pipe; no browser is downloaded. Without ``/usr/bin/chromium`` (or
``$ILLUMON_CHROMIUM``) the tests skip with the reason. The data are synthetic (:mod:`illumon_service.demo`), so no
measured data set is needed. Screenshots go to the test's temporary folder and, when ``$ILLUMON_SCREENSHOT_DIR`` is
set, are copied there.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import httpx
import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed (pip install -e '.[dev]')")

CHROMIUM = Path(os.environ.get("ILLUMON_CHROMIUM", "/usr/bin/chromium"))
if not CHROMIUM.exists():
    pytest.skip(f"Chromium not found at {CHROMIUM}: `make browser` installs Debian's chromium (needs root and apt-get)",
                allow_module_level=True)

from illumon_service.demo import demo_cameras, post_day  # noqa: E402 - after the skips
from illumon_service.process import free_port, stop_process, wait_healthy  # noqa: E402

ILLUMON = Path(sys.executable).with_name("illumon")
ARGS = ["--no-sandbox", "--headless", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-proxy-server"]
DESKTOP = {"width": 1280, "height": 900}
PHONE = {"width": 390, "height": 844}


@dataclass
class Fleet:
    """The running service with the two demo cameras."""

    base: str
    admin: str
    cameras: dict[str, dict]  # name → {id, token, name}
    http: httpx.Client

    def api(self, path: str, token: str | None = None) -> dict | list:
        """GET a JSON API path with a bearer token (the admin's by default)."""
        r = self.http.get(self.base + path, headers={"Authorization": f"Bearer {token or self.admin}"})
        r.raise_for_status()
        return r.json()


@contextmanager
def illumon_server(data: Path) -> Iterator[tuple[str, str, httpx.Client]]:
    """``illumon serve`` on a free loopback port with ``data`` as its data dir: (base URL, admin token, HTTP client)."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("ILLUMON_")}
    cmd = [str(ILLUMON), "serve", "--host", "127.0.0.1", "--port", str(port), "--data-dir", str(data), "--log-level", "warning"]
    log = (data / "serve.log").open("w")
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    http = httpx.Client(trust_env=False, timeout=60)
    try:
        wait_healthy(proc, base, timeout=60, describe=lambda: (data / "serve.log").read_text())
        yield base, (data / "admin_token").read_text().strip(), http
    finally:
        stop_process(proc)
        log.close()
        http.close()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Iterator[Fleet]:
    """``illumon serve`` on a free loopback port, two cameras registered, a day posted and refitted."""
    with illumon_server(tmp_path_factory.mktemp("serve")) as (base, admin, http):
        cams = post_day(base, admin, demo_cameras())
        yield Fleet(base, admin, {c["name"]: c for c in cams}, http)


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    """Headless Debian Chromium through Playwright."""
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=ARGS)
        try:
            yield b
        finally:
            b.close()


def _login(page, fleet: Fleet, token: str, path: str = "/") -> None:
    page.goto(fleet.base + path)
    assert "/login" in page.url, page.url
    page.fill("#token", token)
    with page.expect_navigation():
        page.click("#login-form button[type=submit]")


def _keep(path: Path) -> None:
    target = os.environ.get("ILLUMON_SCREENSHOT_DIR")
    if target:
        Path(target).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(target) / path.name)


def _utc(iso: str) -> str:
    return datetime.fromisoformat(iso).strftime("%Y-%m-%d %H:%M UTC")


def test_admin_sees_both_cameras_with_api_values(browser, fleet: Fleet, tmp_path: Path) -> None:
    ctx = browser.new_context(viewport=DESKTOP)
    page = ctx.new_page()
    page.goto(fleet.base + "/")
    assert page.url.startswith(fleet.base + "/login")  # unauthenticated: redirected to the form
    shot = tmp_path / "login-desktop.png"
    page.screenshot(path=str(shot))
    _keep(shot)
    page.fill("#token", "not-a-token")
    page.click("#login-form button[type=submit]")
    assert page.locator(".error").inner_text() == "Unknown token."
    _login(page, fleet, fleet.admin)
    assert page.url == fleet.base + "/"
    cookie = next(c for c in ctx.cookies() if c["name"] == "illumon_session")
    assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
    assert page.evaluate("document.cookie") == ""  # not readable by scripts
    assert page.locator("#cameras tbody tr").count() == 2
    for name, cam in fleet.cameras.items():
        latest = fleet.api(f"/v1/cameras/{cam['id']}/estimates")[-1]
        frames = fleet.api(f"/v1/cameras/{cam['id']}/frames")
        row = page.locator(f'#cameras tr[data-camera-id="{cam["id"]}"]')
        cell = lambda field, row=row: row.locator(f'td[data-field="{field}"]')  # noqa: E731
        assert row.locator("td").first.inner_text().startswith(name)
        assert cell("cct_k").inner_text() == f"{latest['cct_k']:.0f} K"
        assert float(cell("cct_k").get_attribute("data-value")) == pytest.approx(latest["cct_k"], rel=1e-12)
        assert cell("duv").inner_text() == f"{latest['duv']:+.4f}"
        g = latest["gains_rgb"]
        assert cell("gains").inner_text() == f"{g[0]:.3f} / {g[2]:.3f}"
        assert cell("confidence").inner_text() == f"{latest['confidence']:.2f}"
        assert cell("last_frame_at").inner_text() == _utc(frames[-1]["taken_at"])
        # A simulated day: warm morning, bluer noon, the latest (19:00 UTC) warmer than the day's maximum.
        day = [e["cct_k"] for e in fleet.api(f"/v1/cameras/{cam['id']}/estimates")]
        assert len(day) == len(frames) == 28
        assert max(day) > latest["cct_k"] + 500
        kinds = cell("alerts").locator("[data-kind]").evaluate_all("els => els.map(e => e.dataset.kind)")
        expected = {"regions_missing", "clipping"} if name == "yard" else set()  # the yard's late frames: see demo
        p = latest.get("non_daylight")
        expected |= {"non_daylight"} if ((p >= 0.5) if p is not None else abs(latest["duv"]) > 0.02) else set()
        expected |= {"low_confidence"} if latest["confidence"] < 0.5 else set()
        warned = fleet.api(f"/v1/cameras/{cam['id']}")["warnings"]  # the latest refit's, one alert each
        expected |= {"refit_warning"} if warned else set()
        assert set(kinds) == expected, (kinds, warned)
        if not expected:
            assert cell("alerts").inner_text() == "OK"
    shot = tmp_path / "index-desktop.png"
    page.screenshot(path=str(shot), full_page=True)
    _keep(shot)
    ctx.close()


def test_camera_page_charts_and_screenshot(browser, fleet: Fleet, tmp_path: Path) -> None:
    ctx = browser.new_context(viewport=DESKTOP)
    page = ctx.new_page()
    _login(page, fleet, fleet.admin)
    for name, cam in fleet.cameras.items():
        page.click(f'#cameras tr[data-camera-id="{cam["id"]}"] a')
        page.wait_for_url(f"{fleet.base}/cameras/{cam['id']}")
        assert page.locator("#camera-name").inner_text().startswith(name)
        history = fleet.api(f"/v1/cameras/{cam['id']}/estimates")
        for chart in ("chart-cct", "chart-duv", "chart-gains"):
            svg = page.locator(f"svg#{chart}")
            assert svg.is_visible()
            n_lines = 2 if chart == "chart-gains" else 1
            points = svg.locator("polyline").evaluate_all("els => els.map(e => e.points.numberOfItems)")
            assert points == [len(history)] * n_lines
            # Frames after the refit are estimated by the scene model: their intervals are drawn as a band.
            assert svg.locator("polygon").count() >= n_lines
        latest = fleet.api(f"/v1/cameras/{cam['id']}/illuminant")
        assert page.locator('#summary [data-field="cct_k"]').inner_text() == f"{latest['cct_k']:.0f} K"
        assert latest["intervals"] and f"{latest['intervals']['cct_lo']:.0f}–" in page.locator("#summary").inner_text()
        shot = tmp_path / f"camera-{name}-desktop.png"
        page.screenshot(path=str(shot), full_page=True)
        assert shot.stat().st_size > 10_000
        _keep(shot)
        page.goto(fleet.base + "/")
    ctx.close()


def test_camera_token_sees_only_its_camera(browser, fleet: Fleet) -> None:
    roof, yard = fleet.cameras["roof"], fleet.cameras["yard"]
    ctx = browser.new_context(viewport=DESKTOP)
    page = ctx.new_page()
    _login(page, fleet, roof["token"], f"/cameras/{roof['id']}")
    assert page.url == f"{fleet.base}/cameras/{roof['id']}"
    page.goto(fleet.base + "/")
    assert page.locator("#cameras tbody tr").count() == 1
    assert page.locator(f'#cameras tr[data-camera-id="{roof["id"]}"]').count() == 1
    resp = page.goto(f"{fleet.base}/cameras/{yard['id']}")
    assert resp.status == 404
    assert page.locator("#not-found").is_visible() and "yard" not in page.content()
    # Logging out forgets the cookie: the pages ask for a token again.
    with page.expect_navigation():
        page.click("form.logout button")
    assert "/login" in page.url
    page.goto(f"{fleet.base}/cameras/{roof['id']}")
    assert "/login" in page.url
    ctx.close()


def test_phone_width(browser, fleet: Fleet, tmp_path: Path) -> None:
    ctx = browser.new_context(viewport=PHONE, device_scale_factor=2, is_mobile=True, has_touch=True)
    page = ctx.new_page()
    _login(page, fleet, fleet.admin)
    overflow = "document.documentElement.scrollWidth - document.documentElement.clientWidth"
    assert page.evaluate(overflow) <= 0
    # Each camera is one card: its cells stack, so every value is on screen without scrolling sideways.
    yard = page.locator(f'#cameras tr[data-camera-id="{fleet.cameras["yard"]["id"]}"] td[data-field="alerts"]')
    box = yard.bounding_box()
    assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= PHONE["width"]
    shot = tmp_path / "index-phone.png"
    page.screenshot(path=str(shot), full_page=True)
    _keep(shot)
    page.goto(f"{fleet.base}/cameras/{fleet.cameras['roof']['id']}")
    assert page.evaluate(overflow) <= 0
    assert not page.locator("svg#chart-cct").is_visible()  # the compact charts replace the wide ones
    svg_box = page.locator("svg#chart-cct-compact").bounding_box()
    assert svg_box is not None and svg_box["width"] <= PHONE["width"]
    shot = tmp_path / "camera-roof-phone.png"
    page.screenshot(path=str(shot), full_page=True)
    _keep(shot)
    ctx.close()
