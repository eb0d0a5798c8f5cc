"""Ingest: one frame carried from its bytes (or the client's region means) to its stored estimate.

* :func:`ingest_image` — an uploaded image: decoded (:mod:`.decode`), registered to its view's reference frame and its
  regions measured where they lie now (:mod:`.registration`) by :func:`measure_image`, then stored;
* :func:`ingest_observations` — region means measured by the client: checked against the camera's regions
  (:func:`observed`), then stored;
* :func:`store_frame` — the frame estimated with its view's scene model (:func:`~.estimation.estimate_frame`, the
  camera's applied gains and exposure divided out first), written durably through the group commit (:mod:`.crud`),
  answered only after the commit that holds it.

A post with an ``Idempotency-Key`` is stored once; a retry gets the first answer (:mod:`.idempotency`). The routes
(:mod:`.api.routes.frames`) only parse the request (:mod:`.api.forms`), call these and answer.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from fastapi import HTTPException
from fastapi.responses import JSONResponse
from illumon.camera import ResponseCurve
from sqlalchemy.orm import Session
from starlette.datastructures import State

from . import crud
from .datafiles import stored_path
from .decode import DecodedFrame, ImageError, decode_frame
from .estimation import current_model, estimate_frame, undo_camera_gains, undo_camera_gains_sd
from .idempotency import Claim, is_conflict, key_lock, keyed, replay, stored
from .limits import regions_outside
from .metrics import Metrics
from .pending import keep_original
from .proposals import MIN_FRAMES, Thumbnail, make_thumbnail, save_thumbnail
from .regions import Region, RegionError, response_for
from .registration import (
    Registration,
    measure_shifted,
    prune_thumbnails,
    register_frame,
    thumbnail_due,
    thumbs_dir,
)
from .settings import Settings
from .storage import Camera, Frame, as_utc, utcnow

__all__ = ["FrameUpload", "Observation", "Measured", "ingest_image", "ingest_observations", "measure_image", "store_frame",
           "MIN_REGISTER_SIDE"]

MIN_REGISTER_SIDE = 32
"""Frames smaller than this (pixels, either side) keep no thumbnail and are not registered."""

Answer = dict | JSONResponse
"""A frame post's answer: the 201 body, or the replay of the first answer to a retried ``Idempotency-Key``."""


@dataclass(frozen=True)
class FrameUpload:
    """An uploaded frame as the form gave it (:func:`~.api.forms.read_frame_form`)."""

    image: bytes | bytearray
    taken_at: datetime
    applied_gains: list[float] | None = None
    exposure: float | None = None
    view: str | None = None


@dataclass(frozen=True)
class Observation:
    """Region means measured by the client, as posted (:class:`~.api.schemas.ObservationIn`): linear values on the
    0…``white_level`` scale, ``None`` for a missing region."""

    patches: dict[str, list[float] | None]
    sd: dict[str, list[float] | None] | None = None
    white_level: float = 1.0
    taken_at: datetime | None = None
    applied_gains: list[float] | None = None
    exposure: float | None = None


@dataclass
class Measured:
    """A frame's region means (linear 0…1) and what is stored with them."""

    taken_at: datetime
    patches: dict
    patch_sd: dict | None = None
    applied_gains: list[float] | None = None
    exposure: float | None = None
    size: tuple[int, int] | None = None
    """(width, height) of the image; ``None`` for client-measured means."""
    image: bytes | bytearray | None = None
    fmt: str | None = None
    region_ids: list[str] | None = None
    """The view's region ids (the camera's own when ``None``)."""
    view: str | None = None
    registration: Registration | None = None
    thumb: Thumbnail | None = None
    warnings: list[str] = field(default_factory=list)


def _once(sessions: Callable[[], Session], claim: Claim | None, work: Callable[[], Answer]) -> Answer:
    """``work()``, or the stored answer when ``claim``'s key was stored already; retries with the same key wait for
    the first, then get its answer."""
    with key_lock(claim):
        if claim is not None and (first := stored(sessions, claim)) is not None:
            return replay(first, claim)
        return work()


