"""Helpers and fixtures of the service tests (imported by conftest.py): a TestClient on a temporary data dir and a camera
with rendered frames.

The scene: a measured camera (Nikon D5100), 8 measured reflectances as static regions on a grey background, 12 Granada
daylight spectra, per-pixel noise and a moving clutter rectangle (a passer-by) that partly covers regions; frames are
encoded sRGB 8-bit PNG. Tests that need the measured data skip when ``illumon.simulation.datasets.shared_data_dir()`` is None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from illumon.camera import ResponseCurve, camera_white, render
from illumon.simulation import datasets
from illumon_service.app import create_app
from illumon_service.settings import Settings

ADMIN = "admin-test-token"
N_FRAMES = 12
SIZE = (320, 240)  # width, height
T0 = datetime(2025, 6, 1, 6, 0, tzinfo=timezone.utc)


def same_value(a: object, b: object) -> bool:
    """Equal values of equal types, floats bit for bit (NaN equal to NaN, -0.0 not 0.0), through lists and dicts (keys
    in the same order): what a stored JSON value must read back as."""
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return list(a) == list(b) and all(same_value(a[k], b[k]) for k in a)
    return type(a) is type(b) and a == b


def admin_headers() -> dict[str, str]:
    """Authorization header of the admin."""
    return {"Authorization": f"Bearer {ADMIN}"}


def bearer(token: str) -> dict[str, str]:
    """Authorization header for ``token``."""
    return {"Authorization": f"Bearer {token}"}


def make_settings(tmp_path, **overrides) -> Settings:
    """Test settings: temporary data dir, fixed admin token, refits run inline."""
    base = {"data_dir": tmp_path, "admin_token": ADMIN, "jobs_inline": True, "max_upload_bytes": 2_000_000}
    base.update(overrides)
    return Settings(**base)


@pytest.fixture
def client(tmp_path):
    """A TestClient of a fresh service."""
    with TestClient(create_app(make_settings(tmp_path))) as c:
        yield c


def need_data() -> None:
    """Skip the test when the measured data sets are absent."""
    if datasets.shared_data_dir() is None:
        pytest.skip("measured data (../shared/data or $ILLUMON_SHARED_DATA) not available")


@dataclass
class Scene:
    """A rendered history with its truth."""

    css: np.ndarray
    regions: list[dict]
    images: list[bytes]
    times: list[datetime]
    true_white: np.ndarray  # F × 3


def grid_regions(n: int = 8, size: int = 40) -> list[dict]:
    """``n`` square regions laid out in two rows."""
    out = []
    for i in range(n):
        col, row = i % 4, i // 4
        out.append({"id": f"r{i}", "x": 20 + col * 75, "y": 40 + row * 100, "width": size, "height": size})
    return out


def render_image(lin_regions: np.ndarray, background: np.ndarray, regions: list[dict], rng: np.random.Generator,
                 clutter: tuple[int, int, int, int] | None, encoding: str = "srgb") -> np.ndarray:
    """Linear region values (P × 3) → an RGB image (uint8 sRGB, or uint16 linear) with noise and clutter."""
    w, h = SIZE
    img = np.empty((h, w, 3))
    img[:] = background
    for r, v in zip(regions, lin_regions, strict=True):
        img[r["y"] : r["y"] + r["height"], r["x"] : r["x"] + r["width"]] = v
    img *= 1.0 + 0.02 * rng.standard_normal(img.shape)
    img += 0.002 * rng.standard_normal(img.shape)
    if clutter is not None:
        x, y, cw, ch = clutter
        img[y : y + ch, x : x + cw] = [0.6, 0.05, 0.05]
    if encoding == "srgb":
        return np.round(ResponseCurve("srgb", white_level=255).encode(img)).astype(np.uint8)
    return np.round(np.clip(img, 0, 1) * 65535).astype(np.uint16)


def paint_srgb(size: tuple[int, int], background: np.ndarray, rects: list[tuple[dict, np.ndarray]],
               rng: np.random.Generator, noise: float = 0.01) -> np.ndarray:
    """An 8-bit sRGB image (``size`` = width, height) of a flat linear ``background`` with each rectangle (a region
    dict: x, y, width, height) filled with its linear value, then multiplicative Gaussian noise of ``noise``."""
    w, h = size
    img = np.empty((h, w, 3))
    img[:] = background
    for r, v in rects:
        img[r["y"] : r["y"] + r["height"], r["x"] : r["x"] + r["width"]] = v
    img *= 1 + noise * rng.standard_normal(img.shape)
    return np.round(ResponseCurve("srgb", white_level=255).encode(np.clip(img, 0, 1))).astype(np.uint8)


def encode_png(rgb: np.ndarray, ext: str = ".png") -> bytes:
    """RGB array → encoded image bytes via OpenCV."""
    ok, buf = cv2.imencode(ext, np.ascontiguousarray(rgb[:, :, ::-1]))
    assert ok
    return buf.tobytes()


@pytest.fixture(scope="session")
def scene() -> Scene:
    """12 frames of a static scene under Granada daylight, sRGB 8-bit PNG."""
    need_data()
    rng = np.random.default_rng(7)
    css = datasets.load_camera("Nikon_D5100")
    _, day = datasets.load_granada_daylight()
    _, refl = datasets.load_reflectance_set("munsell_matt_1269")
    refl = refl[rng.choice(len(refl), 8, replace=False)]
    idx = rng.choice(len(day), N_FRAMES, replace=False)
    e = day[idx]
    regions = grid_regions()
    lin = render(css, e, refl)  # F × P × 3
    grey = render(css, e, np.full((1, 61), 0.3))[:, 0]
    images, times = [], []
    for f in range(N_FRAMES):
        k = 0.75 / lin[f].max() * np.exp(0.1 * rng.standard_normal())
        clutter = (10 + 23 * f, 30, 14, 70)  # moves across the top row, covering under half of a region
        img = render_image(lin[f] * k, grey[f] * k, regions, rng, clutter)
        images.append(encode_png(img))
        times.append(T0 + timedelta(minutes=20 * f))
    return Scene(css, regions, images, times, camera_white(css, e))


def camera_body(css: np.ndarray, regions: list[dict], encoding: str = "srgb", name: str = "test camera") -> dict:
    """JSON body registering a camera with sensitivities on the 5-nm grid."""
    wl = list(range(400, 701, 5))
    return {
        "name": name,
        "sensitivities": {"wavelength_nm": wl, "r": css[:, 0].tolist(), "g": css[:, 1].tolist(),
                          "b": css[:, 2].tolist()},
        "regions": regions,
        "response": {"encoding": encoding, "black_level": 0, "white_level": 255 if encoding == "srgb" else None},
    }


def register(client: TestClient, css: np.ndarray, regions: list[dict], **kw) -> tuple[int, str]:
    """Register a camera; returns (id, token)."""
    r = client.post("/v1/cameras", json=camera_body(css, regions, **kw), headers=admin_headers())
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["token"]


def post_image(client: TestClient, cam: int, token: str, data: bytes, taken_at: datetime | None = None,
               content_type: str = "image/png"):
    """POST one image as multipart."""
    form = {"taken_at": taken_at.isoformat()} if taken_at else {}
    return client.post(f"/v1/cameras/{cam}/frames", files={"image": ("f.png", data, content_type)}, data=form,
                       headers=bearer(token))


@dataclass
class Populated:
    """A service with the scene's camera registered, its frames posted and refitted."""

    client: TestClient
    camera_id: int
    token: str
    frame_ids: list[int]
    scene: Scene
    job: dict


@pytest.fixture(scope="session")
def populated(tmp_path_factory, scene) -> Populated:
    """Register the scene's camera, post its frames and run a refit (inline)."""
    tmp = tmp_path_factory.mktemp("populated")
    with TestClient(create_app(make_settings(tmp))) as c:
        cam, token = register(c, scene.css, scene.regions)
        ids = []
        for img, t in zip(scene.images, scene.times, strict=True):
            r = post_image(c, cam, token, img, t)
            assert r.status_code == 201, r.text
            ids.append(r.json()["frame_id"])
        r = c.post(f"/v1/cameras/{cam}/refit", headers=bearer(token))
        assert r.status_code == 202, r.text
        job = c.get(f"/v1/jobs/{r.json()['job_id']}", headers=bearer(token)).json()
        yield Populated(c, cam, token, ids, scene, job)
