"""Queries of the ``jobs`` table: a refit job's life (queued → running → done | failed), the heartbeats of running
jobs, and a camera's latest finished refit and its warnings."""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from ..storage import Job, utcnow

__all__ = ["add_job", "get_job", "set_job", "claim_job", "beat_jobs", "unfinished_jobs", "latest_job",
           "refit_warnings"]


def add_job(session: Session, job_id: str, camera_id: int, attempt: int = 1) -> None:
    """Record a queued refit job (not committed)."""
    session.add(Job(id=job_id, camera_id=camera_id, state="queued", progress=0.0, attempt=attempt))


def get_job(session: Session, job_id: str) -> Job | None:
    """The job ``job_id``, or ``None``."""
    return session.get(Job, job_id)


def set_job(session: Session, job_id: str, **fields: object) -> None:
    """Set fields of a job (not committed; nothing when the job is gone)."""
    job = session.get(Job, job_id)
    if job is not None:
        for k, v in fields.items():
            setattr(job, k, v)


def claim_job(session: Session, job_id: str) -> bool:
    """Take a queued job (``queued`` → ``running``, heartbeat now) unless another process took it first."""
    done = session.execute(update(Job).where(Job.id == job_id, Job.state == "queued")
                           .values(state="running", progress=0.0, heartbeat_at=utcnow()))
    return done.rowcount == 1


def beat_jobs(session: Session, job_ids: list[str]) -> None:
    """Renew the heartbeat of the running jobs among ``job_ids``."""
    session.execute(update(Job).where(Job.id.in_(job_ids), Job.state == "running").values(heartbeat_at=utcnow()))


def unfinished_jobs(session: Session) -> Sequence[Job]:
    """Every job still ``running`` or ``queued``."""
    return session.scalars(select(Job).where(Job.state.in_(("running", "queued")))).all()


def _latest(session: Session, camera_id: int, states: tuple[str, ...]) -> Job | None:
    """The camera's latest job finished in one of ``states``, or ``None``."""
    return session.scalars(
        select(Job).where(Job.camera_id == camera_id, Job.state.in_(states))
        .order_by(Job.finished_at.desc(), Job.created_at.desc()).limit(1)).first()


def latest_job(session: Session, camera_id: int) -> Job | None:
    """The camera's latest finished refit job (``done`` or ``failed``), or ``None``."""
    return _latest(session, camera_id, ("done", "failed"))


def refit_warnings(session: Session, camera_id: int) -> list[str]:
    """The warnings of the camera's latest successful refit (e.g. a tone response that does not match the frames)."""
    job = _latest(session, camera_id, ("done",))
    if job is None or not job.summary:
        return []
    return [str(w) for w in job.summary.get("warnings") or []]
