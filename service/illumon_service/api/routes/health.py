"""Liveness and metrics."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import PlainTextResponse

from ... import crud
from ...deps import SessionDep, get_principal, require_admin
from ..schemas import HealthOut

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=HealthOut)
def healthz(session: SessionDep) -> dict:
    """``{"status": "ok"}`` when the database answers."""
    crud.ping(session)
    return {"status": "ok"}


@router.get("/metrics", response_class=PlainTextResponse)
def metrics(request: Request, session: SessionDep) -> PlainTextResponse:
    """Prometheus text: frames ingested, estimate and ingest latency, refit durations and outcomes, errors.

    As ``ILLUMON_METRICS`` says: ``public`` (default), ``admin`` (the admin bearer token; 401 / 403 otherwise) or
    ``off`` (404)."""
    mode = request.app.state.settings.metrics
    if mode == "off":
        raise HTTPException(404, "metrics are off (ILLUMON_METRICS=off)")
    if mode == "admin":
        require_admin(get_principal(request, session))
    return PlainTextResponse(request.app.state.metrics.render(), media_type="text/plain; version=0.0.4")
