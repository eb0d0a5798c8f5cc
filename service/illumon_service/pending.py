"""Frames posted before a view has regions, so that an installer's first frames are not wasted: their original images
are kept, at most :attr:`~.settings.Settings.pending_max_frames` per camera view (the oldest dropped first), under
``<data dir>/pending/camera-<id>/<frame id>.<format>``, and measured with the regions once they are confirmed
(``PUT …/regions`` or the regions page); their files are deleted then. A frame whose original was dropped stays
stored without region values (its reason: ``no_regions``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from sqlalchemy.orm import Session

from . import crud
from .datafiles import atomic_write
from .settings import Settings
from .storage import Frame

__all__ = ["pending_dir", "pending_files", "keep_original", "measure_pending", "measure_original", "atomic_write"]


DEFAULT_MAX_BYTES = 512 * 1024 * 1024
"""Default bound on the bytes of a view's kept originals (:attr:`~.settings.Settings.pending_max_bytes`)."""


def pending_dir(data_dir: Path | str, camera_id: int) -> Path:
    """Folder of a camera's kept originals."""
    return Path(data_dir) / "pending" / f"camera-{camera_id}"


def pending_files(data_dir: Path | str, camera_id: int, frame_id: int) -> list[Path]:
    """The kept original of one frame (a list: empty when none is kept)."""
    folder = pending_dir(data_dir, camera_id)
    if not folder.is_dir():
        return []
    return [p for p in folder.glob(f"{frame_id}.*") if p.suffix in (".png", ".jpeg", ".tiff")]


def keep_original(session: Session, data_dir: Path | str, camera_id: int, view: str | None, frame_id: int,
                  data: bytes | bytearray, fmt: str, limit: int, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
    """Keep a frame's original image until its view has regions, and drop the originals of the view's older frames
    beyond ``limit`` files or ``max_bytes`` in all (the files only: the frames stay stored)."""
    if limit <= 0 or len(data) > max_bytes:
        return
    folder = pending_dir(data_dir, camera_id)
    atomic_write(folder / f"{frame_id}.{fmt}", data)
    kept = _kept_ids(folder)
    view_ids = sorted({f.id for f in crud.view_frames(session, camera_id, view, kept)} | {frame_id})
    sizes = {i: sum(p.stat().st_size for p in pending_files(data_dir, camera_id, i)) for i in view_ids}
    total = sum(sizes.values())
    for old in view_ids:  # oldest first
        if len(view_ids) <= limit and total <= max_bytes:
            break
        for p in pending_files(data_dir, camera_id, old):
            p.unlink(missing_ok=True)
        total -= sizes[old]
        view_ids = [i for i in view_ids if i != old]


def _kept_ids(folder: Path) -> list[int]:
    out = []
    for p in folder.glob("*.*"):
        stem = p.name.split(".", 1)[0]
        if stem.isdigit():
            out.append(int(stem))
    return sorted(out)


def measure_pending(session: Session, data_dir: Path | str, camera_id: int, view: str | None,
                    measure: Callable[[bytes, Frame], tuple[dict, dict] | None]) -> int:
    """Measure the view's kept originals with ``measure(image bytes, frame) → (patches, patch_sd)`` (``None``: the
    image could not be measured), store the values with their frames (committed) and delete the files. Returns the
    number of frames measured."""
    folder = pending_dir(data_dir, camera_id)
    if not folder.is_dir():
        return 0
    kept = _kept_ids(folder)
    if not kept:
        return 0
    frames = crud.view_frames(session, camera_id, view, kept)
    done, files = 0, []
    for f in frames:
        paths = pending_files(data_dir, camera_id, f.id)
        if not paths:
            continue
        files += paths
        if (f.registration or {}).get("state") == "view_change":
            continue
        out = measure(paths[0].read_bytes(), f)
        if out is None:
            continue
        f.patches, f.patch_sd = out
        f.not_estimated = "no_model" if sum(v is not None for v in f.patches.values()) >= 2 else "too_few_regions"
        done += 1
    session.commit()
    for p in files:
        p.unlink(missing_ok=True)
    return done


def measure_original(data: bytes, regions: list[dict], response: dict, registration: dict | None,
                     settings: Settings) -> tuple[dict, dict] | None:
    """Region means and standard errors of a kept original, its regions moved by the frame's stored registration
    shift (as at ingest); ``None`` when the image no longer decodes."""
    from .decode import ImageError, decode_frame
    from .regions import Region, response_for
    from .registration import Registration, measure_shifted

    try:
        frame = decode_frame(data, [Region(**r) for r in regions], max_pixels=settings.max_image_pixels,
                             max_bytes=settings.max_decoded_bytes)
    except ImageError:
        return None
    reg = registration or {}
    shift = reg.get("shift") or (0.0, 0.0)
    return measure_shifted(frame, regions, response_for(response, frame.full_scale),
                           Registration(str(reg.get("state") or "ok"), (float(shift[0]), float(shift[1])), None),
                           settings.clip_fraction, settings.min_region_fraction)
