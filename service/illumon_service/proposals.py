"""Reference-region proposals from a camera's stored frames, so that an installer confirms regions rather than
drawing them, computed with OpenCV and numpy.

The service keeps a small *thumbnail* of every frame (:func:`make_thumbnail`): the frame linearised through the
camera's response and downscaled by area averaging (``cv2.INTER_AREA`` on linear values, so a thumbnail pixel is the
mean light of the pixels it replaces) to at most :data:`THUMB_SIDE` pixels on its longer side, plus each thumbnail
pixel's unclipped fraction. Thumbnails are 16-bit RGBA PNGs (RGB linear × 65535, alpha the unclipped fraction); a
view keeps at most one new thumbnail per ten minutes of frames (:func:`~.registration.thumbnail_due`), and of those
the latest one of every hour of the day (UTC) and its :data:`KEEP_RECENT` most recent ones
(:func:`~.registration.prune_thumbnails`), so proposals see the light of a whole day while the disk holds ≤ 32 small
files (≤ 0.5 MB each) per view; full frames (``keep_images``) are not needed. Every frame's thumbnail is computed
(~1.5 ms for 1920 × 1080) to register it (:mod:`.registration`), whether or not it is kept.

A proposal is a rectangle whose pixels, once each frame's exposure and illuminant are divided out (each frame's
channels divided by their median over the unclipped pixels: a diagonal, von Kries change of light, Finlayson et al.,
"Color constancy at a pixel", JOSA A 18(2), 2001), are

* static — small temporal change of every pixel (``change``: the window's mean per-pixel temporal standard deviation
  of log values) and of the window's mean (``drift``): passers-by, foliage in wind, the sky (whose radiance does not
  follow the light on the ground) and specular highlights that move with the sun all change;
* uniform — low spatial texture of the time-averaged log image (``texture``): a window across two surfaces or on
  clutter is not;
* unclipped in every frame (``clipped``) and not dark in any channel (``dark``: the window's median-over-frames mean,
  relative to full scale, of its darkest channel).

The score is ``exp(−½ Σ (reason / scale)²)`` over change, drift and texture, times a soft darkness penalty, zero
when clipped. Windows of three sizes on a grid are scored with integral images; proposals are then chosen greedily
best first without overlaps, each candidate's score multiplied by its chromatic distance to those already chosen
(``1 − exp(−d² / 2σ²)`` in log-chromaticity), so a scene's ten grey walls do not fill the list: the scene model needs
surfaces of different colours (Marguier & Süsstrunk 2007; Tominaga & Wandell 1989 on the rank of surface sets).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from illumon.camera import ResponseCurve
from numpy.typing import NDArray

from .regions import _lut, clip_level

__all__ = [
    "THUMB_SIDE", "KEEP_RECENT", "MIN_FRAMES", "Thumbnail", "make_thumbnail", "save_thumbnail", "load_thumbnail",
    "thumbnail_grey", "shifted", "propose_regions", "Proposal", "preview_jpeg",
]

THUMB_SIDE = 320
"""Longer side of a stored thumbnail, in pixels."""
KEEP_RECENT = 8
"""Most recent thumbnails a camera keeps besides the latest one of each hour of the day."""
MIN_FRAMES = 5
"""Fewest stored frames (thumbnails) proposals are computed from."""
MAX_FRAMES = 32
"""Most thumbnails used for one set of proposals (the most recent ones of each hour first)."""

CHANGE_SCALE = 0.15
"""Per-pixel temporal standard deviation of log values at which the score falls to exp(−½) (chosen on the
development scenes of ``benchmarks/regions_setup.py``)."""
DRIFT_SCALE = 0.12
"""Temporal standard deviation of the window's log mean at which the score falls to exp(−½)."""
TEXTURE_SCALE = 0.08
"""Spatial standard deviation of the time-averaged log values at which the score falls to exp(−½) (a surface with
±15 % pixel texture has ~0.09 at full resolution, less once averaged into thumbnail pixels)."""
DARK_LEVEL = 0.01
"""A window whose darkest channel's median linear value (of full scale) is below this scores less (halved at it)."""
CHROMA_SIGMA = 0.08
"""Log-chromaticity distance at which a candidate keeps exp(−½)… of its score next to an already chosen one."""
WINDOW_FRACTIONS = (0.045, 0.07, 0.1)
"""Window sides, as fractions of the thumbnail's longer side."""


@dataclass(frozen=True)
class Thumbnail:
    """A downscaled, linearised frame."""

    linear: NDArray[np.float32]
    """h × w × 3 linear values, 0…1 of full scale."""
    unclipped: NDArray[np.float32]
    """h × w fraction of each thumbnail pixel's full-resolution pixels that are not clipped."""
    factor: float
    """Full-resolution pixels per thumbnail pixel along each axis."""


