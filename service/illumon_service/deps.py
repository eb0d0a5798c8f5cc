"""FastAPI dependencies: database session, bearer-token authentication and what a caller may see."""

from __future__ import annotations

import hmac
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from sqlalchemy.orm import Session

from . import crud
from .storage import Camera, Estimate, hash_token

__all__ = ["nearest_estimate", "SessionDep", "Principal", "PrincipalDep", "AdminDep", "camera_for", "not_found",
           "visible_cameras", "visible_camera"]


def get_session(request: Request) -> Iterator[Session]:
    """A database session for the request (routes commit explicitly before answering)."""
    with request.app.state.sessions() as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session)]


@dataclass(frozen=True)
class Principal:
    """Who is calling: the admin, or one camera."""

    admin: bool
    camera_id: int | None = None


def principal_from_token(request: Request, session: Session, token: str) -> Principal | None:
    """The admin or the camera whose token is ``token`` (compared by its SHA-256 with the stored hashes), else
    ``None``: the one token-to-caller lookup of the JSON API and the pages."""
    token = token.strip()
    if not token:
        return None
    if hmac.compare_digest(hash_token(token), request.app.state.admin_token_hash):
        return Principal(admin=True)
    cam = crud.camera_by_token(session, token)
    return None if cam is None else Principal(admin=False, camera_id=cam.id)


def get_principal(request: Request, session: SessionDep) -> Principal:
    """Authenticate ``Authorization: Bearer <token>`` as the admin or a camera; 401 otherwise."""
    scheme, _, token = request.headers.get("authorization", "").partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        raise HTTPException(401, "missing bearer token (Authorization: Bearer <token>)",
                            headers={"WWW-Authenticate": "Bearer"})
    principal = principal_from_token(request, session, token)
    if principal is None:
        raise HTTPException(401, "invalid token", headers={"WWW-Authenticate": "Bearer"})
    return principal


PrincipalDep = Annotated[Principal, Depends(get_principal)]


def require_admin(principal: PrincipalDep) -> Principal:
    """Only the admin token; a camera token gets 403."""
    if not principal.admin:
        raise HTTPException(403, "this route needs the admin token")
    return principal


AdminDep = Annotated[Principal, Depends(require_admin)]


def not_found(camera_id: int) -> HTTPException:
    """The 404 for a camera that does not exist or that the caller may not see."""
    return HTTPException(404, f"unknown camera {camera_id}")


def camera_for(session: Session, principal: Principal, camera_id: int) -> Camera:
    """The camera if the caller may use it; another camera's resources answer 404, as unknown ones."""
    if not principal.admin and principal.camera_id != camera_id:
        raise not_found(camera_id)
    if not 0 < camera_id < 2**63:  # beyond a 64-bit integer column: no such camera (not a database error)
        raise not_found(camera_id)
    cam = crud.get_camera(session, camera_id)
    if cam is None:
        raise not_found(camera_id)
    return cam


def nearest_estimate(session: Session, camera_id: int, at: datetime | None) -> Estimate:
    """:func:`.crud.nearest_estimate`, or 404 when the camera has no estimate yet (the routes ``illuminant`` and
    ``wb-gains`` share it)."""
    e = crud.nearest_estimate(session, camera_id, at)
    if e is None:
        raise HTTPException(404, f"no estimate yet for camera {camera_id}; POST /v1/cameras/{camera_id}/refit")
    return e


def visible_cameras(session: Session, principal: Principal) -> list[Camera]:
    """The cameras the caller may see: every camera for the admin, its own for a camera token."""
    return crud.cameras(session, None if principal.admin else principal.camera_id)


def visible_camera(session: Session, principal: Principal, camera_id: int) -> Camera | None:
    """The camera if the caller may see it, else ``None`` (unknown, or another camera's)."""
    return crud.get_camera(session, camera_id) if (principal.admin or principal.camera_id == camera_id) else None
