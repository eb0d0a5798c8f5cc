"""A simulated day for two cameras, to look at the status page and to test it end to end.

Nothing here needs the measured data sets: sensitivities are the two NPL cameras shipped with colour-science, the
scene is ColorChecker patches (shipped with colour-science), and the light is CIE daylight along the daylight locus,
warm at dawn and dusk and bluest at noon, rendered and noised by :func:`illumon.simulation.simulate_history`.

* ``roof``: a clear day, every patch seen in every frame.
* ``yard``: an overcast day whose late frames lose two patches (a shadow or an obstruction: region values missing)
  and see one patch clipped, so its row on the status page carries alerts.

The flow is that of a real deployment: register, post the morning's observations, refit (multi-frame retrieval and a
scene model), then post the afternoon, whose frames are estimated one by one by the model, with intervals.

Run ``python -m illumon_service.demo --url http://127.0.0.1:8000 --token-file var/admin_token`` against a running
service (``make run``) to fill it; the module only uses the standard library to talk HTTP.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import urllib.request
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

__all__ = ["DemoCamera", "demo_cameras", "post_day"]

DAY = datetime(2025, 6, 21, tzinfo=timezone.utc)
"""The simulated day (UTC)."""


@dataclass
class DemoCamera:
    """A camera's registration body and its day of observation bodies (linear values 0…1)."""

    name: str
    body: dict
    observations: list[dict]
    refit_after: int
    """Number of observations to post before the refit."""
    true_cct: list[float] = field(default_factory=list)


def _cct_of_day(hours: np.ndarray, low: float, high: float) -> np.ndarray:
    """CCT (K) along a day: ``low`` at 05:00 and 19:00 UTC, ``high`` at noon."""
    return low + (high - low) * np.sin(np.pi * np.clip((hours - 5.0) / 14.0, 0.0, 1.0))


def _camera(name: str, npl_camera: str, patches: list[int], hours: np.ndarray, cct: np.ndarray, seed: int,
            refit_after: int, trouble_from: int | None = None) -> DemoCamera:
    import colour
    from illumon.daylight import daylight_locus_xy, daylight_spectrum
    from illumon.priors import colourchecker_reflectances
    from illumon.simulation import simulate_history
    from illumon.spectra import GRID, resample_columns

    sd = colour.MSDS_CAMERA_SENSITIVITIES[npl_camera]
    wl, vals = np.asarray(sd.wavelengths, dtype=float), np.asarray(sd.values, dtype=float)
    if wl[-1] < 700:  # the Sigma data stop at 680 nm: extend with a fast decay (an IR-cut filter's tail)
        step = float(wl[-1] - wl[-2])
        tail = np.arange(wl[-1] + step, 700.0 + step / 2, step)
        wl = np.concatenate([wl, tail])
        vals = np.vstack([vals, vals[-1] * np.exp(-(tail - sd.wavelengths[-1]) / 10.0)[:, None]])
    css = np.clip(resample_columns(wl, vals, GRID), 0.0, None)
    _, refl = colourchecker_reflectances()
    refl = refl[patches]
    sim = simulate_history(css, daylight_spectrum(daylight_locus_xy(cct)), refl, rng=seed)
    ids = [f"p{j:02d}" for j in range(len(patches))]
    regions = [{"id": rid, "x": 16 + 48 * (j % 6), "y": 16 + 48 * (j // 6), "width": 32, "height": 32}
               for j, rid in enumerate(ids)]
    wl = [float(v) for v in range(400, 701, 5)]
    body = {
        "name": name,
        "sensitivities": {"wavelength_nm": wl, "r": css[:, 0].tolist(), "g": css[:, 1].tolist(), "b": css[:, 2].tolist()},
        "regions": regions,
        "response": {"encoding": "linear"},
    }
    values = sim.observations.values
    obs = []
    for i, h in enumerate(hours):
        patches_i: dict[str, list[float] | None] = {rid: [float(v) for v in values[i, j]] for j, rid in enumerate(ids)}
        if trouble_from is not None and i >= trouble_from:
            patches_i[ids[0]] = None  # shadowed / obstructed: the region is missing
            patches_i[ids[1]] = None
            patches_i[ids[2]] = [0.995, 0.97, 0.99]  # a glint: clipped
        obs.append({"taken_at": (DAY + timedelta(hours=float(h))).isoformat(), "patches": patches_i})
    return DemoCamera(name, body, obs, refit_after, [float(v) for v in cct])


def demo_cameras(frames: int = 28) -> list[DemoCamera]:
    """The two demo cameras with ``frames`` observations each, every 30 min from 05:30 UTC."""
    hours = 5.5 + 0.5 * np.arange(frames)
    refit_after = max(2, frames * 4 // 7)
    roof = _camera("roof", "Nikon 5100 (NPL)", [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 13, 14], hours,
                   _cct_of_day(hours, 3800.0, 6400.0), seed=1, refit_after=refit_after)
    yard = _camera("yard", "Sigma SDMerill (NPL)", [1, 2, 5, 9, 10, 11, 15, 16, 17, 18], hours,
                   _cct_of_day(hours, 5600.0, 7200.0), seed=2, refit_after=refit_after,
                   trouble_from=max(refit_after + 1, frames - 4))
    return [roof, yard]


def _call(base: str, method: str, path: str, token: str, body: dict | None = None) -> dict:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base.rstrip("/") + path, data=data, method=method,
                                 headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"})
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # the operator's own service: no proxy
    with opener.open(req, timeout=300) as resp:
        return json.loads(resp.read() or b"null")


def post_day(base: str, admin_token: str, cameras: list[DemoCamera] | None = None, timeout: float = 300.0) -> list[dict]:
    """Register the demo cameras on the service at ``base``, post their day and refit; returns ``[{id, token, name}]``."""
    out = []
    for cam in cameras or demo_cameras():
        reg = _call(base, "POST", "/v1/cameras", admin_token, cam.body)
        cid, token = reg["id"], reg["token"]
        for i, ob in enumerate(cam.observations):
            if i == cam.refit_after:
                job = _call(base, "POST", f"/v1/cameras/{cid}/refit", token)
                deadline = time.monotonic() + timeout
                while True:
                    state = _call(base, "GET", f"/v1/jobs/{job['job_id']}", token)
                    if state["state"] in ("done", "failed") or time.monotonic() > deadline:
                        break
                    time.sleep(0.2)
                if state["state"] != "done":
                    raise RuntimeError(f"refit of camera {cid} did not finish: {state}")
            _call(base, "POST", f"/v1/cameras/{cid}/observations", token, ob)
        out.append({"id": cid, "token": token, "name": cam.name})
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m illumon_service.demo``: fill a running service with the two demo cameras."""
    p = argparse.ArgumentParser(prog="python -m illumon_service.demo", description=__doc__.split("\n\n")[0])
    p.add_argument("--url", default="http://127.0.0.1:8000", help="service address (http://127.0.0.1:8000)")
    p.add_argument("--token-file", default="var/admin_token", help="file holding the admin token (var/admin_token)")
    p.add_argument("--frames", type=int, default=28, help="observations per camera (28: 05:30–19:00 UTC)")
    args = p.parse_args(argv)
    token = Path(args.token_file).read_text().strip()
    for cam in post_day(args.url, token, demo_cameras(args.frames)):
        print(f"camera {cam['id']} ({cam['name']}): token {cam['token']}  page {args.url.rstrip('/')}/cameras/{cam['id']}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