def ingest_image(state: State, session: Session, cam: Camera, upload: FrameUpload, claim: Claim | None,
                 received: float) -> Answer:
    """Measure an uploaded image with its view's regions, estimate and store it (runs in a worker thread).
    ``received``: when the request arrived (:func:`time.perf_counter`)."""
    configured = crud.view_regions(session, cam, upload.view)
    state.metrics.observe("illumon_ingest_stage_seconds", time.perf_counter() - received, labels='stage="receive"')

    def work() -> Answer:
        measured = measure_image(state.settings, state.metrics, cam, upload, configured)
        return store_frame(state, session, cam, measured, claim)

    out = _once(state.sessions, claim, work)
    state.metrics.observe("illumon_ingest_seconds", time.perf_counter() - received)
    return out


def ingest_observations(state: State, session: Session, cam: Camera, body: Observation,
                        claim: Claim | None) -> Answer:
    """Check and store region means measured by the client (linear values; ``null`` for a missing region): 422 for
    an unknown region, for every region ``null``, or for a standard error without its value."""

    def work() -> Answer:
        measured = observed(cam, body)
        return store_frame(state, session, cam, measured, claim)

    return _once(state.sessions, claim, work)


def observed(cam: Camera, body: Observation) -> Measured:
    """Client-measured region means as stored: checked against the camera's regions, divided by the white level."""
    known = {r["id"] for r in cam.regions}
    unknown = sorted(set(body.patches) - known)
    if unknown:
        raise HTTPException(422, f"unknown region id(s) {', '.join(map(repr, unknown))}; known: {sorted(known)}")
    if all(v is None for v in body.patches.values()):
        raise HTTPException(422, "every region is null: the observation holds no value to store; send at least one "
                                 "region's [r, g, b]")
    unknown_sd = sorted(set(body.sd or {}) - set(body.patches))
    if unknown_sd:
        raise HTTPException(422, f"sd given for region id(s) {', '.join(map(repr, unknown_sd))} that have no value in "
                                 "patches; send sd only for regions in patches")
    patches = {k: (None if v is None else [x / body.white_level for x in v]) for k, v in body.patches.items()}
    patch_sd = None if body.sd is None else {
        k: (None if v is None or patches.get(k) is None else [x / body.white_level for x in v]) for k, v in body.sd.items()}
    taken_at = as_utc(body.taken_at) if body.taken_at else utcnow()  # naive means UTC
    return Measured(taken_at, patches, patch_sd, applied_gains=body.applied_gains, exposure=body.exposure)


def measure_image(settings: Settings, metrics: Metrics, cam: Camera, upload: FrameUpload,
                  configured: list[dict]) -> Measured:
    """Decode an image, register it to its view's reference frame and measure its regions (``configured``: the
    view's) where they lie now; a frame whose view changed is stored unmeasured. 4xx for an image that cannot be
    decoded or that none of the regions lies in."""
    with _FLIGHT_LOCK:
        _IN_FLIGHT[0] += 1
        alone = _IN_FLIGHT[0] == 1 and _CPUS > 1
    try:
        t0 = time.perf_counter()
        frame = decode_frame(upload.image, [Region(**r) for r in configured], max_pixels=settings.max_image_pixels,
                             max_reduction=settings.jpeg_max_reduction, max_bytes=settings.max_decoded_bytes)
        t1 = time.perf_counter()
        metrics.observe("illumon_ingest_stage_seconds", t1 - t0, labels='stage="decode"')
        metrics.inc("illumon_ingest_decodes_total", labels=f'scale="1/{frame.scale}"')
        w, h = frame.size
        outside = regions_outside(configured, frame.size)  # accepted before any image size was known
        if configured and len(outside) == len(configured):
            raise RegionError(f"none of the view's regions lies inside the {w}×{h} image (e.g. "
                              f"{outside[0]!r}): is this the camera's own view at its usual resolution? (If the "
                              f"regions are wrong, correct them with PUT /v1/cameras/{cam.id}/regions)")
        extra = [f"region(s) {', '.join(map(repr, outside))} lie outside the {w}×{h} image: stored as missing; "
                 f"correct them with PUT /v1/cameras/{cam.id}/regions"] if outside else []
        thumb, reg, patches, patch_sd = _register_and_measure(
            settings, metrics, cam.id, upload.view, frame, response_for(cam.response, frame.full_scale), configured,
            alone)
    except ImageError as exc:
        raise HTTPException(exc.status, str(exc)) from None
    except RegionError as exc:
        raise HTTPException(422, str(exc)) from None
    finally:
        with _FLIGHT_LOCK:
            _IN_FLIGHT[0] -= 1
    return Measured(upload.taken_at, patches, patch_sd, upload.applied_gains, upload.exposure, frame.size,
                    upload.image, frame.fmt, [r["id"] for r in configured], upload.view, reg, thumb, extra)


