"""Managing a camera's stored data: its regions (checked against the view's image), deleting a frame or a whole camera
with everything stored for it (admin), and a view's region proposals. Shared by the JSON routes and the regions page,
so they cannot differ."""

from __future__ import annotations

import shutil
from pathlib import Path

from fastapi import HTTPException
from sqlalchemy.orm import Session

from . import crud
from .limits import regions_outside
from .registration import reference_path, set_reference, thumbs_dir
from .settings import Settings
from .storage import Camera, Frame

__all__ = ["proposals_for", "MIN_HOURS",
           "save_regions", "save_regions_and_measure", "delete_frame", "delete_camera", "camera_files"]


def save_regions(session: Session, cam: Camera, regions: list[dict], view: str | None, data_dir: Path | str,
                 reference_latest: bool) -> None:
    """Replace a view's regions and commit (the one path of ``PUT …/regions`` and the regions page).

    Every region must lie inside the view's image (the size of its latest stored frame, when it has one): 422 naming
    the regions otherwise, so a typo cannot make the camera's later frames unusable. With ``reference_latest`` the
    view's latest frame becomes its reference frame (the camera was moved for good: the regions were drawn on that
    frame); 409 when the view has no stored frame thumbnail.
    """
    size = crud.view_size(session, cam.id, view)
    if size is None and view is None and getattr(cam, "image_size", None):
        size = (int(cam.image_size[0]), int(cam.image_size[1]))  # declared at registration, no frame yet
    outside = regions_outside(regions, size)
    if outside:
        shown = ", ".join(repr(r) for r in outside[:5]) + (" …" if len(outside) > 5 else "")
        raise HTTPException(422, f"region(s) {shown} lie outside the view's {size[0]}×{size[1]} image: regions are "
                                 "rectangles in the image's pixels (x + width ≤ image width, y + height ≤ height)")
    if reference_latest:
        latest = crud.latest_frame(session, cam.id, view, with_thumbnail=True)
        if latest is None or not set_reference(data_dir, cam.id, view, latest.thumb_path):
            raise HTTPException(409, "no stored frame of this view to take as the reference frame")
        latest.registration = {"state": "reference", "shift": [0.0, 0.0], "response": None}
    crud.set_view_regions(session, cam, view, regions)
    session.commit()


def save_regions_and_measure(session: Session, cam: Camera, regions: list[dict], view: str | None,
                             settings: Settings, reference_latest: bool) -> int:
    """:func:`save_regions`, then measure with the new regions the view's frames posted while it had none (their
    kept originals, :mod:`.pending`). Returns the number of frames measured."""
    save_regions(session, cam, regions, view, settings.data_dir, reference_latest)
    from .pending import measure_original, measure_pending

    return measure_pending(session, settings.data_dir, cam.id, view,
                           lambda data, frame: measure_original(data, regions, cam.response or {}, frame.registration,
                                                                settings))


def _frame_files(data_dir: Path | str, frame: Frame) -> list[Path]:
    """Files stored for one frame: its thumbnail, its kept image and its kept original (regions not yet confirmed)."""
    out = []
    from .datafiles import data_file
    from .pending import pending_files

    for stored in (frame.thumb_path, frame.image_path):
        p = data_file(data_dir, stored)  # never a file outside the data directory (a restored copy's original)
        if p is not None:
            out.append(p)

    out.extend(pending_files(data_dir, frame.camera_id, frame.id))
    return out


def delete_frame(session: Session, data_dir: Path | str, cam: Camera, frame_id: int) -> dict[str, int]:
    """Delete one stored frame of ``cam`` with its estimate and files (committed); 404 for a frame of another
    camera or none. Returns the rows deleted by kind."""
    frame = crud.frame_of(session, cam.id, frame_id)
    if frame is None:
        raise HTTPException(404, f"unknown frame {frame_id} of camera {cam.id}")
    files = _frame_files(data_dir, frame)
    estimates = crud.delete_frame(session, frame)
    for f in files:  # after the commit: a failed commit leaves the frame whole
        f.unlink(missing_ok=True)
    return {"frames": 1, "estimates": estimates}


def camera_files(data_dir: Path | str, camera_id: int) -> list[Path]:
    """Files and folders stored for a camera: thumbnails and reference frames, kept images and originals, scene
    models (every view, every version)."""
    data = Path(data_dir)
    out = [thumbs_dir(data, camera_id), data / "images" / f"camera-{camera_id}",
           data / "pending" / f"camera-{camera_id}"]
    models = data / "models"
    if models.is_dir():
        out += sorted(models.glob(f"camera-{camera_id}.*")) + sorted(models.glob(f"camera-{camera_id}-*"))
    return out


def delete_camera(session: Session, data_dir: Path | str, cam: Camera) -> dict:
    """Delete a camera and everything stored for it: frames, estimates, jobs, calibrations, views (database rows,
    committed together) and its files. Returns what was deleted (counts)."""
    counts = crud.delete_camera_rows(session, cam)
    for path in camera_files(data_dir, cam.id):
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    reference_path(data_dir, cam.id, None).unlink(missing_ok=True)
    return counts


MIN_HOURS = 3
"""Proposals from frames covering fewer hours of the day (UTC) than this carry a warning."""


def proposals_for(session: Session, cam: Camera, view: str | None, count: int, data_dir: Path | str) -> dict:
    """``{"frames_used", "view", "proposals"}`` of a camera's view (thumbnails under ``data_dir``); ``HTTPException``
    409 with too few frames."""
    from .proposals import MAX_FRAMES, MIN_FRAMES, propose_regions
    from .registration import view_thumbnails

    thumbs, frames = view_thumbnails(session, cam, view, data_dir, MAX_FRAMES)
    if len(thumbs) < MIN_FRAMES:
        raise HTTPException(409, f"{len(thumbs)} frame(s) of this view stored; region proposals need at least "
                                 f"{MIN_FRAMES}, spread over the day (post frames to /v1/cameras/{cam.id}/frames)")
    props = propose_regions(thumbs, count, (frames[0].width, frames[0].height))
    hours = len({f.taken_at.hour for f in frames})
    warnings = [] if hours >= MIN_HOURS else [
        f"the frames used cover {hours} hour(s) of the day: a surface that changes with the sun (a highlight, a "
        "moving shadow) may look static; propose again once frames from other hours are stored"]
    return {"frames_used": len(thumbs), "view": view, "hours_covered": hours,
            "proposals": [p.as_dict() for p in props], "warnings": warnings}
