"""Calibration images of a camera (``POST /v1/cameras/{id}/calibration``): a ColorChecker or a grey card, measured
and stored; the next refit uses them (see :mod:`illumon_service.calibration`)."""

from __future__ import annotations

import json

from fastapi import APIRouter, HTTPException, Request, status
from starlette.concurrency import run_in_threadpool

from ...calibration import (
    CalibrationError,
    chart_patch_ids,
    covered_regions,
    detect_colorchecker,
    grid_from_corners,
    measure_patches,
    patch_regions,
    reference_box,
)
from ...decode import ImageError, decode_frame
from ...deps import PrincipalDep, SessionDep, camera_for
from ...regions import Region, RegionError, region_means, response_for
from ...storage import Calibration
from ...uploads import IMAGE_TYPES, parse_gains, parse_positive, read_multipart
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


def _json_field(fields: dict[str, str], name: str) -> object:
    try:
        return json.loads(fields[name])
    except (KeyError, ValueError):
        raise HTTPException(422, f"{name}: expected JSON") from None


def _grey_region(value: object) -> Region:
    if not isinstance(value, dict) or set(value) != {"x", "y", "width", "height"} or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in value.values()):
        raise HTTPException(422, "region: expected JSON {\"x\", \"y\", \"width\", \"height\"} in whole pixels")
    if value["x"] < 0 or value["y"] < 0 or value["width"] <= 0 or value["height"] <= 0:
        raise HTTPException(422, "region: x, y ≥ 0 and width, height > 0")
    return Region("grey", **value)


@router.post("/{camera_id}/calibration", status_code=status.HTTP_201_CREATED, openapi_extra=CALIBRATION_UPLOAD,
             response_model=CalibrationOut)
async def post_calibration(camera_id: int, request: Request, session: SessionDep, principal: PrincipalDep) -> dict:
    """Measure a calibration image (a ColorChecker, found automatically or from its ``corners``, or a grey card's
    ``region``) taken by the camera itself, store it, and answer the patches found: linear means (the camera's
    pipeline undone), clipping, and how many of the camera's regions the same image shows (``scene_regions``: at
    least two tie the reference to the scene's daylight; fewer, and a refit leaves the calibration out)."""
    settings = request.app.state.settings
    cam = await run_in_threadpool(camera_for, session, principal, camera_id)
    if not request.headers.get("content-type", "").lower().startswith("multipart/form-data"):
        raise HTTPException(415, "send multipart/form-data with an 'image' part and a 'kind' field")
    fields, files = await read_multipart(request, settings.max_upload_bytes)
    if "image" not in files:
        raise HTTPException(422, "missing file part 'image'")
    part_type, data = files["image"]
    if part_type not in IMAGE_TYPES:
        raise HTTPException(415, f"image part has content type {part_type!r}; send PNG, JPEG or TIFF")
    kind = fields.get("kind", "")
    if kind not in ("colorchecker", "grey"):
        raise HTTPException(422, f"kind {kind!r}: expected 'colorchecker' or 'grey'")
    corners = _json_field(fields, "corners") if kind == "colorchecker" and "corners" in fields else None
    region = _grey_region(_json_field(fields, "region")) if kind == "grey" else None
    reflectance = None
    if kind == "grey":
        reflectance = parse_positive(fields.get("reflectance"), "reflectance", 0.01, 1.0) or 0.18
        if reflectance > 1:
            raise HTTPException(422, "reflectance: a grey card's reflectance lies in (0, 1]")
    applied_gains = parse_gains(fields.get("applied_gains"))
    exposure = parse_positive(fields.get("exposure"))

    def work() -> dict:
        try:
            frame = decode_frame(data, [], max_pixels=settings.max_image_pixels,
                                 max_bytes=settings.max_decoded_bytes)
            response = response_for(cam.response, frame.full_scale)
            if kind == "grey":
                w, h = frame.size
                if region.x + region.width > w or region.y + region.height > h:
                    raise CalibrationError(f"region ({region.x},{region.y} {region.width}×{region.height}) lies "
                                           f"outside the {w}×{h} image")
                regions, box = [region], reference_box([region])
            else:
                centres, pitch = (grid_from_corners(corners) if corners is not None
                                  else detect_colorchecker(frame.image, frame.full_scale))
                regions = patch_regions(chart_patch_ids(), centres, pitch, frame.size)
                box = reference_box(regions, margin=pitch)
            patches, warnings = measure_patches(frame.image, regions, response, clip_fraction=settings.clip_fraction,
                                                min_fraction=settings.min_region_fraction)
            try:  # the camera's own regions in the same image: the reference's daylight comes from them
                scene = region_means(frame.image, [Region(**r) for r in cam.regions], response,
                                     clip_fraction=settings.clip_fraction, min_fraction=settings.min_region_fraction)
            except RegionError:
                scene = {}
            hidden = covered_regions([Region(**r) for r in cam.regions], box) & set(scene)
            if hidden:  # behind the reference: their values here are the reference's
                scene.update(dict.fromkeys(hidden, None))
                warnings.append(f"{len(hidden)} of the camera's regions overlap the reference and are not used from "
                                f"this image ({', '.join(sorted(hidden)[:4])}{' …' if len(hidden) > 4 else ''})")
            if sum(v is not None for v in scene.values()) < 2:
                warnings.append("fewer than two of the camera's regions are usable in this image: a calibration "
                                "counts only in an image from the camera itself, showing its scene around the "
                                "reference; a refit leaves this one out")
        except ImageError as exc:
            raise HTTPException(exc.status, str(exc)) from None
        except CalibrationError as exc:
            raise HTTPException(422, str(exc)) from None
        row = Calibration(camera_id=cam.id, kind=kind, reflectance=reflectance, applied_gains=applied_gains,
                          exposure=exposure, warnings=warnings,
                          patches={p["id"]: None if p["r"] is None else [p["r"], p["g"], p["b"]] for p in patches},
                          clipped=[p["id"] for p in patches if p["clipped"]], scene=scene)
        session.add(row)
        session.commit()
        return {"calibration_id": row.id, "kind": kind, "patches": patches, "clipped": len(row.clipped),
                "scene_regions": sum(v is not None for v in scene.values()), "warnings": warnings}

    return await run_in_threadpool(work)
