"""Queries of the ``frames`` table: a camera's frames by time and view, their thumbnails, the history a refit reads,
the counts of frames without an estimate, and the public form of a stored frame (:func:`frame_out`)."""

from __future__ import annotations

from collections.abc import Collection, Iterator, Sequence
from datetime import datetime

import numpy as np
from sqlalchemy import String, Text, cast, delete, func, select, type_coerce
from sqlalchemy.engine import Row
from sqlalchemy.orm import Session

from ..storage import Estimate, Frame, as_utc

__all__ = [
    "add_frame", "mark_not_estimated", "frame_of", "delete_frame", "frames_between", "frame_out", "latest_frame",
    "recent_frames", "frame_count", "view_size", "last_thumbnail", "thumbnail_frames", "view_frames",
    "history_chunks", "frames_not_read", "not_estimated_counts",
]


def _view_filter(view: str | None):  # noqa: ANN202 - a SQLAlchemy clause
    """The frames of one view (``None``: the default view)."""
    return Frame.view.is_(None) if view is None else Frame.view == view


_NEWEST_FIRST = (Frame.taken_at.desc(), Frame.id.desc())


def add_frame(session: Session, **columns: object) -> Frame:
    """A new frame row, added and flushed (it has its id)."""
    frame = Frame(**columns)
    session.add(frame)
    session.flush()
    return frame


def mark_not_estimated(session: Session, frame: Frame, reason: str) -> None:
    """Record why a frame has no estimate (:attr:`.storage.Frame.not_estimated`) and flush."""
    frame.not_estimated = reason
    session.flush()


def frame_of(session: Session, camera_id: int, frame_id: int) -> Frame | None:
    """The stored frame ``frame_id`` of the camera (``None`` for another camera's, or none)."""
    frame = session.get(Frame, frame_id) if 0 < frame_id < 2**63 else None
    return frame if frame is not None and frame.camera_id == camera_id else None


def delete_frame(session: Session, frame: Frame) -> int:
    """Delete a frame and its estimate, and commit; returns the number of estimates deleted."""
    estimates = session.execute(delete(Estimate).where(Estimate.frame_id == frame.id)).rowcount
    session.delete(frame)
    session.commit()
    return int(estimates or 0)


def frames_between(session: Session, camera_id: int, since: datetime | None, until: datetime | None,
                   limit: int) -> Sequence[Frame]:
    """A camera's frames in ``since`` ≤ taken_at ≤ ``until``, oldest first, at most ``limit``."""
    q = select(Frame).where(Frame.camera_id == camera_id)
    if since is not None:
        q = q.where(Frame.taken_at >= since)
    if until is not None:
        q = q.where(Frame.taken_at <= until)
    return session.scalars(q.order_by(Frame.taken_at, Frame.id).limit(limit)).all()


def frame_out(f: Frame, estimated: bool) -> dict:
    """The public fields of a stored frame (``estimated``: whether it has an estimate)."""
    return {"frame_id": f.id, "taken_at": as_utc(f.taken_at).isoformat(), "regions": f.patches,
            "width": f.width, "height": f.height, "applied_gains": f.applied_gains, "exposure": f.exposure,
            "view": f.view, "registration": f.registration,
            "not_estimated": None if estimated else (f.not_estimated or "pending")}


def latest_frame(session: Session, camera_id: int, view: str | None, with_thumbnail: bool = False) -> Frame | None:
    """The view's latest stored frame (with ``with_thumbnail``, the latest whose thumbnail is kept), or ``None``."""
    q = select(Frame).where(Frame.camera_id == camera_id, _view_filter(view))
    if with_thumbnail:
        q = q.where(Frame.thumb_path.is_not(None))
    return session.scalars(q.order_by(*_NEWEST_FIRST).limit(1)).first()


def recent_frames(session: Session, camera_id: int, limit: int) -> list[Frame]:
    """The camera's ``limit`` most recent frames (every view), newest first."""
    return list(session.scalars(
        select(Frame).where(Frame.camera_id == camera_id).order_by(*_NEWEST_FIRST).limit(limit)).all())


def frame_count(session: Session, camera_id: int) -> int:
    """How many frames the camera has stored (an index-only count)."""
    return int(session.scalar(select(func.count()).select_from(Frame).where(Frame.camera_id == camera_id)) or 0)


def view_size(session: Session, camera_id: int, view: str | None) -> tuple[int, int] | None:
    """(width, height) of the view's images: those of its latest stored frame that came with an image (``None``
    when it has none yet, e.g. a camera that sends region means)."""
    row = session.execute(
        select(Frame.width, Frame.height).where(Frame.camera_id == camera_id, _view_filter(view),
                                                Frame.width.is_not(None), Frame.height.is_not(None))
        .order_by(*_NEWEST_FIRST).limit(1)).first()
    return None if row is None else (int(row.width), int(row.height))


def last_thumbnail(session: Session, camera_id: int, view: str | None) -> Row | None:
    """``(taken_at, registration)`` of the view's latest frame whose thumbnail is kept, or ``None``."""
    return session.execute(
        select(Frame.taken_at, Frame.registration)
        .where(Frame.camera_id == camera_id, Frame.thumb_path.is_not(None), _view_filter(view))
        .order_by(*_NEWEST_FIRST).limit(1)
    ).first()


