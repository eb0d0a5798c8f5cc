"""``illumon report daylight --measured SPECTRA.csv --out DIR/``: what the CIE D-series gets wrong for measured daylight."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..spectra import SpectralInputError

__all__ = ["add_report_command", "run_daylight_report"]


def run_daylight_report(args: argparse.Namespace) -> int:
    """Handler of ``illumon report daylight``; raises ValueError / SpectralInputError with a one-line message."""
    from ..reports.daylight import daylight_report

    path = Path(args.measured)
    if not path.is_file():
        raise SpectralInputError(f"{path}: no such spectra file (expected wavelength_nm,<id>,… CSV)")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: output path exists and is not a folder")
    if args.histories < 0 or args.frames < 2 or args.patches < 2:
        raise ValueError("--histories must be ≥ 0, --frames and --patches ≥ 2")
    summary = daylight_report(
        path, out, split=args.split, seed=args.seed, n_histories=args.histories, n_frames=args.frames,
        n_patches=args.patches, time_budget_s=args.time_budget, simulate=args.histories > 0,
    )
    g = summary["gain"]
    line = {"report": str(out / "report.md"), "cie_xy_frac_gfc_999": summary["models"]["cie_xy"]["frac_gfc_999"]}
    if "camera_white_at_true_chromaticity" in g:
        line["camera_white_median_deg"] = {k: v["median_deg"] for k, v in g["camera_white_at_true_chromaticity"].items()}
    if "retrieval" in g:
        line["retrieval_median_angular_deg"] = {k: g["retrieval"][k]["median_angular_deg"] for k in ("cie", "measured")}
    print(json.dumps(line))
    return 0


def add_report_command(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``report daylight --measured SPECTRA.csv --out DIR/`` on the top-level ``subparsers``.

    The handler is stored as ``func`` on the parsed namespace (``args.func(args)``).
    """
    report = subparsers.add_parser("report", help="reproducible reports (Markdown + PNG + JSON)")
    sub = report.add_subparsers(dest="report_command", required=True)
    d = sub.add_parser("daylight", help="measured daylight vs the CIE D models, and the measured-daylight gain")
    d.add_argument("--measured", required=True, metavar="SPECTRA.csv", help="wavelength_nm,<id>… spectra")
    d.add_argument("--out", required=True, metavar="DIR", help="output folder")
    d.add_argument("--split", choices=("time", "random"), default="time", help="training / held-out split")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--histories", type=int, default=12, help="simulated histories for the gain (0: skip)")
    d.add_argument("--frames", type=int, default=30)
    d.add_argument("--patches", type=int, default=10)
    d.add_argument("--time-budget", type=float, default=30.0, help="seconds for the simulated retrievals")
    d.set_defaults(func=run_daylight_report)
    return d
