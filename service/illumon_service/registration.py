"""Keeping regions on their surfaces when the view moves (a PTZ preset, a knocked or re-aimed camera): registration
of each frame to its view's reference frame, per-view regions, and frame thumbnails on disk.

Each camera view (``view`` form field of an upload, a PTZ preset id; ``None`` for a fixed camera) has a *reference
frame*: the thumbnail (:mod:`.proposals`) of the first frame stored for that view, kept as
``<data dir>/thumbs/camera-<id>/reference-<view>.png``. Regions and proposals are in the reference frame's pixels.
Every new frame's thumbnail is registered to it by phase correlation (``cv2.phaseCorrelate``; Kuglin & Hines, "The
phase correlation image alignment method", IEEE Cybernetics and Society 1975) of log-grey images under a Hanning
window, the reference weighted towards its static areas (the view's regions and their surroundings, when it has
regions). The shift (full-resolution pixels, content moved right/down positive) moves the regions with the frame when
it is within :data:`MAX_SHIFT_FRACTION` of the image side and the correlation peak is clear
(:data:`MIN_RESPONSE`); otherwise the frame is a *view change*: it is stored (with its thumbnail) but not measured nor
estimated, and the status page and the camera's JSON raise the ``view_change`` alert. ``PUT …/regions?reference=latest``
re-anchors a view on its latest frame after the camera was moved for good.
"""

from __future__ import annotations

import os
import re
import threading
from dataclasses import dataclass
from datetime import datetime, timedelta
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from illumon.camera import ResponseCurve
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from . import crud
from .datafiles import data_file
from .decode import DecodedFrame
from .proposals import KEEP_RECENT, Thumbnail, load_thumbnail, save_thumbnail, thumbnail_grey
from .regions import Region, region_stats
from .storage import Camera, Frame, as_utc

__all__ = [
    "MAX_SHIFT_FRACTION", "MIN_RESPONSE", "MIN_STRUCTURE", "MATCH_SCORE", "match_score",
    "Registration", "thumbs_dir", "reference_path", "view_key",
    "parse_view", "register_frame", "shift_regions", "measure_shifted", "prune_thumbnails", "set_reference",
    "view_thumbnails", "phase_shift", "thumbnail_due", "THUMB_EVERY",
]

MAX_SHIFT_FRACTION = 0.05
"""Largest shift (of the image width in x, of its height in y) regions follow; beyond it the view changed."""
MIN_RESPONSE = 0.15
"""Smallest phase-correlation peak (``cv2.phaseCorrelate``'s response, 0…1) accepted as a registration (chosen on
the development scenes of ``benchmarks/regions_setup.py``: frames of the same view shifted by up to ±20 px and
under other daylight peak at 0.72 or more and register within 0.21 px; another scene of the same layout peaks at
0.012…0.052)."""

MATCH_SCORE = 0.25
"""Smallest :func:`match_score` at which a frame whose correlation peak is weak still counts as the reference's view
(measured with its regions in place, registration ``uncertain``). Chosen on rendered scenes: the same view under
other light scores ≥ 0.34 even with sensor noise that drowns the phase correlation (peaks 0.0–0.15: a cluttered,
low-contrast background), a 100 px jump ≤ 0.15 and another scene of the same layout ≤ 0.17."""
MATCH_BLUR = 1.5
"""Gaussian blur (thumbnail pixels) applied before :func:`match_score`: averages sensor noise, keeps the scene's
structure."""

THUMB_EVERY = timedelta(minutes=10)
"""A view keeps at most one new thumbnail per this much frame time (and one at every change of view state)."""
MIN_STRUCTURE = 0.02
"""Standard deviation of a thumbnail's log grey below which it is featureless and is not registered."""

_VIEW = re.compile(r"^[A-Za-z0-9_.:-]{1,64}$")


@dataclass(frozen=True)
class Registration:
    """Where a frame lies relative to its view's reference frame."""

    state: str
    """``reference`` (this frame became the reference), ``ok`` (registered), ``uncertain`` (a weak correlation peak,
    but the frame still matches the reference with its regions where they were, or at a shift they follow: measured
    there), ``featureless`` (nothing to register on: regions left in place) or ``view_change`` (positive evidence:
    the frame matches the reference neither where the regions were nor at a shift they could follow)."""
    shift: tuple[float, float]
    """(dx, dy) in full-resolution pixels: the scene moved by this much in the image."""
    response: float | None
    """Phase-correlation peak (``None`` for the reference itself)."""
    match: float | None = None
    """Where the peak was weak or the shift too large: the frame's match with the reference at the shift used
    (:func:`match_score`); ``None`` when not needed."""

    def as_dict(self) -> dict:
        """JSON form (stored with the frame)."""
        out = {"state": self.state, "shift": [round(self.shift[0], 2), round(self.shift[1], 2)],
               "response": None if self.response is None else round(self.response, 4)}
        if self.match is not None:
            out["match"] = self.match
        return out


