"""Queries of the ``estimates`` table and the public form of an estimate (:func:`estimate_out`), which the JSON API,
the status page and the ingest answer all use, so they cannot disagree."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime

from sqlalchemy import delete, select, update
from sqlalchemy.engine import Row
from sqlalchemy.orm import Session

from ..storage import Estimate, Frame, as_utc, insert_columns, spectrum_values, upsert_dialect, utcnow

__all__ = [
    "estimate_non_daylight", "estimate_out", "estimate_spectrum", "nearest_estimate", "estimates_between", "latest_estimate",
    "camera_history", "recent_estimate_ids", "estimate_rows", "estimated_frame_ids", "add_estimate",
    "replace_estimates", "drop_estimates", "WRITE_CHUNK",
]

WRITE_CHUNK = 2000
"""Rows a statement of a refit's transaction names at most (one transaction; statements of bounded size)."""


def estimate_non_daylight(e: Estimate) -> float | None:
    """The estimate's ``non_daylight`` (posterior probability that its light is not daylight,
    :mod:`illumon.model.lamps`), stored with its intervals; ``None`` for estimates made without it."""
    v = (getattr(e, "intervals", None) or {}).get("non_daylight")
    return float(v) if isinstance(v, (int, float)) else None


_PUBLIC = ("cct_k", "duv", "xy", "white_rgb", "gains_rgb", "confidence")
"""Columns of an estimate given as stored."""


def estimate_out(e: Estimate) -> dict:
    """The public fields of an estimate (a row of :class:`.storage.Estimate`, or a row with its columns by name)."""
    return {"frame_id": e.frame_id, "taken_at": as_utc(e.taken_at).isoformat(), **{k: getattr(e, k) for k in _PUBLIC},
            "non_daylight": estimate_non_daylight(e), "source": e.source}


def _newest_first(session: Session, camera_id: int, limit: int) -> Sequence[Estimate]:
    """The camera's ``limit`` most recent estimates, newest first."""
    q = select(Estimate).where(Estimate.camera_id == camera_id)
    return session.scalars(q.order_by(Estimate.taken_at.desc(), Estimate.frame_id.desc()).limit(limit)).all()


def latest_estimate(session: Session, camera_id: int) -> Estimate | None:
    """The camera's most recent estimate, or ``None``."""
    rows = _newest_first(session, camera_id, 1)
    return rows[0] if rows else None


def nearest_estimate(session: Session, camera_id: int, at: datetime | None) -> Estimate | None:
    """The estimate nearest ``at`` (the latest without it), or ``None`` when the camera has none yet."""
    if at is None:
        return latest_estimate(session, camera_id)
    q = select(Estimate).where(Estimate.camera_id == camera_id)
    at = as_utc(at)
    before = session.scalars(q.where(Estimate.taken_at <= at).order_by(Estimate.taken_at.desc()).limit(1)).first()
    after = session.scalars(q.where(Estimate.taken_at > at).order_by(Estimate.taken_at.asc()).limit(1)).first()
    cands = [c for c in (before, after) if c is not None]
    return min(cands, key=lambda c: abs((as_utc(c.taken_at) - at).total_seconds())) if cands else None


_COLUMNS = [c for c in Estimate.__table__.columns if c.name not in ("spectrum", "spectrum_f32")]
"""Every column of an estimate but its spectrum (either form): rows rather than ORM objects, a third of the time for
1000 rows (:func:`estimate_out` reads them alike)."""


def estimate_spectrum(e: Estimate) -> list[float] | None:
    """The estimate's spectrum (61 values, 100 at 560 nm): float32 bytes as floats where the row has them, the JSON
    list of rows older versions wrote as it was (:func:`.storage.spectrum_values`)."""
    return spectrum_values(e)


def estimates_between(session: Session, camera_id: int, since: datetime | None, until: datetime | None,
                      limit: int) -> Sequence[Row]:
    """A camera's estimates in ``since`` ≤ taken_at ≤ ``until``, oldest first, at most ``limit``: a range of the
    (camera, time) index. Rows with every column of :class:`.storage.Estimate` by name but its spectrum."""
    q = select(*_COLUMNS).where(Estimate.camera_id == camera_id)
    if since is not None:
        q = q.where(Estimate.taken_at >= as_utc(since))
    if until is not None:
        q = q.where(Estimate.taken_at <= as_utc(until))
    return session.execute(q.order_by(Estimate.taken_at, Estimate.frame_id).limit(limit)).all()


def camera_history(session: Session, camera_id: int, limit: int = 2000) -> list[dict]:
    """The camera's most recent ``limit`` estimates, oldest first, as the JSON API gives them plus ``intervals``."""
    out = []
    for e in reversed(_newest_first(session, camera_id, max(1, limit))):
        d = estimate_out(e)
        d["intervals"] = e.intervals
        out.append(d)
    return out


def recent_estimate_ids(session: Session, camera_id: int, limit: int) -> list[int]:
    """Frame ids of the camera's ``limit`` most recent estimates, newest first (an index-only range scan of
    ``ix_estimates_camera_taken``)."""
    order = (Estimate.taken_at.desc(), Estimate.frame_id.desc())
    return list(session.scalars(select(Estimate.frame_id).where(Estimate.camera_id == camera_id).order_by(*order)
                                .limit(limit)).all())


