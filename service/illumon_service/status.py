"""What the status page shows: each camera's latest estimate, last frame and alerts, and one camera's history.

Reads the same rows as the JSON API, through the same queries (:mod:`.crud`), and formats estimates with the API's own
:func:`~.crud.estimate_out`, so the page and ``GET /v1/cameras/{id}/estimates`` cannot disagree.

Alerts
------
An alert is a named condition the service can see in what it already stores. Each is produced by one *rule*, a
function of an :class:`AlertContext` (the camera, its recent frames and its latest estimate) in :data:`ALERT_RULES`:

* ``regions_missing`` — regions without a value (mostly occluded, shadowed or clipped pixels, or not sent) in at
  least a quarter (and at least 3) of the recent frames: something covers, shadows or changed those static patches;
* ``clipping`` — region values at or above the clip level (``ILLUMON_CLIP_FRACTION`` of white) in recent frames;
* ``non_daylight`` — the latest estimate's ``non_daylight`` (posterior probability that its light is not daylight,
  :mod:`illumon.model.lamps`) is at least 0.5; for an estimate without it, more than 0.02 in Duv off the Planckian
  locus: not daylight (or a wrong camera set-up);
* ``low_confidence`` — the latest estimate's confidence is below 0.5;
* ``no_estimate`` — frames are stored but none is estimated yet (no refit has run);
* ``refit_warning`` — a warning of the latest refit, e.g. a stored history that still looks non-linear for the
  camera's declared tone response (:func:`~.estimation.check_response`: every estimate is then off);
* ``uncalibrated`` — a camera registered without sensitivities and no calibration image yet: its estimates rest on
  the prior from measured cameras (an information, not a fault);
* ``no_regions`` — a camera registered without regions: frames are stored, and the page says how to confirm
  proposed regions (an information);
* ``refit_failed`` — the camera's latest refit failed (its error; the previous estimates stand);
* ``frames_not_estimated`` — stored frames without an estimate because of a view change, values a refit left out or
  a failed estimate (counted by reason);
* ``view_change`` — the latest frame does not register to its view's reference frame (:mod:`.registration`: a
  PTZ preset, a knocked camera): it is stored but not estimated.

A later diagnosis of the history (patch change, shadow, clipping, … from ``illumon.diagnosis``) is one more rule
appended to :data:`ALERT_RULES` that turns stored diagnosis results into :class:`Alert` objects; nothing else in the
page changes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime

from sqlalchemy.orm import Session

from . import crud
from .crud import estimate_non_daylight, estimate_out
from .deps import Principal, visible_cameras
from .settings import Settings
from .storage import Camera, Estimate, Frame, Job, as_utc

__all__ = [
    "Alert",
    "AlertContext",
    "ALERT_RULES",
    "CameraStatus",
    "RECENT_FRAMES",
    "NON_DAYLIGHT_DUV",
    "NON_DAYLIGHT_PROBABILITY",
    "LOW_CONFIDENCE",
    "MISSING_FRACTION",
    "MISSING_MIN_FRAMES",
    "camera_status",
    "fleet_status",
    "chart_history",
    "MAX_CHART_POINTS",
]

RECENT_FRAMES = 12
"""Alerts look at this many of a camera's most recent frames."""
NON_DAYLIGHT_DUV = 0.02
"""|Duv| above this is reported as non-daylight light (estimates without ``non_daylight``)."""
NON_DAYLIGHT_PROBABILITY = 0.5
"""``non_daylight`` alert: the latest estimate's posterior probability of non-daylight light at or above this."""
LOW_CONFIDENCE = 0.5
"""Confidence below this is reported."""
MISSING_FRACTION = 0.25
"""A region missing in at least this fraction of the recent frames (and in :data:`MISSING_MIN_FRAMES`) is reported."""
MISSING_MIN_FRAMES = 3
"""…and in at least this many of them (one passer-by is not an alert)."""


