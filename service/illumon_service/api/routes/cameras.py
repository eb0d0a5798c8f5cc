"""Camera registration and configuration (``/v1/cameras``)."""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, HTTPException, status
from illumon.spectra import SpectralInputError, sensitivities_from_arrays
from sqlalchemy import select
from sqlalchemy.orm import Session

from ...deps import AdminDep, PrincipalDep, SessionDep, camera_for
from ...status import visible_cameras
from ...storage import Calibration, Camera, as_utc, hash_token, new_token, refit_warnings
from ..schemas import ERROR_RESPONSES, CameraIn, RegionsIn

router = APIRouter(prefix="/v1/cameras", tags=["cameras"], responses=ERROR_RESPONSES)


def camera_out(cam: Camera, session: Session) -> dict:
    """Public view of a camera (never its token): its pipeline, whether its sensitivities were measured, its stored
    calibrations, what calibrates it (``calibration``: ``chart`` | ``grey`` | ``measured`` | ``none``) and the
    warnings of its latest refit."""
    cals = session.scalars(select(Calibration).where(Calibration.camera_id == cam.id).order_by(Calibration.id)).all()
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
    cam = Camera(
        name=body.name,
        token_hash=hash_token(token),
        sensitivities=css,
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
