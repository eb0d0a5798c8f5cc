"""``illumon fit OBSERVATIONS.csv [--sensitivities S.csv] [--known-reflectances KNOWN.csv] --model MODEL.json``: learn a
scene model (:mod:`illumon.model`) for a measured camera, or one nobody measured, calibrated by references."""

from __future__ import annotations

import argparse
from typing import Any

from .common import add_primaries, add_white_level, fit_camera_and_scene, read_known

__all__ = ["add_fit_command", "CAMERA_WORDS"]


def _cmd_fit(args: argparse.Namespace) -> int:
    from ..observations import read_observations

    obs = read_observations(args.observations, white_level=args.white_level)
    model = fit_camera_and_scene(args, obs, read_known(args, obs), max_fit_frames=args.max_fit_frames)
    model.save(args.model)
    ident = model.identifiability
    tr = model.training
    cam = model.camera.get("calibration", "measured")
    print(
        f"fitted {len(model.patches)} patches on {tr['frames_used_for_reflectances']} of {tr['frames']} frames; "
        f"CCT {tr['cct_p05']:.0f}–{tr['cct_p95']:.0f} K (5–95 %); noise ×{model.noise['noise_scale']:.2f}; "
        f"condition {ident['condition']:.3g}; camera: {CAMERA_WORDS[cam]} → {args.model}"
    )
    for msg in ident["warnings"]:
        print(f"illumon: warning: {msg}")
    # the identifiability check's own warnings (not a chart's or a lamp's); a single frame's says what it means itself
    if ident.get("determined") is False and tr["frames"] > 1:
        print(
            "illumon: what this means: the frames' colour *differences* are still estimated, but the colour common to "
            "the whole history (how warm or cool every frame is) comes from typical daylight and typical surfaces, not "
            "from this scene; intervals and confidence already include that. Fix: fit on a longer history that spans "
            "clear and overcast days, sunrise to noon (≥ 50 frames over several days), or add a grey card or chart "
            "frame with --known-reflectances."
        )
    return 0


CAMERA_WORDS = {
    "measured": "measured sensitivities",
    "grey": "calibrated by a grey card (channel scales)",
    "chart": "calibrated by a chart (3 × 3 matrix)",
    "none": "nobody measured it and no reference: prior of the measured cameras, wide intervals",
}


def add_fit_command(subparsers: Any) -> None:
    """Register ``illumon fit OBSERVATIONS.csv [--sensitivities S.csv] [--known-reflectances KNOWN.csv] --model M``."""
    p = subparsers.add_parser("fit", help="learn a scene model (patch reflectances) from a history")
    p.add_argument("observations", help="OBSERVATIONS.csv with columns frame,time,patch,r,g,b")
    p.add_argument("--sensitivities", help="camera sensitivities CSV wavelength_nm,r,g,b (none: a camera nobody measured)")
    p.add_argument("--known-reflectances", help="KNOWN.csv wavelength_nm,<patch id>,…: references of known reflectance")
    p.add_argument("--model", required=True, help="MODEL.json to write")
    add_white_level(p)
    add_primaries(p)
    p.add_argument("--max-fit-frames", type=int, default=300, help="frames used for the reflectance fit (300)")
    p.set_defaults(func=_cmd_fit)
