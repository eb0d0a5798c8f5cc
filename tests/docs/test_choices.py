"""The choice lists of the docs are the registries' (``tools/doc_choices.py``), and the prose that names choices agrees."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _tool():
    spec = importlib.util.spec_from_file_location("doc_choices", ROOT / "tools" / "doc_choices.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_docs_list_the_registries_choices():
    tool = _tool()
    for path, make in tool.BLOCKS.items():
        assert tool.rewritten(path, make()) == path.read_text(), f"run python tools/doc_choices.py ({path.name})"


def test_refit_method_prose_names_the_retrieval_methods():
    from illumon.retrieval import METHODS

    assert f"ILLUMON_REFIT_METHOD={'|'.join(METHODS)}" in (ROOT / "docs" / "service.md").read_text()


def test_cli_and_settings_offer_the_registries_names():
    import argparse

    from illumon.cli.estimate import MODEL_EFFECTS, add_estimate_command
    from illumon.daylight import DAYLIGHT_MODELS
    from illumon.retrieval import METHODS
    from illumon_service.settings import REFIT_METHODS, Settings

    sub = argparse.ArgumentParser().add_subparsers()
    add_estimate_command(sub)
    actions = {a.dest: a for a in sub.choices["estimate"]._actions}
    assert actions["method"].choices == list(METHODS)
    assert actions["daylight_model"].choices == list(DAYLIGHT_MODELS)
    assert actions["model_effects"].choices == list(MODEL_EFFECTS)
    assert list(REFIT_METHODS) == ["model", *METHODS]
    assert Settings.model_fields["refit_method"].annotation.__args__ == tuple(REFIT_METHODS)
