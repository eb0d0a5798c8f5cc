"""The ``illumon sensitivity`` subcommand: camera sensitivities from one chart image.

    illumon sensitivity CHART.csv --chart "BabelColor Average" --out SENSITIVITIES.csv [--method NAME]
        [--illuminant-out ILLUMINANT.csv]

``CHART.csv`` has columns ``patch,r,g,b``, patches numbered 1…24 in the chart's standard order, linear camera
counts.
The output (``wavelength_nm,r,g,b``, 400–700 nm at 5 nm, max-normalised over all channels) can be passed to
``illumon estimate --sensitivities``. :func:`add_sensitivity_command` registers the subcommand on an argparse
sub-parser collection; :func:`run` is its handler.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import colour
import numpy as np
from numpy.typing import NDArray

from ..priors import colourchecker_reflectances
from ..sensitivity import ALIASES, METHODS, estimate_sensitivities
from ..spectra import WAVELENGTHS, SpectralInputError, write_spectral_csv

__all__ = ["add_sensitivity_command", "run", "read_chart_csv"]

SELECTABLE = [m for m in METHODS if m != "han2012"] + list(ALIASES)  # han2012 needs a fluorescent chart


def read_chart_csv(path: str | Path, n_patches: int = 24) -> NDArray[np.float64]:
    """Read ``patch,r,g,b`` chart values (n_patches × 3, standard order); errors name file, row and
    problem."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise SpectralInputError(f"{source}: cannot read file ({exc.strerror or exc})") from exc
    rows = [(i, r) for i, r in enumerate(csv.reader(text.splitlines()), start=1) if r and "".join(r).strip()]
    rows = [(i, [c.strip() for c in r]) for i, r in rows if not r[0].lstrip().startswith("#")]
    if not rows:
        raise SpectralInputError(f"{source}: no data rows")
    header_line, header = rows[0]
    cols = [h.lower() for h in header]
    missing = [c for c in ("patch", "r", "g", "b") if c not in cols]
    if missing:
        raise SpectralInputError(f"{source}: row {header_line}: missing column(s) {', '.join(missing)}")
    idx = [cols.index(c) for c in ("patch", "r", "g", "b")]
    values = np.full((n_patches, 3), np.nan)
    for lineno, cells in rows[1:]:
        if len(cells) < len(header):
            raise SpectralInputError(
                f"{source}: row {lineno}: expected {len(header)} columns, found {len(cells)}"
            )
        try:
            patch_f = float(cells[idx[0]])
        except ValueError:
            raise SpectralInputError(f"{source}: row {lineno}: non-numeric patch {cells[idx[0]]!r}") from None
        if patch_f != int(patch_f) or not 1 <= int(patch_f) <= n_patches:
            raise SpectralInputError(
                f"{source}: row {lineno}: patch {cells[idx[0]]!r} is not in 1…{n_patches}"
            )
        patch = int(patch_f)
        rgb = []
        for name, j in zip("rgb", idx[1:], strict=True):
            try:
                v = float(cells[j])
            except ValueError:
                raise SpectralInputError(
                    f"{source}: row {lineno}: non-numeric {name} value {cells[j]!r}"
                ) from None
            if not np.isfinite(v):
                raise SpectralInputError(f"{source}: row {lineno}: non-finite {name} value {cells[j]!r}")
            if v < 0:
                raise SpectralInputError(f"{source}: row {lineno}: negative {name} value {cells[j]!r}")
            rgb.append(v)
        if not np.isnan(values[patch - 1, 0]):
            raise SpectralInputError(f"{source}: row {lineno}: patch {patch} appears twice")
        values[patch - 1] = rgb
    absent = [str(i + 1) for i in range(n_patches) if np.isnan(values[i, 0])]
    if absent:
        raise SpectralInputError(f"{source}: patch(es) {', '.join(absent)} missing; need 1…{n_patches}")
    if np.any(values.max(axis=0) <= 0):
        raise SpectralInputError(f"{source}: a channel is zero on every patch")
    return values


def run(args: argparse.Namespace) -> int:
    """Handler of ``illumon sensitivity``: estimate, then write the sensitivities (and illuminant) CSV."""
    if args.chart not in colour.SDS_COLOURCHECKERS:
        known = ", ".join(k for k in colour.SDS_COLOURCHECKERS if " " in k)
        raise ValueError(f"--chart: unknown chart {args.chart!r}; known: {known}")
    _, refl = colourchecker_reflectances(args.chart)
    rgb = read_chart_csv(args.chart_csv, refl.shape[0])
    result = estimate_sensitivities(rgb, refl, method=args.method)
    c = result.sensitivities
    write_spectral_csv(
        args.out,
        WAVELENGTHS,
        {"r": c[:, 0], "g": c[:, 1], "b": c[:, 2]},
        comments=[
            f"camera sensitivities estimated by illumon sensitivity --method {args.method}",
            f"from {Path(args.chart_csv).name} ({args.chart}); max-normalised over all channels",
        ],
    )
    if getattr(args, "illuminant_out", None):
        if result.illuminant is None:
            raise ValueError(f"--illuminant-out: method {args.method!r} recovers no illuminant")
        write_spectral_csv(
            args.illuminant_out,
            WAVELENGTHS,
            {"illuminant": result.illuminant},
            comments=[f"illuminant recovered by illumon sensitivity --method {args.method}; unit mean"],
        )
    return 0


def add_sensitivity_command(subparsers: argparse._SubParsersAction) -> None:
    """Register ``sensitivity`` on an argparse sub-parser collection (handler in ``func``)."""
    p = subparsers.add_parser(
        "sensitivity",
        help="estimate camera spectral sensitivities from one chart image under unknown daylight",
        description="Estimate camera spectral sensitivities from one ColorChecker image under unknown light.",
    )
    p.add_argument("chart_csv", metavar="CHART.csv", help="patch,r,g,b linear camera values, patches 1…24")
    p.add_argument("--chart", default="BabelColor Average", help="colour-science ColourChecker name")
    p.add_argument("--out", required=True, metavar="SENSITIVITIES.csv", help="output wavelength_nm,r,g,b")
    p.add_argument("--method", default="default", choices=SELECTABLE, help="estimator (default: %(default)s)")
    p.add_argument("--illuminant-out", metavar="FILE", help="also write the recovered illuminant spectrum")
    p.set_defaults(func=run)
