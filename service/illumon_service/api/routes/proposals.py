"""Reference-region proposals (``GET /v1/cameras/{id}/region-proposals``), see :mod:`illumon_service.proposals`."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Query, Request

from ...deps import PrincipalDep, SessionDep, camera_for
from ...proposals import MAX_FRAMES, MIN_FRAMES, propose_regions
from ...registration import parse_view, view_thumbnails
from ..schemas import ERROR_RESPONSES, ErrorOut, ProposalsOut

router = APIRouter(prefix="/v1/cameras", tags=["regions"], responses=ERROR_RESPONSES)

MIN_HOURS = 3
"""Proposals from frames covering fewer hours of the day (UTC) than this carry a warning."""


def proposals_for(session, cam, view: str | None, count: int, data_dir) -> dict:  # noqa: ANN001 - Session, Camera, Path
    """``{"frames_used", "view", "proposals"}`` of a camera's view (thumbnails under ``data_dir``); ``HTTPException``
    409 with too few frames."""
    thumbs, frames = view_thumbnails(session, cam, view, data_dir, MAX_FRAMES)
    if len(thumbs) < MIN_FRAMES:
        raise HTTPException(409, f"{len(thumbs)} frame(s) of this view stored; region proposals need at least "
                                 f"{MIN_FRAMES}, spread over the day (post frames to /v1/cameras/{cam.id}/frames)")
    props = propose_regions(thumbs, count, (frames[0].width, frames[0].height))
    hours = len({f.taken_at.hour for f in frames})
    warnings = [] if hours >= MIN_HOURS else [
        f"the frames used cover {hours} hour(s) of the day: a surface that changes with the sun (a highlight, a "
        "moving shadow) may look static; propose again once frames from other hours are stored"]
    return {"frames_used": len(thumbs), "view": view, "hours_covered": hours,
            "proposals": [p.as_dict() for p in props], "warnings": warnings}


@router.get("/{camera_id}/region-proposals", response_model=ProposalsOut,
            responses={409: {"model": ErrorOut, "description": "Too few frames of the view stored"}})
def region_proposals(camera_id: int, request: Request, session: SessionDep, principal: PrincipalDep,
                     count: int = Query(12, ge=1, le=100, description="proposals wanted (1…100)"),
                     view: str | None = Query(None, description="view (PTZ preset id); the default view if absent"),
                     ) -> dict:
    """Rectangles of static, uniform, matte, unclipped surfaces of distinct colours, best first, from the stored
    frames of the view (at least 5; 409 otherwise), in the view's reference-frame pixels."""
    cam = camera_for(session, principal, camera_id)
    try:
        v = parse_view(view)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    return proposals_for(session, cam, v, count, request.app.state.settings.data_dir)