_MEASURING = ThreadPoolExecutor(max_workers=4, thread_name_prefix="illumon-regions")
"""Region statistics measured beside the registration (both are mostly OpenCV, which releases the GIL)."""
_CPUS = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
_IN_FLIGHT = [0]
"""Frames of this process from their decode to their region statistics; only one alone on a multi-core machine leaves
a core idle for its statistics (with more, every core is already busy with frames and a second thread per frame only
costs: ~1 ms of CPU a frame measured at 8 clients)."""
_FLIGHT_LOCK = threading.Lock()
_LAST_SHIFT: dict[tuple[str, int, str | None], tuple[int, int]] = {}
"""The whole-pixel shift of each view's latest registered frame (this process's): where its next frame's regions are
measured while that frame registers."""


def _register_and_measure(settings: Settings, metrics: Metrics, camera_id: int, view: str | None, frame: DecodedFrame,
                          response: ResponseCurve, configured: list[dict], alone: bool
                          ) -> tuple[Thumbnail | None, Registration, dict, dict | None]:
    """The frame's thumbnail and registration (:func:`~.registration.register_frame`), and its region means and
    standard errors where the registration puts the regions (none for a view change).

    When this frame is ``alone`` (the process's only one being measured: a core is then idle), the regions are
    measured beside the registration, in another thread, at the whole-pixel shift of the view's latest frame (a fixed
    camera's is the same frame after frame); when the frame registers at another one (or as a view change) that
    measurement is dropped and the regions are measured again: the answer is the same as measuring after the
    registration. Stages: ``register`` the thumbnail and registration, ``regions`` the wait for the region statistics
    after it."""
    t1 = time.perf_counter()
    if min(frame.size) < MIN_REGISTER_SIDE:  # a tiny image has nothing to register or propose from
        reg = Registration("ok", (0.0, 0.0), None)
        patches, sd = measure_shifted(frame, configured, response, reg, settings.clip_fraction,
                                      settings.min_region_fraction)
        metrics.observe("illumon_ingest_stage_seconds", time.perf_counter() - t1, labels='stage="regions"')
        return None, reg, patches, sd
    key = (str(settings.data_dir), camera_id, view)
    guess = _LAST_SHIFT.get(key, (0, 0))
    ahead: Future = Future()
    try:
        if alone:
            ahead = _MEASURING.submit(measure_shifted, frame, configured, response, Registration("ok", guess, None),
                                      settings.clip_fraction, settings.min_region_fraction)
        thumb = make_thumbnail(frame.image, response, settings.clip_fraction, frame.size)
        reg = register_frame(settings.data_dir, camera_id, view, thumb, configured, frame.size)
    finally:
        t2 = time.perf_counter()
        # waited for either way: the frame outlives no thread
        measured = alone and ahead.exception() is None and ahead.result()
    metrics.observe("illumon_ingest_stage_seconds", t2 - t1, labels='stage="register"')
    shift = (round(reg.shift[0]), round(reg.shift[1]))
    patches, sd = {}, None  # a view change: stored, not measured (the regions are not where drawn)
    if reg.state != "view_change":
        _LAST_SHIFT[key] = shift
        if alone and shift == guess:
            patches, sd = measured if measured else ahead.result()  # the same inputs: the same values (or error)
        else:
            patches, sd = measure_shifted(frame, configured, response, reg, settings.clip_fraction,
                                          settings.min_region_fraction)
    metrics.observe("illumon_ingest_stage_seconds", time.perf_counter() - t2, labels='stage="regions"')
    return thumb, reg, patches, sd


