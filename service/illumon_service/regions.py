"""Robust region statistics of a decoded frame (decoding: :mod:`.decode`).

A frame's region value is the mean linear camera value of its pixels after removing

* clipped pixels (any channel at or above ``clip_fraction`` of the white level), whose true value is unknown, and
* outliers — passers-by, vehicles, birds — found by median / MAD trimming: pixels more than ``k`` robust standard
  deviations (1.4826 · MAD, floored at a small fraction of the median) from the per-channel median in any channel are
  dropped, twice (median and MAD from at most ~1024 strided pixels of the region).

A region is missing for the frame (``None``) when fewer than ``min_fraction`` of its pixels survive: mostly clipped or
mostly occluded. Images are PNG, JPEG or TIFF, 8- or 16-bit, RGB (grey frames are refused), decoded by OpenCV;
black and white levels of the camera's response are in the image's units (a white level ≤ 255 given for a 16-bit image
is scaled by 257).

Integer images take :func:`_region_means_cv` (OpenCV on each region's pixels, the GIL released; all regions' medians
and MADs at once), which gives the values of the per-region numpy reference :func:`_robust_mean_codes`
(``_PER_REGION``); float images take :func:`_robust_mean`. A JPEG may be decoded at 1/2, 1/4 or 1/8 size
(:func:`.decode.jpeg_reduction`, :func:`.decode.decode_frame`); :func:`region_means` then maps the regions onto the
decoded pixels, weighting those a region cuts by the fraction inside it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import cv2
import numpy as np
from illumon.camera import ResponseCurve
from numpy.typing import NDArray

__all__ = ["RegionError", "Region", "region_means", "region_stats", "response_for", "clip_level", "clipped_regions"]


MeanSE = tuple[NDArray[np.float64], NDArray[np.float64]]
"""A region's mean linear r g b and its standard error (pixel standard deviation over √pixels)."""

_PER_REGION = False
"""Use the per-region numpy path (:func:`_robust_mean_codes`; kept as the reference of :func:`_region_means_cv`)."""

MEDIAN_SAMPLES = 1024
"""Pixels used for a region's median and MAD (an even stride over the region; the mean uses every kept pixel). The
median of 1024 samples is within ~0.04 σ of the region's: plenty for thresholds at 3.5 σ."""


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


def response_for(response: Mapping, full_scale: float) -> ResponseCurve:
    """The camera's :class:`ResponseCurve` in the units of an image whose full scale is ``full_scale``."""
    black = float(response.get("black_level") or 0.0)
    white = response.get("white_level")
    white = full_scale if white is None else float(white)
    if full_scale > 255 and white <= 255:
        black, white = black * 257.0, white * 257.0
    return ResponseCurve(encoding=response.get("encoding", "linear"), gamma=float(response.get("gamma") or 2.2),
                         black_level=black, white_level=white, table=tuple(response.get("table") or ()))


def clip_level(response: ResponseCurve, clip_fraction: float) -> float:
    """The code at and above which a pixel counts as clipped: ``clip_fraction`` of the way from black to white."""
    return response.black_level + clip_fraction * (response.white_level - response.black_level)


def clipped_regions(image: NDArray, regions: Iterable[Region], response: ResponseCurve, clip_fraction: float) -> set[str]:
    """Ids of the regions with at least one pixel at the clip level (:func:`clip_level`) in any channel."""
    level = clip_level(response, clip_fraction)
    return {r.id for r in regions if image[r.y : r.y + r.height, r.x : r.x + r.width].max() >= level}


@lru_cache(maxsize=32)
def _lut(response: ResponseCurve, size: int) -> NDArray[np.float64]:
    """Linear value of every code of an integer image (256 or 65536 entries): linearising becomes a lookup."""
    return response.linearise(np.arange(size, dtype=float))


