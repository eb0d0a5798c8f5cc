"""White-balance gains in camera-software conventions (see :mod:`illumon.gains` for each convention)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Query
from illumon.gains import all_conventions, v4l2_controls

from ...deps import PrincipalDep, SessionDep, camera_for, nearest_estimate
from ...storage import as_utc
from ..schemas import ERROR_RESPONSES, IsoDateTime, WbGainsOut

router = APIRouter(prefix="/v1/cameras", tags=["gains"], responses=ERROR_RESPONSES)

V4L2_TEMPERATURE_RANGE = (2800, 6500)
"""Range (K) of V4L2's ``white_balance_temperature`` the answer is clamped to: the usual UVC range (drivers report
their own with ``v4l2-ctl -L``). Daylight often lies beyond it (a blue sky ~10 000 K); the answer then says so."""


def parse_range(text: str | None) -> tuple[float, float] | None:
    """``"lo,hi"`` → ``(lo, hi)``; 422 when malformed or out of range."""
    if not text:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise HTTPException(422, f"onvif_range {text!r}: expected two numbers 'lo,hi'") from None
    if not (lo < hi) or any(v != v or abs(v) > ONVIF_RANGE_MAX for v in (lo, hi)) or hi - lo < 1e-3:
        raise HTTPException(422, f"onvif_range {text!r}: expected lo < hi within ±{ONVIF_RANGE_MAX:g}, at least 0.001 "
                                 "apart")
    return lo, hi


ONVIF_RANGE_MAX = 1e6
"""Largest magnitude of an ``onvif_range`` end (vendor ranges are 0…255 or so; beyond, the mapping overflows)."""


@router.get("/{camera_id}/wb-gains", response_model=WbGainsOut)
def wb_gains(
    camera_id: int,
    session: SessionDep,
    principal: PrincipalDep,
    at: IsoDateTime | None = None,
    onvif_range: str | None = Query(None, description="vendor CrGain/CbGain range 'lo,hi' (e.g. '0,255')"),
    v4l2_unity: int = Query(1000, gt=0, le=1_000_000, description="red/blue_balance value of unity gain"),
) -> dict:
    """Gains for the estimate nearest ``at`` (latest without it) in every supported convention.

    ``rgb`` = [G/R, 1, G/B] of the camera white; ``onvif`` CrGain/CbGain (unitless gains, or log2-mapped onto
    ``onvif_range``); ``libcamera`` ColourGains [r, b] + ColourTemperature; ``v4l2`` red/blue_balance =
    gain × ``v4l2_unity`` + white_balance_temperature (K, clamped to 2800–6500: ``temperature_clamped`` and a
    sentence in ``notes`` say when); ``dng`` AsShotNeutral = 1/gains; ``android`` RggbChannelVector [r, 1, 1, b].
    """
    camera_for(session, principal, camera_id)
    e = nearest_estimate(session, camera_id, at)
    out = all_conventions(e.white_rgb, e.cct_k, onvif_range=parse_range(onvif_range), v4l2_unity=v4l2_unity)
    lo, hi = V4L2_TEMPERATURE_RANGE
    v4l2 = v4l2_controls(out["rgb"], e.cct_k, unity=v4l2_unity, temperature_range=V4L2_TEMPERATURE_RANGE)
    clamped = not lo <= e.cct_k <= hi
    v4l2.update({"temperature_range_k": [lo, hi], "temperature_clamped": clamped})
    notes = []
    if clamped:
        notes.append(f"v4l2 white_balance_temperature is clamped to {v4l2['white_balance_temperature']} K: the "
                     f"estimate is {e.cct_k:.0f} K, outside the {lo}–{hi} K range UVC cameras accept; the "
                     "red/blue_balance gains are not clamped and carry the full correction")
    out.update({"v4l2": v4l2, "frame_id": e.frame_id, "taken_at": as_utc(e.taken_at).isoformat(),
                "confidence": e.confidence, "cct_k": e.cct_k, "notes": notes})
    return out