def _warnings(cam: Camera, m: Measured, region_ids: list[str], usable: int) -> list[str]:
    """What the answer tells the camera about a frame it stored but may not have estimated."""
    reg = m.registration
    warnings = []
    if reg is not None and reg.state == "view_change":
        warnings.append(f"view change: the frame does not register to its view's reference frame (shift "
                        f"{reg.shift[0]:+.0f}, {reg.shift[1]:+.0f} px, peak {reg.response:.2f}): "
                        "stored but not estimated; if the camera moved for good, confirm its regions again "
                        f"(/cameras/{cam.id}/regions)")
    elif not region_ids:
        warnings.append(f"the camera has no regions yet: the frame is stored; once {MIN_FRAMES} frames are stored, "
                        f"confirm proposed regions at /cameras/{cam.id}/regions (or GET /v1/cameras/{cam.id}/region-proposals)")
    elif usable == 0:
        warnings.append("no region was usable in this frame (each mostly clipped, occluded or dark): it is stored but "
                        "adds nothing to the estimates")
    elif usable < 2:
        warnings.append("only one region was usable: a frame needs two to be estimated")
    if reg is not None and reg.state == "uncertain":
        warnings.append(f"registration uncertain: weak correlation peak ({reg.response:.2f}), but the frame "
                        f"still matches its reference (score {reg.match:.2f}): measured with the regions at "
                        f"shift {reg.shift[0]:+.0f}, {reg.shift[1]:+.0f} px")
    return warnings + m.warnings


def store_frame(state: State, session: Session, cam: Camera, m: Measured, claim: Claim | None) -> Answer:
    """Estimate a frame if a model exists (the camera's applied gains and exposure divided out first), store it
    durably with them, and build the 201 answer.

    The estimate comes first (it needs no frame id); the rows are then written through the app's
    :class:`~illumon_service.storage.GroupCommit`, which returns once they are committed (concurrent ingests share
    one commit), so the answer never precedes durability. With an ``Idempotency-Key`` (``claim``) the key is written
    first (a key another process stored meanwhile fails there, before any file is written) and keeps the answer; a
    retry then gets that answer (:mod:`~illumon_service.idempotency`).
    """
    settings, metrics = state.settings, state.metrics
    region_ids = [r["id"] for r in cam.regions] if m.region_ids is None else m.region_ids
    t0 = time.perf_counter()
    entry = _Stored(settings, cam, m, region_ids, current_model(settings.data_dir, cam.models, cam.id, m.view))
    t1 = time.perf_counter()
    metrics.observe("illumon_estimate_seconds", t1 - t0)
    metrics.observe("illumon_ingest_stage_seconds", t1 - t0, labels='stage="estimate"')
    # The request's session has done its reading: give its connection back to the pool (``cam`` keeps its loaded
    # columns) so that requests waiting for a group commit never hold every pooled connection.
    session.close()
    try:
        out = state.commits.submit(entry.write if claim is None else keyed(entry.write, claim))
    except Exception as exc:
        if claim is not None and is_conflict(exc):  # a concurrent retry in another process stored the frame first
            first = stored(state.sessions, claim)
            if first is not None:
                return replay(first, claim)
        raise
    if m.image is not None and not region_ids and m.fmt:  # measured once the view's regions are confirmed
        with state.sessions() as s:
            keep_original(s, settings.data_dir, cam.id, m.view, out["frame_id"], m.image, m.fmt,
                          settings.pending_max_frames, settings.pending_max_bytes)
    metrics.observe("illumon_ingest_stage_seconds", time.perf_counter() - t1, labels='stage="commit"')
    metrics.inc("illumon_frames_ingested_total")
    return out


