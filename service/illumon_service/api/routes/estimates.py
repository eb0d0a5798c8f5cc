"""Estimates and the illuminant of a camera."""

from __future__ import annotations

from datetime import datetime

from fastapi import APIRouter, HTTPException, Query
from sqlalchemy import select
from sqlalchemy.orm import Session

from ...deps import PrincipalDep, SessionDep, camera_for
from ...estimation import GRID_WAVELENGTHS
from ...storage import Estimate, as_utc
from ..schemas import ERROR_RESPONSES, MAX_LIST, IsoDateTime

router = APIRouter(prefix="/v1/cameras", tags=["estimates"], responses=ERROR_RESPONSES)


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
        "source": e.source,
    }


def nearest_estimate(session: Session, camera_id: int, at: datetime | None) -> Estimate:
    """The estimate nearest ``at`` (latest without it); 404 when the camera has none yet."""
    q = select(Estimate).where(Estimate.camera_id == camera_id)
    if at is None:
        e = session.scalars(q.order_by(Estimate.taken_at.desc(), Estimate.frame_id.desc()).limit(1)).first()
    else:
        at = as_utc(at)
        before = session.scalars(q.where(Estimate.taken_at <= at).order_by(Estimate.taken_at.desc()).limit(1)).first()
        after = session.scalars(q.where(Estimate.taken_at > at).order_by(Estimate.taken_at.asc()).limit(1)).first()
        cands = [c for c in (before, after) if c is not None]
        e = min(cands, key=lambda c: abs((as_utc(c.taken_at) - at).total_seconds())) if cands else None
    if e is None:
        raise HTTPException(404, f"no estimate yet for camera {camera_id}; POST /v1/cameras/{camera_id}/refit")
    return e


@router.get("/{camera_id}/estimates")
def list_estimates(camera_id: int, session: SessionDep, principal: PrincipalDep,
                   since: IsoDateTime | None = None, until: IsoDateTime | None = None,
                   limit: int = Query(10000, ge=1, le=MAX_LIST, description=f"1…{MAX_LIST} estimates")) -> list[dict]:
    """Estimates in ``since`` ≤ taken_at ≤ ``until``, oldest first."""
    camera_for(session, principal, camera_id)
    q = select(Estimate).where(Estimate.camera_id == camera_id)
    if since is not None:
        q = q.where(Estimate.taken_at >= as_utc(since))
    if until is not None:
        q = q.where(Estimate.taken_at <= as_utc(until))
    rows = session.scalars(q.order_by(Estimate.taken_at, Estimate.frame_id).limit(limit)).all()
    return [estimate_out(e) for e in rows]


@router.get("/{camera_id}/illuminant")
def get_illuminant(camera_id: int, session: SessionDep, principal: PrincipalDep, at: IsoDateTime | None = None) -> dict:
    """The estimate nearest ``at`` with its spectrum (relative, 100 at 560 nm) and intervals where known."""
    camera_for(session, principal, camera_id)
    e = nearest_estimate(session, camera_id, at)
    out = estimate_out(e)
    out["spectrum"] = {"wavelength_nm": GRID_WAVELENGTHS, "values": e.spectrum}
    out["intervals"] = e.intervals
    return out
