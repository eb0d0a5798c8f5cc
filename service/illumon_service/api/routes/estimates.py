"""Estimates and the illuminant of a camera."""

from __future__ import annotations

from fastapi import APIRouter, Query

from ... import crud
from ...deps import PrincipalDep, SessionDep, camera_for, nearest_estimate
from ...estimation import GRID_WAVELENGTHS
from ..schemas import ERROR_RESPONSES, MAX_LIST, EstimateOut, IlluminantOut, IsoDateTime

router = APIRouter(prefix="/v1/cameras", tags=["estimates"], responses=ERROR_RESPONSES)


@router.get("/{camera_id}/estimates", response_model=list[EstimateOut])
def list_estimates(camera_id: int, session: SessionDep, principal: PrincipalDep,
                   since: IsoDateTime | None = None, until: IsoDateTime | None = None,
                   limit: int = Query(10000, ge=1, le=MAX_LIST, description=f"1…{MAX_LIST} estimates")) -> list[dict]:
    """Estimates in ``since`` ≤ taken_at ≤ ``until``, oldest first."""
    camera_for(session, principal, camera_id)
    rows = crud.estimates_between(session, camera_id, since, until, limit)
    return [crud.estimate_out(e) for e in rows]


@router.get("/{camera_id}/illuminant", response_model=IlluminantOut)
def get_illuminant(camera_id: int, session: SessionDep, principal: PrincipalDep, at: IsoDateTime | None = None) -> dict:
    """The estimate nearest ``at`` with its spectrum (relative, 100 at 560 nm) and intervals where known."""
    camera_for(session, principal, camera_id)
    e = nearest_estimate(session, camera_id, at)
    out = crud.estimate_out(e)
    out["spectrum"] = {"wavelength_nm": GRID_WAVELENGTHS, "values": crud.estimate_spectrum(e)}
    out["intervals"] = e.intervals
    return out