def parse_view(text: str | None) -> str | None:
    """A ``view`` form field (preset id: 1…64 letters, digits, ``_ . : -``) or ``None``; ``ValueError`` otherwise."""
    if text is None or not text.strip():
        return None
    text = text.strip()
    if not _VIEW.match(text):
        raise ValueError(f"view {text!r}: expected a preset id of 1…64 letters, digits, '_', '.', ':' or '-'")
    return text


def view_key(view: str | None) -> str:
    """File-name key of a view."""
    return "default" if view is None else f"v-{view}"


def thumbs_dir(data_dir: Path | str, camera_id: int) -> Path:
    """Folder of a camera's thumbnails and reference frames."""
    return Path(data_dir) / "thumbs" / f"camera-{camera_id}"


def reference_path(data_dir: Path | str, camera_id: int, view: str | None) -> Path:
    """The view's reference-frame thumbnail."""
    return thumbs_dir(data_dir, camera_id) / f"reference-{view_key(view)}.png"


def _weights(ref: Thumbnail, regions: list[dict]) -> np.ndarray:
    """Weights of the reference's pixels: a Hanning window, times 1 on and around the regions (static surfaces and
    their neighbours), 0.2 elsewhere (sky, foliage and passers-by lie off the regions)."""
    h, w = ref.unclipped.shape
    win = cv2.createHanningWindow((w, h), cv2.CV_32F)
    if not regions:
        return win
    static = np.full((h, w), 0.2, np.float32)
    f = ref.factor
    for r in regions:
        mx, my = r["width"] / 2, r["height"] / 2
        x0, y0 = int(max(0, (r["x"] - mx) / f)), int(max(0, (r["y"] - my) / f))
        x1, y1 = int(min(w, (r["x"] + r["width"] + mx) / f + 1)), int(min(h, (r["y"] + r["height"] + my) / f + 1))
        static[y0:y1, x0:x1] = 1.0
    return win * static


def _prepared_reference(ref: Thumbnail, regions: list[dict]) -> NDArray[np.float32]:
    """The reference's log grey, mean removed and weighted by :func:`_weights` (cached with the reference)."""
    a = thumbnail_grey(ref)
    wts = _weights(ref, regions)
    return ((a - float((a * wts).sum() / wts.sum())) * wts).astype(np.float32)


def phase_shift(ref: Thumbnail, thumb: Thumbnail, regions: list[dict],
                prepared: NDArray[np.float32] | None = None) -> tuple[float, float, float]:
    """(dx, dy, response): the shift of ``thumb``'s content relative to ``ref`` in full-resolution pixels, by phase
    correlation of the mean-removed log-grey images (``ref`` weighted by :func:`_weights`; ``prepared``: that image
    already computed)."""
    b = thumbnail_grey(thumb)
    if ref.unclipped.shape != b.shape:
        return 0.0, 0.0, 0.0
    a = _prepared_reference(ref, regions) if prepared is None else prepared
    b = cv2.multiply(cv2.subtract(b, float(cv2.mean(b)[0])), _hanning(b.shape))
    (dx, dy), response = cv2.phaseCorrelate(a, b)
    return float(dx) * ref.factor, float(dy) * ref.factor, float(response)


