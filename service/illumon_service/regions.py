"""Image decoding and robust region statistics.

A frame's region value is the mean linear camera value of its pixels after removing

* clipped pixels (any channel at or above ``clip_fraction`` of the white level), whose true value is unknown, and
* outliers — passers-by, vehicles, birds — found by median / MAD trimming: pixels more than ``k`` robust standard
  deviations (1.4826 · MAD, floored at a small fraction of the median) from the per-channel median in any channel are
  dropped, twice (median and MAD from at most ~2048 strided pixels of the region).

A region is missing for the frame (``None``) when fewer than ``min_fraction`` of its pixels survive: mostly clipped or
mostly occluded. Images are PNG, JPEG or TIFF, 8- or 16-bit, decoded by OpenCV; black and white levels of the camera's
response are in the image's units (a white level ≤ 255 given for a 16-bit image is scaled by 257).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from illumon.camera import ResponseCurve
from numpy.typing import NDArray

__all__ = ["ImageError", "RegionError", "Region", "sniff_format", "decode_image", "region_means", "response_for"]

MAGIC = {
    b"\x89PNG\r\n\x1a\n": "png",
    b"\xff\xd8\xff": "jpeg",
    b"II*\x00": "tiff",
    b"MM\x00*": "tiff",
}


MEDIAN_SAMPLES = 2048
"""Pixels used for a region's median and MAD (an even stride over the region; the mean uses every kept pixel)."""


class ImageError(ValueError):
    """An upload that is not a decodable PNG, JPEG or TIFF image of a supported depth; ``status`` is the HTTP code."""

    def __init__(self, message: str, status: int = 422) -> None:
        super().__init__(message)
        self.status = status


class RegionError(ValueError):
    """A region that does not fit the image."""


@dataclass(frozen=True)
class Region:
    """A rectangle of static scene, in pixels, origin top-left."""

    id: str
    x: int
    y: int
    width: int
    height: int


def sniff_format(data: bytes) -> str | None:
    """``"png"``, ``"jpeg"`` or ``"tiff"`` from the leading magic bytes, else ``None``."""
    for magic, name in MAGIC.items():
        if data.startswith(magic):
            return name
    return None


def decode_image(data: bytes, *, max_pixels: int = 50_000_000) -> tuple[NDArray, float]:
    """Decode ``data`` to an RGB array (H × W × 3, uint8 or uint16) and its full-scale value (255 or 65535).

    Raises :class:`ImageError` for empty, unrecognised, undecodable, too large or unsupported images.
    """
    if not data:
        raise ImageError("image is empty (0 bytes)", 400)
    fmt = sniff_format(data)
    if fmt is None:
        raise ImageError("image is not PNG, JPEG or TIFF (unrecognised file signature)", 415)
    if fmt == "png" and len(data) >= 24 and data[12:16] == b"IHDR":
        # Refuse decompression bombs before allocating: the PNG header states the size.
        w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
        if w * h > max_pixels:
            raise ImageError(f"image has {w}×{h} pixels; the limit is {max_pixels}", 413)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
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


def response_for(response: Mapping, full_scale: float) -> ResponseCurve:
    """The camera's :class:`ResponseCurve` in the units of an image whose full scale is ``full_scale``."""
    black = float(response.get("black_level") or 0.0)
    white = response.get("white_level")
    white = full_scale if white is None else float(white)
    if full_scale > 255 and white <= 255:
        black, white = black * 257.0, white * 257.0
    return ResponseCurve(
        encoding=response.get("encoding", "linear"),
        gamma=float(response.get("gamma") or 2.2),
        black_level=black,
        white_level=white,
    )


@lru_cache(maxsize=32)
def _lut(response: ResponseCurve, size: int) -> NDArray[np.float64]:
    """Linear value of every code of an integer image (256 or 65536 entries): linearising becomes a lookup."""
    return response.linearise(np.arange(size, dtype=float))


def _robust_mean(lin: NDArray[np.float64], k: float, min_keep: int) -> NDArray[np.float64] | None:
    """Mean of the pixels (3 × N, channel-major for fast medians) within ``k`` robust σ of the median, trimmed twice."""
    keep = np.ones(lin.shape[1], dtype=bool)
    for _ in range(2):
        if keep.sum() < min_keep:
            return None
        sub = lin if keep.all() else lin[:, keep]
        # Median and MAD from at most ~2048 evenly strided pixels: as robust, and regions can be large.
        sub = np.ascontiguousarray(sub[:, :: max(1, sub.shape[1] // MEDIAN_SAMPLES)])
        med = np.median(sub, axis=1, keepdims=True)
        mad = np.median(np.abs(sub - med), axis=1, keepdims=True)
        scale = np.maximum(1.4826 * mad, 0.02 * np.abs(med) + 1e-4)
        keep = np.all(np.abs(lin - med) <= k * scale, axis=0)
    if keep.sum() < min_keep:
        return None
    return lin[:, keep].mean(axis=1)


def region_means(
    image: NDArray,
    regions: Iterable[Region],
    response: ResponseCurve,
    *,
    clip_fraction: float = 0.98,
    min_fraction: float = 0.5,
    k: float = 3.5,
) -> dict[str, list[float] | None]:
    """Robust mean linear RGB (0…1) of each region, ``None`` where the region is mostly clipped or occluded.

    Raises :class:`RegionError` if a region extends beyond the image.
    """
    h, w = image.shape[:2]
    lut = _lut(response, 256 if image.dtype == np.uint8 else 65536) if image.dtype in (np.uint8, np.uint16) else None
    clip_at = response.black_level + clip_fraction * (response.white_level - response.black_level)
    out: dict[str, list[float] | None] = {}
    for r in regions:
        if r.x < 0 or r.y < 0 or r.x + r.width > w or r.y + r.height > h:
            raise RegionError(
                f"region {r.id!r} ({r.x},{r.y} {r.width}×{r.height}) lies outside the {w}×{h} image"
            )
        px = image[r.y : r.y + r.height, r.x : r.x + r.width].reshape(-1, 3)
        n = len(px)
        ok = ~np.any(px >= clip_at, axis=1)
        min_keep = max(1, int(np.ceil(min_fraction * n)))
        if ok.sum() < min_keep:
            out[r.id] = None
            continue
        codes = np.ascontiguousarray(px[ok].T)
        lin = lut[codes] if lut is not None else response.linearise(codes)
        m = _robust_mean(lin, k, min_keep)
        out[r.id] = None if m is None else [float(v) for v in m]
    return out
