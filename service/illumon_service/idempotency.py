"""``Idempotency-Key`` on frame posts: a retried post is answered, not stored again.

A client that sends a frame and gets no answer (a timeout, a dropped connection) cannot know whether it was stored;
sending it again with the same ``Idempotency-Key`` header (any string of 1–255 visible ASCII characters, e.g. a UUID
or the frame's file name and time) is safe. The key is stored with the frame, unique per camera (a unique
constraint), together with a fingerprint of the request and the answer given:

* the same key and the same request again → the original answer (201, header ``Idempotent-Replayed: true``), and
  nothing new is stored;
* the same key with a different request (another image or time) → 422: a key names one frame;
* concurrent retries: in one process they wait for the first (a lock per camera and key), then replay its answer;
  across worker processes the unique constraint lets one commit and the others replay its answer.

Keys are remembered for :data:`~.retention.IDEMPOTENCY_TTL` (7 days), and deleted with their frame.
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from fastapi import HTTPException, Request
from fastapi.responses import JSONResponse
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from . import crud
from .storage import IdempotencyKey

__all__ = ["HEADER", "REPLAYED", "IDEMPOTENCY_DOC", "Claim", "parse_key", "fingerprint", "form_fingerprint", "keyed",
           "stored", "replay", "key_lock", "is_conflict"]

HEADER = "Idempotency-Key"
IDEMPOTENCY_DOC = ("a retried post with the same key (1–255 visible ASCII characters, unique per camera) gets the "
                   "original answer and stores nothing new; the same key with another frame: 422")
"""The header's description in the OpenAPI schema."""
REPLAYED = "Idempotent-Replayed"
MAX_KEY = 255


@dataclass(frozen=True)
class Claim:
    """A key a frame post carries: the camera, the key, the request's fingerprint, and how its answer is kept (the
    JSON values the route sends)."""

    camera_id: int
    key: str
    fingerprint: str
    as_json: Callable[[dict], dict]


def parse_key(request: Request) -> str | None:
    """The request's ``Idempotency-Key`` (``None`` without one); 422 when empty, longer than 255 characters or not
    visible ASCII."""
    value = request.headers.get(HEADER)
    if value is None:
        return None
    value = value.strip()
    if not 0 < len(value) <= MAX_KEY or not all(0x20 <= ord(c) < 0x7F for c in value):
        raise HTTPException(422, f"{HEADER} must be 1–{MAX_KEY} visible ASCII characters (e.g. a UUID)")
    return value


def fingerprint(*parts: bytes | bytearray | str | None) -> str:
    """SHA-256 over the request's parts (image bytes, form fields or JSON body), each length-prefixed."""
    h = hashlib.sha256()
    for p in parts:
        b = b"" if p is None else p.encode() if isinstance(p, str) else p
        h.update(len(b).to_bytes(8, "little"))
        h.update(b)
    return h.hexdigest()


def form_fingerprint(image: bytes | bytearray, fields: dict[str, str]) -> str:
    """:func:`fingerprint` of a multipart frame post: the image and every text field (sorted by name)."""
    return fingerprint(image, json.dumps(sorted(fields.items())))


def keyed(write: Callable[[Session], dict], claim: Claim) -> Callable[[Session], dict]:
    """``write`` (a frame's insert, run by the group commit) with the key stored in the same transaction: the key's
    row first (flushed, so that a key another process stored meanwhile fails before any frame or file is written),
    then the frame, then the key's frame id and answer (``claim.as_json(answer)``)."""

    def run(session: Session) -> dict:
        row = crud.add_idempotency_key(session, claim.camera_id, claim.key, claim.fingerprint)
        answer = write(session)
        row.frame_id = answer["frame_id"]
        row.answer = claim.as_json(answer)
        return answer

    return run


def stored(sessions: sessionmaker[Session] | Session, claim: Claim) -> IdempotencyKey | None:
    """The stored key of ``claim``'s camera, if a frame was stored with it."""
    if isinstance(sessions, Session):
        return crud.idempotency_key(sessions, claim.camera_id, claim.key)
    with sessions() as s:
        return crud.idempotency_key(s, claim.camera_id, claim.key)


def replay(row: IdempotencyKey, claim: Claim) -> JSONResponse:
    """The original answer to a retry; 422 when the key was used for a different request."""
    if row.fingerprint != claim.fingerprint:
        raise HTTPException(422, f"{HEADER} {claim.key!r} was already used for a different frame of this camera; "
                                 "use a new key for each frame")
    return JSONResponse(row.answer, status_code=201, headers={REPLAYED: "true"})


_LOCKS: dict[tuple[int, str], tuple[threading.Lock, int]] = {}
_LOCKS_GUARD = threading.Lock()


@contextmanager
def key_lock(claim: Claim | None) -> Iterator[None]:
    """Serialise the requests of this process that carry the same camera and key (no-op without a key)."""
    if claim is None:
        yield
        return
    k = (claim.camera_id, claim.key)
    with _LOCKS_GUARD:
        lock, users = _LOCKS.get(k, (threading.Lock(), 0))
        _LOCKS[k] = (lock, users + 1)
    try:
        with lock:
            yield
    finally:
        with _LOCKS_GUARD:
            lock, users = _LOCKS[k]
            if users <= 1:
                del _LOCKS[k]
            else:
                _LOCKS[k] = (lock, users - 1)


def is_conflict(exc: BaseException) -> bool:
    """Whether ``exc`` is the unique constraint of the idempotency keys (another process stored the key first)."""
    return isinstance(exc, IntegrityError) and ("idempotency" in str(exc.orig).lower() or "uq_idempotency" in str(exc))
