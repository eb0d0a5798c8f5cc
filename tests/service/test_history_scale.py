"""Storage at scale (issue 29): the (camera, time) indexes exist, on fresh and on older databases, the "latest" and
time-range queries use them, and the camera page draws a bounded number of points whatever the history's length.
No timing here: ``benchmarks/pages.py`` measures."""

from __future__ import annotations

import re
from datetime import datetime, timedelta, timezone

import pytest
from fastapi.testclient import TestClient
from illumon_service.app import create_app
from illumon_service.crud import camera_history, estimates_between, nearest_estimate
from illumon_service.status import MAX_CHART_POINTS, chart_history
from illumon_service.storage import Camera, Estimate, Frame, hash_token, make_engine, make_session_factory
from sqlalchemy import insert, inspect, text
from svc_helpers import ADMIN, make_settings

T_END = datetime(2026, 1, 1, tzinfo=timezone.utc)
INDEXES = {"frames": ("ix_frames_camera_taken", ["camera_id", "taken_at", "id"]),
           "estimates": ("ix_estimates_camera_taken", ["camera_id", "taken_at", "frame_id"])}


def _fill(url: str, sizes: list[int]) -> list[int]:
    """One camera per size, each frame with an estimate (CCT = its index), one frame a minute ending at T_END."""
    engine = make_engine(url)
    fid, ids = 0, []
    with engine.begin() as conn:
        for c, n in enumerate(sizes):
            conn.execute(insert(Camera), [{"id": c + 1, "name": f"cam {c}", "token_hash": hash_token(f"t{c}"),
                                           "sensitivities": [], "regions": [], "response": {"encoding": "srgb"}}])
            frames, ests = [], []
            for k in range(n):
                fid += 1
                t = T_END - timedelta(minutes=n - 1 - k)
                frames.append({"id": fid, "camera_id": c + 1, "taken_at": t, "patches": {}})
                ests.append({"frame_id": fid, "camera_id": c + 1, "taken_at": t, "cct_k": 4000.0 + k, "duv": 0.0,
                             "xy": [0.33, 0.34], "white_rgb": [0.6, 1.0, 0.7], "gains_rgb": [1.6, 1.0, 1.4],
                             "confidence": 0.9, "spectrum": [1.0] * 61, "source": "model",
                             "intervals": {"cct_lo": 3900.0 + k, "cct_hi": 4100.0 + k}})
            conn.execute(insert(Frame), frames)
            conn.execute(insert(Estimate), ests)
            ids.append(c + 1)
    engine.dispose()
    return ids


def _polylines(html: str, chart: str) -> list[list[str]]:
    svg = re.search(rf'<svg[^>]*id="{chart}".*?</svg>', html, re.S).group(0)
    return [m.split() for m in re.findall(r'<polyline[^>]*points="([^"]*)"', svg)]


def test_indexes_exist_on_a_fresh_database(tmp_path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path / 'db.sqlite3'}")
    for table, (name, cols) in INDEXES.items():
        found = {ix["name"]: ix["column_names"] for ix in inspect(engine).get_indexes(table)}
        assert found.get(name) == cols
    engine.dispose()


