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


def _value(text: str, series: str) -> float:
    return float(next(ln for ln in text.splitlines() if ln.startswith(series + " ")).split()[1])


def test_metrics_sum_over_worker_processes(tmp_path):
    """Worker processes sharing a metrics folder: each one's /metrics answers the sum of all of them."""
    from illumon_service.metrics import Metrics

    a = Metrics(tmp_path, process_id="101", interval=3600)
    b = Metrics(tmp_path, process_id="102", interval=3600)
    a.inc("illumon_frames_ingested_total", 3)
    b.inc("illumon_frames_ingested_total", 4)
    a.observe("illumon_ingest_seconds", 0.010)
    b.observe("illumon_ingest_seconds", 0.030)
    b.observe("illumon_ingest_seconds", 0.020)
    b.publish()
    text = a.render()  # a publishes itself, reads b's snapshot
    assert _value(text, "illumon_frames_ingested_total") == 7
    assert _value(text, "illumon_ingest_seconds_count") == 3
    assert abs(_value(text, "illumon_ingest_seconds_sum") - 0.060) < 1e-12
    assert _value(text, "illumon_ingest_seconds_max") == 0.030
    assert _value(b.render(), "illumon_frames_ingested_total") == 7
    # a process alone (no folder) keeps its own figures
    solo = Metrics()
    solo.inc("illumon_frames_ingested_total", 2)
    assert _value(solo.render(), "illumon_frames_ingested_total") == 2
