"""Retention and housekeeping: what the service deletes by itself, and when.

* Frames taken more than ``retain_days`` days ago (``ILLUMON_RETAIN_DAYS``; 0, the default, keeps everything), with
  their estimates, idempotency keys, thumbnails and kept images, and refit jobs finished as long ago.
* Idempotency keys older than :data:`IDEMPOTENCY_TTL` (a retry comes within minutes, not weeks) and expired login
  sessions, whatever ``retain_days`` says.

:class:`Housekeeper` runs :func:`prune_once` every :data:`EVERY` in a daemon thread of the service (one process of
``illumon serve --workers N``: the holder of ``<data dir>/housekeeping.lock``); ``illumon prune`` runs it once, e.g.
from cron. Rows are deleted in short transactions of :data:`CHUNK` frames, files after their rows are committed
(a crash in between leaves an unreferenced file, never a row without its file).
"""

from __future__ import annotations

import logging
import os
import threading
from datetime import datetime, timedelta
from pathlib import Path

from sqlalchemy.orm import Session, sessionmaker

from . import crud
from .datafiles import data_file
from .locks import take_process_lock
from .pending import pending_files
from .settings import Settings
from .storage import make_engine, make_session_factory, utcnow

__all__ = ["prune", "prune_once", "Housekeeper", "IDEMPOTENCY_TTL", "EVERY", "CHUNK"]

log = logging.getLogger("illumon_service.retention")

IDEMPOTENCY_TTL = timedelta(days=7)
"""How long an ``Idempotency-Key`` is remembered."""
EVERY = timedelta(hours=1)
"""How often the service prunes."""
CHUNK = 2000
"""Frames deleted per transaction."""


def prune(sessions: sessionmaker[Session], data_dir: Path | str, retain_days: float,
          now: datetime | None = None) -> dict[str, int]:
    """Delete what the retention settings no longer keep (see the module docstring).

    Parameters
    ----------
    sessions
        Session factory of the service database.
    data_dir
        The data directory (thumbnails and kept images of deleted frames are removed from it).
    retain_days
        Frames taken before ``now - retain_days`` days are deleted; 0 keeps every frame.
    now
        The current time (tests); the clock by default.

    Returns
    -------
    dict
        How many ``frames``, ``estimates``, ``files``, ``jobs``, ``idempotency_keys`` and ``login_sessions`` were
        deleted.
    """
    now = now or utcnow()
    out = {"frames": 0, "estimates": 0, "files": 0, "jobs": 0, "idempotency_keys": 0, "login_sessions": 0}
    if retain_days > 0:
        cutoff = now - timedelta(days=retain_days)
        while True:
            with sessions() as s, s.begin():
                rows, counts = crud.delete_frames_before(s, cutoff, CHUNK)
            if not rows:
                break
            for k, n in counts.items():
                out[k] += n
            for r in rows:  # committed: now the files (and an original kept while the view had no regions)
                paths = [data_file(data_dir, stored) for stored in (r.thumb_path, r.image_path)]
                pending = Path(data_dir) / "pending" / f"camera-{r.camera_id}"
                if pending.is_dir():
                    paths += list(pending.glob(f"{r.id}.*"))
                for path in paths:
                    if path is not None and path.is_file():
                        path.unlink(missing_ok=True)
                        out["files"] += 1
                for path in pending_files(data_dir, r.camera_id, r.id):  # an original kept for regions to come
                    path.unlink(missing_ok=True)
                    out["files"] += 1
        with sessions() as s, s.begin():
            out["jobs"] = crud.delete_jobs_finished_before(s, cutoff)
    with sessions() as s, s.begin():
        out["idempotency_keys"] += crud.delete_keys_created_before(s, now - IDEMPOTENCY_TTL)
        out["login_sessions"] = crud.delete_expired_logins(s, now)
    if out["frames"] or out["jobs"]:
        log.info("retention (%s days): deleted %d frames, %d estimates, %d files, %d jobs", retain_days,
                 out["frames"], out["estimates"], out["files"], out["jobs"])
    return out


def prune_once(settings: Settings, now: datetime | None = None) -> dict[str, int]:
    """:func:`prune` with the settings' database, data directory and ``retain_days`` (``illumon prune``)."""
    if not Path(settings.data_dir).is_dir():
        raise ValueError(f"{settings.data_dir}: no such data directory")
    engine = make_engine(settings.resolved_database_url)
    try:
        return {"retain_days": settings.retain_days,
                **prune(make_session_factory(engine), settings.data_dir, settings.retain_days, now)}
    finally:
        engine.dispose()


class Housekeeper:
    """Runs :func:`prune` at start and every :data:`EVERY` in a daemon thread, in one process per data directory."""

    def __init__(self, sessions: sessionmaker[Session], settings: Settings, every: timedelta = EVERY) -> None:
        self.sessions = sessions
        self.settings = settings
        self.every = every
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock_fd: int | None = None
        self.runs = 0
        """Completed prunes (tests)."""

    def _take_lock(self) -> bool:
        held, self._lock_fd = take_process_lock(Path(self.settings.data_dir) / "housekeeping.lock")
        return held

    def start(self) -> None:
        """Start the thread (no-op when another process sharing the data directory runs it)."""
        if self._thread is not None or not self._take_lock():
            return

        def loop() -> None:
            while True:
                try:
                    prune(self.sessions, self.settings.data_dir, self.settings.retain_days)
                    self.runs += 1
                except Exception:  # noqa: BLE001 - logged; the next round tries again
                    log.exception("housekeeping failed")
                if self._stop.wait(self.every.total_seconds()):
                    return

        self._thread = threading.Thread(target=loop, name="illumon-housekeeping", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread and release the lock."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None
