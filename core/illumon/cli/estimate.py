"""``illumon estimate OBSERVATIONS.csv [--sensitivities S.csv] [--known-reflectances KNOWN.csv] --out ESTIMATES.csv``
(multi-frame retrieval; a camera nobody measured or one with references; or per frame with ``--model``)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from ..registry import Registry
from .common import (
    UsageError,
    add_primaries,
    add_white_level,
    fit_camera_and_scene,
    read_known,
    write_estimates,
    write_reflectances,
)

__all__ = ["add_estimate_command", "MODEL_EFFECTS"]

MODEL_EFFECTS = Registry.choices({
    "none": "estimate with the linear model as it is",
    "auto": "diagnose the history (`illumon diagnose`) and estimate with the effect found modelled",
})
"""``illumon estimate --model-effects``."""


def _cmd_estimate(args: argparse.Namespace) -> int:
    from ..observations import read_observations

    obs = read_observations(args.observations, white_level=args.white_level)
    known = read_known(args, obs)
    if args.exposure == "shared" and (args.model or known or not args.sensitivities or args.method != "joint"):
        raise UsageError("--exposure shared goes with --method joint and --sensitivities (no --model, no references)")
    if args.model and (known or args.sensitivities):
        raise UsageError("--model already holds the camera; --sensitivities and --known-reflectances go with `illumon fit`")
    if args.model:
        from ..model import estimate_with_model

        result, extra = estimate_with_model(obs, args.model)
    elif known or not args.sensitivities or (len(obs.frames) < 2 and args.method == "joint"):
        # a single frame of a measured camera: the scene model (the priors hold what a history would tell)
        result, extra = _estimate_calibrated(args, obs, known)
    else:
        from ..retrieval import MULTI_FRAME, retrieve_illuminants
        from ..spectra import read_sensitivities

        css = measured = read_sensitivities(args.sensitivities)
        if args.primaries == "srgb":
            from ..camera.primaries import to_srgb_primaries

            css = to_srgb_primaries(css)
        if len(obs.frames) < 2 and args.method in MULTI_FRAME:
            raise UsageError(f"{args.observations}: only one frame; --method {args.method} needs at least two (the "
                             "default --method joint estimates a single frame)")
        kwargs = {}
        if args.method == "joint":
            kwargs["daylight"] = args.daylight_model
            kwargs["exposure"] = args.exposure.replace("-", "_")
        if args.model_effects == "auto":
            from ..diagnosis.correction import estimate_with_effects
            from .diagnose import run_diagnosis

            # the diagnosis reads the sensitivities as `illumon diagnose` does (its scene model carries them to sRGB
            # primaries itself when told --primaries srgb)
            diag = run_diagnosis(args.observations, obs, measured, reestimate=False, white_level=args.white_level,
                                 primaries=args.primaries)
            result = estimate_with_effects(obs, css, diag, method=args.method, **kwargs)
            more = [e["effect"] for e in diag.effects[1:]]
            print(f"illumon: model effects: {diag.effect}" + (f" (and {', '.join(more)})" if more else "")
                  + (f" (patch {diag.patch})" if diag.patch else "") + (f" (frame {diag.frame})" if diag.frame else ""),
                  file=sys.stderr)
        else:
            result = retrieve_illuminants(obs, css, method=args.method, **kwargs)
        from ..model.lamps import non_daylight_column

        extra = {"non_daylight": non_daylight_column(obs, css, primaries=args.primaries)}
    write_estimates(args.out, result, extra)
    if args.reflectances:
        write_reflectances(args.reflectances, result)
    return 0


def _estimate_calibrated(args: argparse.Namespace, obs, known: dict[str, np.ndarray]):
    """``estimate`` for a camera nobody measured, or one with references: calibrate jointly with the scene
    (:mod:`illumon.camera.calibration`); ``joint`` gives the fit's own estimates with intervals, other methods run
    on the calibrated sensitivities."""
    model = fit_camera_and_scene(args, obs, known)
    for msg in model.identifiability.get("warnings", []):  # as `illumon fit` says them (here beside the CSV written)
        print(f"illumon: warning: {msg}", file=sys.stderr)
    scene = obs.select_patches(model.patches)
    if args.method == "joint":
        from ..model import interval_columns

        result, extra = model.history_estimate
        return result, interval_columns(result, extra)
    from ..model.lamps import non_daylight_column
    from ..retrieval import retrieve_illuminants

    return (retrieve_illuminants(scene, model.sensitivities, method=args.method),
            {"non_daylight": non_daylight_column(scene, model.sensitivities,
                                                 primaries=model.camera.get("primaries", "camera"))})


def add_estimate_command(sub: Any) -> None:
    """Register ``illumon estimate``."""
    from ..daylight import DAYLIGHT_MODELS
    from ..retrieval import METHODS
    from ..retrieval.joint import EXPOSURE_MODES

    est = sub.add_parser("estimate", help="estimate every frame's illuminant and white-balance gains")
    est.add_argument("observations", help="OBSERVATIONS.csv with columns frame,time,patch,r,g,b")
    est.add_argument("--sensitivities", help="camera sensitivities CSV wavelength_nm,r,g,b (none: a camera nobody measured)")
    est.add_argument("--known-reflectances", help="KNOWN.csv wavelength_nm,<patch id>,…: references of known reflectance")
    est.add_argument("--model", help="scene model JSON from `illumon fit` (per-frame estimates with intervals)")
    est.add_argument("--out", required=True, help="ESTIMATES.csv to write")
    est.add_argument("--method", default="joint", choices=list(METHODS))
    est.add_argument("--daylight-model", default="cie", choices=list(DAYLIGHT_MODELS))
    est.add_argument("--exposure", default="per-frame", choices=[m.replace("_", "-") for m in EXPOSURE_MODES],
                     help="joint: fit every frame's exposure (default: auto-exposure, clouds) or one for all frames "
                          "(locked exposure under daylight of equal power, Marguier & Süsstrunk's assumption)")
    add_white_level(est)
    add_primaries(est)
    est.add_argument("--reflectances", help="also write the recovered patch reflectances to this CSV")
    est.add_argument("--model-effects", default="none", choices=list(MODEL_EFFECTS),
                     help="auto: diagnose the history (`illumon diagnose`) and estimate with the effect modelled")
    est.set_defaults(func=_cmd_estimate)