def test_indexes_added_to_an_older_database_at_start_up(tmp_path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    _fill(url, [50])
    engine = make_engine(url)
    with engine.begin() as conn:  # a database of a version before the indexes
        for name, _ in INDEXES.values():
            conn.execute(text(f"DROP INDEX {name}"))
    assert not {n for n, _ in INDEXES.values()} & {ix["name"] for t in INDEXES for ix in inspect(engine).get_indexes(t)}
    engine.dispose()
    engine = make_engine(url)  # the service's start-up
    for table, (name, cols) in INDEXES.items():
        assert {ix["name"]: ix["column_names"] for ix in inspect(engine).get_indexes(table)}.get(name) == cols
    make_engine(url).dispose()  # idempotent
    engine.dispose()


@pytest.mark.parametrize("sql", [
    "SELECT * FROM estimates WHERE camera_id = 2 ORDER BY taken_at DESC, frame_id DESC LIMIT 1",
    "SELECT * FROM estimates WHERE camera_id = 2 AND taken_at >= '2025-12-31' ORDER BY taken_at, frame_id LIMIT 10",
    "SELECT * FROM frames WHERE camera_id = 2 ORDER BY taken_at DESC, id DESC LIMIT 12",
])
def test_latest_and_range_queries_use_the_index_without_sorting(tmp_path, sql: str) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    _fill(url, [10, 300])
    engine = make_engine(url)
    with engine.connect() as conn:
        conn.exec_driver_sql("ANALYZE")
        plan = " | ".join(str(r[-1]) for r in conn.exec_driver_sql("EXPLAIN QUERY PLAN " + sql).all())
    engine.dispose()
    assert "_camera_taken" in plan and "TEMP B-TREE" not in plan, plan


def test_queries_answer_as_before(tmp_path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    small, large = _fill(url, [10, 3000])
    engine = make_engine(url)
    with make_session_factory(engine)() as s:
        latest = nearest_estimate(s, large, None)
        assert latest.taken_at.replace(tzinfo=timezone.utc) == T_END and latest.cct_k == 4000.0 + 2999
        at = T_END - timedelta(minutes=100, seconds=20)  # nearer the frame 100 minutes before the end
        assert nearest_estimate(s, large, at).cct_k == 4000.0 + 2999 - 100
        rows = estimates_between(s, large, T_END - timedelta(minutes=9), None, 1000)
        assert [e.cct_k for e in rows] == [4000.0 + k for k in range(2990, 3000)]
        assert [e.cct_k for e in estimates_between(s, small, None, None, 3)] == [4000.0, 4001.0, 4002.0]
    engine.dispose()


def test_chart_history_is_bounded_and_keeps_the_newest(tmp_path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    small, large = _fill(url, [40, 5000])
    engine = make_engine(url)
    with make_session_factory(engine)() as s:
        h = chart_history(s, small, limit=2000)
        assert h.stride == 1 and h.count == 40
        assert h.points == camera_history(s, small, limit=2000)  # short histories: every estimate, as before
        assert h.recent == list(reversed(h.points[-24:]))
        h = chart_history(s, large, limit=2000, max_points=300)
        assert h.count == 2000 and h.stride == 7 and len(h.points) <= 300
        full = camera_history(s, large, limit=2000)
        assert h.points == full[::-1][::7][::-1]  # every 7th counted from the newest, oldest first
        assert h.points[-1] == full[-1] and h.recent == list(reversed(full[-24:]))
    engine.dispose()


def test_camera_page_draws_a_bounded_number_of_points(tmp_path) -> None:
    settings = make_settings(tmp_path)
    small, large = _fill(settings.resolved_database_url, [30, 6000])
    with TestClient(create_app(settings)) as c:
        c.post("/login", data={"token": ADMIN, "next": "/"}, follow_redirects=False)
        page = c.get(f"/cameras/{small}")
        assert page.status_code == 200
        assert [len(p) for p in _polylines(page.text, "chart-cct")] == [30]  # short history: every estimate drawn
        assert "(30 estimates;" in page.text
        for limit in (2000, 20000):
            page = c.get(f"/cameras/{large}", params={"limit": limit})
            assert page.status_code == 200
            for chart in ("chart-cct", "chart-duv", "chart-gains", "chart-cct-compact"):
                lines = _polylines(page.text, chart)
                assert lines and all(0 < len(p) <= MAX_CHART_POINTS for p in lines)
            n = min(limit, 6000)
            assert f"({n} estimates, one in {-(-n // MAX_CHART_POINTS)} drawn;" in page.text
            rows = re.findall(r'<tr data-frame-id="(\d+)">', page.text)
            assert rows[0] == str(30 + 6000) and len(rows) == 24  # the newest estimate heads the table


def test_not_estimated_counts_match_the_join(tmp_path) -> None:
    """The counts without a pass over the rows equal those of the outer join of frames and estimates, also for rows
    that break the usual pattern (a frame with a reason and an estimate, frames of older versions without either)."""
    from illumon_service.crud import not_estimated_counts
    from sqlalchemy import delete, func, select, update

    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    a, b = _fill(url, [200, 300])
    engine = make_engine(url)

    def by_join(s, cid: int) -> dict[str, int]:
        rows = s.execute(select(Frame.not_estimated, func.count()).select_from(Frame)
                         .outerjoin(Estimate, Estimate.frame_id == Frame.id)
                         .where(Frame.camera_id == cid, Estimate.frame_id.is_(None))
                         .group_by(Frame.not_estimated)).all()
        return dict(sorted({(r or "pending"): int(n) for r, n in rows}.items()))

    with make_session_factory(engine)() as s:
        assert not_estimated_counts(s, a) == by_join(s, a) == {}
        s.execute(update(Frame).where(Frame.id.in_(range(201, 221))).values(not_estimated="view_change"))
        s.execute(delete(Estimate).where(Estimate.frame_id.in_(range(201, 221))))  # 20 view changes
        s.execute(update(Frame).where(Frame.id.in_(range(230, 235))).values(not_estimated="invalid_values"))
        s.execute(delete(Estimate).where(Estimate.frame_id.in_(range(230, 233))))  # 2 keep an estimate anyway
        s.execute(delete(Estimate).where(Estimate.frame_id.in_(range(300, 340))))  # 40 of older versions: pending
        s.execute(update(Frame).where(Frame.id.in_(range(5, 8))).values(not_estimated="no_model"))
        s.execute(delete(Estimate).where(Estimate.frame_id.in_(range(5, 8))))
        s.commit()
        want = {"invalid_values": 3, "pending": 40, "view_change": 20}
        assert not_estimated_counts(s, b) == by_join(s, b) == want
        assert not_estimated_counts(s, b, frames=300) == want
        assert not_estimated_counts(s, a) == by_join(s, a) == {"no_model": 3}
    engine.dispose()
