"""Refit jobs: a camera's refit (:func:`.refit.refit_camera`) run as a job.

In the service a job runs in one background thread (or inline when ``jobs_inline`` is set, as in tests), its state
in the ``jobs`` table (:class:`JobRunner`: queue, claim, heartbeat, recovery after a crash, the periodic schedule);
the ``illumon refit`` batch command (:func:`run_batch`) refits one camera or, with ``--all``, fans the cameras out
over a Dask cluster (a ``LocalCluster`` unless ``--dask-scheduler`` names one) with a tqdm progress bar.
"""

from __future__ import annotations

import functools
import logging
import os
import sys
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from illumon._blas import limit_blas_threads
from sqlalchemy.orm import Session, sessionmaker

from . import crud
from .estimation import RefitInputError
from .locks import take_process_lock
from .metrics import Metrics
from .refit import refit_camera
from .settings import Settings
from .storage import as_utc, make_engine, make_session_factory, utcnow

__all__ = ["JobRunner", "run_batch", "usable_cpus", "fork_workers"]

log = logging.getLogger("illumon_service.jobs")


class JobRunner:
    """Queues refit jobs, records their state in the ``jobs`` table and runs them one at a time."""

    def __init__(self, sessions: sessionmaker[Session], settings: Settings, metrics: Metrics) -> None:
        self.sessions = sessions
        self.settings = settings
        self.metrics = metrics
        limit_blas_threads()
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="illumon-refit")
        self._stop = threading.Event()
        self._scheduler: threading.Thread | None = None
        self._lock_fd: int | None = None
        self._alive_fd: int | None = None
        self._sweeper: threading.Thread | None = None
        self._running: set[str] = set()
        self._running_lock = threading.Lock()
        self._started: set[str] = set()
        """Jobs this process has handed to its pool (recovery does not start them twice)."""

    def submit(self, camera_id: int, attempt: int = 1) -> str:
        """Record a queued job for the camera and start it; returns the job id."""
        job_id = uuid.uuid4().hex
        with self.sessions() as s, s.begin():
            crud.add_job(s, job_id, camera_id, attempt)
        self._started.add(job_id)
        self._start(job_id, camera_id)
        return job_id

    def _start(self, job_id: str, camera_id: int) -> None:
        if self.settings.jobs_inline:
            self._run(job_id, camera_id)
        else:
            self._pool.submit(self._run, job_id, camera_id)

    def _set(self, job_id: str, **fields) -> None:
        with self.sessions() as s, s.begin():
            crud.set_job(s, job_id, **fields)

    def _claim(self, job_id: str) -> bool:
        """Take a queued job (``queued`` → ``running``, heartbeat now) unless another process took it first."""
        with self.sessions() as s, s.begin():
            return crud.claim_job(s, job_id)

    def _run(self, job_id: str, camera_id: int) -> None:
        if not self._claim(job_id):
            return
        t0 = time.perf_counter()
        with self._running_lock:
            self._running.add(job_id)
        try:
            summary = refit_camera(
                self.sessions,
                camera_id,
                data_dir=Path(self.settings.data_dir),
                max_frames=self.settings.refit_max_frames,
                method=self.settings.refit_method,
                max_fit_frames=self.settings.refit_fit_frames,
                progress=lambda p: self._set(job_id, progress=p, heartbeat_at=utcnow()),
            )
        except Exception as exc:  # noqa: BLE001 - a failed job is reported in its summary, never raised
            if isinstance(exc, RefitInputError):  # the user's history, not a fault: one line
                log.warning("refit of camera %s failed: %s", camera_id, exc)
            else:
                log.exception("refit of camera %s failed", camera_id)
            self.metrics.inc("illumon_refit_total", labels='outcome="failed"')
            self._set(job_id, state="failed", summary={"error": str(exc)}, finished_at=utcnow())
            return
        finally:
            with self._running_lock:
                self._running.discard(job_id)
        self.metrics.observe("illumon_refit_seconds", time.perf_counter() - t0)
        self.metrics.inc("illumon_refit_total", labels='outcome="done"')
        self._set(job_id, state="done", progress=1.0, summary=summary, finished_at=utcnow())

    def _alone(self) -> bool:
        """Hold ``<data dir>/service.lock`` shared for this process's life; ``True`` when no other service process
        held it at start-up (every ``running`` job is then an orphan of a crash, whatever its heartbeat)."""
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not on POSIX: rely on heartbeats alone
            return False
        if self._alive_fd is None:
            self._alive_fd = os.open(Path(self.settings.data_dir) / "service.lock", os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(self._alive_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            alone = True
        except OSError:
            alone = False
        fcntl.flock(self._alive_fd, fcntl.LOCK_SH)
        return alone

    def recover(self, alone: bool = False) -> dict[str, list[str]]:
        """Pick up jobs a crash left behind: a ``running`` job whose heartbeat is older than
        ``job_stale_seconds`` (or any ``running`` job when ``alone``: no other service process is alive) is marked
        ``failed`` (its summary says it was interrupted) and, on its first attempt, run again as a new job (a refit
        is idempotent: it recomputes everything from the stored frames); ``queued`` jobs not yet started are
        started (a claim makes sure one process runs each). Returns the ids: ``{"failed", "requeued", "resumed"}``.
        """
        now = utcnow()
        stale = self.settings.job_stale_seconds
        out: dict[str, list[str]] = {"failed": [], "requeued": [], "resumed": []}
        with self._running_lock:
            mine = set(self._running)
        with self.sessions() as s, s.begin():
            jobs = crud.unfinished_jobs(s)
            retry = []
            for job in jobs:
                beat = as_utc(job.heartbeat_at or job.created_at)
                if job.state != "running" or job.id in mine:
                    continue
                if not alone and beat is not None and (now - beat).total_seconds() < stale:
                    continue
                attempt = job.attempt or 1
                again = attempt < 2
                new_id = uuid.uuid4().hex if again else None
                job.state, job.finished_at = "failed", now
                job.summary = {"error": "interrupted: the service stopped while this refit ran"
                                        + (f"; run again as job {new_id}" if again else "; not run again (second "
                                           "attempt)"), "interrupted": True, "requeued_as": new_id}
                out["failed"].append(job.id)
                if again:
                    crud.add_job(s, new_id, job.camera_id, attempt + 1)
                    retry.append((new_id, job.camera_id))
                    out["requeued"].append(new_id)
            queued = [(j.id, j.camera_id) for j in jobs if j.state == "queued" and j.id not in self._started]
        for job_id, _camera in queued + retry:
            self._started.add(job_id)
            if job_id not in out["requeued"]:
                out["resumed"].append(job_id)
        if any(out.values()):
            log.warning("jobs left by a crash: %d marked failed, %d run again, %d queued resumed",
                        len(out["failed"]), len(out["requeued"]), len(out["resumed"]))
        for job_id, camera_id in queued + retry:
            self._start(job_id, camera_id)
        return out

    def start_recovery(self) -> dict[str, list[str]]:
        """At start-up: :meth:`recover` (every ``running`` job when no other service process shares the data
        dir), then a daemon thread that keeps the heartbeat of this process's running job and recovers stale jobs of
        crashed processes every few seconds."""
        out = self.recover(alone=self._alone())
        if self._sweeper is None:
            period = max(0.5, min(5.0, self.settings.job_stale_seconds / 4))

            def loop() -> None:
                while not self._stop.wait(period):
                    try:
                        with self._running_lock:
                            running = list(self._running)
                        if running:
                            with self.sessions() as s, s.begin():
                                crud.beat_jobs(s, running)
                        self.recover()
                    except Exception:  # noqa: BLE001 - a database hiccup must not end the sweeper
                        log.exception("job heartbeat / recovery failed")

            self._sweeper = threading.Thread(target=loop, name="illumon-jobs-sweeper", daemon=True)
            self._sweeper.start()
        return out

    def _take_schedule_lock(self) -> bool:
        """Hold ``<data dir>/refit-schedule.lock`` (an exclusive ``flock``, released when this process ends): of the
        service processes sharing a data dir (``illumon serve --workers N``) only the holder runs the schedule."""
        held, self._lock_fd = take_process_lock(Path(self.settings.data_dir) / "refit-schedule.lock")
        return held

    def start_schedule(self) -> None:
        """Refit every camera every ``refit_every_hours`` hours in a daemon thread (no-op when the setting is 0, or
        when another process sharing the data dir runs the schedule)."""
        hours = self.settings.refit_every_hours
        if hours <= 0 or self._scheduler is not None:
            return
        if not self._take_schedule_lock():
            log.info("another service process runs the refit schedule")
            return

        def loop() -> None:
            while not self._stop.wait(hours * 3600.0):
                with self.sessions() as s:
                    ids = crud.camera_ids(s)
                for cid in ids:
                    self.submit(cid)

        self._scheduler = threading.Thread(target=loop, name="illumon-refit-schedule", daemon=True)
        self._scheduler.start()

    def shutdown(self) -> None:
        """Stop the schedule and wait for the running job."""
        self._stop.set()
        self._pool.shutdown(wait=True, cancel_futures=True)
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # releases the schedule lock
            self._lock_fd = None
        if self._alive_fd is not None:
            os.close(self._alive_fd)
            self._alive_fd = None


def _refit_worker(
    database_url: str, camera_id: int, data_dir: str, max_frames: int, method: str, max_fit_frames: int = 300
) -> dict:
    """Dask task: refit one camera with the worker process's engine (engines are not picklable; one per process and
    database, :func:`_worker_sessions`)."""
    limit_blas_threads()
    return refit_camera(
        _worker_sessions(database_url), camera_id, data_dir=Path(data_dir), max_frames=max_frames, method=method,
        max_fit_frames=max_fit_frames,
    )


def _worker_sessions(database_url: str) -> sessionmaker[Session]:
    """This process's session factory of ``database_url``, its engine created on first use (a worker's first task,
    or a forked worker before it joins the scheduler: :func:`fork_workers`'s ``prepare``)."""
    with _ENGINES_LOCK:
        if database_url not in _ENGINES:
            _ENGINES[database_url] = make_session_factory(make_engine(database_url))
        return _ENGINES[database_url]


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask; the CPU count where that is unknown)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def worker_config() -> dict[str, object]:
    """The Dask configuration :func:`run_batch` starts its ``LocalCluster`` with: the workers' environment Dask's
    (``distributed.nanny.pre-spawn-environ``: one BLAS and OpenMP thread) but its ``MALLOC_TRIM_THRESHOLD_``, and no
    statistical profiler in the workers (it samples the task's stack every 10 ms for a dashboard the cluster does not
    start).

    Dask sets that glibc threshold to 64 KiB to hand freed memory back to the system at once; set at all, it also
    turns off glibc's adaptive mmap threshold, so every array above 128 KiB a refit makes is mapped and unmapped anew
    and its pages faulted in again: a 1 000-frame refit made ~1 700 page faults in a plain process and ~260 000 with
    the variable or in a Dask worker, where it ran 1.4–2 × slower (``docs/benchmarks.md``). Without it the workers
    allocate as the service's own process does (arrays above glibc's adaptive threshold, at most 32 MiB, are still
    unmapped when freed). A variable set in the calling process's environment is still inherited."""
    import dask
    import distributed  # noqa: F401 - its configuration's defaults

    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ"))
    env.pop("MALLOC_TRIM_THRESHOLD_", None)
    return {"distributed.nanny.pre-spawn-environ": env, "distributed.worker.profile.enabled": False}


_ENGINES: dict[str, sessionmaker[Session]] = {}
_ENGINES_LOCK = threading.Lock()


def run_batch(
    settings: Settings, camera_ids: list[int] | None, dask_scheduler: str | None = None, *,
    n_workers: int | None = None, progress: bool = True,
) -> list[dict]:
    """Refit the given cameras (all when ``None``); more than one camera fans out over Dask. Returns summaries.

    Parameters
    ----------
    settings
        Service settings (database, data dir, refit settings).
    camera_ids
        Cameras to refit; ``None`` for all.
    dask_scheduler
        Address of a Dask scheduler; a ``LocalCluster`` of ``n_workers`` processes (default: the CPUs this process
        may use, at most the number of cameras) otherwise.
    n_workers
        Worker processes, one thread each. When only one worker would run (one camera, one
        usable CPU or ``n_workers=1``) and no scheduler is given, the cameras are refitted serially in this process
        (a message on standard error says so): a one-worker cluster only adds its start-up (~2 s) and task traffic.
    progress
        Show a tqdm progress bar on standard error.

    Notes
    -----
    Each task is a camera id; the worker reads that camera's history itself through one engine per worker process
    (nothing but the id and settings is pickled). The tasks are submitted, and prioritised, largest history first
    (frame counts, index-only): the refits at the end of the batch are the shortest, which keeps both workers busy
    to its end when the cameras' histories differ. The speed-up over serial is bounded by the CPUs left free by other
    work: on a 2-core machine whose other processes keep one core busy, two workers share the remaining core and a
    fleet refit is no faster than serial (the same holds for two plain ``multiprocessing`` processes). Without a
    scheduler, the workers are forked from this process before the cluster starts (:func:`fork_workers`: they have
    its imports, ~2 s less start-up a worker) and join a ``LocalCluster`` that runs the scheduler only; where this
    process cannot fork safely (another thread runs), the ``LocalCluster`` spawns them, with :func:`worker_config`
    (without Dask's ``MALLOC_TRIM_THRESHOLD_``).
    """
    from tqdm import tqdm

    url = settings.resolved_database_url
    engine = make_engine(url)
    sessions = make_session_factory(engine)
    with sessions() as s:
        known = set(crud.camera_ids(s))
        ids = sorted(known) if camera_ids is None else camera_ids
        unknown = [c for c in ids if c not in known]
        if unknown:
            raise ValueError(f"unknown camera {unknown[0]}")
        # the largest histories first (a refit's time grows with its frames, at most refit_max_frames): the last
        # tasks are the short ones, so that no worker is left with a long refit while the other has none
        frames = {c: min(crud.frame_count(s, c), settings.refit_max_frames) for c in ids} if len(ids) > 1 else {}
    engine.dispose()
    args = (str(settings.data_dir), settings.refit_max_frames, settings.refit_method, settings.refit_fit_frames)
    results: list[dict] = []
    cpus = usable_cpus()
    workers = max(1, min(len(ids), n_workers or cpus))
    if dask_scheduler is None and workers == 1:
        if len(ids) > 1:
            why = f"n_workers={n_workers}" if n_workers else f"{cpus} usable CPU"
            print(f"illumon refit: one worker would run ({why}); refitting {len(ids)} cameras serially without Dask",
                  file=sys.stderr, flush=True)
        for cid in tqdm(ids, desc="refit", unit="camera", disable=not progress):
            try:
                results.append(_refit_worker(url, cid, *args))
            except Exception as exc:  # noqa: BLE001 - one camera's failure must not stop the others
                if len(ids) == 1:
                    raise
                results.append({"camera_id": cid, "error": str(exc)})
        return results
    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    forked: list[tuple[Any, Any]] = []
    if dask_scheduler:
        client = Client(dask_scheduler)
    else:
        # before the cluster starts any thread; [] where it cannot fork safely. Each opens its engine while this
        # process starts the scheduler (what its first task did before)
        forked = fork_workers(workers, prepare=functools.partial(_worker_sessions, url))
        client = None
        try:
            with dask.config.set(worker_config()):
                cluster = LocalCluster(n_workers=0 if forked else workers, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
            for _, conn in forked:
                conn.send(cluster.scheduler_address)
            client = Client(cluster)
        except BaseException:
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
            _end_forked(forked)
            raise
    try:
        order = sorted(ids, key=lambda c: -frames.get(c, 0))  # stable: cameras of equal size in the order given
        futures = [client.submit(_refit_worker, url, cid, *args, pure=False, priority=len(order) - i)
                   for i, cid in enumerate(order)]
        futures_ids = {f.key: cid for f, cid in zip(futures, order, strict=True)}
        if forked:  # the tasks wait at the scheduler for the first worker, whose joining is checked only now:
            # Client.wait_for_workers polls every 0.1 s, which before the tasks were submitted delayed them by up to
            # that much (the forked workers join within ~0.1 s of the scheduler's start)
            client.wait_for_workers(1, timeout=FORKED_WORKERS_TIMEOUT)
        for fut in tqdm(as_completed(futures), total=len(futures), desc="refit", unit="camera", disable=not progress):
            try:
                results.append(fut.result())
            except Exception as exc:  # noqa: BLE001 - one camera's failure must not stop the others
                results.append({"camera_id": futures_ids[fut.key], "error": str(exc)})
    finally:
        client.close()
        if cluster is not None:
            cluster.close()  # the scheduler closes its workers, the forked ones among them
        _end_forked(forked)
    return results


FORKED_WORKERS_TIMEOUT = 120.0
"""Seconds :func:`run_batch` waits for the first of its forked workers to join the scheduler (``TimeoutError``
after; the tasks submitted wait for it meanwhile)."""


def fork_workers(n: int, prepare: Callable[[], object] | None = None) -> list[tuple[Any, Any]]:
    """``n`` Dask worker processes forked from this one, each waiting for a scheduler's address (then a
    one-thread :class:`distributed.Worker` of that scheduler until it closes it): ``(process, connection)`` pairs, the
    address to be sent on the connection (``None``: exit). ``[]`` where forking is not safe: more than one thread
    in this process, a running event loop, or no ``fork``. ``prepare``: called in each worker before it waits for
    the address (what its first task would do first, e.g. open its database engine), while this process starts the
    scheduler; an exception it raises is logged and left for the task to meet again.

    Why: a spawned worker (Dask's default, ``LocalCluster``'s nanny) starts a new interpreter that imports
    ``distributed`` and, at its first task, the service, illumon, colour-science and scipy (~2 s a worker on two
    free cores, more on a loaded machine): for a fleet of 12 cameras × 2k frames, whose refits take ~0.45 s each,
    that start-up took all the second worker's gain. A forked worker has everything this process imported.

    Why it is safe: ``fork`` copies only the calling thread, and any lock another thread held at that moment stays
    held in the child forever — which is why Dask's ``multiprocessing-method: fork`` (the nanny forks from a thread
    of its own while the event loop runs in another) can deadlock a worker. Here the processes are forked before the
    cluster exists, from the main thread, while it is the only Python thread of the process
    (:func:`threading.active_count` is 1, checked) and no event loop runs in it: no Python-level lock can be held by
    anyone else. Native threads that may exist then — an idle BLAS pool — are handled by the library's own
    ``pthread_atfork`` handlers (OpenBLAS stops its pool before a fork and restarts it in the child); the child
    pins BLAS to one thread (:func:`~illumon._blas.limit_blas_threads`), as Dask's ``pre-spawn-environ`` does for
    spawned workers. The child never uses a database connection of this process (it drops the engines it
    inherited without closing them, and opens its own, as a spawned worker does) and ends with ``os._exit`` through
    :mod:`multiprocessing`, so no inherited finaliser runs. Results are those of a spawned worker: the same function
    on the same rows (``tests/service/test_jobs.py``)."""
    import asyncio
    import multiprocessing

    if n < 1 or not hasattr(os, "fork") or threading.active_count() != 1 \
            or threading.current_thread() is not threading.main_thread():
        return []
    try:
        asyncio.get_running_loop()
        return []
    except RuntimeError:  # no running loop: the expected case
        pass
    import distributed  # noqa: F401 - imported once here, not in every worker

    if threading.active_count() != 1:  # pragma: no cover - an import started a thread
        return []
    ctx = multiprocessing.get_context("fork")
    out = []
    for i in range(n):
        receive, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_forked_worker, args=(receive, prepare), name=f"illumon-refit-worker-{i}",
                           daemon=True)
        proc.start()
        receive.close()
        out.append((proc, send))
    return out


def _forked_worker(conn: Any, prepare: Callable[[], object] | None = None) -> None:  # noqa: ANN401 - a Connection
    """A forked worker's main (:func:`fork_workers`): ``prepare``, wait for the scheduler's address, then serve it."""
    import asyncio

    import dask
    from distributed import Worker

    _INHERITED.append(dict(_ENGINES))  # the parent's engines: kept, never used or closed here
    _ENGINES.clear()
    limit_blas_threads()
    if prepare is not None:
        try:
            prepare()
        except Exception:  # noqa: BLE001 - the task meets it again and reports it
            log.warning("forked worker: preparing failed", exc_info=True)
    address = conn.recv()
    conn.close()
    if not address:
        return

    logging.getLogger("distributed").setLevel(logging.WARNING)  # as LocalCluster's silence_logs

    async def serve() -> None:  # no memory limit: no nanny to restart a worker, no pause that could stall a task
        async with Worker(address, nthreads=1, name=multiprocessing_name(), memory_limit=0) as worker:
            await worker.finished()

    with dask.config.set({"distributed.worker.profile.enabled": False}):
        asyncio.run(serve())


def multiprocessing_name() -> str:
    """This process's :mod:`multiprocessing` name (a forked worker's Dask name)."""
    import multiprocessing

    return multiprocessing.current_process().name


_INHERITED: list[dict] = []
"""A forked worker's inherited engines (:func:`_forked_worker`)."""


def _end_forked(forked: list[tuple[Any, Any]]) -> None:
    """Let the forked workers go: an empty address to those still waiting for one, then each joined (killed after
    ten seconds)."""
    for _, conn in forked:
        try:
            conn.send(None)
        except (OSError, ValueError):  # already given the address, or gone
            pass
        conn.close()
    for proc, _ in forked:
        proc.join(timeout=10)
        if proc.is_alive():  # pragma: no cover - a worker that did not close
            proc.kill()
            proc.join()
