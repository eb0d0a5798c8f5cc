"""Bodies of a camera's set-up and upkeep: calibration images, region proposals and refit jobs."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from .cameras import ReferenceKind

__all__ = ["CalibrationPatchOut", "CalibrationOut", "ProposalReasons", "ProposalOut", "ProposalsOut", "JobRef",
           "JobOut"]


class CalibrationPatchOut(BaseModel):
    """A measured patch: linear means (``null`` when mostly clipped or occluded) and whether pixels clipped."""

    id: str
    r: float | None
    g: float | None
    b: float | None
    clipped: bool


class CalibrationOut(BaseModel):
    """A stored calibration image: its patches, how many clipped, how many of the camera's own regions the image
    shows (``scene_regions``: fewer than two and a refit leaves it out) and warnings."""

    calibration_id: int
    kind: ReferenceKind
    patches: list[CalibrationPatchOut]
    clipped: int
    scene_regions: int
    warnings: list[str]


class ProposalReasons(BaseModel):
    """What a proposal's score rests on (:func:`illumon_service.proposals.propose_regions`)."""

    model_config = ConfigDict(extra="allow")

    change: float
    drift: float
    texture: float
    clipped: float
    dark: float
    chroma: list[float]
    diversity: float


class ProposalOut(BaseModel):
    """A proposed region in the view's reference-frame pixels with its score (0…1)."""

    x: int
    y: int
    width: int
    height: int
    score: float
    reasons: ProposalReasons


class ProposalsOut(BaseModel):
    """Region proposals of a view, best first, with the number of frames used and the hours of the day they cover."""

    frames_used: int
    view: str | None
    hours_covered: int
    proposals: list[ProposalOut]
    warnings: list[str]


class JobRef(BaseModel):
    """A queued job; poll ``GET /v1/jobs/{job_id}``."""

    job_id: str


class JobOut(BaseModel):
    """A refit job: state, progress (0…1), summary (``null`` until it ends; ``{"error": …}`` when it failed; otherwise
    what the refit measured, open-ended) and times."""

    job_id: str
    camera_id: int
    state: Literal["queued", "running", "done", "failed"]
    progress: float
    summary: dict[str, Any] | None
    created_at: str
    finished_at: str | None
