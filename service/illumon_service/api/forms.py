"""Form parsing: ``multipart/form-data`` bodies read in memory, the form fields every upload route shares
(``taken_at``, ``applied_gains``, ``exposure``, ``view``), each checked against :mod:`..limits`, and the forms of the
frame upload (:func:`read_frame_form`), the calibration upload (:func:`read_calibration_form`) and the regions page
(:func:`regions_from_form`). Every malformed value answers 4xx here, before any work is done."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from datetime import datetime, timezone

from fastapi import HTTPException, Request
from illumon.camera.references import REFERENCE_KINDS

from ..calibration import CalibrationUpload
from ..idempotency import Claim, form_fingerprint, parse_key
from ..ingest import FrameUpload
from ..limits import EXPOSURE_RANGE, GAINS_RANGE, check_gains, control_character
from ..regions import Region
from ..registration import parse_view
from ..storage import as_utc
from .schemas import FrameIngestOut

__all__ = ["IMAGE_TYPES", "MAX_PARTS", "parse_time", "read_multipart", "parse_gains", "parse_positive",
           "parse_view_field", "image_part", "FrameForm", "answer_json", "read_frame_form", "read_calibration_form",
           "regions_from_form"]

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
    """``"r,g,b"`` → three gains within :data:`~..limits.GAINS_RANGE` (``None`` when absent); 422 otherwise."""
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
    :data:`~..limits.EXPOSURE_RANGE`); 422 naming ``field`` otherwise."""
    if text is None or not text.strip():
        return None
    try:
        value = float(text)
    except ValueError:
        raise HTTPException(422, f"{field} {text!r}: expected a number within {lo:g}…{hi:g}") from None
    if not (math.isfinite(value) and lo <= value <= hi):
        raise HTTPException(422, f"{field} {text!r}: expected a number within {lo:g}…{hi:g}")
    return value


def parse_view_field(text: str | None) -> str | None:
    """A ``view`` field or query parameter (:func:`~..registration.parse_view`); 422 when malformed."""
    try:
        return parse_view(text)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None


def image_part(files: dict[str, tuple[str, bytearray]]) -> bytearray:
    """The ``image`` file part of an upload: 422 when missing, 415 when its content type is not an image's."""
    if "image" not in files:
        raise HTTPException(422, "missing file part 'image'")
    part_type, data = files["image"]
    if part_type not in IMAGE_TYPES:
        raise HTTPException(415, f"image part has content type {part_type!r}; send PNG, JPEG or TIFF")
    return data


@dataclass(frozen=True)
class FrameForm:
    """A parsed ``POST …/frames``: the upload, its text fields and its ``Idempotency-Key``."""

    upload: FrameUpload
    fields: dict[str, str]
    key: str | None

    def claim(self, camera_id: int) -> Claim | None:
        """The idempotency claim of the post (``None`` without a key)."""
        return None if self.key is None else Claim(camera_id, self.key, form_fingerprint(self.upload.image,
                                                                                         self.fields), answer_json)


def answer_json(answer: dict) -> dict:
    """A frame post's 201 answer as the JSON values the route sends (kept with its ``Idempotency-Key``)."""
    return FrameIngestOut.model_validate(answer).model_dump(mode="json")


async def read_frame_form(request: Request, limit: int) -> FrameForm:
    """Read and check a frame upload (multipart ``image``; optional ``taken_at``, ``applied_gains``, ``exposure``,
    ``view``): 415 for another content type, 413 beyond ``limit`` bytes, 422 for a malformed field or key."""
    ctype = request.headers.get("content-type", "")
    if not ctype.lower().startswith("multipart/form-data"):
        raise HTTPException(415, f"content type {ctype or 'none'!r}: send multipart/form-data with an 'image' part")
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit + 65536:
        raise HTTPException(413, f"upload of {declared} bytes exceeds the limit of {limit} bytes")
    fields, files = await read_multipart(request, limit)
    data = image_part(files)
    if len(data) > limit:
        raise HTTPException(413, f"image exceeds the upload limit of {limit} bytes")
    key = parse_key(request)
    upload = FrameUpload(data, parse_time(fields.get("taken_at")), parse_gains(fields.get("applied_gains")),
                         parse_positive(fields.get("exposure")), parse_view_field(fields.get("view")))
    return FrameForm(upload, fields, key)


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


async def read_calibration_form(request: Request, limit: int) -> CalibrationUpload:
    """Read and check a calibration upload (see :data:`~.routes.calibration.CALIBRATION_UPLOAD`): 415 for another
    content type, 413 beyond ``limit`` bytes, 422 for a malformed field."""
    if not request.headers.get("content-type", "").lower().startswith("multipart/form-data"):
        raise HTTPException(415, "send multipart/form-data with an 'image' part and a 'kind' field")
    fields, files = await read_multipart(request, limit)
    data = image_part(files)
    kind = fields.get("kind", "")
    if kind not in REFERENCE_KINDS:
        raise HTTPException(422, f"kind {kind!r}: expected {' or '.join(map(repr, REFERENCE_KINDS))}")
    corners = _json_field(fields, "corners") if kind == "colorchecker" and "corners" in fields else None
    region = _grey_region(_json_field(fields, "region")) if kind == "grey" else None
    reflectance = None
    if kind == "grey":
        reflectance = parse_positive(fields.get("reflectance"), "reflectance", 0.01, 1.0) or 0.18
        if reflectance > 1:
            raise HTTPException(422, "reflectance: a grey card's reflectance lies in (0, 1]")
    return CalibrationUpload(data, kind, corners, region, reflectance, parse_gains(fields.get("applied_gains")),
                             parse_positive(fields.get("exposure")))


def regions_from_form(form: dict) -> list[dict]:
    """Regions kept, renamed or added in the regions page's form (``ValueError`` for a malformed number)."""
    out = []
    for prefix, count in (("r", form.get("n_regions")), ("p", form.get("n_proposals"))):
        for i in range(min(int(count or 0), 500)):
            if form.get(f"{prefix}{i}_keep") != "1":
                continue
            out.append({"id": str(form.get(f"{prefix}{i}_id", "")).strip(),
                        **{k: int(form.get(f"{prefix}{i}_{f}", "")) for k, f in
                           (("x", "x"), ("y", "y"), ("width", "w"), ("height", "h"))}})
    if any(str(form.get(f"new_{f}", "")).strip() for f in ("id", "x", "y", "w", "h")):
        out.append({"id": str(form.get("new_id", "")).strip(),
                    **{k: int(str(form.get(f"new_{f}", "")).strip() or "-1") for k, f in
                       (("x", "x"), ("y", "y"), ("width", "w"), ("height", "h"))}})
    return out
