"""Calibration images of a camera (``POST /v1/cameras/{id}/calibration``): a ColorChecker or a grey card, measured
and stored; the next refit uses them (see :mod:`illumon_service.calibration`)."""

from __future__ import annotations

from fastapi import APIRouter, Request, status
from starlette.concurrency import run_in_threadpool

from ...calibration import store_calibration
from ...deps import PrincipalDep, SessionDep, camera_for
from ..forms import read_calibration_form
from ..schemas import CAMERA_APPLIED, ERROR_RESPONSES, CalibrationOut, multipart_body

router = APIRouter(prefix="/v1/cameras", tags=["calibration"], responses=ERROR_RESPONSES)

CALIBRATION_UPLOAD = multipart_body(["image", "kind"], {
    "image": {"type": "string", "format": "binary", "description": "PNG, JPEG or TIFF, RGB, from the camera itself"},
    "kind": {"type": "string", "enum": ["colorchecker", "grey"]},
    "corners": {"type": "string", "description": "colorchecker: JSON [[x, y] × 4], the patch area's corners next to "
                                                 "patches 1, 6, 24 and 19; found automatically when absent"},
    "region": {"type": "string", "description": "grey: JSON {x, y, width, height} of the card"},
    "reflectance": {"type": "string", "description": "grey: the card's reflectance (default 0.18)"},
    **CAMERA_APPLIED,
})
"""OpenAPI request body of the calibration route (parsed by hand, like frames)."""


@router.post("/{camera_id}/calibration", status_code=status.HTTP_201_CREATED, openapi_extra=CALIBRATION_UPLOAD,
             response_model=CalibrationOut)
async def post_calibration(camera_id: int, request: Request, session: SessionDep, principal: PrincipalDep) -> dict:
    """Measure a calibration image (a ColorChecker, found automatically or from its ``corners``, or a grey card's
    ``region``) taken by the camera itself, store it, and answer the patches found: linear means (the camera's
    pipeline undone), clipping, and how many of the camera's regions the same image shows (``scene_regions``: at
    least two tie the reference to the scene's daylight; fewer, and a refit leaves the calibration out)."""
    settings = request.app.state.settings
    cam = await run_in_threadpool(camera_for, session, principal, camera_id)
    upload = await read_calibration_form(request, settings.max_upload_bytes)
    return await run_in_threadpool(store_calibration, settings, session, cam, upload)