def make_thumbnail(image: NDArray, response: ResponseCurve, clip_fraction: float, full_size: tuple[int, int],
                   side: int = THUMB_SIDE) -> Thumbnail:
    """The thumbnail of a decoded frame (integer or float RGB codes, possibly decoded at reduced size):
    linearised through ``response`` (a lookup table: ``cv2.LUT`` for 8-bit codes), area-averaged to at most ``side``
    pixels on the longer side. An image more than twice that size is first sampled every ``s``-th pixel along each
    axis (``s = ⌊long side / 2·side⌋``: 3 for 1920 × 1080), so a thumbnail pixel averages ≥ 2 × 2 samples of the pixels
    it covers (~1.5 ms instead of ~12 ms for 1920 × 1080 × 8 bit; texture then looks up to s times stronger than in a
    full average, still well under :data:`TEXTURE_SCALE` for a ±15 % surface)."""
    full_h, full_w = image.shape[:2]
    step = max(1, max(full_w, full_h) // (2 * side))
    # Work in the pixels' memory order (OpenCV's BGR: decode_image returns a channel-reversed view of it).
    flip = image.ndim == 3 and image.strides[2] < 0
    if flip:
        image = image[:, :, ::-1]
    if step > 1:
        image = cv2.resize(image, (-(-full_w // step), -(-full_h // step)), interpolation=cv2.INTER_NEAREST)
    h, w = image.shape[:2]
    level = clip_level(response, clip_fraction)
    if image.dtype in (np.uint8, np.uint16):
        lut = np.clip(_lut(response, 256 if image.dtype == np.uint8 else 65536), 0.0, 1.0).astype(np.float32)
        lin = cv2.LUT(image, lut) if image.dtype == np.uint8 else lut.take(image)
        cap = min(math.ceil(level) - 1, int(np.iinfo(image.dtype).max))
        ok = cv2.inRange(image, (0, 0, 0), (cap, cap, cap)) if cap >= 0 else np.zeros((h, w), np.uint8)
    else:
        lin = np.clip(response.linearise(image.astype(float)), 0.0, 1.0).astype(np.float32)
        ok = np.where(image.max(axis=2) < level, 255, 0).astype(np.uint8)
    k = max(1.0, max(full_w, full_h) / side)
    tw, th = max(1, round(full_w / k)), max(1, round(full_h / k))
    small = cv2.resize(lin, (tw, th), interpolation=cv2.INTER_AREA)
    if flip:
        small = np.ascontiguousarray(small[:, :, ::-1])
    okk = cv2.resize(ok, (tw, th), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    return Thumbnail(small, okk, full_size[0] / tw)


def save_thumbnail(path: Path, thumb: Thumbnail) -> None:
    """Write a thumbnail as a 16-bit RGBA PNG (RGB linear × 65535, alpha the unclipped fraction)."""
    rgba = np.dstack([thumb.linear[:, :, ::-1], thumb.unclipped])
    ok, buf = cv2.imencode(".png", np.round(np.clip(rgba, 0, 1) * 65535).astype(np.uint16),
                           [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("thumbnail could not be encoded")
    from .datafiles import atomic_write

    atomic_write(path, buf.tobytes())  # a private temporary file: concurrent writers never share one


def load_thumbnail(path: Path | str, full_width: int) -> Thumbnail | None:
    """A thumbnail written by :func:`save_thumbnail` (``None`` when the file is gone or unreadable)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 3 or img.shape[2] != 4:
        return None
    x = img.astype(np.float32) / 65535.0
    return Thumbnail(np.ascontiguousarray(x[:, :, 2::-1]), np.ascontiguousarray(x[:, :, 3]), full_width / x.shape[1])


def thumbnail_grey(thumb: Thumbnail) -> NDArray[np.float32]:
    """Log-luminance grey image of a thumbnail (Rec. 601 weights), for registration."""
    return cv2.log(cv2.cvtColor(thumb.linear, cv2.COLOR_RGB2GRAY) + np.float32(1e-3))


def shifted(thumb: Thumbnail, dx: float, dy: float) -> Thumbnail:
    """``thumb`` moved by (``dx``, ``dy``) full-resolution pixels (pixels moved in from outside are unclipped 0: they
    count as clipped, so no window uses them)."""
    if dx == 0 and dy == 0:
        return thumb
    m = np.float32([[1, 0, dx / thumb.factor], [0, 1, dy / thumb.factor]])
    h, w = thumb.unclipped.shape
    lin = cv2.warpAffine(thumb.linear, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    ok = cv2.warpAffine(thumb.unclipped, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return Thumbnail(lin, ok, thumb.factor)


@dataclass(frozen=True)
class Proposal:
    """A proposed region in full-resolution pixels, its score (0…1) and the reasons behind it."""

    x: int
    y: int
    width: int
    height: int
    score: float
    reasons: dict

    def as_dict(self) -> dict:
        """JSON form."""
        return {"x": self.x, "y": self.y, "width": self.width, "height": self.height, "score": self.score,
                "reasons": self.reasons}


def _box_sums(integral: NDArray[np.float64], x: NDArray, y: NDArray, s_w: int, s_h: int) -> NDArray[np.float64]:
    """Sums over windows ``[y, y+s_h) × [x, x+s_w)`` from an integral image (…, h+1, w+1, …) indexed on axes −3, −2
    when the last axis is channels, else −2, −1."""
    return integral[..., y + s_h, x + s_w, :] - integral[..., y, x + s_w, :] - integral[..., y + s_h, x, :] \
        + integral[..., y, x, :]


def _integral(a: NDArray) -> NDArray[np.float64]:
    """Zero-padded 2-D cumulative sums over axes −3 and −2 of ``a`` (… × h × w × c)."""
    out = np.zeros(a.shape[:-3] + (a.shape[-3] + 1, a.shape[-2] + 1, a.shape[-1]))
    out[..., 1:, 1:, :] = a.cumsum(axis=-3, dtype=np.float64).cumsum(axis=-2)
    return out


def propose_regions(thumbs: Sequence[Thumbnail], count: int = 12, full_size: tuple[int, int] | None = None) -> list[Proposal]:
    """The ``count`` best reference-region proposals (best first) from aligned thumbnails of one view.

    Parameters
    ----------
    thumbs
        At least :data:`MIN_FRAMES` thumbnails of the same size, in the reference frame's coordinates.
    count
        Proposals wanted (fewer when fewer windows qualify).
    full_size
        Full-resolution (width, height), to keep rectangles inside the image.

    Returns
    -------
    list of Proposal
        Rectangles in full-resolution pixels with ``score`` and ``reasons`` (``change``, ``drift``, ``texture``,
        ``clipped``, ``dark``, ``chroma``: the window's mean log(r/g), log(b/g), and ``diversity``, the factor its
        chromatic distance to the better proposals applied).
    """
    if len(thumbs) < MIN_FRAMES:
        raise ValueError(f"{len(thumbs)} frames; proposals need at least {MIN_FRAMES}")
    x = np.stack([t.linear for t in thumbs]).astype(np.float64)  # T × h × w × 3
    ok = np.stack([t.unclipped for t in thumbs]) > 0.999  # T × h × w
    cands = _scored_windows(x, ok)
    if not cands:
        return []
    _, h, w, _ = x.shape
    factor = thumbs[0].factor
    fw, fh = full_size if full_size else (round(w * factor), round(h * factor))
    return _choose(cands, count, factor, fw, fh)


def _scored_windows(x: NDArray[np.float64], ok: NDArray[np.bool_]) -> list[tuple]:
    """Every window of the grid scoring above 0.02: ``(x, y, width, height, score, change, drift, texture, clipped,
    dark, chroma, rank)`` in thumbnail pixels, from the thumbnails' linear values ``x`` (T × h × w × 3) and their
    unclipped pixels ``ok`` (T × h × w)."""
    t_n, h, w, _ = x.shape
    # Divide out each frame's exposure and illuminant: channel medians over the unclipped, not black pixels.
    norm = np.empty((t_n, 3))
    for i in range(t_n):
        px = x[i][ok[i] & (x[i].min(axis=2) > 1e-3)]
        norm[i] = np.median(px, axis=0) if len(px) > 100 else np.maximum(x[i].reshape(-1, 3).mean(axis=0), 1e-6)
    logs = np.log(x / norm[:, None, None, :] + 0.01)  # T × h × w × 3
    mean_log = logs.mean(axis=0)  # h × w × 3
    pixel_sd = np.sqrt(((logs - mean_log) ** 2).mean(axis=0).mean(axis=2))  # h × w
    clipped = (~ok).mean(axis=0)  # h × w: fraction of frames in which the pixel clips

    i_lin = _integral(x / norm[:, None, None, :])  # T × (h+1) × (w+1) × 3
    i_raw = _integral(np.median(x, axis=0)[None])[0]
    i_m = _integral(mean_log[None])[0]
    i_m2 = _integral((mean_log**2)[None])[0]
    i_sd = _integral(pixel_sd[None, :, :, None])[0]
    i_cl = _integral(clipped[None, :, :, None])[0]

    cands = []  # (x, y, sw, sh, score, reasons)
    for frac in WINDOW_FRACTIONS:
        s = max(4, round(frac * max(h, w)))
        for sw, sh in ((s, s), (2 * s, s), (s, 2 * s)):
            if sw > w or sh > h:
                continue
            step = max(1, s // 3)
            ys, xs = np.meshgrid(np.arange(0, h - sh + 1, step), np.arange(0, w - sw + 1, step), indexing="ij")
            xs, ys = xs.ravel(), ys.ravel()
            n = sw * sh
            means = _box_sums(i_lin, xs, ys, sw, sh) / n  # T × N × 3
            drift = np.log(np.maximum(means, 1e-6)).std(axis=0).max(axis=1)
            m1 = _box_sums(i_m, xs, ys, sw, sh) / n
            tex = np.sqrt(np.maximum(_box_sums(i_m2, xs, ys, sw, sh) / n - m1**2, 0)).mean(axis=1)
            change = _box_sums(i_sd, xs, ys, sw, sh)[:, 0] / n
            clip = _box_sums(i_cl, xs, ys, sw, sh)[:, 0] / n
            raw = _box_sums(i_raw, xs, ys, sw, sh) / n  # N × 3: typical linear value
            dark = raw.min(axis=1)
            score = np.exp(-0.5 * ((change / CHANGE_SCALE) ** 2 + (drift / DRIFT_SCALE) ** 2
                                   + (tex / TEXTURE_SCALE) ** 2))
            score *= dark**2 / (dark**2 + DARK_LEVEL**2)
            score[clip > 0] = 0.0
            rank = score * (n / (s * s)) ** 0.05  # among equals, the larger window (more pixels, less noise)
            chroma = np.column_stack([m1[:, 0] - m1[:, 1], m1[:, 2] - m1[:, 1]])
            for j in np.flatnonzero(score > 0.02):
                cands.append((int(xs[j]), int(ys[j]), sw, sh, float(score[j]), float(change[j]), float(drift[j]),
                              float(tex[j]), float(clip[j]), float(dark[j]), chroma[j], float(rank[j])))
    return cands


def _choose(cands: list[tuple], count: int, factor: float, fw: int, fh: int) -> list[Proposal]:
    """The ``count`` best windows, greedily best first without overlaps, each candidate's score multiplied by its
    chromatic distance to those already chosen; rectangles in full-resolution pixels (``factor`` per thumbnail pixel)
    inside the ``fw`` × ``fh`` image."""
    cands.sort(key=lambda c: -c[11])
    cands = cands[:5000]
    box = np.array([c[:4] for c in cands])
    base = np.array([c[11] for c in cands])
    chroma = np.array([c[10] for c in cands])
    alive = np.ones(len(cands), dtype=bool)
    div = np.ones(len(cands))
    chosen: list[Proposal] = []
    while len(chosen) < count and alive.any():
        eff = np.where(alive, base * div, -1.0)
        j = int(np.argmax(eff))
        if eff[j] <= 0.01:
            break
        c = cands[j]
        x0, y0 = math.ceil(c[0] * factor), math.ceil(c[1] * factor)
        x1, y1 = min(fw, math.floor((c[0] + c[2]) * factor)), min(fh, math.floor((c[1] + c[3]) * factor))
        chosen.append(Proposal(x0, y0, x1 - x0, y1 - y0, round(c[4], 4), {
            "change": round(c[5], 4), "drift": round(c[6], 4), "texture": round(c[7], 4), "clipped": round(c[8], 4),
            "dark": round(c[9], 5), "chroma": [round(float(v), 4) for v in c[10]], "diversity": round(float(div[j]), 4),
        }))
        # No overlaps (one surface, one region; a gap of a thumbnail pixel keeps edges apart).
        bx, by, bw, bh = box[:, 0], box[:, 1], box[:, 2], box[:, 3]
        overlap = (bx < c[0] + c[2] + 1) & (bx + bw + 1 > c[0]) & (by < c[1] + c[3] + 1) & (by + bh + 1 > c[1])
        alive &= ~overlap
        d2 = ((chroma - c[10]) ** 2).sum(axis=1)
        div = np.minimum(div, 1.0 - np.exp(-0.5 * d2 / CHROMA_SIGMA**2))
    return chosen


def preview_jpeg(thumb: Thumbnail, quality: int = 85) -> bytes:
    """A thumbnail as an sRGB JPEG for the regions page (exposure normalised so its 99th percentile is near white)."""
    lin = thumb.linear
    top = float(np.percentile(lin, 99)) or 1.0
    enc = ResponseCurve("srgb", white_level=255).encode(np.clip(lin / top * 0.9, 0, 1))
    ok, buf = cv2.imencode(".jpg", np.round(enc[:, :, ::-1]).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("thumbnail could not be encoded")
    return buf.tobytes()