def match_score(ref: Thumbnail, thumb: Thumbnail, regions: list[dict], dx: float = 0.0, dy: float = 0.0) -> float:
    """How well ``thumb``, moved back by (``dx``, ``dy``) full-resolution pixels, matches the reference where the
    regions and their surroundings are: the weighted (:func:`_weights`) zero-mean normalised correlation of the two
    log-grey images after a :data:`MATCH_BLUR` blur (−1…1; 1: the same view). Unlike the phase-correlation peak,
    which weighs every spatial frequency alike and so drowns in sensor noise on a low-contrast background, it rests on
    the scene's coarse structure."""
    a = cv2.GaussianBlur(thumbnail_grey(ref), (0, 0), MATCH_BLUR)
    b = cv2.GaussianBlur(thumbnail_grey(thumb), (0, 0), MATCH_BLUR)
    if a.shape != b.shape:
        return -1.0
    if dx or dy:
        h, w = b.shape
        m = np.float32([[1, 0, -dx / ref.factor], [0, 1, -dy / ref.factor]])
        b = cv2.warpAffine(b, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    wts = _weights(ref, regions)
    total = float(wts.sum())
    da = a - float((a * wts).sum() / total)
    db = b - float((b * wts).sum() / total)
    den = float(np.sqrt((wts * da * da).sum() * (wts * db * db).sum()))
    return float((wts * da * db).sum() / den) if den > 0 else -1.0


@lru_cache(maxsize=16)
def _hanning(shape: tuple[int, int]) -> NDArray[np.float32]:
    return cv2.createHanningWindow((shape[1], shape[0]), cv2.CV_32F)


_REFERENCES: dict[str, tuple[int, Thumbnail]] = {}
_PREPARED: dict[str, tuple[Thumbnail, tuple, NDArray[np.float32]]] = {}
_REF_LOCK = threading.Lock()


def _reference(path: Path, width: int) -> Thumbnail | None:
    """The reference thumbnail at ``path``, read once per file version (``None`` when there is none)."""
    try:
        mtime = path.stat().st_mtime_ns
    except FileNotFoundError:
        return None
    with _REF_LOCK:
        hit = _REFERENCES.get(str(path))
    if hit is not None and hit[0] == mtime:
        return hit[1]
    ref = load_thumbnail(path, width)
    if ref is not None:
        with _REF_LOCK:
            if len(_REFERENCES) > 1024:
                _REFERENCES.clear()
                _PREPARED.clear()
            _REFERENCES[str(path)] = (mtime, ref)
    return ref


def register_frame(data_dir: Path | str, camera_id: int, view: str | None, thumb: Thumbnail,
                   regions: list[dict], size: tuple[int, int]) -> Registration:
    """Register ``thumb`` to its view's reference frame (the frame becomes the reference when there is none)."""
    path = reference_path(data_dir, camera_id, view)
    ref = _reference(path, size[0])
    if ref is None:
        if _claim_reference(path, thumb):
            return Registration("reference", (0.0, 0.0), None)
        ref = _reference(path, size[0])  # a concurrent first frame became the reference: register to it
    if ref is None or ref.unclipped.shape != thumb.unclipped.shape:
        save_thumbnail(path, thumb)
        return Registration("reference", (0.0, 0.0), None)
    if float(thumbnail_grey(thumb).std()) < MIN_STRUCTURE or float(thumbnail_grey(ref).std()) < MIN_STRUCTURE:
        # nothing to register on (fog, a flat image): no evidence that the view moved; regions stay where they are
        return Registration("featureless", (0.0, 0.0), None)
    key = tuple((r["x"], r["y"], r["width"], r["height"]) for r in regions)
    with _REF_LOCK:
        hit = _PREPARED.get(str(path))
    if hit is None or hit[0] is not ref or hit[1] != key:
        hit = (ref, key, _prepared_reference(ref, regions))
        with _REF_LOCK:
            _PREPARED[str(path)] = hit
    dx, dy, response = phase_shift(ref, thumb, regions, hit[2])
    within = abs(dx) <= MAX_SHIFT_FRACTION * size[0] and abs(dy) <= MAX_SHIFT_FRACTION * size[1]
    if response >= MIN_RESPONSE and within:
        return Registration("ok", (dx, dy), response)
    # No clear registration: a view change only on positive evidence. Where the regions were, does the frame still
    # look like the reference? And, for a shift regions could follow, does it there?
    in_place = match_score(ref, thumb, regions)
    moved = match_score(ref, thumb, regions, dx, dy) if within and (dx or dy) else -1.0
    if max(in_place, moved) >= MATCH_SCORE:
        if moved > in_place:
            return Registration("uncertain", (dx, dy), response, round(moved, 3))
        return Registration("uncertain", (0.0, 0.0), response, round(in_place, 3))
    return Registration("view_change", (dx, dy), response, round(max(in_place, moved), 3))


def _claim_reference(path: Path, thumb: Thumbnail) -> bool:
    """Make ``thumb`` the view's first reference frame unless another frame got there first: written to a private
    temporary file, then hard-linked into place (the link fails when the reference exists), so concurrent first
    frames of a camera agree on one reference and never share a temporary file."""
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.{threading.get_ident()}.claim.png")
    save_thumbnail(tmp, thumb)
    try:
        os.link(tmp, path)
        return True
    except FileExistsError:
        return False
    finally:
        tmp.unlink(missing_ok=True)


def set_reference(data_dir: Path | str, camera_id: int, view: str | None, thumb_file: str | None) -> bool:
    """Make a stored frame's thumbnail (``thumb_file``, its stored path) the view's reference frame (after the camera
    was moved for good)."""
    source = data_file(data_dir, thumb_file)
    if source is None or not source.is_file():
        return False
    path = reference_path(data_dir, camera_id, view)
    path.parent.mkdir(parents=True, exist_ok=True)
    from .datafiles import atomic_write

    atomic_write(path, source.read_bytes())
    return True


def shift_regions(regions: list[dict], reg: Registration, size: tuple[int, int]) -> tuple[list[Region], list[str]]:
    """The regions moved with the frame (whole pixels), and the ids of those the shift takes out of the image."""
    dx, dy = round(reg.shift[0]), round(reg.shift[1])
    inside, outside = [], []
    for r in regions:
        moved = Region(r["id"], r["x"] + dx, r["y"] + dy, r["width"], r["height"])
        if moved.x < 0 or moved.y < 0 or moved.x + moved.width > size[0] or moved.y + moved.height > size[1]:
            outside.append(r["id"])
        else:
            inside.append(moved)
    return inside, outside


def measure_shifted(frame: DecodedFrame, regions: list[dict], response: ResponseCurve, reg: Registration,
                    clip_fraction: float, min_fraction: float) -> tuple[dict, dict]:
    """Region means and their standard errors of a decoded frame (:func:`~.regions.region_stats`), the regions moved
    by the frame's registration shift; a region the shift takes out of the image is missing (``None``)."""
    moved, outside = shift_regions(regions, reg, frame.size)
    stats = region_stats(frame.image, moved, response, scale=frame.scale, size=frame.size,
                         clip_fraction=clip_fraction, min_fraction=min_fraction)
    stats.update({rid: None for rid in outside})
    patches = {r["id"]: None if stats[r["id"]] is None else stats[r["id"]][0] for r in regions}
    sd = {r["id"]: None if stats[r["id"]] is None else stats[r["id"]][1] for r in regions}
    return patches, sd


def thumbnail_due(session: Session, camera_id: int, view: str | None, taken_at: datetime,
                  reg: Registration | None) -> bool:
    """Whether a new frame's thumbnail is kept: when the view's latest kept one is :data:`THUMB_EVERY` away in time,
    or was registered otherwise (the first frame after a view change, or back), so a camera posting every few seconds
    writes one small file per ten minutes, not one per frame."""
    last = crud.last_thumbnail(session, camera_id, view)
    if last is None:
        return True
    moved = (last.registration or {}).get("state") == "view_change"
    if moved != (reg is not None and reg.state == "view_change"):
        return True
    return abs(taken_at - as_utc(last.taken_at)) >= THUMB_EVERY


def prune_thumbnails(session: Session, camera_id: int, view: str | None, data_dir: Path | str) -> None:
    """Keep a view's :data:`~.proposals.KEEP_RECENT` most recent thumbnails and the latest one of every hour of the
    day (UTC); delete the others' files (under ``data_dir``) and forget their paths (not committed)."""
    rows = crud.thumbnail_frames(session, camera_id, view)
    hours: set[int] = set()
    for i, f in enumerate(rows):
        hour = (as_utc(f.taken_at) or datetime.min).hour
        if i < KEEP_RECENT or hour not in hours:
            hours.add(hour)
            continue
        old = data_file(data_dir, f.thumb_path)
        if old is not None:
            old.unlink(missing_ok=True)
        f.thumb_path = None


def view_thumbnails(session: Session, cam: Camera, view: str | None, data_dir: Path | str, limit: int = 32
                    ) -> tuple[list[Thumbnail], list[Frame]]:
    """The kept thumbnails (under ``data_dir``) of a view's registered frames (newest first, at most ``limit``), each
    moved back by its stored shift into the reference frame's pixels, and their frames."""
    from .proposals import shifted

    rows = crud.thumbnail_frames(session, cam.id, view)
    thumbs, frames = [], []
    for f in rows:
        reg = f.registration or {}
        if reg.get("state") == "view_change" or not f.width:
            continue
        path = data_file(data_dir, f.thumb_path)
        t = None if path is None else load_thumbnail(path, f.width)
        if t is None or (thumbs and t.unclipped.shape != thumbs[0].unclipped.shape):
            continue
        dx, dy = reg.get("shift") or (0.0, 0.0)
        thumbs.append(shifted(t, -dx, -dy))
        frames.append(f)
        if len(thumbs) >= limit:
            break
    return thumbs, frames
