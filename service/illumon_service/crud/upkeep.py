"""Queries of the service's upkeep: retention (:mod:`..retention`), backups (:mod:`..backup`) and the stored file
paths of older versions (:mod:`..datafiles`)."""

from __future__ import annotations

import logging
from datetime import datetime
from pathlib import Path

from sqlalchemy import delete, func, inspect, select, text, update
from sqlalchemy.engine import Engine, Row
from sqlalchemy.orm import Session

from ..datafiles import PATH_COLUMNS, data_file, relative_form
from ..storage import Calibration, Camera, Estimate, Frame, IdempotencyKey, Job, LoginSession

__all__ = [
    "ping", "delete_frames_before", "delete_jobs_finished_before", "delete_keys_created_before",
    "delete_expired_logins", "row_counts", "has_cameras", "forget_missing_files", "relativize_paths",
]

log = logging.getLogger("illumon_service.datafiles")


def ping(session: Session) -> None:
    """A round trip to the database (raises when it does not answer)."""
    session.execute(text("SELECT 1"))


def delete_frames_before(session: Session, cutoff: datetime, limit: int) -> tuple[list[Row], dict[str, int]]:
    """Delete the oldest ``limit`` frames taken before ``cutoff`` with their estimates and idempotency keys (within
    the caller's transaction). Returns the frames' ``(id, camera_id, thumb_path, image_path)`` (their files are the
    caller's to delete once committed) and how many ``frames``, ``estimates`` and ``idempotency_keys`` went."""
    rows = list(session.execute(select(Frame.id, Frame.camera_id, Frame.thumb_path, Frame.image_path)
                                .where(Frame.taken_at < cutoff).order_by(Frame.id).limit(limit)).all())
    counts = {"frames": 0, "estimates": 0, "idempotency_keys": 0}
    if not rows:
        return rows, counts
    ids = [r.id for r in rows]
    counts["estimates"] = session.execute(delete(Estimate).where(Estimate.frame_id.in_(ids))).rowcount or 0
    counts["idempotency_keys"] = session.execute(
        delete(IdempotencyKey).where(IdempotencyKey.frame_id.in_(ids))).rowcount or 0
    counts["frames"] = session.execute(delete(Frame).where(Frame.id.in_(ids))).rowcount or 0
    return rows, counts


def delete_jobs_finished_before(session: Session, cutoff: datetime) -> int:
    """Delete the jobs that finished (done or failed) before ``cutoff``; returns how many."""
    return session.execute(delete(Job).where(Job.state.in_(("done", "failed")),
                                             Job.finished_at < cutoff)).rowcount or 0


def delete_keys_created_before(session: Session, cutoff: datetime) -> int:
    """Delete the idempotency keys stored before ``cutoff``; returns how many."""
    return session.execute(delete(IdempotencyKey).where(IdempotencyKey.created_at < cutoff)).rowcount or 0


def delete_expired_logins(session: Session, now: datetime) -> int:
    """Delete the login sessions expired at ``now``; returns how many."""
    return session.execute(delete(LoginSession).where(LoginSession.expires_at < now)).rowcount or 0


def row_counts(engine: Engine) -> dict[str, int]:
    """Rows of each table a backup's manifest counts."""
    with engine.connect() as conn:
        return {name: int(conn.execute(select(func.count()).select_from(model)).scalar_one())
                for name, model in (("cameras", Camera), ("frames", Frame), ("estimates", Estimate), ("jobs", Job),
                                    ("calibrations", Calibration), ("idempotency_keys", IdempotencyKey))}


def has_cameras(engine: Engine) -> bool:
    """Whether the database holds illumon data (a ``cameras`` table with a row)."""
    if "cameras" not in inspect(engine).get_table_names():
        return False
    with engine.connect() as conn:
        return conn.execute(select(func.count()).select_from(Camera)).scalar_one() > 0


def forget_missing_files(engine: Engine, data_dir: Path) -> int:
    """Clear the stored paths whose file is not under ``data_dir`` — frame thumbnails and kept images, and the
    cameras' scene models in use (:attr:`~.storage.Camera.models`: a view whose model file is missing has none until
    the next refit, rather than a name that cannot be read); returns how many."""
    n = 0
    with engine.begin() as conn:
        for cid, models in conn.execute(select(Camera.id, Camera.models).where(Camera.models.is_not(None))).all():
            kept = {k: v for k, v in (models or {}).items()
                    if isinstance(v, dict) and (f := data_file(data_dir / "models", str(v.get("file") or "")))
                    is not None and f.is_file()}
            if kept != (models or {}):
                conn.execute(update(Camera).where(Camera.id == cid).values(models=kept or None))
                n += len(models or {}) - len(kept)
        for col in PATH_COLUMNS:
            for fid, value in conn.execute(select(Frame.id, col).where(col.is_not(None))).all():
                path = data_file(data_dir, value)
                if path is None or not path.is_file():
                    conn.execute(update(Frame).where(Frame.id == fid).values({col.key: None}))
                    n += 1
    return n


def relativize_paths(engine: Engine, data_dir: Path | str) -> dict[str, int]:
    """Rewrite the absolute file paths of an older database relative to ``data_dir`` (see
    :func:`~..datafiles.relative_form`); those that cannot be (outside any data directory) are cleared, as the file
    is not this data directory's. Idempotent, one transaction; returns ``{"relativized": n, "cleared": m}``."""
    counts = {"relativized": 0, "cleared": 0}
    with engine.begin() as conn:
        for col in PATH_COLUMNS:
            rows = conn.execute(select(Frame.id, col).where(col.like("/%"))).all()  # POSIX absolute paths only
            for fid, value in rows:
                new = relative_form(data_dir, value)
                conn.execute(update(Frame).where(Frame.id == fid).values({col.key: new}))
                counts["relativized" if new is not None else "cleared"] += 1
    if any(counts.values()):
        log.info("file paths made relative to the data directory: %(relativized)d (cleared: %(cleared)d)", counts)
    return counts
