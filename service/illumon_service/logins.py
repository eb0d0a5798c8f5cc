"""Status-page logins: the cookie holds a random session id, never the token.

``POST /login`` with a valid token creates a session: a random 256-bit id goes to the browser in the cookie, and the
server stores only its SHA-256 together with the hash of the token that logged in and an expiry
(:data:`MAX_AGE`). A request's cookie is looked up by its hash; the session counts only while its token still
authenticates (the admin token unchanged, the camera still registered with that token), so changing a token or
deleting a camera ends its sessions. ``POST /logout`` deletes the session. A stolen cookie therefore gives a
revocable, expiring page session, not the token the camera posts frames with. Expired sessions are deleted by the
housekeeping (:mod:`.retention`).
"""

from __future__ import annotations

import hmac
from datetime import timedelta

from fastapi import Request
from sqlalchemy.orm import Session

from . import crud
from .deps import Principal
from .storage import as_utc, hash_token, new_token, utcnow

__all__ = ["MAX_AGE", "create_login", "principal_from_login", "end_login"]

MAX_AGE = timedelta(days=7)
"""How long a login lasts."""


def create_login(session: Session, token: str) -> str:
    """Store a login for ``token`` (already checked) and commit; returns the session id for the cookie."""
    sid = new_token()
    crud.add_login(session, hash_token(sid), hash_token(token.strip()), utcnow() + MAX_AGE)
    return sid


def principal_from_login(request: Request, session: Session, sid: str) -> Principal | None:
    """The admin or camera a cookie's session id stands for, or ``None`` (unknown, expired, or its token no longer
    valid)."""
    sid = sid.strip()
    if not sid:
        return None
    row = crud.get_login(session, hash_token(sid))
    if row is None or as_utc(row.expires_at) <= utcnow():
        return None
    if hmac.compare_digest(row.token_hash, request.app.state.admin_token_hash):
        return Principal(admin=True)
    camera_id = crud.camera_id_by_token_hash(session, row.token_hash)
    return None if camera_id is None else Principal(admin=False, camera_id=camera_id)


def end_login(session: Session, sid: str) -> None:
    """Delete the session (logout) and commit."""
    if sid.strip():
        crud.delete_login(session, hash_token(sid.strip()))