@dataclass
class _Stored:
    """A frame on its way to the database: its estimate with the model in use at ingest, and the write that the group
    commit runs (:meth:`write`)."""

    settings: Settings
    cam: Camera
    m: Measured
    region_ids: list[str]
    first: tuple[Path, str] | None
    """The scene model (file, version) in use at ingest; ``None`` before the first refit."""
    estimate: dict | None = field(init=False)
    """The frame's estimate with that model."""
    usable: int = field(init=False)
    """Regions with a value."""
    undone: dict = field(init=False)
    """Region means with the camera's applied gains and exposure divided out."""
    undone_sd: dict | None = field(init=False)
    warnings: list[str] = field(init=False)

    def __post_init__(self) -> None:
        m, matrix = self.m, (self.cam.response or {}).get("matrix")
        self.usable = sum(v is not None for v in m.patches.values())
        self.undone = undo_camera_gains(m.patches, m.applied_gains, m.exposure, matrix)
        self.undone_sd = undo_camera_gains_sd(m.patch_sd, m.applied_gains, m.exposure, matrix)
        self.warnings = _warnings(self.cam, m, self.region_ids, self.usable)
        self.estimate = self.estimate_with(self.first)

    def estimate_with(self, model: tuple[Path, str] | None) -> dict | None:
        """The frame's estimate with ``model`` (``None`` without a model or two usable regions)."""
        if model is None or self.usable < 2:
            return None
        return estimate_frame(self.settings.data_dir, self.cam.id, "new", self.m.taken_at.isoformat(), self.undone,
                              self.region_ids, self.m.view, self.undone_sd, model_file=model[0])

    def write(self, session: Session) -> dict:
        """Store the frame (its thumbnail and image files too) and its estimate; returns the 201 answer."""
        m, cam = self.m, self.cam
        frame = crud.add_frame(session, camera_id=cam.id, taken_at=m.taken_at, patches=m.patches,
                               width=m.size[0] if m.size else None, height=m.size[1] if m.size else None,
                               applied_gains=m.applied_gains, exposure=m.exposure, view=m.view, patch_sd=m.patch_sd,
                               registration=None if m.registration is None else m.registration.as_dict())
        self._keep_files(session, frame)
        # The model in use now (the frame's insert holds SQLite's write lock; the row lock orders this with a
        # refit's commit on PostgreSQL): a refit that committed since the estimate makes it again with the new
        # model, so no estimate of an old model lands after a refit.
        now = current_model(self.settings.data_dir, crud.models_for_update(session, cam.id), cam.id, m.view)
        use = self.estimate if (now and now[1]) == (self.first and self.first[1]) else self.estimate_with(now)
        row = None
        if use is not None:
            row = crud.add_estimate(session, frame_id=frame.id, camera_id=cam.id, taken_at=m.taken_at,
                                    model=now[1] if now else None, **use)
        else:
            crud.mark_not_estimated(session, frame, (
                "view_change" if m.registration is not None and m.registration.state == "view_change"
                else "no_regions" if not self.region_ids else "too_few_regions" if self.usable < 2
                else "no_model" if now is None else "estimate_failed"))
        return {
            "frame_id": frame.id,
            "taken_at": as_utc(frame.taken_at).isoformat(),
            "regions": m.patches,
            "applied_gains": m.applied_gains,
            "exposure": m.exposure,
            "usable_regions": self.usable,
            "view": m.view,
            "registration": None if m.registration is None else m.registration.as_dict(),
            "estimate": crud.estimate_out(row) if row is not None else None,
            "warnings": self.warnings,
        }

    def _keep_files(self, session: Session, frame: Frame) -> None:
        """The frame's thumbnail when one is due (pruning the view's older ones), and its image with ``keep_images``."""
        m, data_dir = self.m, self.settings.data_dir
        if m.thumb is not None and thumbnail_due(session, self.cam.id, m.view, m.taken_at, m.registration):
            path = thumbs_dir(data_dir, self.cam.id) / f"{frame.id}.png"
            save_thumbnail(path, m.thumb)
            frame.thumb_path = stored_path(data_dir, path)
            prune_thumbnails(session, self.cam.id, m.view, data_dir)
        if m.image is not None and self.settings.keep_images:
            folder = Path(data_dir) / "images" / f"camera-{self.cam.id}"
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{frame.id}.{m.fmt}"
            path.write_bytes(m.image)
            frame.image_path = stored_path(data_dir, path)
