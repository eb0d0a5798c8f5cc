"""Camera registration and configuration (``/v1/cameras``)."""

from __future__ import annotations

from typing import Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request, status
from illumon.spectra import SpectralInputError, sensitivities_from_arrays
from sqlalchemy.orm import Session

from ... import crud
from ...deps import AdminDep, PrincipalDep, SessionDep, camera_for, visible_cameras
from ...manage import delete_camera, save_regions_and_measure
from ...settings import Settings
from ...status import camera_status
from ...storage import Camera, as_utc, hash_token, new_token
from ..forms import parse_view_field
from ..schemas import ERROR_RESPONSES, CameraCreated, CameraIn, CameraOut, DeletedOut, ErrorOut, RegionsIn

router = APIRouter(prefix="/v1/cameras", tags=["cameras"], responses=ERROR_RESPONSES)


def camera_out(cam: Camera, session: Session, settings: Settings | None = None) -> dict:
    """Public view of a camera (never its token): its pipeline, whether its sensitivities were measured, its stored
    calibrations, what calibrates it (``calibration``: ``chart`` | ``grey`` | ``measured`` | ``none``), the
    warnings of its latest refit, the regions of its other views (PTZ presets) and, with ``settings``, its alerts (those
    of the status page)."""
    cals = crud.calibrations(session, cam.id)
    kinds = {c.kind for c in cals}
    measured = bool(cam.sensitivities)
    return {
        "id": cam.id,
        "name": cam.name,
        "regions": cam.regions,
        "response": cam.response,
        "sensitivities": "measured" if measured else "unmeasured",
        "calibration": ("chart" if "colorchecker" in kinds else "grey" if "grey" in kinds
                        else "measured" if measured else "none"),
        "calibrations": [{"calibration_id": c.id, "kind": c.kind, "created_at": as_utc(c.created_at).isoformat()}
                         for c in cals],
        "created_at": as_utc(cam.created_at).isoformat(),
        "warnings": crud.refit_warnings(session, cam.id),
        "not_estimated": crud.not_estimated_counts(session, cam.id),
        "views": crud.camera_views(session, cam.id),
        **({} if settings is None else {"alerts": [
            {"kind": a.kind, "label": a.label, "message": a.message, "severity": a.severity}
            for a in camera_status(session, cam, settings).alerts]}),
    }


# exclude_unset: a camera registered by an older version keeps its pipeline's missing keys missing
@router.get("", response_model=list[CameraOut], response_model_exclude_unset=True)
def list_cameras(request: Request, session: SessionDep, principal: PrincipalDep) -> list[dict]:
    """The cameras the caller may see (every camera for the admin, its own for a camera token), by id."""
    return [camera_out(cam, session, request.app.state.settings) for cam in visible_cameras(session, principal)]


@router.post("", status_code=status.HTTP_201_CREATED, response_model=CameraCreated)
def register_camera(body: CameraIn, session: SessionDep, _admin: AdminDep) -> dict:
    """Register a camera (admin); the answer carries the camera token, shown only once."""
    s = body.sensitivities
    css: list = []  # unmeasured: a prior from the measured cameras, pinned by calibration images
    if s is not None:
        try:
            css = sensitivities_from_arrays(s.wavelength_nm, np.column_stack([s.r, s.g, s.b]),
                                            source="sensitivities").tolist()
        except SpectralInputError as exc:
            raise HTTPException(422, str(exc)) from None
        except (ValueError, AssertionError) as exc:  # colour-science's interpolators reject some samplings this way
            raise HTTPException(422, f"sensitivities: cannot be resampled onto 400–700 nm at 5 nm ({exc})") from None
    token = new_token()
    cam = crud.create_camera(
        session,
        name=body.name,
        token_hash=hash_token(token),
        sensitivities=css,
        regions=[r.model_dump() for r in body.regions],
        response=body.response.resolved(measured=body.sensitivities is not None),
        image_size=None if body.image_size is None else [body.image_size.width, body.image_size.height],
    )
    return {"id": cam.id, "token": token}


@router.get("/{camera_id}", response_model=CameraOut, response_model_exclude_unset=True)
def get_camera(camera_id: int, request: Request, session: SessionDep, principal: PrincipalDep) -> dict:
    """A camera's configuration and alerts."""
    return camera_out(camera_for(session, principal, camera_id), session, request.app.state.settings)


@router.put("/{camera_id}/regions", response_model=CameraOut, response_model_exclude_unset=True,
            responses={409: {"model": ErrorOut, "description": "reference=latest without a "
                                                                                     "stored frame of the view"}})
def put_regions(camera_id: int, body: RegionsIn, request: Request, session: SessionDep, principal: PrincipalDep,
                view: str | None = Query(None, description="view (PTZ preset id); the default view if absent"),
                reference: Literal["keep", "latest"] = Query(
                    "keep", description="'latest': the view's latest frame becomes its reference frame (after the "
                                        "camera moved for good)")) -> dict:
    """Replace the regions of a camera's view, in its reference frame's pixels (stored frames keep their old region
    values)."""
    cam = camera_for(session, principal, camera_id)
    v = parse_view_field(view)
    save_regions_and_measure(session, cam, [r.model_dump() for r in body.regions], v, request.app.state.settings,
                             reference == "latest")
    return camera_out(cam, session, request.app.state.settings)


@router.delete("/{camera_id}", response_model=DeletedOut)
def remove_camera(camera_id: int, request: Request, session: SessionDep, principal: AdminDep) -> dict:
    """Delete a camera and everything stored for it (admin): frames, estimates, jobs, calibrations, views, models,
    thumbnails and kept images. Its token stops working at once."""
    cam = camera_for(session, principal, camera_id)
    deleted = delete_camera(session, request.app.state.settings.data_dir, cam)
    return {"camera_id": camera_id, "frame_id": None, "deleted": deleted}