ID_CHUNK = 900
"""Ids bound per statement when reading rows by id: under SQLite's default limit of bound parameters of old
versions (999)."""


def estimate_rows(session: Session, frame_ids: Sequence[int]) -> list[Row]:
    """The estimates of ``frame_ids`` (sorted by id) as rows without their spectra, fetched by primary key."""
    wanted = sorted(frame_ids)
    out: list[Row] = []
    for start in range(0, len(wanted), ID_CHUNK):
        out += session.execute(select(*_COLUMNS).where(Estimate.frame_id.in_(wanted[start : start + ID_CHUNK]))).all()
    return out


def estimated_frame_ids(session: Session, frame_ids: Sequence[int]) -> set[int]:
    """Those of ``frame_ids`` that have an estimate."""
    if not frame_ids:
        return set()
    return set(session.scalars(select(Estimate.frame_id).where(Estimate.frame_id.in_(frame_ids))).all())


def add_estimate(session: Session, **columns: object) -> Estimate:
    """A new estimate row, added and flushed."""
    row = Estimate(**columns)
    session.add(row)
    session.flush()
    return row


def replace_estimates(session: Session, chunks: Iterable[Mapping[str, Sequence]], *, camera_id: int,
                      **constants: object) -> int:
    """Replace the estimates of the frames of ``chunks`` (frames of camera ``camera_id``) and clear those frames'
    reason for having none; returns the rows written. Each chunk holds the estimate's columns a column at a time
    (``frame_id`` among them; at most :data:`WRITE_CHUNK` rows), ``constants`` the columns every row has the same
    value of (``model``), and ``created_at`` is the chunk's time. SQLAlchemy Core statements within the caller's
    transaction:

    * the spectrum's two columns (``spectrum``, the JSON of older versions, and ``spectrum_f32``) are both written,
      the one a chunk does not give as ``None`` (the JSON column's ``null``);
    * per chunk one executemany INSERT (:func:`.storage.insert_columns`); when a frame of the chunk has a stored
      estimate, its rows replace the stored ones (``replace_on``: ``INSERT … ON CONFLICT (frame_id) DO UPDATE`` of
      every column, where :func:`.storage.upsert_dialect`: SQLite ≥ 3.24, PostgreSQL; elsewhere a DELETE of the
      chunk's frames first) — the same rows as a DELETE and INSERT, every column being given. Which frames have
      one is read once (the camera's estimates, an index-only scan; every writer stores an estimate under its
      frame's camera): a chunk of frames without any is a plain INSERT (on SQLite the upsert into an empty range
      cost 0.35 s more CPU at 100k frames than the INSERT; over stored rows it saves 0.7 s);
    * the frames of the camera that have a reason are read once from the partial index
      ``ix_frames_camera_not_estimated`` (few), and only those of a chunk are updated: an UPDATE naming every frame
      written looked up 100k frames by key to change none. The set read stays right for the transaction: the caller
      holds the camera's row (:func:`.refit.write_refit`: no other refit of the camera runs its write meanwhile), and
      an ingest records a reason only for the frame it stores, in the transaction that stores it (a frame this one
      cannot be writing unless it saw it committed, reason included).
    """
    estimates, frames = Estimate.__table__, Frame.__table__
    upsert = upsert_dialect(session.connection().dialect)
    marked = set(session.scalars(select(frames.c.id).where(frames.c.camera_id == camera_id,
                                                           frames.c.not_estimated.is_not(None))).all())
    stored = set(session.scalars(select(estimates.c.frame_id).where(estimates.c.camera_id == camera_id)).all())
    written = 0
    for columns in chunks:
        ids = [int(i) for i in columns["frame_id"]]
        if not ids:
            continue
        replace = any(i in stored for i in ids)
        if replace and not upsert:
            session.execute(delete(estimates).where(estimates.c.frame_id.in_(ids)))
        # both forms of the spectrum always set: a row replaced keeps none of the other form
        unset = {k: None for k in ("spectrum", "spectrum_f32") if k not in columns and k not in constants}
        written += insert_columns(session, estimates, {**columns, "frame_id": ids},
                                  {**constants, **unset, "camera_id": camera_id, "created_at": utcnow()},
                                  replace_on=("frame_id",) if replace and upsert else None)
        clear = [i for i in ids if i in marked]
        if clear:
            session.execute(update(frames).where(frames.c.id.in_(clear)).values(not_estimated=None))
    return written


def drop_estimates(session: Session, reasons: dict[int, str]) -> None:
    """Delete the estimates of the frames of ``reasons`` (frame id → why it has none now) and record the reason, in
    statements of :data:`WRITE_CHUNK` frames (within the caller's transaction)."""
    ids = sorted(reasons)
    for start in range(0, len(ids), WRITE_CHUNK):
        part = ids[start : start + WRITE_CHUNK]
        session.execute(delete(Estimate).where(Estimate.frame_id.in_(part)))
        for reason in sorted({reasons[i] for i in part}):
            which = [i for i in part if reasons[i] == reason]
            session.execute(update(Frame).where(Frame.id.in_(which)).values(not_estimated=reason))
