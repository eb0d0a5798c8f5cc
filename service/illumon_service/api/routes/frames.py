"""Frame ingest: images (``/frames``) and client-side region means (``/observations``)."""

from __future__ import annotations

import math
import time
from datetime import datetime, timezone
from pathlib import Path

from fastapi import APIRouter, Header, HTTPException, Query, Request, status
from fastapi.responses import JSONResponse
from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from ...crud import estimate_out
from ...datafiles import stored_path
from ...decode import ImageError, decode_frame, sniff_format
from ...deps import PrincipalDep, SessionDep, camera_for
from ...estimation import estimate_frame, undo_camera_gains, undo_camera_gains_sd
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
from ..schemas import ERROR_RESPONSES, FRAME_UPLOAD, MAX_LIST, FrameIngestOut, FrameOut, IsoDateTime, ObservationIn

router = APIRouter(prefix="/v1/cameras", tags=["frames"], responses=ERROR_RESPONSES)

MIN_REGISTER_SIDE = 32
"""Frames smaller than this (pixels, either side) keep no thumbnail and are not registered."""

IMAGE_TYPES = {"image/png", "image/jpeg", "image/jpg", "image/tiff", "application/octet-stream", ""}


def parse_time(text: str | None) -> datetime:
    """ISO 8601 → aware UTC datetime (naive means UTC); now when empty. 422 when malformed."""
    if not text:
        return datetime.now(timezone.utc)
    try:
        t = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise HTTPException(422, f"taken_at {text!r} is not ISO 8601") from None
    return as_utc(t)


MAX_PARTS = 10


async def read_multipart(request: Request, limit: int) -> tuple[dict[str, str], dict[str, tuple[str, bytearray]]]:
    """Parse a ``multipart/form-data`` body in memory: ``(text fields, {name: (content type, contents)})``.

    Streams the body through ``python_multipart`` into memory (Starlette's form parser spools files over 1 MB to
    disk, one thread-pool hop per chunk: ~50 ms for a 9 MB frame); 413 past ``limit`` (+64 KiB for the other parts),
    400 for a body that is not valid multipart or has more than :data:`MAX_PARTS` parts.
    """
    from python_multipart.multipart import MultipartParser, parse_options_header

    _, params = parse_options_header(request.headers.get("content-type", ""))
    boundary = params.get(b"boundary")
    if not boundary:
        raise HTTPException(400, "multipart body without a boundary parameter")
    parts: list[dict] = []
    hdr: dict[str, bytearray] = {"field": bytearray(), "value": bytearray()}

    def on_part_begin() -> None:
        if len(parts) >= MAX_PARTS:
            raise HTTPException(400, f"multipart body has more than {MAX_PARTS} parts")
        parts.append({"headers": {}, "data": bytearray()})

    def on_part_data(data: bytes, start: int, end: int) -> None:
        parts[-1]["data"] += memoryview(data)[start:end]  # appended without an intermediate copy

    def on_header_field(data: bytes, start: int, end: int) -> None:
        hdr["field"] += data[start:end]

    def on_header_value(data: bytes, start: int, end: int) -> None:
        hdr["value"] += data[start:end]

    def on_header_end() -> None:
        parts[-1]["headers"][bytes(hdr["field"]).decode("latin-1").lower()] = bytes(hdr["value"])
        hdr["field"].clear()
        hdr["value"].clear()

    parser = MultipartParser(boundary, {"on_part_begin": on_part_begin, "on_part_data": on_part_data,
                                        "on_header_field": on_header_field, "on_header_value": on_header_value,
                                        "on_header_end": on_header_end})
    total = 0
    try:
        async for chunk in request.stream():
            total += len(chunk)
            if total > limit + 65536:
                raise HTTPException(413, f"upload exceeds the limit of {limit} bytes")
            parser.write(chunk)
        parser.finalize()
    except HTTPException:
        raise
    except Exception as exc:  # noqa: BLE001 - python_multipart raises several types for malformed bodies
        raise HTTPException(400, f"malformed multipart body ({type(exc).__name__})") from None
    fields: dict[str, str] = {}
    files: dict[str, tuple[str, bytearray]] = {}
    for part in parts:
        _, disp = parse_options_header(part["headers"].get("content-disposition", b""))
        name = disp.get(b"name", b"").decode("utf-8", "replace")
        if b"filename" in disp:
            ctype = part["headers"].get("content-type", b"").decode("latin-1").split(";")[0].strip().lower()
            files[name] = (ctype, part["data"])  # the bytearray itself: a 10 MB frame is not copied again
        else:
            try:
                fields[name] = bytes(part["data"]).decode("utf-8")
            except UnicodeDecodeError:
                raise HTTPException(422, f"form field {name!r} is not UTF-8 text") from None
    return fields, files


