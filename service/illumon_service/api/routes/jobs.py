"""Refit jobs."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, status

from ... import crud
from ...deps import PrincipalDep, SessionDep, camera_for
from ...storage import as_utc
from ..schemas import ERROR_RESPONSES, JobOut, JobRef

router = APIRouter(tags=["jobs"], responses=ERROR_RESPONSES)


@router.post("/v1/cameras/{camera_id}/refit", status_code=status.HTTP_202_ACCEPTED, response_model=JobRef)
def refit(camera_id: int, request: Request, session: SessionDep, principal: PrincipalDep) -> dict:
    """Queue a refit: re-estimate the camera's most recent stored frames by multi-frame retrieval."""
    camera_for(session, principal, camera_id)
    session.close()
    return {"job_id": request.app.state.jobs.submit(camera_id)}


@router.get("/v1/jobs/{job_id}", response_model=JobOut)
def get_job(job_id: str, session: SessionDep, principal: PrincipalDep) -> dict:
    """A job's state (queued, running, done, failed), progress (0…1) and summary."""
    job = crud.get_job(session, job_id)
    if job is None or (not principal.admin and principal.camera_id != job.camera_id):
        raise HTTPException(404, f"unknown job {job_id}")
    return {
        "job_id": job.id,
        "camera_id": job.camera_id,
        "state": job.state,
        "progress": job.progress,
        "summary": job.summary,
        "created_at": as_utc(job.created_at).isoformat(),
        "finished_at": as_utc(job.finished_at).isoformat() if job.finished_at else None,
    }
