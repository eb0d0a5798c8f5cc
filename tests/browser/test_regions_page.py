"""The regions page end to end (issue 17): a real ``illumon serve``, a camera registered without regions, frames of a
synthetic scene, and headless Chromium confirming proposals through the page's plain HTML form (no scripts: the
Content Security Policy stays ``default-src 'none'``). Skips like ``test_status_page.py`` without Chromium; needs no
measured data.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path

import cv2
import numpy as np
import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed (pip install -e '.[dev]')")

CHROMIUM = Path(os.environ.get("ILLUMON_CHROMIUM", "/usr/bin/chromium"))
if not CHROMIUM.exists():
    pytest.skip(f"Chromium not found at {CHROMIUM}: `make browser` installs Debian's chromium (needs root and apt-get)",
                allow_module_level=True)

from test_status_page import DESKTOP, PHONE, _keep, browser, illumon_server  # noqa: E402, F401 - browser: fixture

W, H = 480, 360
PATCHES = [(40, 80, 60, 50, (0.55, 0.25, 0.15)), (150, 80, 70, 50, (0.2, 0.45, 0.2)), (260, 90, 60, 60, (0.15, 0.2, 0.5)),
           (360, 80, 70, 50, (0.6, 0.6, 0.55)), (60, 200, 80, 50, (0.5, 0.45, 0.1)), (250, 210, 70, 45, (0.3, 0.15, 0.35))]


def synthetic_frames(n: int, seed: int = 3) -> list[bytes]:
    """PNG frames of coloured static patches on a mosaic of random tiles, under changing light, with a walker."""
    rng = np.random.default_rng(seed)
    base = np.repeat(np.repeat(rng.uniform(0.05, 0.7, (H // 8, W // 8, 3)), 8, axis=0), 8, axis=1)
    for x, y, w, h, c in PATCHES:
        base[y : y + h, x : x + w] = c
    base *= 1 + 0.05 * rng.uniform(-1, 1, (H, W, 1))
    out = []
    for _ in range(n):
        img = base * rng.uniform(0.7, 1.1, 3) * 0.9
        x = int(rng.integers(0, W - 30))
        img[290:355, x : x + 25] = rng.uniform(0.05, 0.8, 3)
        enc = np.round(255 * np.clip(img, 0, 1) ** (1 / 2.2)).astype(np.uint8)
        ok, buf = cv2.imencode(".png", np.ascontiguousarray(enc[:, :, ::-1]))
        assert ok
        out.append(buf.tobytes())
    return out


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Iterator[dict]:
    """``illumon serve`` with one camera registered without regions and 8 frames posted."""
    with illumon_server(tmp_path_factory.mktemp("regions-serve")) as (base, admin, http):
        auth = {"Authorization": f"Bearer {admin}"}
        r = http.post(base + "/v1/cameras", json={"name": "gate", "regions": [], "response": {"encoding": "gamma",
                                                                                              "gamma": 2.2}}, headers=auth)
        r.raise_for_status()
        cam = r.json()["id"]
        t0 = datetime(2025, 6, 1, 6, tzinfo=timezone.utc)
        for k, img in enumerate(synthetic_frames(8)):
            r = http.post(f"{base}/v1/cameras/{cam}/frames", files={"image": ("f.png", img, "image/png")},
                          data={"taken_at": (t0 + timedelta(hours=k)).isoformat()}, headers=auth)
            r.raise_for_status()
        yield {"base": base, "admin": admin, "camera": cam, "http": http, "auth": auth}


def test_confirm_proposals_in_the_browser(browser, served, tmp_path: Path) -> None:  # noqa: F811 - the fixture
    base, cam = served["base"], served["camera"]
    ctx = browser.new_context(viewport=DESKTOP)
    page = ctx.new_page()
    problems: list[str] = []
    page.on("console", lambda m: problems.append(m.text) if m.type == "error" and "404" not in m.text else None)
    page.on("response", lambda r: problems.append(f"{r.status} {r.url}")
            if r.status >= 400 and not r.url.endswith("/favicon.ico") else None)
    images: list[tuple[str, int, str]] = []
    page.on("response", lambda r: images.append((r.url, r.status, r.headers.get("content-type", "")))
            if r.url.endswith("latest.jpg") else None)
    page.goto(f"{base}/cameras/{cam}/regions")
    assert "/login" in page.url
    page.fill("#token", served["admin"])
    with page.expect_navigation():
        page.click("#login-form button[type=submit]")
    assert page.url == f"{base}/cameras/{cam}/regions"
    page.wait_for_load_state("networkidle")
    assert images and images[0][1] == 200 and images[0][2] == "image/jpeg"
    api = served["http"].get(f"{base}/v1/cameras/{cam}/region-proposals", headers=served["auth"]).json()["proposals"]
    rows = page.locator("table.regions tr.proposal")
    assert rows.count() == len(api) >= 4
    assert page.locator("#regions-svg g.proposal").count() == len(api)
    # a proposal's rectangle is drawn where the API puts it (SVG user units = frame pixels)
    rect = page.locator('#regions-svg g.proposal[data-proposal="1"] rect')
    assert [int(rect.get_attribute(a)) for a in ("x", "y", "width", "height")] == \
        [api[0][k] for k in ("x", "y", "width", "height")]
    shot = tmp_path / "regions-desktop.png"
    page.screenshot(path=str(shot), full_page=True)
    _keep(shot)
    # keep the first two proposals (renamed), drop the rest, add one by coordinates
    best = max(p["score"] for p in api)
    for i in range(rows.count()):
        box = page.locator(f'input[name="p{i}_keep"]')
        assert box.is_checked() == (api[i]["score"] >= round(best / 2, 2))  # no regions yet: good proposals ticked
        if i < 2:
            box.check()
        if i >= 2:
            box.uncheck()
    page.fill('input[name="p0_id"]', "wall")
    page.fill('input[name="new_id"]', "door")
    page.fill('input[name="new_x"]', "10")
    page.fill('input[name="new_y"]', "20")
    page.fill('input[name="new_w"]', "30")
    page.fill('input[name="new_h"]', "40")
    with page.expect_navigation():
        page.click("#save-regions")
    assert page.url == f"{base}/cameras/{cam}/regions?saved=1"
    assert page.locator("#saved").inner_text() == "Saved 3 regions."
    got = served["http"].get(f"{base}/v1/cameras/{cam}", headers=served["auth"]).json()["regions"]
    assert got == [{"id": "wall", **{k: api[0][k] for k in ("x", "y", "width", "height")}},
                   {"id": "p2", **{k: api[1][k] for k in ("x", "y", "width", "height")}},
                   {"id": "door", "x": 10, "y": 20, "width": 30, "height": 40}]
    assert page.locator("#regions-svg g.region").count() == 3
    assert not problems, problems  # no CSP violation, no failed load
    phone = browser.new_context(viewport=PHONE, storage_state=ctx.storage_state())
    p2 = phone.new_page()
    p2.goto(f"{base}/cameras/{cam}/regions")
    width = p2.evaluate("document.querySelector('#regions-svg').getBoundingClientRect().width")
    assert 300 <= width <= PHONE["width"]  # the frame scales to the phone's width
    shot = tmp_path / "regions-phone.png"
    p2.screenshot(path=str(shot), full_page=True)
    _keep(shot)
    phone.close()
    ctx.close()
