"""Queries and the public form of stored rows, shared by routes, the status page and jobs (the template's crud layer):
routes stay thin and the page and the JSON API cannot disagree."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

from sqlalchemy import select
from sqlalchemy.orm import Session

from .storage import Estimate, as_utc

__all__ = ["estimate_out", "nearest_estimate", "estimates_between"]


def estimate_non_daylight(e: Estimate) -> float | None:
    """The estimate's ``non_daylight`` (posterior probability that its light is not daylight,
    :mod:`illumon.model.lamps`), stored with its intervals; ``None`` for estimates made without it."""
    v = (getattr(e, "intervals", None) or {}).get("non_daylight")
    return float(v) if isinstance(v, (int, float)) else None


def estimate_out(e: Estimate) -> dict:
    """The public fields of an estimate."""
    return {
        "frame_id": e.frame_id,
        "taken_at": as_utc(e.taken_at).isoformat(),
        "cct_k": e.cct_k,
        "duv": e.duv,
        "xy": e.xy,
        "white_rgb": e.white_rgb,
        "gains_rgb": e.gains_rgb,
        "confidence": e.confidence,
        "non_daylight": estimate_non_daylight(e),
        "source": e.source,
    }


def nearest_estimate(session: Session, camera_id: int, at: datetime | None) -> Estimate | None:
    """The estimate nearest ``at`` (the latest without it), or ``None`` when the camera has none yet."""
    q = select(Estimate).where(Estimate.camera_id == camera_id)
    if at is None:
        return session.scalars(q.order_by(Estimate.taken_at.desc(), Estimate.frame_id.desc()).limit(1)).first()
    at = as_utc(at)
    before = session.scalars(q.where(Estimate.taken_at <= at).order_by(Estimate.taken_at.desc()).limit(1)).first()
    after = session.scalars(q.where(Estimate.taken_at > at).order_by(Estimate.taken_at.asc()).limit(1)).first()
    cands = [c for c in (before, after) if c is not None]
    return min(cands, key=lambda c: abs((as_utc(c.taken_at) - at).total_seconds())) if cands else None


def estimates_between(session: Session, camera_id: int, since: datetime | None, until: datetime | None,
                      limit: int) -> Sequence[Estimate]:
    """A camera's estimates in ``since`` ≤ taken_at ≤ ``until``, oldest first, at most ``limit``: a range of the
    (camera, time) index. Rows with every column of :class:`.storage.Estimate` by name but its ``spectrum`` (not
    ORM objects: a third of the time for 1000 rows; :func:`estimate_out` reads them alike)."""
    columns = [c for c in Estimate.__table__.columns if c.name != "spectrum"]
    q = select(*columns).where(Estimate.camera_id == camera_id)
    if since is not None:
        q = q.where(Estimate.taken_at >= as_utc(since))
    if until is not None:
        q = q.where(Estimate.taken_at <= as_utc(until))
    return session.execute(q.order_by(Estimate.taken_at, Estimate.frame_id).limit(limit)).all()  # type: ignore[return-value]