@dataclass(frozen=True)
class Alert:
    """One alert of a camera: a stable ``kind``, a short ``label`` for the table, a sentence and a severity."""

    kind: str
    label: str
    message: str
    severity: str = "warning"  # "info" | "warning"


@dataclass
class AlertContext:
    """What a rule may look at."""

    camera: Camera
    frames: list[Frame]
    """Most recent frames, newest first (at most :data:`RECENT_FRAMES`)."""
    latest: Estimate | None
    settings: Settings
    frame_count: int
    refit_warnings: list[str] = field(default_factory=list)
    """Warnings of the camera's latest finished refit (:func:`~.crud.refit_warnings`)."""
    uncalibrated: bool = False
    """No measured sensitivities and no calibration image."""
    not_estimated: dict[str, int] = field(default_factory=dict)
    """Stored frames without an estimate, by reason (:func:`~.crud.not_estimated_counts`)."""
    last_job: Job | None = None
    """The camera's latest finished refit job (done or failed)."""


def _measured(frame: Frame) -> bool:
    """A frame of the default view that was measured with its regions (not a view change, not another preset)."""
    reg = getattr(frame, "registration", None) or {}
    return getattr(frame, "view", None) is None and reg.get("state") != "view_change"


def _regions_missing(ctx: AlertContext) -> list[Alert]:
    ids = [r["id"] for r in ctx.camera.regions]
    frames = [f for f in ctx.frames if _measured(f)]
    n = len(frames)
    if n == 0 or not ids:
        return []
    need = max(MISSING_MIN_FRAMES, math.ceil(MISSING_FRACTION * n))
    counts = {rid: sum(1 for f in frames if f.patches.get(rid) is None) for rid in ids}
    worst = sorted((rid for rid in ids if counts[rid] >= need), key=lambda rid: (-counts[rid], rid))
    if not worst:
        return []
    names = ", ".join(worst[:4]) + (f" and {len(worst) - 4} more" if len(worst) > 4 else "")
    return [Alert("regions_missing", "Regions missing",
                  f"{len(worst)} of {len(ids)} regions missing in at least {need} of the last {n} frames ({names}): "
                  "patch covered, shadowed or changed?")]


def _clipping(ctx: AlertContext) -> list[Alert]:
    level = ctx.settings.clip_fraction
    hits: dict[str, int] = {}
    for f in ctx.frames:
        for rid, v in f.patches.items():
            if v is not None and max(v) >= level:
                hits[rid] = hits.get(rid, 0) + 1
    if not hits:
        return []
    names = ", ".join(sorted(hits)[:3])
    return [Alert("clipping", "Clipping", f"region values at the clip level in recent frames ({names})")]


def _non_daylight(ctx: AlertContext) -> list[Alert]:
    e = ctx.latest
    if e is None:
        return []
    p = estimate_non_daylight(e)
    if p is not None:  # the model's posterior of non-daylight light; the Duv rule for estimates made without it
        if p < NON_DAYLIGHT_PROBABILITY:
            return []
        return [Alert("non_daylight", "Non-daylight light",
                      f"the latest frame's light is not daylight with probability {p:.2f}")]
    if abs(e.duv) <= NON_DAYLIGHT_DUV:
        return []
    return [Alert("non_daylight", "Non-daylight light",
                  f"latest Duv {e.duv:+.4f} is more than {NON_DAYLIGHT_DUV} off the Planckian locus")]


def _low_confidence(ctx: AlertContext) -> list[Alert]:
    e = ctx.latest
    if e is None or e.confidence >= LOW_CONFIDENCE:
        return []
    return [Alert("low_confidence", "Low confidence", f"latest estimate's confidence is {e.confidence:.2f}")]


def _no_estimate(ctx: AlertContext) -> list[Alert]:
    if ctx.latest is not None or ctx.frame_count == 0:
        return []
    return [Alert("no_estimate", "No estimate yet",
                  f"{ctx.frame_count} frames stored, none estimated: run a refit", severity="info")]


def _refit_warning(ctx: AlertContext) -> list[Alert]:
    return [Alert("refit_warning", "Check set-up", w) for w in ctx.refit_warnings]


