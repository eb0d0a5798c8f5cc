"""Pieces every ``illumon`` command shares: the one-line usage error, argument types, the ESTIMATES.csv writer, and
reading a camera's references and fitting it (``estimate`` and ``fit``)."""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

__all__ = ["UsageError", "white_level_arg", "add_white_level", "write_estimates", "write_reflectances", "read_known",
           "fit_camera_and_scene"]


class UsageError(Exception):
    """A problem with the user's input, reported as one line and exit status 2."""


def white_level_arg(text: str) -> float:
    """argparse type of ``--white-level``: a positive finite number."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"white level must be a number, got {text!r}") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"white level must be positive, got {text!r}")
    return v


def add_white_level(parser: argparse.ArgumentParser) -> None:
    """``--white-level`` (value of a saturated pixel, 255 by default), as every command that reads observations has it."""
    parser.add_argument("--white-level", type=white_level_arg, default=255.0, help="value of a saturated pixel (255)")


def write_estimates(path: str | Path, result, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write a retrieval result as ``ESTIMATES.csv`` (one row per frame; docs/cli.md lists the columns)."""
    extra = extra or {}
    cols = ["frame", "time", "cct_k", "duv", "x", "y", "white_r", "white_g", "white_b", "gain_r", "gain_g", "gain_b"]
    cols += list(extra)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for i, frame in enumerate(result.frames):
            row = [
                frame,
                result.times[i] if result.times else "",
                f"{result.cct[i]:.1f}",
                f"{result.duv[i]:.5f}",
                f"{result.xy[i, 0]:.5f}",
                f"{result.xy[i, 1]:.5f}",
                *(f"{v:.6f}" for v in result.white[i]),
                *(f"{v:.6f}" for v in result.gains[i]),
            ]
            row += [f"{extra[k][i]:.6g}" for k in extra]
            w.writerow(row)


def write_reflectances(path: str | Path, result) -> None:
    from ..spectra import WAVELENGTHS, write_spectral_csv

    write_spectral_csv(
        path,
        WAVELENGTHS,
        {p: result.reflectances[j] for j, p in enumerate(result.patches)},
        comments=[f"illumon {result.method}: recovered patch reflectances (0…1)"],
    )


def read_known(args: argparse.Namespace, obs) -> dict[str, np.ndarray]:
    """``--known-reflectances`` of ``estimate``/``fit``: read, and check that every known patch is observed."""
    if not getattr(args, "known_reflectances", None):
        return {}
    from ..camera.references import read_known_reflectances

    known = read_known_reflectances(args.known_reflectances)
    missing = [p for p in known if p not in obs.patches]
    if missing:
        raise UsageError(
            f"{args.known_reflectances}: known patch {missing[0]!r} never appears in {args.observations}"
            + (f" (nor {len(missing) - 1} more)" if len(missing) > 1 else "")
        )
    return known


def fit_camera_and_scene(args: argparse.Namespace, obs, known: dict[str, np.ndarray], **kwargs):
    """Fit the scene model with measured (``--sensitivities``) or unmeasured sensitivities and references;
    errors name the observations file."""
    from ..model import fit_scene_model
    from ..spectra import read_sensitivities

    css = read_sensitivities(args.sensitivities) if args.sensitivities else None
    try:
        return fit_scene_model(obs, css, known_reflectances=known or None,
                               primaries=getattr(args, "primaries", "camera"), **kwargs)
    except np.linalg.LinAlgError:  # a numerical dead end: main's one line on degenerate fits says cause and fix
        raise
    except ValueError as exc:
        raise ValueError(f"{args.observations}: {exc}") from None


def add_primaries(parser: argparse.ArgumentParser) -> None:
    """``--primaries camera|srgb``: the camera's output space (:data:`illumon.camera.primaries.PRIMARIES`)."""
    from ..camera.primaries import PRIMARIES

    parser.add_argument("--primaries", default="camera", choices=list(PRIMARIES),
                        help="output space: camera (sensor RGB, raw) or srgb (rendered output: white balance and a colour "
                             "matrix to sRGB primaries; IP, surveillance and phone cameras)")
