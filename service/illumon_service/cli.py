"""``illumon serve``, ``illumon refit``, ``illumon backup`` / ``restore`` and ``illumon prune``, registered on the core
CLI by :func:`add_serve_command`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

__all__ = ["add_serve_command"]


def _settings(args: argparse.Namespace):  # noqa: ANN202 - avoids importing pydantic at CLI start-up
    from .settings import Settings

    overrides = {}
    if getattr(args, "data_dir", None):
        overrides["data_dir"] = Path(args.data_dir)
    if getattr(args, "database_url", None):
        overrides["database_url"] = args.database_url
    return Settings(**overrides)


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from .app import admin_token, create_app

    settings = _settings(args)
    workers = args.workers
    if workers <= 1:
        uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level=args.log_level)
        return 0
    # Several worker processes, each building the app from the environment: the tables and the admin token are
    # created here first, so that the workers only open them.
    import os

    from .storage import make_engine

    Path(settings.data_dir).mkdir(parents=True, exist_ok=True)
    make_engine(settings.resolved_database_url).dispose()
    admin_token(settings)
    os.environ["ILLUMON_DATA_DIR"] = str(Path(settings.data_dir).resolve())
    # Each worker publishes its metrics here and /metrics sums them; counts start again with this server.
    metrics_dir = Path(settings.data_dir).resolve() / "metrics"
    metrics_dir.mkdir(exist_ok=True)
    for old in metrics_dir.glob("*.json"):
        old.unlink()
    os.environ["ILLUMON_METRICS_DIR"] = str(metrics_dir)
    if settings.database_url:
        os.environ["ILLUMON_DATABASE_URL"] = settings.database_url
    import socket

    from uvicorn.supervisors import Multiprocess

    # What uvicorn.run(…, workers=N) does, plus TCP_NODELAY on the shared listening socket: uvicorn binds it without
    # naming IPPROTO_TCP, so asyncio does not disable Nagle's algorithm on the connections the workers accept, and a
    # response's last segment then waits for the client's delayed ACK (~40 ms per request on a keep-alive
    # connection). Linux gives accepted sockets the listening socket's TCP_NODELAY.
    # A worker imports numpy, SciPy and colour-science before it answers uvicorn's health check: on a busy two-core
    # machine that takes longer than uvicorn's 5 s, and the supervisor then kills and restarts every worker for ever.
    config = uvicorn.Config("illumon_service.app:create_app", factory=True, workers=workers, host=args.host,
                            port=args.port, log_level=args.log_level, timeout_worker_healthcheck=WORKER_START_SECONDS)
    sock = config.bind_socket()
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    Multiprocess(config, sockets=[sock]).run()
    return 0


WORKER_START_SECONDS = 60
"""How long a ``serve --workers N`` worker may take to start and to answer the supervisor's health check."""


def _cmd_refit(args: argparse.Namespace) -> int:
    from .jobs import run_batch

    settings = _settings(args)
    Path(settings.data_dir).mkdir(parents=True, exist_ok=True)
    ids = None if args.all else [args.camera]
    results = run_batch(settings, ids, args.dask_scheduler, n_workers=args.workers)
    for r in results:
        print(json.dumps(r, sort_keys=True))
    return 1 if any("error" in r for r in results) else 0


def _cmd_backup(args: argparse.Namespace) -> int:
    from .backup import backup, one_line_errors

    with one_line_errors("backup"):
        print(json.dumps(backup(_settings(args), Path(args.dest)), sort_keys=True))
    return 0


def _cmd_restore(args: argparse.Namespace) -> int:
    from .backup import one_line_errors, restore

    with one_line_errors("restore"):
        print(json.dumps(restore(_settings(args), Path(args.src), force=args.force), sort_keys=True))
    return 0


def _cmd_prune(args: argparse.Namespace) -> int:
    from .backup import one_line_errors
    from .retention import prune_once

    if args.retain_days is not None and not args.retain_days >= 0:
        raise ValueError(f"--retain-days {args.retain_days}: expected a number of days ≥ 0 (0 keeps everything)")
    settings = _settings(args)
    if args.retain_days is not None:
        settings = settings.model_copy(update={"retain_days": args.retain_days})
    with one_line_errors("prune"):
        print(json.dumps(prune_once(settings), sort_keys=True))
    return 0


def _add_operations_commands(subparsers: argparse._SubParsersAction) -> None:
    """``backup``, ``restore`` and ``prune`` (:mod:`.backup`, :mod:`.retention`)."""
    bk = subparsers.add_parser("backup", help="back up the database and data directory (while the service runs)")
    bk.add_argument("dest", help="new folder to write the backup to")
    rs = subparsers.add_parser("restore", help="restore a backup into an empty data directory (service stopped)")
    rs.add_argument("src", help="backup folder written by `illumon backup`")
    rs.add_argument("--force", action="store_true", help="replace the database and files already there")
    pr = subparsers.add_parser("prune", help="delete frames and estimates older than the retention period")
    pr.add_argument("--retain-days", type=float, help="days of frames to keep (ILLUMON_RETAIN_DAYS; 0 = keep all)")
    for p, func in ((bk, _cmd_backup), (rs, _cmd_restore), (pr, _cmd_prune)):
        p.add_argument("--data-dir", help="service data folder (./var)")
        p.add_argument("--database-url", help="SQLAlchemy URL (SQLite under the data dir by default)")
        p.set_defaults(func=func)


def add_serve_command(subparsers: argparse._SubParsersAction) -> None:
    """Register ``serve`` (the HTTP service), ``refit`` (batch re-estimation), ``backup``, ``restore`` and ``prune``
    on the ``illumon`` command."""
    serve = subparsers.add_parser("serve", help="run the HTTP service")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind (127.0.0.1)")
    serve.add_argument("--port", type=int, default=8000, help="port (8000)")
    serve.add_argument("--data-dir", help="folder for the SQLite database, admin token and models (./var)")
    serve.add_argument("--database-url", help="SQLAlchemy URL, e.g. postgresql+psycopg://… (SQLite by default)")
    serve.add_argument("--workers", type=int, default=1,
                       help="worker processes (1); SQLite in WAL mode is shared, /metrics sums all workers")
    serve.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    serve.set_defaults(func=_cmd_serve)

    refit = subparsers.add_parser("refit", help="re-estimate stored frames of one or all cameras")
    which = refit.add_mutually_exclusive_group(required=True)
    which.add_argument("--camera", type=int, help="camera id")
    which.add_argument("--all", action="store_true", help="every camera (fanned out over Dask)")
    refit.add_argument("--data-dir", help="service data folder (./var)")
    refit.add_argument("--database-url", help="SQLAlchemy URL (SQLite under the data dir by default)")
    refit.add_argument("--dask-scheduler", help="address of a Dask scheduler (a LocalCluster by default)")
    refit.add_argument("--workers", type=int, help="LocalCluster worker processes (usable CPUs); 1 refits serially")
    refit.set_defaults(func=_cmd_refit)
    _add_operations_commands(subparsers)
