"""The ``illumon`` command: one module per subcommand, over the library (nothing in the library imports it).

Subcommands: ``estimate`` (:mod:`.estimate`), ``fit`` (:mod:`.fit`), ``sensitivity`` (:mod:`.sensitivity`), ``report
daylight`` (:mod:`.report`), ``diagnose`` (:mod:`.diagnose`), and the commands of plug-ins: every entry point of the
group :data:`PLUGIN_GROUP` (``illumon.cli``) names a function that adds its subcommands to the parser's subparsers.
The service package registers ``serve`` / ``refit`` / ``backup`` / ``restore`` / ``prune`` that way (see
``pyproject.toml``); the library never imports it. Errors in the user's input print one line ``illumon: error: …``
naming the file, row and problem, and exit with status 2; nothing prints a traceback.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence
from importlib.metadata import entry_points

import numpy as np

from .common import UsageError, white_level_arg, write_estimates
from .diagnose import add_diagnose_command
from .estimate import add_estimate_command
from .fit import add_fit_command
from .report import add_report_command
from .sensitivity import add_sensitivity_command

__all__ = ["main", "build_parser", "write_estimates", "white_level_arg", "UsageError"]


PLUGIN_GROUP = "illumon.cli"
"""Entry-point group of the command's plug-ins: each entry point names a function ``add(subparsers)`` that adds its
subcommands (the service's is ``illumon_service.cli:add_serve_command``)."""

SERVICE_COMMANDS = ("serve", "refit", "backup", "restore", "prune")
"""The subcommands the service extra provides; where no plug-in adds them, stand-ins say which extra to install."""


def _service_missing(args: argparse.Namespace) -> int:
    raise UsageError(f"`illumon {args.command}` needs the service extra: pip install 'illumon[service]'")


def _add_plugin_commands(sub: argparse._SubParsersAction) -> None:
    """The subcommands of every plug-in of :data:`PLUGIN_GROUP` that loads, then stand-ins for the service's
    commands no plug-in added (a plug-in whose package cannot be imported is skipped, as if not installed)."""
    for entry in entry_points(group=PLUGIN_GROUP):
        try:
            add = entry.load()
        except ImportError:
            continue
        add(sub)
    for name in SERVICE_COMMANDS:
        if name not in sub.choices:
            p = sub.add_parser(name, help=f"{name} (needs the service extra)", add_help=False)
            p.set_defaults(func=_service_missing)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``illumon`` command."""
    parser = argparse.ArgumentParser(
        prog="illumon", description="Daylight illuminant and white balance for fixed cameras"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (add_estimate_command, add_fit_command, add_sensitivity_command, add_report_command, add_diagnose_command):
        add(sub)
    _add_plugin_commands(sub)
    return parser


DEGENERATE = ("the fit is degenerate on these data: the patches, frames or values do not differ enough to separate its "
              "unknowns (patches of one colour, frames under one light, values near black) — add patches of different "
              "colours or frames under different light, or check --white-level")
"""The one line a numerical dead end inside a fit is reported with (exit 2)."""


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``illumon`` console script."""
    warnings.filterwarnings("ignore")
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown and getattr(args, "func", None) is not _service_missing:  # the stand-ins take any arguments
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return int(args.func(args) or 0)
    except (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError) as exc:
        # a numerical dead end inside a fit: the data do not separate its unknowns
        print(f"illumon: error: {DEGENERATE} ({exc})", file=sys.stderr)
        return 2
    except (UsageError, ValueError, KeyError, FileNotFoundError) as exc:
        msg = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
        print(f"illumon: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # pragma: no cover
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
