"""Region statistics measured beside the registration (issue 29): a frame alone in its process has its regions
measured in another thread at the view's latest whole-pixel shift while it registers; the answer equals measuring
after the registration, when the guess holds and when the frame moved."""

from __future__ import annotations

import cv2
import numpy as np
from illumon_service import ingest
from illumon_service.decode import decode_frame
from illumon_service.metrics import Metrics
from illumon_service.regions import Region, response_for
from svc_helpers import make_settings

REGIONS = [{"id": f"r{i}", "x": 60 + 90 * i, "y": 80, "width": 40, "height": 40} for i in range(5)]


def _frame(dx: int) -> bytes:
    rng = np.random.default_rng(0)
    scene = cv2.GaussianBlur(rng.random((300, 600, 3)).astype(np.float32), (0, 0), 3) * 0.5 + 0.2
    for i, r in enumerate(REGIONS):
        scene[r["y"] - 10 : r["y"] + 50, r["x"] - 10 : r["x"] + 50] = (0.2 + 0.1 * i, 0.5, 0.7 - 0.1 * i)
    img = np.roll(scene, dx, axis=1)[20:260, 20:580]
    img = img * (1 + 0.01 * rng.standard_normal(img.shape))
    return cv2.imencode(".png", np.round(np.clip(img, 0, 1) * 65535).astype(np.uint16))[1].tobytes()


def test_beside_equals_after(tmp_path) -> None:
    settings = make_settings(tmp_path)
    regions = [dict(r, y=r["y"] - 20, x=r["x"] - 20) for r in REGIONS]
    got = {}
    for alone in (False, True):
        ingest._LAST_SHIFT.clear()
        for k, dx in enumerate((0, 0, 3, 3, -2)):  # reference, same shift, moved, same again, moved back
            frame = decode_frame(_frame(dx), [Region(**r) for r in regions])
            out = ingest._register_and_measure(settings, Metrics(), 7, f"v{alone}", frame,
                                               response_for({"encoding": "linear"}, frame.full_scale), regions, alone)
            got[alone, k] = out[1:]
    for k in range(5):
        assert got[True, k] == got[False, k], k
    assert got[True, 2][0].state == "ok" and round(got[True, 2][0].shift[0]) == 3
    assert all(v is not None for v in got[True, 3][1].values())
