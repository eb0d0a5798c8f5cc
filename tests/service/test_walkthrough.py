"""The README's walkthrough (issue 19), run as written against a live ``illumon serve``.

The commands are read from the README itself (the fenced block between ``<!-- walkthrough:begin`` and
``<!-- walkthrough:end -->``), so the README and this test cannot drift; only the server's address and the admin token
file are substituted. The frames the walkthrough posts are rendered here: the README camera's own sensitivities, six
ColorChecker patches (colour-science's BabelColor data) as its regions on a grey background, CIE daylight from 4000 K
to 9000 K, noise, sRGB-encoded JPEG as an ordinary camera sends.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from datetime import datetime, timedelta, timezone
from pathlib import Path

import cv2
import numpy as np
import pytest
from illumon.camera import ResponseCurve, angular_error_deg, camera_white, render
from illumon.daylight import daylight_locus_xy, daylight_spectrum
from illumon.reflectance import colourchecker_reflectances
from illumon.spectra import sensitivities_from_arrays
from serve_helpers import start_server

README = Path(__file__).resolve().parents[2] / "README.md"
PATCHES = ["dark skin", "foliage", "moderate red", "yellow green", "blue", "neutral 5 (.70 D)"]
"""ColorChecker patches painted into the walkthrough's six regions."""
N_FRAMES = 10


def walkthrough_script(readme: str = README.read_text()) -> str:
    """The shell commands of the README's walkthrough block."""
    m = re.search(r"<!-- walkthrough:begin.*?-->\s*```sh\n(.*?)```\s*<!-- walkthrough:end -->", readme, re.S)
    assert m, "README has no walkthrough block"
    return m.group(1)


def _camera_json(script: str) -> dict:
    m = re.search(r"cat > camera.json <<'JSON'\n(.*?)\nJSON\n", script, re.S)
    assert m, "walkthrough registers no camera.json"
    return json.loads(m.group(1))


def _render_frames(body: dict, folder: Path) -> tuple[list[datetime], np.ndarray]:
    """JPEG frames of the README camera named by their UTC time; returns the times and the true camera whites."""
    s = body["sensitivities"]
    css = sensitivities_from_arrays(s["wavelength_nm"], np.column_stack([s["r"], s["g"], s["b"]]), source="README")
    names, refl = colourchecker_reflectances()
    refl = refl[[names.index(n) for n in PATCHES]]
    rng = np.random.default_rng(19)
    ccts = np.linspace(4000, 9000, N_FRAMES)
    rng.shuffle(ccts)
    e = np.stack([daylight_spectrum(xy) for xy in daylight_locus_xy(ccts)])
    lin = render(css, e, refl)
    grey = render(css, e, np.full((1, 61), 0.2))[:, 0]
    t0 = datetime(2025, 6, 1, 6, tzinfo=timezone.utc)
    times = []
    folder.mkdir()
    for f in range(N_FRAMES):
        k = 0.8 / lin[f].max()
        img = np.empty((240, 320, 3))
        img[:] = grey[f] * k
        for r, v in zip(body["regions"], lin[f] * k, strict=True):
            img[r["y"] : r["y"] + r["height"], r["x"] : r["x"] + r["width"]] = v
        img *= 1 + 0.01 * rng.standard_normal(img.shape)
        code = np.round(ResponseCurve("srgb", white_level=255).encode(np.clip(img, 0, 1))).astype(np.uint8)
        t = t0 + timedelta(minutes=30 * f)
        times.append(t)
        ok, buf = cv2.imencode(".jpg", code[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert ok
        (folder / f"{t.strftime('%Y-%m-%dT%H:%M:%SZ')}.jpg").write_bytes(buf.tobytes())
    return times, camera_white(css, e)


@pytest.mark.skipif(not (shutil.which("curl") and shutil.which("jq")), reason="the walkthrough needs curl and jq")
def test_readme_walkthrough_runs(tmp_path):
    script = walkthrough_script()
    assert "http://127.0.0.1:8000" in script and "var/admin_token" in script
    work = tmp_path / "work"
    work.mkdir()
    times, truth = _render_frames(_camera_json(script), work / "frames")
    server = start_server(tmp_path / "data", env={"ILLUMON_ADMIN_TOKEN": "walkthrough-admin"})
    try:
        (work / "var").mkdir()
        (work / "var" / "admin_token").write_text("walkthrough-admin\n")
        run = subprocess.run(["bash", "-euo", "pipefail", "-c", script.replace("http://127.0.0.1:8000", server.base)],
                             cwd=work, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, f"walkthrough failed ({run.returncode}):\n{run.stdout}\n{run.stderr}\n{server.log()}"
        lines = [json.loads(line) for line in run.stdout.splitlines()]
        posted, (job, illum, gains), cams = lines[:N_FRAMES], lines[N_FRAMES : N_FRAMES + 3], lines[N_FRAMES + 3 :]
        assert all(p["usable_regions"] == len(PATCHES) and p["warnings"] == [] for p in posted), posted
        assert job == {"state": "done", "frames": N_FRAMES, "warnings": []}, job
        assert illum["taken_at"] == times[-1].isoformat()
        assert cams == [{"id": 1, "name": "roof-east", "warnings": []}]
        # the answers are the estimates: every frame's camera white within 2° of the truth (measured 0.9–1.1°)
        with server.client() as c:
            est = c.get("/v1/cameras/1/estimates", headers={"Authorization": "Bearer walkthrough-admin"}).json()
        assert len(est) == N_FRAMES
        err = angular_error_deg(np.array([e["white_rgb"] for e in est]), truth)
        assert np.max(err) < 2.0, err
        assert gains["rgb"] == pytest.approx(est[-1]["gains_rgb"])
        assert bool(gains["notes"]) == gains["v4l2"]["temperature_clamped"]
    finally:
        server.stop()