def _robust_mean(lin: NDArray[np.float64], k: float, min_keep: int) -> MeanSE | None:
    """Mean (and standard error) of the pixels (3 × N, channel-major for fast medians) within ``k`` robust σ of the
    median, trimmed twice.

    The general path, for float images; integer images take :func:`_robust_mean_codes` (same result).
    """
    keep = np.ones(lin.shape[1], dtype=bool)
    for _ in range(2):
        if keep.sum() < min_keep:
            return None
        sub = lin if keep.all() else lin[:, keep]
        # Median and MAD from at most ~1024 evenly strided pixels: as robust, and regions can be large.
        sub = np.ascontiguousarray(sub[:, :: max(1, sub.shape[1] // MEDIAN_SAMPLES)])
        med = np.median(sub, axis=1, keepdims=True)
        mad = np.median(np.abs(sub - med), axis=1, keepdims=True)
        scale = np.maximum(1.4826 * mad, 0.02 * np.abs(med) + 1e-4)
        keep = np.all(np.abs(lin - med) <= k * scale, axis=0)
    if keep.sum() < min_keep:
        return None
    return _mean_se(lin[:, keep])


def _code_width(lut: NDArray[np.float64], med: NDArray[np.float64]) -> NDArray[np.float64]:
    """Linear width of one code at ``med`` (the larger of the gaps to its neighbouring codes in the lookup table).

    The trimming scale is at least this: when the pixels' noise is below a code (a clean 8-bit region), the robust
    σ from the MAD is 0 or a fraction of a code, and trimming at ``k`` such σ keeps only the median code, so the
    region's mean becomes its median code, off by up to half a code (seen on the image-based simulator,
    ``benchmarks/imgsim.py``, where dark linear 8-bit regions read as a tone curve). ``k`` codes either side are kept.
    """
    i = np.clip(np.searchsorted(lut, med, side="left"), 0, lut.size - 1)
    up = lut[np.minimum(i + 1, lut.size - 1)] - lut[i]
    down = lut[i] - lut[np.maximum(i - 1, 0)]
    return np.maximum(up, down)


def _mean_se(kept: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean and standard error (sample standard deviation over √n) per channel of kept pixels (3 × n)."""
    n = kept.shape[1]
    return kept.mean(axis=1), kept.std(axis=1) / math.sqrt(n)


def _mad_8bit(codes: NDArray[np.uint8], lut: NDArray[np.float64], med: NDArray[np.float64], half: int) -> NDArray[np.float64]:
    """Upper median of ``|lut[codes] − med|`` per channel (3 × m codes) from a 256-bin histogram.

    8-bit samples hold few distinct values, on which ``np.partition`` is slow; sorting 256 deviations is not.
    """
    counts = np.bincount((codes.astype(np.intp) + (np.arange(3) * 256)[:, None]).ravel(), minlength=768).reshape(3, 256)
    dev = np.abs(lut[None, :] - med[:, None])  # 3 × 256
    order = np.argsort(dev, axis=1, kind="stable")
    cum = np.cumsum(np.take_along_axis(counts, order, axis=1), axis=1)
    pos = np.minimum((cum <= half).sum(axis=1), 255)  # first sorted deviation whose cumulative count exceeds half
    return np.take_along_axis(dev, np.take_along_axis(order, pos[:, None], axis=1), axis=1)[:, 0]


def _robust_mean_codes(codes: NDArray, lut: NDArray[np.float64], k: float, min_keep: int) -> MeanSE | None:
    """:func:`_robust_mean` on integer codes (3 × N, channel-major) of an image linearised by the monotone ``lut``.

    Only the ≤ 1024 sampled pixels are linearised for the median and MAD; the interval ``median ± k·scale`` in linear
    light becomes an interval of codes (the lookup table is non-decreasing), so the trimming compares small integers
    and only the kept pixels are linearised for the mean. Channel-major layout keeps every test elementwise.
    """
    n = codes.shape[1]
    keep: NDArray[np.bool_] | None = None  # None: every pixel
    top = np.iinfo(codes.dtype).max
    for _ in range(2):
        idx = None if keep is None else np.flatnonzero(keep)
        nk = n if idx is None else idx.size
        if nk < min_keep:
            return None
        step = max(1, nk // MEDIAN_SAMPLES)
        sample = codes[:, ::step] if idx is None else np.take(codes, idx[::step], axis=1)  # 3 × m codes
        # (Upper) medians: the codes sorted (radix sort of small integers), the median code linearised (the table is
        # monotone); the MAD by one partition of the linear deviations. Several times cheaper than np.median.
        ordered = np.sort(sample, axis=1, kind="stable")
        half = ordered.shape[1] // 2
        med = lut[ordered[:, half]]
        if lut.size <= 256:
            mad = _mad_8bit(ordered, lut, med, half)
        else:
            mad = np.partition(np.abs(np.take(lut, ordered) - med[:, None]), half, axis=1)[:, half]
        scale = np.maximum(np.maximum(1.4826 * mad, 0.02 * np.abs(med) + 1e-4), _code_width(lut, med))
        lo = np.searchsorted(lut, med - k * scale, side="left")  # first code with lut ≥ med − kσ
        hi = np.searchsorted(lut, med + k * scale, side="right") - 1  # last code with lut ≤ med + kσ
        if np.any(lo > hi) or np.any(lo > top) or np.any(hi < 0):
            return None
        keep = (codes[0] >= lo[0]) & (codes[0] <= hi[0])
        for c in (1, 2):
            keep &= (codes[c] >= codes.dtype.type(lo[c])) & (codes[c] <= codes.dtype.type(hi[c]))
    if np.count_nonzero(keep) < min_keep:
        return None
    return _mean_se(np.take(lut, codes.compress(keep, axis=1)))  # compress/take: ~4× faster than [:, mask]


def _sample_stats(
    samples: list[NDArray], lut: NDArray[np.float64], top: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Upper median and upper-median absolute deviation, in linear light, of every region's median samples.

    ``samples`` holds one ``m × 3`` array of integer codes per region (``m ≥ 1``, or 0 for a region no longer
    computed, whose statistics are then meaningless); returns two ``3 × R`` arrays, exactly the values
    :func:`_robust_mean_codes` computes region by region. The codes are sorted (a radix sort of small integers), so
    the median is the linearised middle code (the lookup table is non-decreasing). For the MAD, the pixels within
    ``t`` of the median are a run of consecutive sorted samples and, ``|v − median|`` being convex, a run's largest
    deviation is at one of its ends: the ``(h+1)``-th smallest deviation (``h = m // 2``) is therefore the smallest,
    over runs ``s … s+h``, of ``max(|v_s − median|, |v_{s+h} − median|)`` — elementwise, no partition needed.
    """
    nreg = len(samples)
    m = np.array([s.shape[0] for s in samples])
    half = m // 2
    width = max(1, int(m.max()))
    same = bool(np.all(m == width))  # the usual case: regions of one size, nothing dropped or the same count kept
    if same:
        codes = np.stack(samples, axis=0).transpose(2, 0, 1)  # 3 × R × m
    else:
        codes = np.full((3, nreg, width), top, dtype=samples[0].dtype)  # padding with the top code sorts last
        for r, s in enumerate(samples):
            codes[:, r, : s.shape[0]] = s.T
    codes = np.sort(codes, axis=2, kind="stable")
    # Run starts s ≤ h and ends s + h ≥ h: below the median, med − v is |v − med| (bit for bit), above, v − med.
    if same:  # runs s … s + h, s = 0 … m − 1 − h
        h = int(half[0])
        med = lut.take(codes[..., h : h + 1])  # 3 × R × 1
        dev = lut.take(codes[..., : width - h])
        np.subtract(med, dev, out=dev)
        upper = lut.take(codes[..., h:])
        upper -= med
        np.maximum(dev, upper, out=dev)
        return med[..., 0], dev.min(axis=2)
    med = lut[np.take_along_axis(codes, half[None, :, None], axis=2)[..., 0]][..., None]  # 3 × R × 1
    runs = width - int(half.min())  # the longest range of run starts; a region's runs beyond m − 1 − h are masked
    ends = np.minimum(np.arange(runs)[None, :] + half[:, None], width - 1)  # R × runs
    ends = np.broadcast_to(ends, codes.shape[:2] + (runs,))
    dev = np.abs(lut.take(codes[..., :runs]) - med)  # abs: the masked runs may pass the median
    np.maximum(dev, np.abs(lut.take(np.take_along_axis(codes, ends, axis=2)) - med), out=dev)
    dev[:, np.arange(runs)[None, :] > (m - 1 - half)[:, None]] = np.inf
    return med[..., 0], dev.min(axis=2)


def _kept_mean(
    crop: NDArray, mask: NDArray[np.uint8] | None, lut: NDArray[np.float64], weight: NDArray[np.float64] | None,
    min_weight: float,
) -> MeanSE | None:
    """Mean linear value and its standard error, per channel of ``crop`` (h × w × 3 codes), of the pixels where
    ``mask`` is non-zero.

    The codes are linearised through the lookup table (``cv2.LUT`` for 8-bit, ``np.take`` for 16-bit codes) and
    averaged by ``cv2.meanStdDev`` with double accumulators; the standard error is the pixels' standard deviation
    over √count. With ``weight`` (h × w, each pixel's share of the region, see :func:`_decoded_regions`) mean and
    variance are weighted (the count becomes the effective ``(Σw)²/Σw²``), and ``None`` when the kept pixels weigh
    less than ``min_weight``.
    """
    lin = cv2.LUT(crop, lut) if lut.size <= 256 else lut.take(crop)
    count = crop.shape[0] * crop.shape[1] if mask is None else cv2.countNonZero(mask)
    if weight is None:
        mean, sd = cv2.meanStdDev(lin, mask=mask)
        return mean[:3, 0], sd[:3, 0] / math.sqrt(max(count, 1))
    kept = cv2.mean(weight, mask)[0]  # mean weight of the kept pixels: Σ w / count
    if kept * count < min_weight:
        return None
    wl = lin * weight[..., None]
    mean = np.array(cv2.mean(wl, mask)[:3]) / kept
    second = np.array(cv2.mean(wl * lin, mask)[:3]) / kept
    n_eff = kept**2 * count / max(cv2.mean(weight * weight, mask)[0], 1e-300)  # (Σw)² / Σw²
    return mean, np.sqrt(np.maximum(second - mean**2, 0.0) / max(n_eff, 1.0))


def _region_means_cv(
    image: NDArray, regions: list[Region], lut: NDArray[np.float64], clip_code: int, k: float, min_fraction: float,
    weights: list[NDArray[np.float64] | None] | None = None,
) -> list[MeanSE | None]:
    """:func:`_robust_mean_codes` of every region of an integer image (same values, region for region), fast.

    ``image`` (h × w × 3, uint8 or uint16) must have contiguous pixels (channel stride = item size), in any channel
    order: the lookup table is the same for every channel, so the means come out in the image's channel order. The
    bulk work runs in OpenCV on each region's view, without copies and with the GIL released: one ``cv2.inRange``
    per trimming pass gives the kept pixels (clipping folded in: a pixel is kept when every channel lies in
    ``[lo, min(hi, clip − 1)]``), ``cv2.countNonZero`` their number, and the final mean is ``cv2.mean`` of the
    linearised codes. Python only handles the
    ≤ ~1024 strided median samples of each region (gathered from the kept pixels' flat indices), whose medians and
    MADs are computed for all regions at once (:func:`_sample_stats`). ``weights`` (per region, ``None`` or each
    pixel's share of it) weight the final mean and the ``min_fraction`` test of a region decoded at reduced size
    whose edges cut decoded pixels; medians and trimming treat its pixels alike.
    """
    nreg = len(regions)
    top = int(np.iinfo(image.dtype).max)
    cap = min(clip_code - 1, top)  # highest unclipped code
    # Contiguous copies of the crops (a memcpy per row): flat pixel indices then address them directly.
    crops = [np.ascontiguousarray(image[r.y : r.y + r.height, r.x : r.x + r.width]) for r in regions]
    pixels = [c.reshape(-1, 3) for c in crops]
    sizes = [r.width * r.height for r in regions]
    min_keep = [max(1, math.ceil(min_fraction * n)) for n in sizes]
    masks: list[NDArray[np.uint8] | None] = [None] * nreg  # None: every pixel kept
    counts = list(sizes)
    if cap < top:
        for r, crop in enumerate(crops):
            if crop.max() > cap:  # some pixel clipped (the maximum is ~8× cheaper than the mask)
                masks[r] = cv2.inRange(crop, (0, 0, 0), (cap, cap, cap))
                counts[r] = cv2.countNonZero(masks[r])
    alive = [c >= mk for c, mk in zip(counts, min_keep, strict=True)]
    empty = np.zeros((0, 3), image.dtype)
    for _ in range(2):
        samples = []
        for r in range(nreg):
            if not alive[r]:
                samples.append(empty)
                continue
            step = max(1, counts[r] // MEDIAN_SAMPLES)
            mask = masks[r]
            if mask is None or counts[r] == sizes[r]:
                samples.append(pixels[r][::step])
            else:  # the kept pixels' flat indices, every step-th of them
                samples.append(pixels[r].take(mask.reshape(-1).view(bool).nonzero()[0][::step], axis=0))
        med, mad = _sample_stats(samples, lut, top)
        scale = np.maximum(np.maximum(1.4826 * mad, 0.02 * np.abs(med) + 1e-4), _code_width(lut, med))
        lo = np.searchsorted(lut, med - k * scale, side="left").T.tolist()  # R × 3: first code with lut ≥ med − kσ
        hi = np.minimum(np.searchsorted(lut, med + k * scale, side="right") - 1, cap).T.tolist()  # last ≤ med + kσ
        for r in range(nreg):
            if not alive[r]:
                continue
            lo_r, hi_r = lo[r], hi[r]
            if lo_r[0] > hi_r[0] or lo_r[1] > hi_r[1] or lo_r[2] > hi_r[2]:
                alive[r] = False
                continue
            masks[r] = cv2.inRange(crops[r], tuple(lo_r), tuple(hi_r))
            counts[r] = cv2.countNonZero(masks[r])
            alive[r] = counts[r] >= min_keep[r]
    weights = weights or [None] * nreg
    return [_kept_mean(crops[r], masks[r], lut, weights[r], 0.0 if weights[r] is None else min_fraction * weights[r].sum())
            if alive[r] else None for r in range(nreg)]


def _decoded_regions(regions: list[Region], scale: int) -> tuple[list[Region], list[NDArray[np.float64] | None]]:
    """``regions`` (full-resolution pixels) on an image decoded at 1/``scale`` size, and their pixels' weights.

    Decoded pixel ``j`` covers full-resolution pixels ``j·s … j·s + s − 1``; a region keeps every decoded pixel it
    touches, each weighted by the fraction of it inside the region (``None``: edges on the grid, all weights 1).
    """
    out, weights = [], []
    for r in regions:
        x0, y0 = r.x // scale, r.y // scale
        x1, y1 = -(-(r.x + r.width) // scale), -(-(r.y + r.height) // scale)
        out.append(Region(r.id, x0, y0, x1 - x0, y1 - y0))
        if (r.x % scale, r.y % scale, r.width % scale, r.height % scale) == (0, 0, 0, 0):
            weights.append(None)
            continue

        def cover(a: int, b: int, lo: int, hi: int) -> NDArray[np.float64]:
            j = np.arange(a, b)
            return (np.minimum((j + 1) * scale, hi) - np.maximum(j * scale, lo)) / scale

        weights.append(np.outer(cover(y0, y1, r.y, r.y + r.height), cover(x0, x1, r.x, r.x + r.width)))
    return out, weights


def region_means(
    image: NDArray, regions: Iterable[Region], response: ResponseCurve, **kwargs: Any
) -> dict[str, list[float] | None]:
    """Robust mean linear RGB (0…1) of each region (:func:`region_stats` without the standard errors)."""
    return {k: None if v is None else v[0] for k, v in region_stats(image, regions, response, **kwargs).items()}


def region_stats(
    image: NDArray,
    regions: Iterable[Region],
    response: ResponseCurve,
    *,
    clip_fraction: float = 0.98,
    min_fraction: float = 0.5,
    k: float = 3.5,
    scale: int = 1,
    size: tuple[int, int] | None = None,
) -> dict[str, tuple[list[float], list[float]] | None]:
    """Robust mean linear RGB (0…1) of each region and its standard error, ``None`` where the region is mostly clipped
    or occluded.

    The standard error is the kept pixels' standard deviation over √count: the noise of the mean when the pixels'
    spread is noise, an upper bound when it is partly the surface's own (static) texture.

    ``image`` may be decoded at 1/``scale`` of the full resolution (:func:`.decode.jpeg_reduction`); ``regions`` are always
    in full-resolution pixels and ``size`` is the full-resolution (width, height) (default: the image's × scale).
    The means are then those of the decoded pixels a region touches, weighted by their share of it; a decoded pixel
    is close to the mean of the codes it replaces, so its linear value differs from the mean of theirs by a
    (Jensen) term of the order of the response curve's curvature times the codes' variance within the pixel.
    Raises :class:`RegionError` if a region extends beyond the image.
    """
    h, w = image.shape[:2]
    if size is not None:
        w, h = size
    elif scale > 1:
        w, h = w * scale, h * scale
    integer = image.dtype in (np.uint8, np.uint16)
    lut = _lut(response, 256 if image.dtype == np.uint8 else 65536) if integer else None
    clip_at = clip_level(response, clip_fraction)
    regions = list(regions)
    for r in regions:
        if r.x < 0 or r.y < 0 or r.x + r.width > w or r.y + r.height > h:
            raise RegionError(
                f"region {r.id!r} ({r.x},{r.y} {r.width}×{r.height}) lies outside the {w}×{h} image"
            )
    weights: list[NDArray[np.float64] | None] | None = None
    if scale > 1:
        regions, weights = _decoded_regions(regions, scale)
        if not integer or (_PER_REGION and any(wt is not None for wt in weights)):
            raise ValueError("a reduced-resolution decode needs an integer image (and, for the reference path, regions on "
                             "the decoded pixel grid)")
    if integer and regions and not _PER_REGION:
        limit = min(int(np.ceil(clip_at)), np.iinfo(image.dtype).max + 1)
        if limit <= 0:  # every code clipped
            return {r.id: None for r in regions}
        # Work in the pixels' memory order: OpenCV decodes BGR and decode_image returns a reversed view of it.
        item = image.dtype.itemsize
        flip = image.strides[2] == -item
        base = image[:, :, ::-1] if flip else image  # any other layout: each crop is copied to contiguous pixels
        stats = _region_means_cv(base, regions, lut, limit, k, min_fraction, weights)
        return {r.id: None if m is None else (_floats(m[0], flip), _floats(m[1], flip))
                for r, m in zip(regions, stats, strict=True)}
    return _region_stats_per_region(image, regions, response, lut, clip_at, k, min_fraction)


def _region_stats_per_region(image: NDArray, regions: list[Region], response: ResponseCurve,
                             lut: NDArray[np.float64] | None, clip_at: float, k: float, min_fraction: float
                             ) -> dict[str, tuple[list[float], list[float]] | None]:
    """:func:`region_stats` region by region in numpy (the reference path, and the path of float images); ``lut``:
    the response's lookup table for an integer image, ``None`` for a float one."""
    integer = lut is not None
    out: dict[str, tuple[list[float], list[float]] | None] = {}
    for r in regions:
        block = image[r.y : r.y + r.height, r.x : r.x + r.width]
        n = r.width * r.height
        min_keep = max(1, int(np.ceil(min_fraction * n)))
        if integer:
            codes = np.moveaxis(block, 2, 0).reshape(3, n)  # channel-major copy: elementwise tests, no axis-1 reductions
            # Integer codes: a pixel is clipped when any channel reaches ceil(clip_at).
            limit = min(int(np.ceil(clip_at)), np.iinfo(image.dtype).max + 1)
            if limit <= np.iinfo(image.dtype).max:
                c = image.dtype.type(limit)
                ok = (codes[0] < c) & (codes[1] < c) & (codes[2] < c)
                n_ok = int(np.count_nonzero(ok))
                if n_ok < min_keep:
                    out[r.id] = None
                    continue
                if n_ok < n:
                    codes = codes.compress(ok, axis=1)
            m = _robust_mean_codes(codes, lut, k, min_keep)
        else:
            px = block.reshape(-1, 3)
            ok = ~np.any(px >= clip_at, axis=1)
            if ok.sum() < min_keep:
                out[r.id] = None
                continue
            m = _robust_mean(response.linearise(np.ascontiguousarray(px[ok].T)), k, min_keep)
        out[r.id] = None if m is None else (_floats(m[0]), _floats(m[1]))
    return out


def _floats(v: NDArray[np.float64], flip: bool = False) -> list[float]:
    return [float(x) for x in (v[::-1] if flip else v)]