def _uncalibrated(ctx: AlertContext) -> list[Alert]:
    if not ctx.uncalibrated:
        return []
    return [Alert("uncalibrated", "Uncalibrated", "no sensitivities and no reference seen yet: estimates rest on the "
                  "measured cameras' prior (wider intervals); POST a grey card or ColorChecker image to "
                  "/v1/cameras/{id}/calibration".replace("{id}", str(ctx.camera.id)), severity="info")]


def _no_regions(ctx: AlertContext) -> list[Alert]:
    if ctx.camera.regions:
        return []
    from .proposals import MIN_FRAMES

    cid = ctx.camera.id
    todo = (f"confirm proposed regions at /cameras/{cid}/regions" if ctx.frame_count >= MIN_FRAMES else
            f"post at least {MIN_FRAMES} frames spread over the day ({ctx.frame_count} so far), then confirm proposed "
            f"regions at /cameras/{cid}/regions")
    return [Alert("no_regions", "No regions", f"no reference regions yet: frames are stored but not estimated; {todo}",
                  severity="info")]


def _view_change(ctx: AlertContext) -> list[Alert]:
    if not ctx.frames:
        return []
    latest = ctx.frames[0]
    reg = getattr(latest, "registration", None) or {}
    if reg.get("state") != "view_change":
        return []
    dx, dy = reg.get("shift") or (0.0, 0.0)
    view = "" if getattr(latest, "view", None) is None else f" (view {latest.view})"
    return [Alert("view_change", "View changed",
                  f"latest frame{view} does not match its reference frame (shift {dx:+.0f}, {dy:+.0f} px, peak "
                  f"{reg.get('response') or 0:.2f}): stored, not estimated. Camera moved? If for good, confirm its "
                  f"regions again at /cameras/{ctx.camera.id}/regions")]


REASON_WORDS = {
    "view_change": "view changed", "no_regions": "posted before regions", "too_few_regions": "fewer than two regions",
    "no_model": "awaiting a refit", "invalid_values": "left out by the refit (values out of range)",
    "estimate_failed": "estimate failed", "pending": "awaiting a refit",
}
"""What each reason a frame has no estimate means (:attr:`.storage.Frame.not_estimated`)."""


def _refit_failed(ctx: AlertContext) -> list[Alert]:
    job = ctx.last_job
    if job is None or job.state != "failed":
        return []
    error = str((job.summary or {}).get("error") or "unknown error")
    return [Alert("refit_failed", "Refit failed",
                  f"the latest refit (job {job.id}) failed: {error}. The previous estimates stand; fix the cause, "
                  "then refit again")]


def _frames_not_estimated(ctx: AlertContext) -> list[Alert]:
    counts = {k: v for k, v in ctx.not_estimated.items() if k in ("view_change", "invalid_values", "estimate_failed")}
    if not counts:
        return []
    parts = ", ".join(f"{n} {REASON_WORDS.get(k, k)}" for k, n in sorted(counts.items()))
    return [Alert("frames_not_estimated", "Frames not estimated",
                  f"{sum(counts.values())} stored frame(s) have no estimate: {parts} (GET "
                  f"/v1/cameras/{ctx.camera.id}/frames lists each with its reason)")]


ALERT_RULES: list[Callable[[AlertContext], list[Alert]]] = [
    _view_change, _refit_failed, _frames_not_estimated, _no_regions, _refit_warning, _uncalibrated,
    _regions_missing, _clipping, _non_daylight, _low_confidence,
    _no_estimate,
]
"""Rules producing a camera's alerts, in display order; append a rule to add a kind of alert."""


@dataclass
class CameraStatus:
    """One camera's row of the status table."""

    id: int
    name: str
    regions: int
    frames: int
    last_frame_at: datetime | None
    latest: dict | None
    """The latest estimate as the JSON API gives it (``estimate_out``), with ``intervals``."""
    alerts: list[Alert] = field(default_factory=list)
    not_estimated: dict[str, int] = field(default_factory=dict)
    """Stored frames without an estimate, by reason."""
    warnings: list[str] = field(default_factory=list)
    """Every warning of the latest refit (one list: tone response, calibration, identifiability, white balance)."""


