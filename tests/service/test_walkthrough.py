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
from illumon.camera import angular_error_deg, camera_white, render
from illumon.daylight import daylight_locus_xy, daylight_spectrum
from illumon.priors import colourchecker_reflectances
from illumon.spectra import sensitivities_from_arrays
from serve_helpers import start_server
from svc_helpers import paint_srgb

README = Path(__file__).resolve().parents[2] / "README.md"
PATCHES = ["dark skin", "foliage", "moderate red", "yellow green", "blue", "neutral 5 (.70 D)"]
"""ColorChecker patches painted into the walkthrough's six regions."""
N_SETUP = 6
"""Frames of the first hours (``setup/``: stored for the proposals, before any region exists)."""
N_FRAMES = 10
"""Frames after the regions are confirmed (``frames/``)."""


def walkthrough_script(readme: str = README.read_text()) -> str:
    """The shell commands of the README's walkthrough block."""
    m = re.search(r"<!-- walkthrough:begin.*?-->\s*```sh\n(.*?)```\s*<!-- walkthrough:end -->", readme, re.S)
    assert m, "README has no walkthrough block"
    return m.group(1)


def _heredoc(script: str, name: str) -> dict:
    m = re.search(rf"cat > {re.escape(name)} <<'JSON'\n(.*?)\nJSON\n", script, re.S)
    assert m, f"walkthrough writes no {name}"
    return json.loads(m.group(1))


def _card_region(script: str) -> dict:
    m = re.search(r"-F kind=grey -F 'region=(\{.*?\})'", script)
    assert m, "walkthrough posts no grey card region"
    return json.loads(m.group(1))


