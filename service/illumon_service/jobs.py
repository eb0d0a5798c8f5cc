"""Refit jobs: re-estimate a camera's stored frames (scene model fit + per-frame estimates by default).

In the service a job runs in one background thread (or inline when ``jobs_inline`` is set, as in tests); the
``illumon refit`` batch command runs the same :func:`refit_camera` for one camera or, with ``--all``, fans the cameras
out over a Dask cluster (a ``LocalCluster`` unless ``--dask-scheduler`` names one) with a tqdm progress bar.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from sqlalchemy import delete, insert, select, true, update
from sqlalchemy.orm import Session, sessionmaker

from .estimation import (
    CALIBRATION_PREFIX,
    RefitInputError,
    camera_primaries,
    check_response,
    estimate_frame,
    model_path,
    refit_estimates,
    sensitivities_array,
    undo_camera_gains,
    undo_camera_gains_sd,
    versioned_model_path,
    view_model_key,
)
from .limits import frame_problem
from .locks import take_process_lock
from .metrics import Metrics
from .registration import view_regions
from .settings import Settings
from .storage import Calibration, Camera, Estimate, Frame, Job, as_utc, make_engine, make_session_factory, utcnow

__all__ = ["refit_camera", "JobRunner", "run_batch", "usable_cpus"]

from illumon._blas import limit_blas_threads

log = logging.getLogger("illumon_service.jobs")


WRITE_CHUNK = 2000
"""Estimates written per transaction by a refit (short transactions keep concurrent ingest waiting little)."""


def refit_camera(
    sessions: sessionmaker[Session],
    camera_id: int,
    *,
    data_dir: Path,
    max_frames: int = 100_000,
    method: str = "model",
    max_fit_frames: int = 300,
    progress: Callable[[float], None] | None = None,
) -> dict:
    """Re-estimate the most recent ``max_frames`` frames of a camera and store the estimates; returns a summary.

    Frames it cannot use are left out and reported (``dropped``: frame id and reason — a value outside the ranges of
    :mod:`.limits`, stored by an older version), never a reason to fail. Each view's new scene model is written to a
    new versioned file; the estimates and the switch to the new models (:attr:`.storage.Camera.models`) are then
    committed in one transaction (:func:`_commit_refit`), so a crash at any point leaves either the old estimates and
    models or the new ones, never a mixture; frames stored while the fit ran are estimated with the new model in that
    same transaction.

    Parameters
    ----------
    sessions
        Session factory of the service database.
    camera_id
        The camera to refit.
    data_dir
        Service data folder (the fitted scene models go to ``models/camera-<id>[-view-<view>].<version>.json``).
    max_frames
        At most this many of the most recent frames are re-estimated.
    method
        ``model`` (scene model fit + per-frame estimates) or a retrieval method; see :func:`refit_estimates`.
    max_fit_frames
        Frames the scene model's reflectances are fitted on (spread over the illuminant range).
    progress
        Called with the fraction done (0…1).

    Returns
    -------
    dict
        Frames estimated, skipped, dropped (``dropped``: ``[{"frame_id", "reason"}]``, at most
        :data:`MAX_DROPPED_LISTED`, ``dropped_frames`` their number), method, model ``version``, timings
        (``seconds``, ``read_s``, ``fit_s``, ``write_s``), the check of the declared tone response
        (``response_check``, :func:`~.estimation.check_response`) and ``warnings``: every warning of the refit in one
        list (tone response, calibration images, views, the model's identifiability and white-balance warnings), shown
        with the camera and on the status page.

    Raises
    ------
    RefitInputError
        Too few usable frames.
    """
    t0 = time.perf_counter()
    started = time.time()
    report = progress or (lambda _p: None)
    with sessions() as s:
        cam = s.get(Camera, camera_id)
        if cam is None:
            raise ValueError(f"unknown camera {camera_id}")
        rows = s.execute(
            select(Frame.id, Frame.taken_at, Frame.patches, Frame.applied_gains, Frame.exposure, Frame.view,
                   Frame.registration, Frame.patch_sd)
            .where(Frame.camera_id == camera_id)
            .order_by(Frame.taken_at.desc(), Frame.id.desc()).limit(max_frames)
        ).all()
        read_ids = [r.id for r in rows]
        # Frames of an unknown view (a view change) or measured before any region existed carry no region values.
        rows = [r for r in rows if r.patches and (r.registration or {}).get("state") != "view_change"]
        dropped: list[dict] = []
        usable_rows = []
        for r in rows:
            problem = frame_problem(r.patches, r.patch_sd, r.applied_gains, r.exposure)
            if problem is None:
                usable_rows.append(r)
            else:
                dropped.append({"frame_id": r.id, "reason": problem})
        rows = usable_rows
        views = sorted({r.view for r in rows if r.view is not None})
        view_ids = {v: [r["id"] for r in view_regions(s, cam, v)] for v in views}
        rows = [r for r in rows if r.view is None or view_ids.get(r.view)]
        region_ids = [r["id"] for r in cam.regions]
        css = sensitivities_array(cam.sensitivities)
        encoding = (cam.response or {}).get("encoding", "linear")
        matrix = (cam.response or {}).get("matrix")
        primaries = camera_primaries(cam.response, css is not None)
        cals = s.scalars(select(Calibration).where(Calibration.camera_id == camera_id).order_by(Calibration.id)).all()
        calibrations, known, cal_warnings = calibration_frames(cals, matrix)
    if dropped:
        log.warning("refit of camera %s: %d frame(s) left out (%s)", camera_id, len(dropped), dropped[0]["reason"])
    rows.reverse()
    frames = [_history_row(r, matrix) for r in rows if r.view is None]
    times = {str(r.id): r.taken_at for r in rows}
    t_read = time.perf_counter()
    report(0.1)
    version = uuid.uuid4().hex[:16]
    new_models: dict[str | None, Path] = {}
    view_warnings = []
    estimates: dict = {}
    for v in views:  # each PTZ preset: its own regions and scene model (calibration images are of the default view)
        vf = [_history_row(r, matrix) for r in rows if r.view == v]
        path = versioned_model_path(data_dir, camera_id, v, version)
        try:
            est_v, summary_v = refit_estimates(vf, view_ids[v], css, method=method, model_file=path,
                                               max_fit_frames=max_fit_frames, primaries=primaries)
            estimates.update(est_v)
            new_models[v] = path
            view_warnings += [f"view {v!r}: {w}" for w in summary_v.get("identifiability_warnings") or []]
        except RefitInputError as exc:
            view_warnings.append(f"view {v!r} not refitted: {exc}")
    if not frames and estimates:
        summary = {"frames": 0, "method": method, "views": len(views)}
    else:
        path = versioned_model_path(data_dir, camera_id, None, version)
        try:
            est_d, summary = refit_estimates(
                frames, region_ids, css, method=method, model_file=path,
                max_fit_frames=max_fit_frames, calibrations=calibrations, known_reflectances=known, primaries=primaries,
            )
        except Exception:
            for p in new_models.values():  # nothing committed: the new files of the other views go too
                p.unlink(missing_ok=True)
            path.unlink(missing_ok=True)
            raise
        estimates.update(est_d)
        if path.is_file():
            new_models[None] = path
    t_check = time.perf_counter()
    check = check_response(frames, region_ids, css, encoding) if frames else {"warnings": []}
    summary["response_check"] = {k: v for k, v in check.items() if k != "warnings"}
    summary["response_check_s"] = round(time.perf_counter() - t_check, 3)  # part of fit_s
    model_warnings = [str(w) for w in summary.get("identifiability_warnings") or []]
    if isinstance(summary.get("model"), str) and summary["model"].startswith("scene model fit failed"):
        model_warnings.append(summary["model"])
    summary["warnings"] = list(dict.fromkeys(cal_warnings + check["warnings"] + view_warnings + model_warnings))
    summary["views"] = len(views) + bool(frames)
    summary["version"] = version
    summary["dropped_frames"] = len(dropped)
    summary["dropped"] = dropped[:MAX_DROPPED_LISTED]
    t_fit = time.perf_counter()
    report(0.8)
    ids_of = {v: (view_ids[v] if v is not None else region_ids) for v in new_models}
    used = {r.id: sum(r.patches.get(k) is not None for k in ids_of[r.view]) for r in rows if r.view in new_models}
    written = _commit_refit(sessions, data_dir, camera_id, version, new_models, estimates, times,
                            ids_of, matrix, read_ids, dropped, used)
    _remove_old_models(data_dir, camera_id, new_models, started)
    t_end = time.perf_counter()
    summary.update({
        "camera_id": camera_id,
        "frames_written": written,
        "seconds": round(t_end - t0, 3),
        "read_s": round(t_read - t0, 3),
        "fit_s": round(t_fit - t_read, 3),
        "write_s": round(t_end - t_fit, 3),
    })
    report(1.0)
    return summary


MAX_DROPPED_LISTED = 100
"""Frames a refit's summary lists by id among those it left out (all are counted)."""


def _commit_refit(
    sessions: sessionmaker[Session], data_dir: Path, camera_id: int, version: str, new_models: dict[str | None, Path],
    estimates: dict[str, dict], times: dict, region_ids: dict[str | None, list[str]], matrix: list | None,
    read_ids: list[int], dropped: list[dict], used: dict[int, int] | None = None,
) -> int:
    """Store a refit in one transaction: switch the camera's views to their new model files, replace the estimates,
    estimate with the new models the frames stored since the refit read the history, and record why the others have
    none. Returns the number of estimates written.

    The camera row is updated first: on SQLite that takes the write lock before anything is read, on PostgreSQL it
    locks the row that every ingest locks (:func:`frame_model_guard`) before storing an estimate, so no ingest
    commits an estimate of the old model after this commit."""
    read = set(read_ids)
    with sessions() as s, s.begin():
        cam = s.get(Camera, camera_id, with_for_update=True)
        if cam is None:  # deleted while the refit ran
            for p in new_models.values():
                p.unlink(missing_ok=True)
            return 0
        models = dict(cam.models or {})
        for v, p in new_models.items():
            models[view_model_key(v)] = {"file": p.name, "version": version}
        cam.models = models
        s.flush()
        late = s.execute(
            select(Frame.id, Frame.taken_at, Frame.patches, Frame.applied_gains, Frame.exposure, Frame.view,
                   Frame.registration, Frame.patch_sd)
            .where(Frame.camera_id == camera_id, Frame.id.not_in(read) if read else true())
        ).all()
        rows = {fid: {"frame_id": int(fid), "camera_id": camera_id, "taken_at": times[fid], "model": version, **est}
                for fid, est in estimates.items()}
        for r in late:  # stored while the refit fitted: estimated now with the new model of their view
            if r.view not in new_models or not r.patches or frame_problem(r.patches, r.patch_sd, r.applied_gains,
                                                                          r.exposure):
                continue
            if (r.registration or {}).get("state") == "view_change":
                continue
            row = _history_row(r, matrix)
            est = estimate_frame(data_dir, camera_id, row[0], row[1], row[2], region_ids[r.view], r.view, row[3],
                                 model_file=new_models[r.view])
            if est is not None:
                rows[str(r.id)] = {"frame_id": r.id, "camera_id": camera_id, "taken_at": r.taken_at, "model": version,
                                   **est}
        ids = [int(fid) for fid in rows]
        for start in range(0, len(ids), WRITE_CHUNK):  # one transaction; statements of bounded size
            s.execute(delete(Estimate).where(Estimate.frame_id.in_(ids[start : start + WRITE_CHUNK])))
        items = list(rows.values())
        for start in range(0, len(items), WRITE_CHUNK):
            s.execute(insert(Estimate), items[start : start + WRITE_CHUNK])
        for start in range(0, len(ids), WRITE_CHUNK):
            s.execute(update(Frame).where(Frame.id.in_(ids[start : start + WRITE_CHUNK])).values(not_estimated=None))
        # frames the refit used but could not estimate (fewer than two regions seen, a non-finite white): no estimate
        # of the previous model stays behind
        missed = sorted(set(used or {}) - set(ids))
        for start in range(0, len(missed), WRITE_CHUNK):
            part = missed[start : start + WRITE_CHUNK]
            s.execute(delete(Estimate).where(Estimate.frame_id.in_(part)))
            for reason in ("too_few_regions", "estimate_failed"):
                which = [i for i in part if (used[i] < 2) == (reason == "too_few_regions")]
                if which:
                    s.execute(update(Frame).where(Frame.id.in_(which)).values(not_estimated=reason))
        bad = [d["frame_id"] for d in dropped]
        for start in range(0, len(bad), WRITE_CHUNK):
            part = bad[start : start + WRITE_CHUNK]
            s.execute(delete(Estimate).where(Estimate.frame_id.in_(part)))
            s.execute(update(Frame).where(Frame.id.in_(part)).values(not_estimated="invalid_values"))
        if _commit_hook is not None:
            _commit_hook()
    return len(rows)


_commit_hook: Callable[[], None] | None = None
"""Called inside a refit's transaction just before it commits (tests simulate a crash there)."""


def _remove_old_models(data_dir: Path, camera_id: int, new_models: dict[str | None, Path], started: float) -> None:
    """Delete the model files of the refitted views other than the new ones, older than this refit (an older
    version's unversioned file too; a newer refit running elsewhere keeps its file)."""
    for v, keep in new_models.items():
        legacy = model_path(data_dir, camera_id, v)
        for p in [legacy, *legacy.parent.glob(f"{legacy.stem}.*.json")]:
            try:
                if p != keep and p.is_file() and p.stat().st_mtime < started:
                    p.unlink()
            except FileNotFoundError:
                pass


def _history_row(r: Frame, matrix: list | None) -> tuple[str, str, dict, dict | None]:
    """A stored frame as a history row for :func:`.estimation.build_observations`: id, time, region means and their
    standard errors, with the camera's applied gains and exposure divided out."""
    return (str(r.id), as_utc(r.taken_at).isoformat(), undo_camera_gains(r.patches, r.applied_gains, r.exposure, matrix),
            undo_camera_gains_sd(r.patch_sd, r.applied_gains, r.exposure, matrix))


def calibration_frames(
    cals: list[Calibration], matrix: list | None = None
) -> tuple[list[tuple[str, str, dict]], dict[str, np.ndarray], list[str]]:
    """Stored calibrations as extra frames of a refit's history: ``calibration-<id>`` holding the reference patches
    and the camera's regions seen in the same image (the camera's applied gains divided out); the known reflectances
    of the references — the ColorChecker's (:func:`illumon.camera.colorchecker_references`, ids ``chart:01`` …) and
    each grey card's (:func:`illumon.camera.grey_card_reference`, id ``grey:<calibration id>``); and a warning for
    each calibration left out because its image shows fewer than two usable regions of the scene."""
    from illumon.camera import colorchecker_references, grey_card_reference

    frames, known, warnings = [], {}, []
    chart = colorchecker_references()
    for c in cals:
        scene = {k: v for k, v in (c.scene or {}).items() if v is not None}
        refs = {k: v for k, v in c.patches.items() if v is not None}
        if len(scene) < 2 or not refs:
            warnings.append(f"calibration {c.id} ({c.kind}) left out: its image shows fewer than two usable regions "
                            "of the scene" if refs else f"calibration {c.id} ({c.kind}) left out: no usable patch")
            continue
        if c.kind == "grey":
            pid = f"grey:{c.id}"
            refs = {pid: refs["grey"]}
            known.update(grey_card_reference(pid, c.reflectance or 0.18))
        else:
            known.update({k: chart[k] for k in refs})
        patches = undo_camera_gains({**scene, **refs}, c.applied_gains, c.exposure, matrix)
        frames.append((f"{CALIBRATION_PREFIX}{c.id}", as_utc(c.created_at).isoformat(), patches))
    return frames, known, warnings


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
            s.add(Job(id=job_id, camera_id=camera_id, state="queued", progress=0.0, attempt=attempt))
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
            job = s.get(Job, job_id)
            if job is not None:
                for k, v in fields.items():
                    setattr(job, k, v)

    def _claim(self, job_id: str) -> bool:
        """Take a queued job (``queued`` → ``running``, heartbeat now) unless another process took it first."""
        with self.sessions() as s, s.begin():
            done = s.execute(update(Job).where(Job.id == job_id, Job.state == "queued")
                             .values(state="running", progress=0.0, heartbeat_at=utcnow()))
        return done.rowcount == 1

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
            jobs = s.scalars(select(Job).where(Job.state.in_(("running", "queued")))).all()
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
                    s.add(Job(id=new_id, camera_id=job.camera_id, state="queued", progress=0.0, attempt=attempt + 1))
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
                                s.execute(update(Job).where(Job.id.in_(running), Job.state == "running")
                                          .values(heartbeat_at=utcnow()))
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
                    ids = list(s.scalars(select(Camera.id)).all())
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
    database, created on the first task)."""
    limit_blas_threads()
    with _ENGINES_LOCK:
        if database_url not in _ENGINES:
            _ENGINES[database_url] = make_session_factory(make_engine(database_url))
        sessions = _ENGINES[database_url]
    return refit_camera(
        sessions, camera_id, data_dir=Path(data_dir), max_frames=max_frames, method=method,
        max_fit_frames=max_fit_frames,
    )


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask; the CPU count where that is unknown)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


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
        Worker processes of the ``LocalCluster``, one thread each. When only one worker would run (one camera, one
        usable CPU or ``n_workers=1``) and no scheduler is given, the cameras are refitted serially in this process
        (a message on standard error says so): a one-worker cluster only adds its start-up (~2 s) and task traffic.
    progress
        Show a tqdm progress bar on standard error.

    Notes
    -----
    Each task is a camera id; the worker reads that camera's history itself through one engine per worker process
    (nothing but the id and settings is pickled). The speed-up over serial is bounded by the CPUs left free by other
    work: on a 2-core machine whose other processes keep one core busy, two workers share the remaining core and a
    fleet refit is no faster than serial (the same holds for two plain ``multiprocessing`` processes).
    """
    from tqdm import tqdm

    url = settings.resolved_database_url
    engine = make_engine(url)
    sessions = make_session_factory(engine)
    with sessions() as s:
        known = set(s.scalars(select(Camera.id)).all())
    engine.dispose()
    ids = sorted(known) if camera_ids is None else camera_ids
    unknown = [c for c in ids if c not in known]
    if unknown:
        raise ValueError(f"unknown camera {unknown[0]}")
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
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if dask_scheduler:
        client = Client(dask_scheduler)
    else:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
    try:
        futures = [client.submit(_refit_worker, url, cid, *args, pure=False) for cid in ids]
        futures_ids = {f.key: cid for f, cid in zip(futures, ids, strict=True)}
        for fut in tqdm(as_completed(futures), total=len(futures), desc="refit", unit="camera", disable=not progress):
            try:
                results.append(fut.result())
            except Exception as exc:  # noqa: BLE001 - one camera's failure must not stop the others
                results.append({"camera_id": futures_ids[fut.key], "error": str(exc)})
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return results
