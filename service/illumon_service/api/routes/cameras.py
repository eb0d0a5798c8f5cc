"""Camera registration and configuration (``/v1/cameras``)."""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, HTTPException, status
from illumon.spectra import SpectralInputError, sensitivities_from_arrays
from sqlalchemy.orm import Session

from ...deps import AdminDep, PrincipalDep, SessionDep, camera_for
from ...status import visible_cameras
from ...storage import Camera, as_utc, hash_token, new_token, refit_warnings
from ..schemas import ERROR_RESPONSES, CameraIn, RegionsIn

router = APIRouter(prefix="/v1/cameras", tags=["cameras"], responses=ERROR_RESPONSES)


def camera_out(cam: Camera, session: Session) -> dict:
    """Public view of a camera (never its token), with the warnings of its latest refit."""
    return {
        "id": cam.id,
        "name": cam.name,
        "regions": cam.regions,
        "response": cam.response,
        "created_at": as_utc(cam.created_at).isoformat(),
        "warnings": refit_warnings(session, cam.id),
    }


@router.get("")
def list_cameras(session: SessionDep, principal: PrincipalDep) -> list[dict]:
    """The cameras the caller may see (every camera for the admin, its own for a camera token), by id."""
    return [camera_out(cam, session) for cam in visible_cameras(session, principal)]


@router.post("", status_code=status.HTTP_201_CREATED)
def register_camera(body: CameraIn, session: SessionDep, _admin: AdminDep) -> dict:
    """Register a camera (admin); the answer carries the camera token, shown only once."""
    s = body.sensitivities
    try:
        css = sensitivities_from_arrays(s.wavelength_nm, np.column_stack([s.r, s.g, s.b]), source="sensitivities")
    except SpectralInputError as exc:
        raise HTTPException(422, str(exc)) from None
    except (ValueError, AssertionError) as exc:  # colour-science's interpolators reject some samplings this way
        raise HTTPException(422, f"sensitivities: cannot be resampled onto 400–700 nm at 5 nm ({exc})") from None
    token = new_token()
    cam = Camera(
        name=body.name,
        token_hash=hash_token(token),
        sensitivities=css.tolist(),
        regions=[r.model_dump() for r in body.regions],
        response=body.response.model_dump(),
    )
    session.add(cam)
    session.commit()
    return {"id": cam.id, "token": token}


@router.get("/{camera_id}")
def get_camera(camera_id: int, session: SessionDep, principal: PrincipalDep) -> dict:
    """A camera's configuration."""
    return camera_out(camera_for(session, principal, camera_id), session)


@router.put("/{camera_id}/regions")
def put_regions(camera_id: int, body: RegionsIn, session: SessionDep, principal: PrincipalDep) -> dict:
    """Replace a camera's regions (stored frames keep their old region values)."""
    cam = camera_for(session, principal, camera_id)
    cam.regions = [r.model_dump() for r in body.regions]
    session.commit()
    return camera_out(cam, session)
