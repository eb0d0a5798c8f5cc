"""Parsing of uploads: ``multipart/form-data`` bodies read in memory, and the form fields every upload route shares
(``taken_at``, ``applied_gains``, ``exposure``), each checked against :mod:`.limits`."""

from __future__ import annotations

import math
from datetime import datetime, timezone

from fastapi import HTTPException, Request

from .limits import EXPOSURE_RANGE, GAINS_RANGE, check_gains, control_character
from .storage import as_utc

__all__ = ["IMAGE_TYPES", "MAX_PARTS", "parse_time", "read_multipart", "parse_gains", "parse_positive"]

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
            bad = control_character(fields[name])
            if bad is not None:
                raise HTTPException(422, f"form field {name!r}: control character {bad} not allowed")
    return fields, files


def parse_gains(text: str | None, field: str = "applied_gains") -> list[float] | None:
    """``"r,g,b"`` → three gains within :data:`~.limits.GAINS_RANGE` (``None`` when absent); 422 otherwise."""
    if text is None or not text.strip():
        return None
    try:
        return check_gains([float(v) for v in text.split(",")], field)
    except ValueError:
        raise HTTPException(422, f"{field} {text!r}: expected three gains 'r,g,b' within {GAINS_RANGE[0]:g}…"
                                 f"{GAINS_RANGE[1]:g}") from None


def parse_positive(text: str | None, field: str = "exposure", lo: float = EXPOSURE_RANGE[0],
                   hi: float = EXPOSURE_RANGE[1]) -> float | None:
    """A form field holding a number within ``lo``…``hi`` (``None`` when absent; by default a relative exposure,
    :data:`~.limits.EXPOSURE_RANGE`); 422 naming ``field`` otherwise."""
    if text is None or not text.strip():
        return None
    try:
        value = float(text)
    except ValueError:
        raise HTTPException(422, f"{field} {text!r}: expected a number within {lo:g}…{hi:g}") from None
    if not (math.isfinite(value) and lo <= value <= hi):
        raise HTTPException(422, f"{field} {text!r}: expected a number within {lo:g}…{hi:g}")
    return value
