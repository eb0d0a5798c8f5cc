"""The ``illumon`` command itself: ``serve`` / ``refit`` without the service extra say which extra to install."""

import sys

import pytest
from illumon.cli import main


@pytest.mark.parametrize("command", [["serve", "--port", "9"], ["refit", "--all"]])
def test_service_commands_without_the_extra(monkeypatch, capsys, command):
    monkeypatch.setitem(sys.modules, "illumon_service.cli", None)  # as if the service extra were not installed
    assert main(command) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"illumon: error: `illumon {command[0]}` needs the service extra: pip install 'illumon[service]'"
