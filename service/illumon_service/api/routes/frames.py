"""Frame ingest: images (``/frames``) and client-side region means (``/observations``)."""

from __future__ import annotations

import time
from datetime import datetime
from pathlib import Path

from fastapi import APIRouter, Header, HTTPException, Query, Request, status
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from ...crud import estimate_out
from ...datafiles import stored_path
from ...decode import ImageError, decode_frame, sniff_format
from ...deps import AdminDep, PrincipalDep, SessionDep, camera_for
from ...estimation import current_model, estimate_frame, undo_camera_gains, undo_camera_gains_sd
from ...idempotency import (
    IDEMPOTENCY_DOC,
    Claim,
    fingerprint,
    form_fingerprint,
    is_conflict,
    key_lock,
    keyed,
    parse_key,
    replay,
    stored,
)
from ...limits import regions_outside
from ...manage import delete_frame
from ...pending import keep_original
from ...proposals import MIN_FRAMES, Thumbnail, make_thumbnail, save_thumbnail
from ...regions import Region, RegionError, region_stats, response_for
from ...registration import (
    Registration,
    parse_view,
    prune_thumbnails,
    register_frame,
    shift_regions,
    thumbnail_due,
    thumbs_dir,
    view_regions,
)
from ...storage import Camera, Estimate, Frame, as_utc
from ...uploads import IMAGE_TYPES, parse_gains, parse_positive, parse_time, read_multipart
from ..schemas import ERROR_RESPONSES, FRAME_UPLOAD, MAX_LIST, DeletedOut, FrameIngestOut, FrameOut, IsoDateTime, ObservationIn

router = APIRouter(prefix="/v1/cameras", tags=["frames"], responses=ERROR_RESPONSES)

MIN_REGISTER_SIDE = 32
"""Frames smaller than this (pixels, either side) keep no thumbnail and are not registered."""

