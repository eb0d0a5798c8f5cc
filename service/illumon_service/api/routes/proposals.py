"""Reference-region proposals (``GET /v1/cameras/{id}/region-proposals``), see :mod:`illumon_service.proposals`."""

from __future__ import annotations

from fastapi import APIRouter, Query, Request

from ...deps import PrincipalDep, SessionDep, camera_for
from ...manage import proposals_for
from ..forms import parse_view_field
from ..schemas import ERROR_RESPONSES, ErrorOut, ProposalsOut

router = APIRouter(prefix="/v1/cameras", tags=["regions"], responses=ERROR_RESPONSES)

@router.get("/{camera_id}/region-proposals", response_model=ProposalsOut,
            responses={409: {"model": ErrorOut, "description": "Too few frames of the view stored"}})
def region_proposals(camera_id: int, request: Request, session: SessionDep, principal: PrincipalDep,
                     count: int = Query(12, ge=1, le=100, description="proposals wanted (1…100)"),
                     view: str | None = Query(None, description="view (PTZ preset id); the default view if absent"),
                     ) -> dict:
    """Rectangles of static, uniform, matte, unclipped surfaces of distinct colours, best first, from the stored
    frames of the view (at least 5; 409 otherwise), in the view's reference-frame pixels."""
    cam = camera_for(session, principal, camera_id)
    v = parse_view_field(view)
    return proposals_for(session, cam, v, count, request.app.state.settings.data_dir)