def parse_gains(text: str | None, field: str = "applied_gains") -> list[float] | None:
    """``"r,g,b"`` → three positive finite multipliers (``None`` when absent); 422 otherwise."""
    if text is None or not text.strip():
        return None
    try:
        gains = [float(v) for v in text.split(",")]
    except ValueError:
        raise HTTPException(422, f"{field} {text!r}: expected three numbers 'r,g,b'") from None
    if len(gains) != 3 or not all(math.isfinite(g) and g > 0 for g in gains):
        raise HTTPException(422, f"{field} {text!r}: expected three positive finite numbers 'r,g,b'")
    return gains


def parse_positive(text: str | None, field: str = "exposure") -> float | None:
    """A form field holding a positive finite number (``None`` when absent), e.g. the relative exposure; 422
    otherwise."""
    if text is None or not text.strip():
        return None
    try:
        value = float(text)
    except ValueError:
        raise HTTPException(422, f"{field} {text!r}: expected a positive number") from None
    if not (math.isfinite(value) and value > 0):
        raise HTTPException(422, f"{field} {text!r}: expected a positive finite number")
    return value


def _store(
    request: Request, session: Session, cam: Camera, taken_at: datetime, patches: dict, size: tuple[int, int] | None,
    image: bytes | bytearray | None = None, fmt: str | None = None, applied_gains: list[float] | None = None,
    exposure: float | None = None, region_ids: list[str] | None = None, view: str | None = None,
    registration: Registration | None = None, thumb: Thumbnail | None = None, patch_sd: dict | None = None,
    claim: Claim | None = None,
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
    t0 = time.perf_counter()
    matrix = (cam.response or {}).get("matrix")
    est = None if usable < 2 else estimate_frame(
        settings.data_dir, cam.id, "new", taken_at.isoformat(),
        undo_camera_gains(patches, applied_gains, exposure, matrix), region_ids, view,
        undo_camera_gains_sd(patch_sd, applied_gains, exposure, matrix))
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
        row = None
        if est is not None:
            row = Estimate(frame_id=frame.id, camera_id=cam.id, taken_at=taken_at, **est)
            session.add(row)
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
                                 max_reduction=settings.jpeg_max_reduction)
            t1 = time.perf_counter()
            metrics.observe("illumon_ingest_stage_seconds", t1 - t0, labels='stage="decode"')
            metrics.inc("illumon_ingest_decodes_total", labels=f'scale="1/{frame.scale}"')
            w, h = frame.size
            for r in configured:  # in the reference frame's pixels, every region lies inside the image
                if r["x"] + r["width"] > w or r["y"] + r["height"] > h:
                    raise RegionError(f"region {r['id']!r} ({r['x']},{r['y']} {r['width']}×{r['height']}) lies "
                                      f"outside the {w}×{h} image")
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
                      exposure, [r["id"] for r in configured], view, reg, thumb, patch_sd, claim)

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
    return [{"frame_id": f.id, "taken_at": as_utc(f.taken_at).isoformat(), "regions": f.patches,
             "width": f.width, "height": f.height, "applied_gains": f.applied_gains, "exposure": f.exposure,
             "view": f.view, "registration": f.registration}
            for f in rows]