def thumbnail_frames(session: Session, camera_id: int, view: str | None) -> Sequence[Frame]:
    """The view's frames whose thumbnail is kept, newest first."""
    return session.scalars(
        select(Frame).where(Frame.camera_id == camera_id, Frame.thumb_path.is_not(None), _view_filter(view))
        .order_by(*_NEWEST_FIRST)
    ).all()


def view_frames(session: Session, camera_id: int, view: str | None, frame_ids: Sequence[int]) -> Sequence[Frame]:
    """Those of ``frame_ids`` that are frames of the camera's view, by id."""
    return session.scalars(select(Frame).where(
        Frame.camera_id == camera_id, Frame.id.in_(frame_ids), _view_filter(view)).order_by(Frame.id)).all()


_HISTORY = (Frame.id, Frame.taken_at, Frame.patches, Frame.applied_gains, Frame.exposure, Frame.view,
            Frame.registration, Frame.patch_sd)
"""The columns of a frame a refit reads."""

_HISTORY_TEXT = tuple(cast(c, Text).label(c.key) if c.key in ("patches", "applied_gains", "registration", "patch_sd")
                      else type_coerce(c, String).label(c.key) if c.key == "taken_at" else c for c in _HISTORY)
"""The same columns, the JSON ones as their stored text and the time as the driver gives it (SQLite: its stored
text; the caller decodes them)."""


def history_chunks(session: Session, camera_id: int, limit: int, chunk: int) -> Iterator[Sequence[Row]]:
    """The camera's ``limit`` most recent frames (the columns a refit reads, its JSON columns as their stored text:
    ``patches``, ``applied_gains``, ``registration``, ``patch_sd``; ``taken_at`` as the driver gives it, not through
    the column type's conversion: SQLite's stored text, PostgreSQL's datetime), newest first, ``chunk`` rows at a time (one
    query whose rows are fetched as they are used), so that a refit never holds the whole history as rows."""
    q = select(*_HISTORY_TEXT).where(Frame.camera_id == camera_id).order_by(*_NEWEST_FIRST).limit(limit)
    # the session's connection: Core rows as the driver fetches them, without the ORM's loading of each row
    yield from session.connection().execute(q.execution_options(yield_per=chunk)).partitions()


def frames_not_read(session: Session, camera_id: int, read_ids: Collection[int]) -> list[Row]:
    """The camera's frames other than ``read_ids`` (the columns a refit reads), in id order: those stored since it
    read. The camera's frame ids are read from the (camera, time) index and the others fetched by key, rather than
    one statement naming every id read."""
    result = session.connection().execute(select(Frame.id).where(Frame.camera_id == camera_id)).scalars()
    ids = np.fromiter(result, dtype=np.int64)
    read = np.fromiter(read_ids, dtype=np.int64, count=len(read_ids))
    # numpy takes a lookup table over the ids' range where it is small (dense ids) rather than a sort (setdiff1d)
    others = np.unique(ids[~np.isin(ids, read)]).tolist() if ids.size else []
    out: list[Row] = []
    for start in range(0, len(others), ID_CHUNK):
        out += session.execute(select(*_HISTORY).where(Frame.id.in_(others[start : start + ID_CHUNK]))
                               .order_by(Frame.id)).all()
    return out


ID_CHUNK = 900
"""Ids bound per statement when fetching frames by id (under old SQLite versions' limit of 999 parameters)."""


def not_estimated_counts(session: Session, camera_id: int, frames: int | None = None) -> dict[str, int]:
    """The camera's stored frames that have no estimate, counted by reason (:attr:`.storage.Frame.not_estimated`;
    ``pending`` for frames of older versions, which recorded none).

    Without a pass over the history's rows: frames with a reason are a range of the partial index
    ``ix_frames_camera_not_estimated`` (each checked for an estimate by key); frames without a reason and without an
    estimate are counted as the camera's frames less its estimates (index-only counts), corrected for the frames with
    a reason that do have an estimate. ``frames`` is the camera's frame count when the caller has it already.
    """
    marked = Frame.not_estimated.is_not(None)
    rows = session.execute(
        select(Frame.not_estimated, Estimate.frame_id.is_not(None), func.count()).select_from(Frame)
        .outerjoin(Estimate, Estimate.frame_id == Frame.id)
        .where(Frame.camera_id == camera_id, marked)
        .group_by(Frame.not_estimated, Estimate.frame_id.is_not(None))).all()
    out: dict[str, int] = {}
    marked_frames = marked_estimated = 0
    for reason, estimated, n in rows:
        marked_frames += int(n)
        if estimated:
            marked_estimated += int(n)
        else:
            out[reason] = out.get(reason, 0) + int(n)
    if frames is None:
        frames = frame_count(session, camera_id)
    estimates = session.scalar(select(func.count()).select_from(Estimate).where(Estimate.camera_id == camera_id)) or 0
    pending = (int(frames) - marked_frames) - (int(estimates) - marked_estimated)
    if pending > 0:
        out["pending"] = pending
    return dict(sorted(out.items()))
