"""The FastAPI application factory."""

from __future__ import annotations

import logging
import os
import sys
import tempfile
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DataError
from starlette.exceptions import HTTPException as StarletteHTTPException

from . import crud
from .api.routes import calibration, cameras, estimates, frames, gains, health, jobs, pages, proposals
from .jobs import JobRunner
from .memory import tune_allocator
from .metrics import Metrics
from .retention import Housekeeper
from .settings import Settings
from .storage import GroupCommit, hash_token, make_engine, make_session_factory, new_token

__all__ = ["create_app", "admin_token"]

log = logging.getLogger("illumon_service")


def admin_token(settings: Settings) -> str:
    """The admin token: ``ILLUMON_ADMIN_TOKEN``, else ``<data dir>/admin_token``, else a new one stored there (0600).

    A newly generated token is printed once on standard error.
    """
    if settings.admin_token:
        return settings.admin_token
    path = Path(settings.data_dir) / "admin_token"
    if path.is_file():
        return path.read_text().strip()
    # Written to a private temporary file, then hard-linked into place: the link fails if another process (a second
    # uvicorn worker) got there first, and a reader never sees a half-written file; the loser reads the winner's token.
    token = new_token()
    fd, tmp = tempfile.mkstemp(prefix=".admin_token-", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:  # mkstemp creates the file with mode 0600
            fh.write(token + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.link(tmp, path)
        except FileExistsError:
            return path.read_text().strip()
    finally:
        os.unlink(tmp)
    print(f"illumon: generated admin token (stored in {path}, mode 0600): {token}", file=sys.stderr, flush=True)
    return token


def _validation_detail(exc: RequestValidationError) -> list[dict]:
    """Validation errors without the offending input (which may hold NaN and is not JSON-serialisable)."""
    out = []
    for err in exc.errors():
        out.append({"loc": list(err.get("loc", ())), "msg": str(err.get("msg", "")), "type": err.get("type", "")})
    return out


def allowed_methods(app: FastAPI, scope: dict) -> str:
    """The ``Allow`` header value for the request's path: the methods of every route matching it."""
    from starlette.routing import Match

    methods: set[str] = set()
    for route in app.router.routes:
        match, _ = route.matches({**scope, "method": "GET"})
        if match != Match.NONE or route.matches({**scope, "method": "POST"})[0] != Match.NONE:
            methods |= set(getattr(route, "methods", None) or ())
    return ", ".join(sorted(methods))


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service: database (tables created), admin token, job runner, routes and error handlers."""
    settings = settings or Settings()
    tune_allocator()  # decoded frames reuse freed memory (:mod:`.memory`)
    Path(settings.data_dir).mkdir(parents=True, exist_ok=True, mode=0o700)  # a new data dir: its owner's only
    engine = make_engine(settings.resolved_database_url)
    crud.relativize_paths(engine, settings.data_dir)  # databases of older versions stored absolute file paths
    sessions = make_session_factory(engine)
    metrics = Metrics(settings.metrics_dir)
    runner = JobRunner(sessions, settings, metrics)
    housekeeper = Housekeeper(sessions, settings)  # retention, expired idempotency keys and login sessions

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        runner.start_recovery()  # jobs a crash left running or queued
        runner.start_schedule()
        housekeeper.start()
        yield
        housekeeper.stop()
        runner.shutdown()
        engine.dispose()

    app = FastAPI(title="illumon", version="0.1.0", lifespan=lifespan,
                  description="Daylight illuminant and white-balance estimation for fixed cameras")
    app.state.settings = settings
    app.state.engine = engine
    app.state.sessions = sessions
    # Frames: concurrent ingests share one durable commit.
    app.state.commits = GroupCommit(sessions, lambda n: metrics.observe("illumon_ingest_commit_frames", n))
    app.state.metrics = metrics
    app.state.jobs = runner
    app.state.housekeeper = housekeeper
    app.state.admin_token_hash = hash_token(admin_token(settings))

    @app.exception_handler(RequestValidationError)
    async def _on_validation(_request: Request, exc: RequestValidationError) -> JSONResponse:
        metrics.inc("illumon_http_errors_total", labels='status="422"')
        return JSONResponse({"detail": _validation_detail(exc)}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _on_http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        metrics.inc("illumon_http_errors_total", labels=f'status="{exc.status_code}"')
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:  # Starlette's Allow lists one route's methods; list every route's on the path
            headers = {**(headers or {}), "Allow": allowed_methods(app, request.scope)}
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=headers)

    @app.exception_handler(DataError)
    async def _on_data_error(request: Request, exc: DataError) -> JSONResponse:
        # A value the database refuses to store (every text and number is checked at the door, so this is a
        # safety net): the client's value, not a server fault.
        metrics.inc("illumon_http_errors_total", labels='status="422"')
        log.warning("database refused a value on %s %s: %s", request.method, request.url.path, str(exc.orig)[:200])
        return JSONResponse({"detail": "a value of the request cannot be stored (e.g. a control character or a "
                                       "number out of range)"}, status_code=422)

    @app.exception_handler(Exception)
    async def _on_error(request: Request, exc: Exception) -> JSONResponse:
        metrics.inc("illumon_http_errors_total", labels='status="500"')
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse({"detail": "internal server error"}, status_code=500)

    for module in (cameras, calibration, frames, estimates, gains, jobs, health, proposals):
        app.include_router(module.router)
    pages.install(app)  # status page: /, /cameras/{id}, /login, /static
    return app
