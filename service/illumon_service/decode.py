"""Image decoding for ingest: PNG, JPEG or TIFF, 8- or 16-bit, RGB, decoded by OpenCV after the size its header
declares is checked (a decompression bomb costs nothing), optionally at 1/2, 1/4 or 1/8 size for JPEG where every
region stays large enough (:func:`jpeg_reduction`). Grey frames are refused for colour cameras (:func:`is_grey`)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .regions import Region

__all__ = ["ImageError", "DecodedFrame", "sniff_format", "declared_size", "declared_layout", "check_budget",
           "decode_image", "decode_frame", "DEFAULT_MAX_BYTES",
           "jpeg_reduction", "is_grey", "MIN_REDUCED_SIDE"]

MAGIC = {
    b"\x89PNG\r\n\x1a\n": "png",
    b"\xff\xd8\xff": "jpeg",
    b"II*\x00": "tiff",
    b"MM\x00*": "tiff",
}

DEFAULT_MAX_BYTES = 64 * 1024 * 1024
"""Default largest decoded image in bytes (:attr:`~.settings.Settings.max_decoded_bytes`)."""

MIN_REDUCED_SIDE = 32
"""Smallest width and height, in decoded pixels, a region may have for a reduced-resolution JPEG decode."""

_REDUCED = {
    2: (cv2.IMREAD_REDUCED_GRAYSCALE_2, cv2.IMREAD_REDUCED_COLOR_2),
    4: (cv2.IMREAD_REDUCED_GRAYSCALE_4, cv2.IMREAD_REDUCED_COLOR_4),
    8: (cv2.IMREAD_REDUCED_GRAYSCALE_8, cv2.IMREAD_REDUCED_COLOR_8),
}
"""imdecode flags (grey, colour) of each reduction factor."""


class ImageError(ValueError):
    """An upload that is not a decodable PNG, JPEG or TIFF image of a supported depth; ``status`` is the HTTP code."""

    def __init__(self, message: str, status: int = 422) -> None:
        super().__init__(message)
        self.status = status


def sniff_format(data: bytes | bytearray) -> str | None:
    """``"png"``, ``"jpeg"`` or ``"tiff"`` from the leading magic bytes, else ``None``."""
    for magic, name in MAGIC.items():
        if data.startswith(magic):
            return name
    return None


def _jpeg_sof(data: bytes | bytearray) -> tuple[int, int, int, int] | None:
    """``(width, height, bits per sample, components)`` from a JPEG's first SOF marker, ``None`` if not found.

    Scans the markers as libjpeg does: fill bytes (``FF FF``) and stray bytes between segments (which libjpeg skips
    with a warning, then decodes the image) are skipped too, so no file it would decode hides its size from this
    check. Stops at the first scan (``SOS``): a frame header must come before it.
    """
    i, n = 2, len(data)
    try:
        while i + 9 < n:
            if data[i] != 0xFF:
                j = data.find(b"\xff", i)
                if j < 0:
                    return None
                i = j
                continue
            marker = data[i + 1]
            if marker == 0xFF:
                i += 1
                continue
            if marker in (0xD8, 0x01, 0x00) or 0xD0 <= marker <= 0xD7:
                i += 2
                continue
            if marker in (0xDA, 0xD9):  # start of scan or end of image before any frame header
                return None
            seg = int.from_bytes(data[i + 2 : i + 4], "big")
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
                h = int.from_bytes(data[i + 5 : i + 7], "big")
                w = int.from_bytes(data[i + 7 : i + 9], "big")
                return w, h, data[i + 4], data[i + 9]
            if seg < 2:
                return None
            i += 2 + seg
    except IndexError:
        return None
    return None


PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 4, 6: 4}
"""Channels OpenCV decodes a PNG of each colour type to (palette: RGB; grey with alpha: BGRA)."""


def declared_layout(data: bytes | bytearray, fmt: str) -> tuple[int, int, int, int] | None:
    """``(width, height, channels, bytes per sample)`` stated by a PNG (IHDR), JPEG (first SOF marker) or TIFF
    (first IFD, every entry read, wherever the size tags are) header, read without decoding anything; ``None`` when
    the header is too short or malformed to say (such an image is not decoded)."""
    try:
        if fmt == "png":
            if len(data) >= 26 and data[12:16] == b"IHDR":
                depth, kind = data[24], data[25]
                return (int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big"),
                        PNG_CHANNELS.get(kind, 4), 2 if depth > 8 else 1)
            return None
        if fmt == "jpeg":
            sof = _jpeg_sof(data)
            return None if sof is None else (sof[0], sof[1], max(1, sof[3]), 2 if sof[2] > 8 else 1)
        if fmt == "tiff":
            order = "little" if data[:2] == b"II" else "big"
            off = int.from_bytes(data[4:8], order)
            n = int.from_bytes(data[off : off + 2], order)
            if off < 8 or off + 2 + 12 * n > len(data):
                return None
            tags: dict[int, int] = {}
            for k in range(n):
                e = off + 2 + 12 * k
                tag, typ = int.from_bytes(data[e : e + 2], order), int.from_bytes(data[e + 2 : e + 4], order)
                if tag in (256, 257, 258, 277):
                    count = int.from_bytes(data[e + 4 : e + 8], order)
                    if tag == 258 and typ == 3 and count > 2:  # bits per sample of each channel, stored elsewhere
                        at = int.from_bytes(data[e + 8 : e + 12], order)
                        value = int.from_bytes(data[at : at + 2], order)
                    else:
                        value = int.from_bytes(data[e + 8 : e + (10 if typ == 3 else 12)], order)
                    tags[tag] = value
            if 256 not in tags or 257 not in tags:
                return None
            bits = tags.get(258, 8) or 8
            return tags[256], tags[257], max(1, tags.get(277, 1)), max(1, -(-bits // 8))
    except (IndexError, ValueError):
        return None
    return None


def declared_size(data: bytes | bytearray, fmt: str) -> tuple[int, int] | None:
    """Width and height stated by a PNG, JPEG or TIFF header (:func:`declared_layout`); ``None`` when it does not
    say."""
    layout = declared_layout(data, fmt)
    return None if layout is None else (layout[0], layout[1])


def check_budget(data: bytes | bytearray, fmt: str, max_pixels: int, max_bytes: int) -> tuple[int, int]:
    """The declared (width, height) when the decoded image fits ``max_pixels`` and ``max_bytes`` (width × height ×
    channels × bytes per sample); :class:`ImageError` 413 when it does not, 422 when the header does not say."""
    layout = declared_layout(data, fmt)
    if layout is None or layout[0] <= 0 or layout[1] <= 0:
        raise ImageError(f"image header does not state a valid size (truncated or malformed {fmt.upper()}): "
                         "not decoded")
    w, h, ch, bps = layout
    if w * h > max_pixels:
        raise ImageError(f"image has {w}×{h} pixels; the limit is {max_pixels}", 413)
    if w * h * ch * bps > max_bytes:
        raise ImageError(f"image of {w}×{h} pixels, {ch} channel(s) of {8 * bps} bits would take "
                         f"{w * h * ch * bps / 2**20:.0f} MiB decoded; the limit is {max_bytes / 2**20:.0f} MiB", 413)
    return w, h


def jpeg_reduction(
    data: bytes | bytearray, regions: Iterable[Region], max_reduction: int, min_side: int = MIN_REDUCED_SIDE,
) -> int:
    """The factor (1, 2, 4 or 8) by which to decode ``data`` at reduced resolution for robust means of ``regions``.

    libjpeg decodes a JPEG at 1/2, 1/4 or 1/8 of its size by scaling its inverse DCT (each decoded pixel is close to
    the mean of the s × s pixels it replaces), saving the full-size IDCT, colour conversion and upsampling. The factor
    is the largest one ≤ ``max_reduction`` at which every region still spans at least ``min_side`` decoded pixels in
    each direction; 1 for anything but an 8-bit grey or three-component JPEG, or when ``max_reduction`` is 1.
    """
    if max_reduction < 2 or sniff_format(data) != "jpeg":
        return 1
    sof = _jpeg_sof(data)
    if sof is None or sof[2] != 8 or sof[3] not in (1, 3):
        return 1
    regions = list(regions)
    for s in (8, 4, 2):
        if s <= max_reduction and all(min(r.width, r.height) >= s * min_side for r in regions):
            return s
    return 1


def decode_image(data: bytes | bytearray, *, max_pixels: int = 50_000_000, reduction: int = 1,
                 max_bytes: int = DEFAULT_MAX_BYTES) -> tuple[NDArray, float]:
    """Decode ``data`` to an RGB array (H × W × 3, uint8 or uint16) and its full-scale value (255 or 65535).

    ``reduction`` 2, 4 or 8 (a JPEG only, see :func:`jpeg_reduction`) decodes at that fraction of the size, ⌈H/s⌉ ×
    ⌈W/s⌉. Raises :class:`ImageError` for empty, unrecognised, undecodable, too large or unsupported images.
    """
    if not data:
        raise ImageError("image is empty (0 bytes)", 400)
    fmt = sniff_format(data)
    if fmt is None:
        raise ImageError("image is not PNG, JPEG or TIFF (unrecognised file signature)", 415)
    # Refuse decompression bombs before allocating: the header states the size (an image whose header does not is
    # not decoded at all).
    check_budget(data, fmt, max_pixels, max_bytes)
    if reduction == 1:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    else:
        sof = _jpeg_sof(data) if fmt == "jpeg" else None
        if reduction not in _REDUCED or sof is None or sof[2] != 8 or sof[3] not in (1, 3):
            raise ValueError(f"cannot decode this image at 1/{reduction} size (an 8-bit JPEG at 1/2, 1/4 or 1/8 only)")
        # IMREAD_UNCHANGED ignores the EXIF orientation; so must the reduced decode, or regions would move.
        flags = _REDUCED[reduction][sof[3] == 3] | cv2.IMREAD_IGNORE_ORIENTATION
        img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
        if img is not None and img.shape[:2] != (-(-sof[1] // reduction), -(-sof[0] // reduction)):
            raise ImageError("image could not be decoded (its size differs from the one its header states)")
    if img is None or img.size == 0:
        raise ImageError("image could not be decoded (corrupt or truncated file)")
    if img.shape[0] * img.shape[1] > max_pixels:
        raise ImageError(f"image has {img.shape[1]}×{img.shape[0]} pixels; the limit is {max_pixels}", 413)
    if img.dtype == np.uint8:
        full = 255.0
    elif img.dtype == np.uint16:
        full = 65535.0
    else:
        raise ImageError(f"unsupported sample type {img.dtype}; use 8- or 16-bit images")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[:, :, 2::-1]
    elif img.shape[2] == 3:
        img = img[:, :, ::-1]
    else:
        raise ImageError(f"unsupported channel count {img.shape[2]}; use RGB or grey images")
    return img, full


GREY_SAMPLE_STRIDE = 8
""":func:`is_grey` compares the channels of every 8th pixel along each axis (~0.1 ms for 1920×1080)."""


def is_grey(image: NDArray) -> bool:
    """Whether a decoded RGB image is grey: its three channels identical at every sampled pixel (a single-channel
    image, expanded by :func:`decode_image`, or a grey image saved as RGB). A colour camera's noise alone makes its
    channels differ somewhere."""
    sample = image[::GREY_SAMPLE_STRIDE, ::GREY_SAMPLE_STRIDE]
    return bool(np.array_equal(sample[..., 0], sample[..., 1]) and np.array_equal(sample[..., 1], sample[..., 2]))


@dataclass(frozen=True)
class DecodedFrame:
    """An uploaded frame decoded for region statistics (:func:`decode_frame`)."""

    image: NDArray
    """RGB pixels, H × W × 3, uint8 or uint16; at 1/``scale`` of the full resolution."""
    full_scale: float
    """255 or 65535."""
    scale: int
    """Full-resolution pixels per decoded pixel along each axis (1, or 2, 4, 8 for a reduced JPEG decode)."""
    size: tuple[int, int]
    """Full-resolution (width, height)."""
    fmt: str | None = None
    """The upload's format (:func:`sniff_format`: ``png``, ``jpeg`` or ``tiff``)."""


def decode_frame(
    data: bytes | bytearray, regions: Iterable[Region], *, max_pixels: int = 50_000_000, max_reduction: int = 1,
    max_bytes: int = DEFAULT_MAX_BYTES,
) -> DecodedFrame:
    """Decode an upload for the robust means of ``regions``: a JPEG at the reduction :func:`jpeg_reduction` allows
    (at most ``max_reduction``), anything else at full size. Raises :class:`ImageError` like :func:`decode_image`, and
    (422) for a grey image (:func:`is_grey`), which carries no colour to estimate the light from."""
    scale = jpeg_reduction(data, regions, max_reduction)
    image, full = decode_image(data, max_pixels=max_pixels, reduction=scale, max_bytes=max_bytes)
    if is_grey(image):
        raise ImageError(
            "image is grey (one channel, or three identical ones): the light is estimated from the colours of the "
            "regions, so a colour camera's frames must be RGB — is the camera in monochrome or night (IR) mode?"
        )
    size = declared_size(data, "jpeg") if scale > 1 else None
    return DecodedFrame(image, full, scale, size or (int(image.shape[1]), int(image.shape[0])), sniff_format(data))
