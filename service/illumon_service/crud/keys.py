"""Queries of what a request carries besides its token: the ``Idempotency-Key`` of a frame post
(:mod:`..idempotency`) and the status page's login sessions (:mod:`..logins`)."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from ..storage import IdempotencyKey, LoginSession

__all__ = ["idempotency_key", "add_idempotency_key", "add_login", "get_login", "delete_login"]


def idempotency_key(session: Session, camera_id: int, key: str) -> IdempotencyKey | None:
    """The camera's stored ``Idempotency-Key`` ``key``, or ``None``."""
    q = select(IdempotencyKey).where(IdempotencyKey.camera_id == camera_id, IdempotencyKey.key == key)
    return session.scalars(q).first()


def add_idempotency_key(session: Session, camera_id: int, key: str, fingerprint: str) -> IdempotencyKey:
    """Store a key (added and flushed: a key another process stored meanwhile fails here)."""
    row = IdempotencyKey(camera_id=camera_id, key=key, fingerprint=fingerprint)
    session.add(row)
    session.flush()
    return row


def add_login(session: Session, id_hash: str, token_hash: str, expires_at: datetime) -> None:
    """Store a login session and commit."""
    session.add(LoginSession(id_hash=id_hash, token_hash=token_hash, expires_at=expires_at))
    session.commit()


def get_login(session: Session, id_hash: str) -> LoginSession | None:
    """The login session whose id has the SHA-256 ``id_hash``, or ``None``."""
    return session.get(LoginSession, id_hash)


def delete_login(session: Session, id_hash: str) -> None:
    """Delete a login session and commit."""
    session.execute(delete(LoginSession).where(LoginSession.id_hash == id_hash))
    session.commit()
