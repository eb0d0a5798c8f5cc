"""``illumon diagnose OBSERVATIONS.csv --sensitivities SENSITIVITIES.csv --out REPORT.json [--white-level 255]
[--primaries camera|srgb]``."""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from .common import add_primaries, add_white_level

__all__ = ["add_diagnose_command", "run_diagnosis"]




def run_diagnosis(observations_path: str, obs, sensitivities, *, reestimate: bool = True,
                  white_level: float | None = None, primaries: str = "camera"):
    """Diagnose ``obs`` with input checks whose messages name the file (raises ``ValueError``). ``white_level``: the
    codes the values were divided by (the lit values are counted above the history's censoring level,
    :func:`illumon.diagnosis.noise.history_dark_level`)."""
    from ..diagnosis.fit import RANK, diagnose, min_frames, short_history_hint

    f, p = len(obs.frames), len(obs.patches)
    if f < min_frames(primaries):
        raise ValueError(f"{observations_path}: only {f} frame(s); diagnosis needs at least {RANK + 2}"
                         + short_history_hint(primaries))
    if p < 3:
        raise ValueError(f"{observations_path}: only {p} patch(es); diagnosis needs at least 3")
    if (obs.present.sum(axis=1) < 2).any():
        bad = obs.frames[int((obs.present.sum(axis=1) < 2).argmax())]
        raise ValueError(f"{observations_path}: frame {bad!r} has fewer than two patches")
    from ..diagnosis.noise import history_dark_level

    values = np.asarray(obs.values, dtype=float)
    # a history near black is refused; a dim one of a high bit depth (a 16-bit camera's regions at a few % of white,
    # thousands of codes above black) is read above its own censoring level
    level = history_dark_level(values, white_level)
    lit = int(np.sum(np.nan_to_num(values) > level))
    if lit < 2 * (RANK + 2):
        raise ValueError(f"{observations_path}: only {lit} value(s) above {level:.3g} of the white level (the "
                         f"brightest is {np.nanmax(values):.3g}); diagnosis reads the values above it — is "
                         "--white-level the camera's white?")
    return diagnose(obs, sensitivities, reestimate=reestimate, white_level=white_level, primaries=primaries)


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from ..observations import read_observations
    from ..spectra import read_sensitivities

    obs = read_observations(args.observations, white_level=args.white_level)
    css = read_sensitivities(args.sensitivities)
    diag = run_diagnosis(args.observations, obs, css, white_level=args.white_level, primaries=args.primaries)
    report = diag.to_json()
    if report["parameters"].get("clip_level") is not None:
        report["parameters"]["clip_level_value"] = round(report["parameters"]["clip_level"] * args.white_level, 4)
    if "offsets" in report["parameters"]:
        report["parameters"]["offsets_value"] = [round(v * args.white_level, 4) for v in report["parameters"]["offsets"]]
    with open(args.out, "w") as fh:
        json.dump(report, fh, indent=1, allow_nan=False, default=float)
        fh.write("\n")
    return 0


def add_diagnose_command(subparsers: Any) -> None:
    """Register ``illumon diagnose``."""
    p = subparsers.add_parser("diagnose", help="name the effect that breaks the linear model in a history")
    p.add_argument("observations", help="OBSERVATIONS.csv with columns frame,time,patch,r,g,b")
    p.add_argument("--sensitivities", required=True, help="camera sensitivities CSV wavelength_nm,r,g,b")
    p.add_argument("--out", required=True, help="REPORT.json to write")
    add_white_level(p)
    add_primaries(p)
    p.set_defaults(func=_cmd_diagnose)