def _render_frames(body: dict, regions: list[dict], card: dict, work: Path) -> tuple[list[datetime], np.ndarray]:
    """JPEG frames of the README camera named by their UTC time (``setup/``, then ``frames/``) and ``card.jpg``, the
    scene with a grey card (0.18) in the README's rectangle; returns the times and true camera whites of
    ``frames/``."""
    s = body["sensitivities"]
    css = sensitivities_from_arrays(s["wavelength_nm"], np.column_stack([s["r"], s["g"], s["b"]]), source="README")
    names, refl = colourchecker_reflectances()
    refl = refl[[names.index(n) for n in PATCHES]]
    rng = np.random.default_rng(19)
    n = N_SETUP + N_FRAMES + 1
    ccts = np.linspace(4000, 9000, n)
    rng.shuffle(ccts)
    e = np.stack([daylight_spectrum(xy) for xy in daylight_locus_xy(ccts)])
    lin = render(css, e, refl)
    grey = render(css, e, np.full((1, 61), 0.2))[:, 0]
    card_rgb = render(css, e, np.full((1, 61), 0.18))[:, 0]
    t0 = datetime(2025, 6, 1, 6, tzinfo=timezone.utc)
    times = [t0 + timedelta(hours=f) for f in range(N_SETUP)]
    times += [t0 + timedelta(hours=N_SETUP, minutes=30 * f) for f in range(N_FRAMES)]
    for folder in ("setup", "frames"):
        (work / folder).mkdir()
    for f in range(n):
        k = 0.8 / lin[f].max()
        rects = list(zip(regions, lin[f] * k, strict=True)) + ([(card, card_rgb[f] * k)] if f == n - 1 else [])
        code = paint_srgb((320, 240), grey[f] * k, rects, rng)
        ok, buf = cv2.imencode(".jpg", code[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert ok
        if f == n - 1:
            (work / "card.jpg").write_bytes(buf.tobytes())
        else:
            folder = "setup" if f < N_SETUP else "frames"
            (work / folder / f"{times[f].strftime('%Y-%m-%dT%H:%M:%SZ')}.jpg").write_bytes(buf.tobytes())
    return times[N_SETUP:], camera_white(css, e[N_SETUP : N_SETUP + N_FRAMES])


@pytest.mark.skipif(not (shutil.which("curl") and shutil.which("jq")), reason="the walkthrough needs curl and jq")
def test_readme_walkthrough_runs(tmp_path):
    script = walkthrough_script()
    assert "http://127.0.0.1:8000" in script and "var/admin_token" in script
    assert "curl -sf" not in script and script.count("curl --fail-with-body") >= 8  # error bodies are shown
    work = tmp_path / "work"
    work.mkdir()
    regions = _heredoc(script, "regions.json")["regions"]
    times, truth = _render_frames(_heredoc(script, "camera.json"), regions, _card_region(script), work)
    server = start_server(tmp_path / "data", env={"ILLUMON_ADMIN_TOKEN": "walkthrough-admin"})
    try:
        (work / "var").mkdir()
        (work / "var" / "admin_token").write_text("walkthrough-admin\n")
        run = subprocess.run(["bash", "-euo", "pipefail", "-c", script.replace("http://127.0.0.1:8000", server.base)],
                             cwd=work, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, f"walkthrough failed ({run.returncode}):\n{run.stdout}\n{run.stderr}\n{server.log()}"
        lines = [json.loads(line) for line in run.stdout.splitlines()]
        assert len(lines) == 1 + N_SETUP + 2 + N_FRAMES + 5, run.stdout
        registered, setup, rest = lines[0], lines[1 : 1 + N_SETUP], lines[1 + N_SETUP :]
        proposals, put, posted, rest = rest[0], rest[1], rest[2 : 2 + N_FRAMES], rest[2 + N_FRAMES :]
        calibration, job, illum, gains, camera = rest
        assert registered == {"id": 1} and (work / "camera-token.json").stat().st_mode & 0o077 == 0
        assert all(p["usable_regions"] == 0 and "no regions yet" in p["warnings"][0] for p in setup), setup
        assert proposals["frames_used"] == N_SETUP and proposals["hours_covered"] == N_SETUP
        assert proposals["warnings"] == [] and len(proposals["proposals"]) >= 3, proposals
        assert put == {"regions": [r["id"] for r in regions]}
        assert all(p["usable_regions"] == len(PATCHES) and p["warnings"] == [] and p["estimate"] is None
                   for p in posted), posted
        assert calibration["kind"] == "grey" and calibration["scene_regions"] == len(regions), calibration
        assert calibration["clipped"] == 0 and calibration["warnings"] == []
        # every frame after the regions (and the set-up frames too where their kept originals are measured once the
        # regions are confirmed) estimated, no error, no warning
        assert {**job, "frames": None} == {"state": "done", "frames": None, "error": None, "warnings": [], "detail": None}
        assert job["frames"] in (N_FRAMES, N_SETUP + N_FRAMES), job
        assert illum["taken_at"] == times[-1].isoformat()
        assert camera["name"] == "roof-east" and camera["calibration"] == "grey" and camera["warnings"] == []
        assert isinstance(camera["alerts"], list), camera
        # the answers are the estimates: every frame's camera white within 1.5° of the truth
        with server.client() as c:
            est = c.get("/v1/cameras/1/estimates", headers={"Authorization": "Bearer walkthrough-admin"}).json()
        est = [e for e in est if e["taken_at"] in {t.isoformat() for t in times}]
        assert len(est) == N_FRAMES
        err = angular_error_deg(np.array([e["white_rgb"] for e in est]), truth)
        assert np.max(err) < 1.5, err
        print(f"\nwalkthrough: camera white error median {np.median(err):.2f}°, max {np.max(err):.2f}°; "
              f"alerts {[a['kind'] for a in camera['alerts']]}")
        assert gains["rgb"] == pytest.approx(est[-1]["gains_rgb"])
        # …and the gains are the true white's (gain_c = white_g / white_c), not only the service's own formula
        assert gains["rgb"] == pytest.approx(list(truth[-1, 1] / truth[-1]), rel=0.06)
        assert bool(gains["notes"]) == gains["v4l2"]["temperature_clamped"]
    finally:
        server.stop()


def test_readme_synopsis_matches_the_parser():
    """Every ``illumon`` subcommand is in the README's synopsis, and every option the synopsis names exists."""
    import argparse

    from illumon.cli import build_parser

    block = re.search(r"## Command line\s*```\n(.*?)```", README.read_text(), re.S)
    assert block, "README has no command-line synopsis"
    text = block.group(1).replace("\\\n", " ")
    commands = [line.split() for line in text.splitlines() if line.startswith("illumon ")]
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert {c[1] for c in commands} == set(sub.choices), "README synopsis and `illumon` subcommands differ"
    for words in commands:
        p = sub.choices[words[1]]
        if words[1] == "report":
            p = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction)).choices[words[2]]
        known = {o for a in p._actions for o in a.option_strings}
        named = {w.strip("[]|").split("=")[0] for w in words if w.strip("[").startswith("--")}
        assert named <= known, (words[1], named - known)