def camera_status(session: Session, cam: Camera, settings: Settings) -> CameraStatus:
    """Latest estimate, last frame, frame count and alerts of ``cam``."""
    frames = crud.recent_frames(session, cam.id, RECENT_FRAMES)
    count = crud.frame_count(session, cam.id)
    latest = crud.latest_estimate(session, cam.id)
    calibrated = bool(cam.sensitivities) or crud.has_calibration(session, cam.id)
    counts = crud.not_estimated_counts(session, cam.id, count)
    ctx = AlertContext(cam, frames, latest, settings, count, crud.refit_warnings(session, cam.id), not calibrated,
                       counts, crud.latest_job(session, cam.id))
    alerts = [a for rule in ALERT_RULES for a in rule(ctx)]
    out = None
    if latest is not None:
        out = estimate_out(latest)
        out["intervals"] = latest.intervals
    return CameraStatus(
        id=cam.id, name=cam.name, regions=len(cam.regions), frames=count,
        last_frame_at=as_utc(frames[0].taken_at) if frames else None, latest=out, alerts=alerts,
        not_estimated=counts, warnings=crud.refit_warnings(session, cam.id),
    )


def fleet_status(session: Session, principal: Principal, settings: Settings) -> list[CameraStatus]:
    """A :class:`CameraStatus` for every camera the caller may see."""
    return [camera_status(session, cam, settings) for cam in visible_cameras(session, principal)]


MAX_CHART_POINTS = 640
"""The camera page draws at most this many points per series, whatever the history's length: the wide chart's plot
area is 642 px across (the compact one's 322), so more points would share pixel columns; drawing costs ~0.1 ms a
point (six charts, bands included)."""


@dataclass
class ChartHistory:
    """What the camera page draws: the window's estimates thinned to a bounded number of points, and the newest."""

    points: list[dict]
    """At most ``max_points`` estimates of the window, oldest first, every ``stride``-th counted from the newest (so
    the newest is always drawn), as the JSON API gives them plus ``intervals``."""
    recent: list[dict]
    """The window's newest ``recent`` estimates, newest first (the page's table), same form."""
    count: int
    """Estimates in the window (the camera's most recent ``limit``)."""
    stride: int
    """1 when every estimate of the window is drawn."""


def chart_history(session: Session, camera_id: int, limit: int = 2000, max_points: int = MAX_CHART_POINTS,
                  recent: int = 24) -> ChartHistory:
    """The camera's most recent ``limit`` estimates, thinned by a stride to at most ``max_points``, and its newest
    ``recent`` ones.

    The window is read as frame ids only, newest first (an index-only range scan of ``ix_estimates_camera_taken``);
    the drawn and recent rows are then fetched by primary key, as plain rows without their spectra. The page's cost is therefore
    bounded by ``max_points`` + ``recent`` rows, plus ``limit`` index entries, whatever the history's length.

    Parameters
    ----------
    session
        Database session.
    camera_id
        The camera.
    limit
        Size of the window (the most recent estimates); at least 1.
    max_points
        Upper bound of the drawn points; at least 1.
    recent
        How many of the newest estimates the table lists.

    Returns
    -------
    ChartHistory
    """
    ids = crud.recent_estimate_ids(session, camera_id, max(1, limit))
    stride = max(1, math.ceil(len(ids) / max(1, max_points)))
    drawn = ids[::stride]
    rows: dict[int, dict] = {}
    for e in crud.estimate_rows(session, set(drawn) | set(ids[:recent])):
        d = estimate_out(e)  # type: ignore[arg-type] - a row with the estimate's columns by name
        d["intervals"] = e.intervals
        rows[e.frame_id] = d
    return ChartHistory(points=[rows[i] for i in reversed(drawn) if i in rows],
                        recent=[rows[i] for i in ids[:recent] if i in rows], count=len(ids), stride=stride)
