"""Queries of a camera's own rows: the camera (by id or token), its views' regions, its calibration images, and the
deletion of everything stored for it."""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from ..storage import Calibration, Camera, CameraView, Estimate, Frame, Job, hash_token

__all__ = [
    "get_camera", "camera_by_token", "camera_id_by_token_hash", "cameras", "camera_ids", "create_camera",
    "models_for_update", "use_models", "calibrations", "has_calibration", "add_calibration", "camera_views", "view_regions",
    "set_view_regions", "delete_camera_rows",
]


def get_camera(session: Session, camera_id: int, for_update: bool = False) -> Camera | None:
    """The camera ``camera_id`` (``for_update``: its row locked until the transaction ends), or ``None``."""
    return session.get(Camera, camera_id, with_for_update=True) if for_update else session.get(Camera, camera_id)


def camera_by_token(session: Session, token: str) -> Camera | None:
    """The camera whose token is ``token``, or ``None``."""
    return session.scalars(select(Camera).where(Camera.token_hash == hash_token(token))).first()


def camera_id_by_token_hash(session: Session, token_hash: str) -> int | None:
    """The id of the camera whose token has the SHA-256 ``token_hash``, or ``None``."""
    row = session.execute(select(Camera.id).where(Camera.token_hash == token_hash)).first()
    return None if row is None else int(row.id)


def cameras(session: Session, only: int | None = None) -> list[Camera]:
    """Every camera by id, or only the camera ``only``."""
    q = select(Camera).order_by(Camera.id)
    if only is not None:
        q = q.where(Camera.id == only)
    return list(session.scalars(q).all())


def camera_ids(session: Session) -> list[int]:
    """The ids of every camera."""
    return list(session.scalars(select(Camera.id)).all())


def create_camera(session: Session, **columns: object) -> Camera:
    """Store a new camera and commit."""
    cam = Camera(**columns)
    session.add(cam)
    session.commit()
    return cam


def models_for_update(session: Session, camera_id: int) -> dict | None:
    """The camera's scene models in use (:attr:`.storage.Camera.models`), its row locked until the transaction ends
    (on SQLite the transaction already holds the write lock)."""
    return session.execute(select(Camera.models).where(Camera.id == camera_id).with_for_update()).scalar()


def use_models(session: Session, cam: Camera, models: dict[str, dict]) -> None:
    """Switch views of the camera to new scene models (view key → ``{"file", "version"}``, other views kept) and
    flush: the row's update takes the database's write lock (SQLite) or holds the row's (PostgreSQL) until the
    transaction ends."""
    cam.models = {**(cam.models or {}), **models}
    session.flush()


def calibrations(session: Session, camera_id: int) -> Sequence[Calibration]:
    """The camera's stored calibration images, oldest first."""
    return session.scalars(select(Calibration).where(Calibration.camera_id == camera_id).order_by(Calibration.id)).all()


def has_calibration(session: Session, camera_id: int) -> bool:
    """Whether the camera has a stored calibration image."""
    return session.scalar(select(func.count()).select_from(Calibration).where(Calibration.camera_id == camera_id)) > 0


def add_calibration(session: Session, **columns: object) -> Calibration:
    """Store a calibration image's measurement and commit."""
    row = Calibration(**columns)
    session.add(row)
    session.commit()
    return row


def camera_views(session: Session, camera_id: int) -> dict[str, list]:
    """The regions of the camera's views other than its default one, by view."""
    return {v.view: v.regions for v in session.scalars(
        select(CameraView).where(CameraView.camera_id == camera_id).order_by(CameraView.view)).all()}


def _view_row(session: Session, camera_id: int, view: str) -> CameraView | None:
    return session.scalars(select(CameraView).where(CameraView.camera_id == camera_id, CameraView.view == view)).first()


def view_regions(session: Session, cam: Camera, view: str | None) -> list[dict]:
    """The regions of a view (the camera's own for ``None``)."""
    if view is None:
        return list(cam.regions)
    row = _view_row(session, cam.id, view)
    return list(row.regions) if row is not None else []


def set_view_regions(session: Session, cam: Camera, view: str | None, regions: list[dict]) -> None:
    """Replace a view's regions (not committed)."""
    if view is None:
        cam.regions = regions
        return
    row = _view_row(session, cam.id, view)
    if row is None:
        session.add(CameraView(camera_id=cam.id, view=view, regions=regions))
    else:
        row.regions = regions


def delete_camera_rows(session: Session, cam: Camera) -> dict[str, int]:
    """Delete a camera and its frames, estimates, jobs, calibrations and views, and commit; returns how many frames,
    estimates, jobs and calibrations were deleted."""
    counts = {name: int(session.scalar(select(func.count()).select_from(model).where(model.camera_id == cam.id)) or 0)
              for name, model in (("frames", Frame), ("estimates", Estimate), ("jobs", Job),
                                  ("calibrations", Calibration))}
    for model in (Estimate, Frame, Job, Calibration, CameraView):  # explicit: not every database cascades
        session.execute(delete(model).where(model.camera_id == cam.id))
    session.delete(cam)
    session.commit()
    return counts
