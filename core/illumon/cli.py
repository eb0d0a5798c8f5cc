"""The ``illumon`` command.

Subcommands: ``estimate`` (multi-frame retrieval, or per-frame with a learned ``--model``), ``fit``, ``sensitivity``,
``report daylight``, ``diagnose`` and ``serve`` where installed. Errors in the user's input print one line
``illumon: error: …`` naming the file, row and problem, and exit with status 2; nothing prints a traceback.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["main", "build_parser", "write_estimates", "white_level_arg"]


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


def write_estimates(path: str | Path, result, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write a retrieval result as ``ESTIMATES.csv`` (one row per frame; see the README for the columns)."""
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


def _write_reflectances(path: str | Path, result) -> None:
    from .spectra import WAVELENGTHS, write_spectral_csv

    write_spectral_csv(
        path,
        WAVELENGTHS,
        {p: result.reflectances[j] for j, p in enumerate(result.patches)},
        comments=[f"illumon {result.method}: recovered patch reflectances (0…1)"],
    )


def _cmd_estimate(args: argparse.Namespace) -> int:
    from .observations import read_observations

    obs = read_observations(args.observations, white_level=args.white_level)
    known = read_known(args, obs)
    if args.model and (known or args.sensitivities):
        raise UsageError("--model already holds the camera; --sensitivities and --known-reflectances go with `illumon fit`")
    if args.model:
        try:
            from .model import estimate_with_model
        except ImportError as exc:  # pragma: no cover - the model module ships with the package
            raise UsageError(f"--model needs illumon.model ({exc})") from None
        result, extra = estimate_with_model(obs, args.model)
    elif known or not args.sensitivities:
        result, extra = _estimate_calibrated(args, obs, known)
    else:
        from .retrieval import retrieve_illuminants
        from .spectra import read_sensitivities

        css = read_sensitivities(args.sensitivities)
        if len(obs.frames) < 2:
            raise UsageError(
                f"{args.observations}: only one frame; multi-frame retrieval needs at least two (or use --model)"
            )
        kwargs = {}
        if args.method == "joint":
            kwargs["daylight"] = args.daylight_model
        if args.model_effects == "auto":
            from .diagnosis.cli import run_diagnosis
            from .diagnosis.fit import estimate_with_effect

            diag = run_diagnosis(args.observations, obs, css, reestimate=False)
            result = estimate_with_effect(obs, css, diag, method=args.method, **kwargs)
            print(f"illumon: model effects: {diag.effect}"
                  + (f" (patch {diag.patch})" if diag.patch else "") + (f" (frame {diag.frame})" if diag.frame else ""),
                  file=sys.stderr)
        else:
            result = retrieve_illuminants(obs, css, method=args.method, **kwargs)
        extra = None
    write_estimates(args.out, result, extra)
    if args.reflectances:
        _write_reflectances(args.reflectances, result)
    return 0


def read_known(args: argparse.Namespace, obs) -> dict[str, np.ndarray]:
    """``--known-reflectances`` of ``estimate``/``fit``: read, and check that every known patch is observed."""
    if not getattr(args, "known_reflectances", None):
        return {}
    from .camera.references import read_known_reflectances

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
    from .model import fit_scene_model
    from .spectra import read_sensitivities

    css = read_sensitivities(args.sensitivities) if args.sensitivities else None
    if len(obs.frames) < 2:
        raise UsageError(f"{args.observations}: only one frame; a history needs at least two")
    try:
        return fit_scene_model(obs, css, known_reflectances=known or None, **kwargs)
    except ValueError as exc:
        raise ValueError(f"{args.observations}: {exc}") from None


def _estimate_calibrated(args: argparse.Namespace, obs, known: dict[str, np.ndarray]):
    """``estimate`` for a camera nobody measured, or one with references: calibrate jointly with the scene
    (:mod:`illumon.camera.calibration`); ``joint`` gives the fit's own estimates with intervals, other methods run
    on the calibrated sensitivities."""
    model = fit_camera_and_scene(args, obs, known)
    scene = obs.select_patches(model.patches)
    if args.method == "joint":
        from .model import interval_columns

        result, extra = model.history_estimate
        return result, interval_columns(result, extra)
    from .retrieval import retrieve_illuminants

    return retrieve_illuminants(scene, model.sensitivities, method=args.method), None


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``illumon`` command."""
    parser = argparse.ArgumentParser(
        prog="illumon", description="Daylight illuminant and white balance for fixed cameras"
    )
    sub = parser.add_subparsers(dest="command", required=True)

    est = sub.add_parser("estimate", help="estimate every frame's illuminant and white-balance gains")
    est.add_argument("observations", help="OBSERVATIONS.csv with columns frame,time,patch,r,g,b")
    est.add_argument("--sensitivities", help="camera sensitivities CSV wavelength_nm,r,g,b (none: a camera nobody measured)")
    est.add_argument("--known-reflectances", help="KNOWN.csv wavelength_nm,<patch id>,…: references of known reflectance")
    est.add_argument("--model", help="scene model JSON from `illumon fit` (per-frame estimates with intervals)")
    est.add_argument("--out", required=True, help="ESTIMATES.csv to write")
    est.add_argument("--method", default="joint", choices=["joint", "marguier2007", "gray_world"])
    est.add_argument("--daylight-model", default="cie", choices=["cie", "measured"])
    est.add_argument("--white-level", type=white_level_arg, default=255.0, help="value of a saturated pixel (255)")
    est.add_argument("--reflectances", help="also write the recovered patch reflectances to this CSV")
    est.add_argument("--model-effects", default="none", choices=["none", "auto"],
                     help="auto: diagnose the history (`illumon diagnose`) and estimate with the effect modelled")
    est.set_defaults(func=_cmd_estimate)

    for module, fn in (
        ("illumon.model", "add_fit_command"),
        ("illumon.sensitivity.cli", "add_sensitivity_command"),
        ("illumon.reports.cli", "add_report_command"),
        ("illumon.diagnosis.cli", "add_diagnose_command"),
        ("illumon_service.cli", "add_serve_command"),
    ):
        try:
            mod = __import__(module, fromlist=[fn])
        except ImportError:
            continue
        getattr(mod, fn)(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``illumon`` console script."""
    warnings.filterwarnings("ignore")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (UsageError, ValueError, KeyError, FileNotFoundError, np.linalg.LinAlgError) as exc:
        msg = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
        print(f"illumon: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # pragma: no cover
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
