"""/healthz and /metrics."""

from __future__ import annotations


def test_healthz(client):
    r = client.get("/healthz")
    assert r.status_code == 200 and r.json()["status"] == "ok"


def test_metrics(populated):
    text = populated.client.get("/metrics").text
    count = next(ln for ln in text.splitlines() if ln.startswith("illumon_frames_ingested_total "))
    assert int(count.split()[1]) >= 12
    assert "illumon_estimate_seconds_count" in text
    assert "illumon_refit_seconds_sum" in text
    assert "illumon_http_errors_total" in text
