"""GroupCommit: concurrent writes share one commit, none returns before it, a failing write fails alone."""

from __future__ import annotations

import threading
from datetime import datetime, timezone

import pytest
from illumon_service.storage import Camera, Frame, GroupCommit, make_engine, make_session_factory
from sqlalchemy import func, select


@pytest.fixture
def sessions(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'db.sqlite3'}")
    factory = make_session_factory(engine)
    with factory() as s:
        s.add(Camera(name="c", token_hash="h", sensitivities=[], regions=[], response={}))
        s.commit()
    yield factory
    engine.dispose()


def _frame_writer(release: threading.Event | None = None, fail: bool = False):
    def write(session) -> int:
        if release is not None:
            release.wait(10)
        if fail:
            raise ValueError("bad frame")
        frame = Frame(camera_id=1, taken_at=datetime.now(timezone.utc), patches={})
        session.add(frame)
        session.flush()
        return frame.id

    return write


def _count(sessions) -> int:
    with sessions() as s:
        return s.scalar(select(func.count()).select_from(Frame))


def test_concurrent_writes_share_commits_and_fail_alone(sessions):
    commits = GroupCommit(sessions)
    release = threading.Event()
    results: dict[int, object] = {}
    seen_on_return: dict[int, bool] = {}

    def run(i: int, write) -> None:
        try:
            results[i] = commits.submit(write)
            with sessions() as s:  # committed by the time submit returns: visible to another connection
                seen_on_return[i] = s.get(Frame, results[i]) is not None
        except ValueError as exc:
            results[i] = exc

    first = threading.Thread(target=run, args=(0, _frame_writer(release)))
    first.start()  # leads, and blocks inside its write until the others are queued
    others = [threading.Thread(target=run, args=(i, _frame_writer(fail=i == 5))) for i in range(1, 8)]
    for t in others:
        t.start()
    while len(commits._pending) < 7:  # noqa: SLF001 - wait until the seven are queued behind the first
        threading.Event().wait(0.01)
    release.set()
    for t in [first, *others]:
        t.join(20)
    assert isinstance(results[5], ValueError)
    ids = [results[i] for i in range(8) if i != 5]
    assert len(set(ids)) == 7 and all(isinstance(v, int) for v in ids)
    assert all(seen_on_return.values()) and len(seen_on_return) == 7
    assert _count(sessions) == 7
    # 1 (the first) + 7 queued: one batch that failed on frame 5 and ran again one write each (6 commits)
    assert commits.batches == 1 + 6


def test_queued_writes_commit_together(sessions):
    commits = GroupCommit(sessions)
    release = threading.Event()
    threads = [threading.Thread(target=commits.submit, args=(_frame_writer(release if i == 0 else None),))
               for i in range(6)]
    threads[0].start()
    while not commits._leading:  # noqa: SLF001
        threading.Event().wait(0.01)
    for t in threads[1:]:
        t.start()
    while len(commits._pending) < 5:  # noqa: SLF001
        threading.Event().wait(0.01)
    release.set()
    for t in threads:
        t.join(20)
    assert _count(sessions) == 6
    assert commits.batches == 2  # the first alone, then the five queued behind it in one transaction
