"""Every key a numpydoc ``References`` section cites is an entry of ``docs/bibliography.md``, and every entry is cited."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CITATION = re.compile(r"^\s*\.\. \[([A-Za-z][\w.-]*)\] ", re.M)


def _bibliography_keys() -> set[str]:
    text = (ROOT / "docs" / "bibliography.md").read_text()
    return set(re.findall(r"^\| `([^`]+)` \|", text, re.M))


def _cited_keys() -> dict[str, list[str]]:
    cited: dict[str, list[str]] = {}
    for path in [*(ROOT / "core" / "illumon").rglob("*.py"), *(ROOT / "benchmarks").glob("*.py")]:
        for key in CITATION.findall(path.read_text()):
            cited.setdefault(key, []).append(str(path.relative_to(ROOT)))
    return cited


def test_every_cited_key_is_in_the_bibliography():
    known = _bibliography_keys()
    missing = {k: v for k, v in _cited_keys().items() if k not in known}
    assert not missing, missing


def test_every_bibliography_entry_is_cited():
    assert _bibliography_keys() - set(_cited_keys()) == set()


def test_no_numbered_citations_left():
    numbered = [str(p.relative_to(ROOT)) for p in (ROOT / "core" / "illumon").rglob("*.py")
                if re.search(r"^\s*\.\. \[\d+\] ", p.read_text(), re.M)]
    assert not numbered, numbered
