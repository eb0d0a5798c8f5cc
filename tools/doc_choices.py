"""Write the choice lists of ``docs/cli.md`` and ``docs/service.md`` from the registries that define them.

Run: ``python tools/doc_choices.py`` (rewrites the blocks between ``<!-- choices -->`` and ``<!-- /choices -->``);
``--check`` exits 1 when a block differs from its registries (``tests/docs/test_choices.py`` runs the same check).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEGIN = "<!-- choices: written by tools/doc_choices.py from the registries, do not edit by hand -->"
END = "<!-- /choices -->"


def _section(title: str, where: str, registry, note: str = "") -> str:
    return f"{title} (`{where}`{note}):\n\n{registry.markdown()}\n"


def cli_block() -> str:
    """The choices of the ``illumon`` command."""
    from illumon.camera.primaries import PRIMARIES
    from illumon.cli.estimate import MODEL_EFFECTS
    from illumon.daylight import DAYLIGHT_MODELS
    from illumon.registry import Registry
    from illumon.retrieval import METHODS
    from illumon.retrieval.joint import EXPOSURE_MODES
    from illumon.sensitivity import METHODS as SENSITIVITY_METHODS

    exposures = Registry.choices({k.replace("_", "-"): v for k, v in EXPOSURE_MODES.descriptions.items()})
    return "\n".join([
        _section("`estimate --method`", "illumon.retrieval.METHODS", METHODS),
        _section("`estimate --daylight-model`", "illumon.daylight.DAYLIGHT_MODELS", DAYLIGHT_MODELS),
        _section("`estimate --exposure`", "illumon.retrieval.joint.EXPOSURE_MODES", exposures),
        _section("`estimate --model-effects`", "illumon.cli.estimate.MODEL_EFFECTS", MODEL_EFFECTS),
        _section("`estimate`, `fit` `--primaries`", "illumon.camera.primaries.PRIMARIES", PRIMARIES),
        _section("`sensitivity --method`", "illumon.sensitivity.METHODS", SENSITIVITY_METHODS,
                 "; `han2012` needs a fluorescent chart and is not offered by the command; `bayes` and `huynh2016` "
                 "are accepted as earlier names"),
    ])


def service_block() -> str:
    """The choices of the service's settings and JSON."""
    from illumon.camera import ENCODINGS
    from illumon.camera.primaries import PRIMARIES
    from illumon.camera.references import REFERENCE_KINDS
    from illumon_service.settings import REFIT_METHODS

    return "\n".join([
        _section("`ILLUMON_REFIT_METHOD`", "illumon_service.settings.REFIT_METHODS", REFIT_METHODS),
        _section("`response.encoding`", "illumon.camera.ENCODINGS", ENCODINGS),
        _section("`response.primaries`", "illumon.camera.primaries.PRIMARIES", PRIMARIES),
        _section("calibration `kind`", "illumon.camera.references.REFERENCE_KINDS", REFERENCE_KINDS),
    ])


BLOCKS = {ROOT / "docs" / "cli.md": cli_block, ROOT / "docs" / "service.md": service_block}


def rewritten(path: Path, block: str) -> str:
    """``path``'s text with its choices block replaced by ``block``."""
    text = path.read_text()
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{block}{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="only check; exit 1 when a document differs")
    args = ap.parse_args(argv)
    stale = []
    for path, make in BLOCKS.items():
        new = rewritten(path, make())
        if new != path.read_text():
            stale.append(path.name)
            if not args.check:
                path.write_text(new)
    if args.check and stale:
        print(f"choice lists out of date in {', '.join(stale)}: run python tools/doc_choices.py", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
