"""Frame ingest: images (``/frames``) and client-side region means (``/observations``), carried to their estimate by
:mod:`illumon_service.ingest`; the stored frames (list, admin delete)."""

from __future__ import annotations

import time

from fastapi import APIRouter, Header, Query, Request, status
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from ... import crud
from ...deps import AdminDep, PrincipalDep, SessionDep, camera_for
from ...idempotency import IDEMPOTENCY_DOC, Claim, fingerprint, parse_key
from ...ingest import Observation, ingest_image, ingest_observations
from ...manage import delete_frame
from ..forms import answer_json, parse_time, read_frame_form
from ..schemas import ERROR_RESPONSES, FRAME_UPLOAD, MAX_LIST, DeletedOut, FrameIngestOut, FrameOut, IsoDateTime, ObservationIn

router = APIRouter(prefix="/v1/cameras", tags=["frames"], responses=ERROR_RESPONSES)


@router.post("/{camera_id}/frames", status_code=status.HTTP_201_CREATED, openapi_extra=FRAME_UPLOAD,
             response_model=FrameIngestOut)
async def post_frame(camera_id: int, request: Request, session: SessionDep, principal: PrincipalDep,
                     idempotency_key: str | None = Header(None, max_length=255, description=IDEMPOTENCY_DOC),
                     ) -> dict | JSONResponse:
    """Ingest one image (multipart ``image``; optional ``taken_at``, ``applied_gains`` "r,g,b" and ``exposure``, which
    the camera applied and the service divides out): robust region means, then an estimate."""
    received = time.perf_counter()
    cam = await run_in_threadpool(camera_for, session, principal, camera_id)
    form = await read_frame_form(request, request.app.state.settings.max_upload_bytes)
    return await run_in_threadpool(ingest_image, request.app.state, session, cam, form.upload, form.claim(cam.id),
                                   received)


@router.post("/{camera_id}/observations", status_code=status.HTTP_201_CREATED, response_model=FrameIngestOut)
def post_observations(camera_id: int, body: ObservationIn, request: Request, session: SessionDep,
                      principal: PrincipalDep,
                      idempotency_key: str | None = Header(None, max_length=255, description=IDEMPOTENCY_DOC),
                      ) -> dict | JSONResponse:
    """Ingest region means measured by the client (linear values; ``null`` for a missing region; 422 when every
    region is ``null``)."""
    cam = camera_for(session, principal, camera_id)
    key = parse_key(request)
    claim = None if key is None else Claim(cam.id, key, fingerprint(body.model_dump_json()), answer_json)
    return ingest_observations(request.app.state, session, cam, Observation(**body.model_dump()), claim)


@router.get("/{camera_id}/frames", response_model=list[FrameOut])
def list_frames(camera_id: int, session: SessionDep, principal: PrincipalDep, since: IsoDateTime | None = None,
                until: IsoDateTime | None = None,
                limit: int = Query(1000, ge=1, le=MAX_LIST, description=f"1…{MAX_LIST} frames")) -> list[dict]:
    """Stored frames (region means, linear 0…1) in ``since`` ≤ taken_at ≤ ``until``, oldest first."""
    camera_for(session, principal, camera_id)
    rows = crud.frames_between(session, camera_id, None if since is None else parse_time(since.isoformat()),
                               None if until is None else parse_time(until.isoformat()), limit)
    estimated = crud.estimated_frame_ids(session, [f.id for f in rows])
    return [crud.frame_out(f, f.id in estimated) for f in rows]


@router.delete("/{camera_id}/frames/{frame_id}", response_model=DeletedOut)
def remove_frame(camera_id: int, frame_id: int, request: Request, session: SessionDep, principal: AdminDep) -> dict:
    """Delete one stored frame with its estimate and files (admin): e.g. a frame whose values are wrong."""
    cam = camera_for(session, principal, camera_id)
    deleted = delete_frame(session, request.app.state.settings.data_dir, cam, frame_id)
    return {"camera_id": camera_id, "frame_id": frame_id, "deleted": deleted}