def _store(
    request: Request, session: Session, cam: Camera, taken_at: datetime, patches: dict, size: tuple[int, int] | None,
    image: bytes | bytearray | None = None, fmt: str | None = None, applied_gains: list[float] | None = None,
    exposure: float | None = None, region_ids: list[str] | None = None, view: str | None = None,
    registration: Registration | None = None, thumb: Thumbnail | None = None, patch_sd: dict | None = None,
    extra_warnings: list[str] | None = None, claim: Claim | None = None,
) -> dict | JSONResponse:
    """Estimate a frame if a model exists (the camera's applied gains and exposure divided out first), store it
    durably with them, and build the 201 answer.

    The estimate comes first (it needs no frame id); the rows are then written through the app's
    :class:`~illumon_service.storage.GroupCommit`, which returns once they are committed (concurrent ingests share
    one commit), so the answer never precedes durability. With an ``Idempotency-Key`` (``claim``) the key is written
    first (a key another process stored meanwhile fails there, before any file is written) and keeps the answer; a
    retry then gets that answer (:mod:`~illumon_service.idempotency`).
    """
    settings = request.app.state.settings
    metrics = request.app.state.metrics
    usable = sum(v is not None for v in patches.values())
    region_ids = [r["id"] for r in cam.regions] if region_ids is None else region_ids
    warnings = []
    if registration is not None and registration.state == "view_change":
        warnings.append(f"view change: the frame does not register to its view's reference frame (shift "
                        f"{registration.shift[0]:+.0f}, {registration.shift[1]:+.0f} px, peak {registration.response:.2f}): "
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
    if registration is not None and registration.state == "uncertain":
        warnings.append(f"registration uncertain: weak correlation peak ({registration.response:.2f}), but the frame "
                        f"still matches its reference (score {registration.match:.2f}): measured with the regions at "
                        f"shift {registration.shift[0]:+.0f}, {registration.shift[1]:+.0f} px")
    warnings += extra_warnings or []
    t0 = time.perf_counter()
    matrix = (cam.response or {}).get("matrix")
    undone = undo_camera_gains(patches, applied_gains, exposure, matrix)
    undone_sd = undo_camera_gains_sd(patch_sd, applied_gains, exposure, matrix)

    def estimate_with(model: tuple[Path, str] | None) -> dict | None:
        if model is None or usable < 2:
            return None
        return estimate_frame(settings.data_dir, cam.id, "new", taken_at.isoformat(), undone, region_ids, view,
                              undone_sd, model_file=model[0])

    model = current_model(settings.data_dir, cam.models, cam.id, view)
    est = estimate_with(model)
    t1 = time.perf_counter()
    metrics.observe("illumon_estimate_seconds", t1 - t0)
    metrics.observe("illumon_ingest_stage_seconds", t1 - t0, labels='stage="estimate"')
    # The request's session has done its reading: give its connection back to the pool (``cam`` keeps its loaded
    # columns) so that requests waiting for a group commit never hold every pooled connection.
    session.close()

    def write(session: Session) -> dict:
        frame = Frame(camera_id=cam.id, taken_at=taken_at, patches=patches,
                      width=size[0] if size else None, height=size[1] if size else None,
                      applied_gains=applied_gains, exposure=exposure, view=view, patch_sd=patch_sd,
                      registration=None if registration is None else registration.as_dict())
        session.add(frame)
        session.flush()
        if thumb is not None and thumbnail_due(session, cam.id, view, taken_at, registration):
            path = thumbs_dir(settings.data_dir, cam.id) / f"{frame.id}.png"
            save_thumbnail(path, thumb)
            frame.thumb_path = stored_path(settings.data_dir, path)
            prune_thumbnails(session, cam.id, view, settings.data_dir)
        if image is not None and settings.keep_images:
            folder = Path(settings.data_dir) / "images" / f"camera-{cam.id}"
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{frame.id}.{fmt}"
            path.write_bytes(image)
            frame.image_path = stored_path(settings.data_dir, path)
        # The model in use now (the frame's insert holds SQLite's write lock; the row lock orders this with a
        # refit's commit on PostgreSQL): a refit that committed since the estimate above makes it again with the new
        # model, so no estimate of an old model lands after a refit.
        models_now = session.execute(select(Camera.models).where(Camera.id == cam.id).with_for_update()).scalar()
        now = current_model(settings.data_dir, models_now, cam.id, view)
        use = est if (now and now[1]) == (model and model[1]) else estimate_with(now)
        row = None
        if use is not None:
            row = Estimate(frame_id=frame.id, camera_id=cam.id, taken_at=taken_at, model=now[1] if now else None, **use)
            session.add(row)
        else:
            frame.not_estimated = ("view_change" if registration is not None and registration.state == "view_change"
                                   else "no_regions" if not region_ids else "too_few_regions" if usable < 2
                                   else "no_model" if now is None else "estimate_failed")
        session.flush()
        return {
            "frame_id": frame.id,
            "taken_at": as_utc(frame.taken_at).isoformat(),
            "regions": patches,
            "applied_gains": applied_gains,
            "exposure": exposure,
            "usable_regions": usable,
            "view": view,
            "registration": None if registration is None else registration.as_dict(),
            "estimate": estimate_out(row) if row is not None else None,
            "warnings": warnings,
        }

    try:
        out = request.app.state.commits.submit(write if claim is None else keyed(write, claim, _answer_json))
    except Exception as exc:
        if claim is not None and is_conflict(exc):  # a concurrent retry in another process stored the frame first
            first = stored(request.app.state.sessions, claim)
            if first is not None:
                return replay(first, claim)
        raise
    if image is not None and not region_ids and fmt:  # measured once the view's regions are confirmed
        with request.app.state.sessions() as s:
            keep_original(s, settings.data_dir, cam.id, view, out["frame_id"], image, fmt, settings.pending_max_frames,
                          settings.pending_max_bytes)
    metrics.observe("illumon_ingest_stage_seconds", time.perf_counter() - t1, labels='stage="commit"')
    metrics.inc("illumon_frames_ingested_total")
    return out


def _answer_json(answer: dict) -> dict:
    """A frame's 201 answer as JSON values (kept with its idempotency key)."""
    return FrameIngestOut.model_validate(answer).model_dump(mode="json")


@router.post("/{camera_id}/frames", status_code=status.HTTP_201_CREATED, openapi_extra=FRAME_UPLOAD,
             response_model=FrameIngestOut)
async def post_frame(camera_id: int, request: Request, session: SessionDep, principal: PrincipalDep,
                     idempotency_key: str | None = Header(None, max_length=255, description=IDEMPOTENCY_DOC),
                     ) -> dict | JSONResponse:
    """Ingest one image (multipart ``image``; optional ``taken_at``, ``applied_gains`` "r,g,b" and ``exposure``, which
    the camera applied and the service divides out): robust region means, then an estimate."""
    t_start = time.perf_counter()
    settings = request.app.state.settings
    cam = await run_in_threadpool(camera_for, session, principal, camera_id)
    ctype = request.headers.get("content-type", "")
    if not ctype.lower().startswith("multipart/form-data"):
        raise HTTPException(415, f"content type {ctype or 'none'!r}: send multipart/form-data with an 'image' part")
    limit = settings.max_upload_bytes
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit + 65536:
        raise HTTPException(413, f"upload of {declared} bytes exceeds the limit of {limit} bytes")
    fields, files = await read_multipart(request, limit)
    if "image" not in files:
        raise HTTPException(422, "missing file part 'image'")
    part_type, data = files["image"]
    if part_type not in IMAGE_TYPES:
        raise HTTPException(415, f"image part has content type {part_type!r}; send PNG, JPEG or TIFF")
    if len(data) > limit:
        raise HTTPException(413, f"image exceeds the upload limit of {limit} bytes")
    key = parse_key(request)
    claim = None if key is None else Claim(cam.id, key, form_fingerprint(data, fields))
    taken_at = parse_time(fields.get("taken_at"))
    applied_gains = parse_gains(fields.get("applied_gains"))
    exposure = parse_positive(fields.get("exposure"))
    try:
        view = parse_view(fields.get("view"))
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    configured = await run_in_threadpool(view_regions, session, cam, view)
    metrics = request.app.state.metrics
    metrics.observe("illumon_ingest_stage_seconds", time.perf_counter() - t_start, labels='stage="receive"')

    def work() -> dict | JSONResponse:
        try:
            t0 = time.perf_counter()
            regions = [Region(**r) for r in configured]
            frame = decode_frame(data, regions, max_pixels=settings.max_image_pixels,
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
            response = response_for(cam.response, frame.full_scale)
            thumb: Thumbnail | None = None
            reg = Registration("ok", (0.0, 0.0), None)
            if min(w, h) >= MIN_REGISTER_SIDE:  # a tiny image has nothing to register or propose from
                thumb = make_thumbnail(frame.image, response, settings.clip_fraction, frame.size)
                reg = register_frame(settings.data_dir, cam.id, view, thumb, configured, frame.size)
            t2 = time.perf_counter()
            metrics.observe("illumon_ingest_stage_seconds", t2 - t1, labels='stage="register"')
            patch_sd: dict | None = None
            if reg.state == "view_change":  # stored, not measured: the regions are not where they were drawn
                patches: dict = {}
            else:
                moved, outside = shift_regions(configured, reg, frame.size)
                stats = region_stats(
                    frame.image, moved, response, scale=frame.scale,
                    size=frame.size, clip_fraction=settings.clip_fraction, min_fraction=settings.min_region_fraction,
                )
                stats.update({rid: None for rid in outside})
                patches = {r["id"]: None if stats[r["id"]] is None else stats[r["id"]][0] for r in configured}
                patch_sd = {r["id"]: None if stats[r["id"]] is None else stats[r["id"]][1] for r in configured}
            t1 = t2
            metrics.observe("illumon_ingest_stage_seconds", time.perf_counter() - t1, labels='stage="regions"')
        except ImageError as exc:
            raise HTTPException(exc.status, str(exc)) from None
        except RegionError as exc:
            raise HTTPException(422, str(exc)) from None
        return _store(request, session, cam, taken_at, patches, frame.size, data, sniff_format(data), applied_gains,
                      exposure, [r["id"] for r in configured], view, reg, thumb, patch_sd, extra, claim)

    def work_once() -> dict | JSONResponse:
        with key_lock(claim):  # retries with the same key wait for the first, then get its answer
            if claim is not None and (first := stored(request.app.state.sessions, claim)) is not None:
                return replay(first, claim)
            return work()

    out = await run_in_threadpool(work_once)
    request.app.state.metrics.observe("illumon_ingest_seconds", time.perf_counter() - t_start)
    return out


@router.post("/{camera_id}/observations", status_code=status.HTTP_201_CREATED, response_model=FrameIngestOut)
def post_observations(camera_id: int, body: ObservationIn, request: Request, session: SessionDep,
                      principal: PrincipalDep,
                      idempotency_key: str | None = Header(None, max_length=255, description=IDEMPOTENCY_DOC),
                      ) -> dict | JSONResponse:
    """Ingest region means measured by the client (linear values; ``null`` for a missing region; 422 when every
    region is ``null``)."""
    cam = camera_for(session, principal, camera_id)
    key = parse_key(request)
    claim = None if key is None else Claim(cam.id, key, fingerprint(body.model_dump_json()))
    with key_lock(claim):
        if claim is not None and (first := stored(request.app.state.sessions, claim)) is not None:
            return replay(first, claim)
        return _observations(cam, body, request, session, claim)


def _observations(cam: Camera, body: ObservationIn, request: Request, session: Session, claim: Claim | None
                  ) -> dict | JSONResponse:
    """Check and store client-measured region means (:func:`post_observations`)."""
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
    taken_at = parse_time(body.taken_at.isoformat() if body.taken_at else None)
    return _store(request, session, cam, taken_at, patches, None, applied_gains=body.applied_gains,
                  exposure=body.exposure, patch_sd=patch_sd, claim=claim)


@router.get("/{camera_id}/frames", response_model=list[FrameOut])
def list_frames(camera_id: int, session: SessionDep, principal: PrincipalDep, since: IsoDateTime | None = None,
                until: IsoDateTime | None = None,
                limit: int = Query(1000, ge=1, le=MAX_LIST, description=f"1…{MAX_LIST} frames")) -> list[dict]:
    """Stored frames (region means, linear 0…1) in ``since`` ≤ taken_at ≤ ``until``, oldest first."""
    camera_for(session, principal, camera_id)
    q = select(Frame).where(Frame.camera_id == camera_id)
    if since is not None:
        q = q.where(Frame.taken_at >= parse_time(since.isoformat()))
    if until is not None:
        q = q.where(Frame.taken_at <= parse_time(until.isoformat()))
    rows = session.scalars(q.order_by(Frame.taken_at, Frame.id).limit(limit)).all()
    estimated = set(session.scalars(select(Estimate.frame_id).where(
        Estimate.frame_id.in_([f.id for f in rows]))).all()) if rows else set()
    return [{"frame_id": f.id, "taken_at": as_utc(f.taken_at).isoformat(), "regions": f.patches,
             "width": f.width, "height": f.height, "applied_gains": f.applied_gains, "exposure": f.exposure,
             "view": f.view, "registration": f.registration,
             "not_estimated": None if f.id in estimated else (f.not_estimated or "pending")}
            for f in rows]


@router.delete("/{camera_id}/frames/{frame_id}", response_model=DeletedOut)
def remove_frame(camera_id: int, frame_id: int, request: Request, session: SessionDep, principal: AdminDep) -> dict:
    """Delete one stored frame with its estimate and files (admin): e.g. a frame whose values are wrong."""
    cam = camera_for(session, principal, camera_id)
    deleted = delete_frame(session, request.app.state.settings.data_dir, cam, frame_id)
    return {"camera_id": camera_id, "frame_id": frame_id, "deleted": deleted}
