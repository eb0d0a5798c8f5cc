"""/wb-gains and illumon.gains: every convention agrees with the estimate's RGB gains."""

from __future__ import annotations

import numpy as np
import pytest
from illumon.gains import all_conventions
from svc_helpers import bearer


def _check(g: dict, gains_rgb: list[float]) -> None:
    r, one, b = g["rgb"]
    assert one == 1.0
    np.testing.assert_allclose([r, one, b], gains_rgb, rtol=1e-9)
    np.testing.assert_allclose(g["libcamera"]["ColourGains"], [r, b])
    np.testing.assert_allclose(g["dng"]["AsShotNeutral"], [1 / r, 1, 1 / b])
    np.testing.assert_allclose(g["android"]["RggbChannelVector"], [r, 1, 1, b])
    assert g["onvif"]["Mode"] == "MANUAL"
    np.testing.assert_allclose([g["onvif"]["CrGain"], g["onvif"]["CbGain"]], [r, b])
    assert g["v4l2"]["red_balance"] == round(1000 * r) and g["v4l2"]["blue_balance"] == round(1000 * b)
    assert 2800 <= g["v4l2"]["white_balance_temperature"] <= 6500


def test_wb_gains_every_frame(populated):
    c, cam, token = populated.client, populated.camera_id, populated.token
    est = c.get(f"/v1/cameras/{cam}/estimates", headers=bearer(token)).json()
    for e in est:
        r = c.get(f"/v1/cameras/{cam}/wb-gains", params={"at": e["taken_at"]}, headers=bearer(token))
        assert r.status_code == 200
        g = r.json()
        assert g["taken_at"] == e["taken_at"] and g["confidence"] == e["confidence"]
        _check(g, e["gains_rgb"])
        assert g["libcamera"]["ColourTemperature"] == round(e["cct_k"])
    # against the rendered truth, not the service's own formula: gain_c = white_g / white_c of the true white
    truth = populated.scene.true_white[:, 1:2] / populated.scene.true_white
    by_id = {e["frame_id"]: e for e in est}
    for i, fid in enumerate(populated.frame_ids):
        g = c.get(f"/v1/cameras/{cam}/wb-gains", params={"at": by_id[fid]["taken_at"]}, headers=bearer(token)).json()
        np.testing.assert_allclose(g["rgb"], truth[i], rtol=0.03)


def test_onvif_range(populated):
    c, cam, token = populated.client, populated.camera_id, populated.token
    g = c.get(f"/v1/cameras/{cam}/wb-gains", params={"onvif_range": "0,255"}, headers=bearer(token)).json()
    r, _, b = g["rgb"]
    for gain, v in ((r, g["onvif"]["CrGain"]), (b, g["onvif"]["CbGain"])):
        assert 0 <= v <= 255
        assert (v > 127.5) == (gain > 1)
    bad = c.get(f"/v1/cameras/{cam}/wb-gains", params={"onvif_range": "9,1"}, headers=bearer(token))
    assert bad.status_code == 422 and "onvif_range" in bad.json()["detail"]


def test_core_conventions():
    g = all_conventions([0.5, 1.0, 0.8], 5000.0, onvif_range=(0, 100))
    assert g["rgb"] == [2.0, 1.0, 1.25]
    assert g["onvif"]["CrGain"] == pytest.approx(50 + 50 * 1 / 2)  # log2(2) = 1 of ±2
    assert g["dng"]["AsShotNeutral"] == [0.5, 1.0, 0.8]
    with pytest.raises(ValueError):
        all_conventions([0.0, 1.0, 1.0], 5000.0)


def test_v4l2_temperature_clamp_is_said(client):
    """Issue 19: a 9806 K estimate answered white_balance_temperature 6500 with no word; the answer now says so."""
    from datetime import datetime, timezone

    from illumon_service.storage import Estimate, Frame
    from svc_helpers import grid_regions, register

    cid, token = register(client, np.ones((61, 3)), grid_regions())
    t = datetime(2025, 6, 1, 12, tzinfo=timezone.utc)
    with client.app.state.sessions() as s, s.begin():
        for i, cct in enumerate((9806.0, 5000.0)):
            f = Frame(camera_id=cid, taken_at=t.replace(hour=12 + i), patches={})
            s.add(f)
            s.flush()
            s.add(Estimate(frame_id=f.id, camera_id=cid, taken_at=f.taken_at, cct_k=cct, duv=0.0, xy=[0.3, 0.3],
                           white_rgb=[0.8, 1.0, 0.9], gains_rgb=[1.25, 1.0, 1 / 0.9], confidence=0.9, spectrum=[],
                           intervals=None, source="test"))
    hot = client.get(f"/v1/cameras/{cid}/wb-gains", params={"at": "2025-06-01T12:00:00Z"}, headers=bearer(token)).json()
    v = hot["v4l2"]
    assert v["white_balance_temperature"] == 6500 and v["temperature_clamped"] is True
    assert v["temperature_range_k"] == [2800, 6500]
    assert len(hot["notes"]) == 1 and "9806 K" in hot["notes"][0] and "2800–6500 K" in hot["notes"][0]
    assert v["red_balance"] == 1250  # the gains themselves are not clamped
    mild = client.get(f"/v1/cameras/{cid}/wb-gains", params={"at": "2025-06-01T13:00:00Z"}, headers=bearer(token)).json()
    assert mild["v4l2"]["white_balance_temperature"] == 5000 and mild["v4l2"]["temperature_clamped"] is False
    assert mild["notes"] == []
