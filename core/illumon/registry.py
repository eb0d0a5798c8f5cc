"""One registry per choice a user makes: the names typed, what each selects and a line saying what it is.

A :class:`Registry` is a plain ``dict`` of name → what the name selects (a function, a class, or the description
itself for a choice that only switches behaviour), with :attr:`Registry.descriptions` beside it. Everything that
offers the choice reads the registry, never a copy of its names: the CLI's ``choices=``, the service's ``Settings``
and HTTP schemas (:meth:`Registry.literal`, so the OpenAPI document lists the same names in the same order), and the
choice lists of ``docs/cli.md`` and ``docs/service.md`` (:meth:`Registry.markdown`; a test checks they agree). The names
are what users type: they keep their spelling (``gray_world``, ``colorchecker``) whatever the Python names do.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Generic, Literal, TypeVar

__all__ = ["Registry"]

V = TypeVar("V")


class Registry(dict[str, V], Generic[V]):
    """Names → what each selects, in the order offered (the first is listed first, not necessarily the default).

    Parameters
    ----------
    entries
        ``name: (value, description)`` for every name.
    """

    descriptions: dict[str, str]

    def __init__(self, entries: Mapping[str, tuple[V, str]]) -> None:
        super().__init__({name: value for name, (value, _) in entries.items()})
        self.descriptions = {name: description for name, (_, description) in entries.items()}

    @classmethod
    def choices(cls, descriptions: Mapping[str, str]) -> Registry[str]:
        """A registry whose names select nothing but themselves: each value is its description."""
        return Registry({name: (text, text) for name, text in descriptions.items()})

    def with_first(self, name: str, value: V, description: str) -> Registry[V]:
        """A new registry with ``name`` offered before these names (e.g. the service's ``model`` before the retrieval
        methods)."""
        return Registry({name: (value, description), **{k: (v, self.descriptions[k]) for k, v in self.items()}})

    def literal(self, names: Iterable[str] | None = None) -> Any:
        """``Literal[<names>]`` for pydantic fields (every name by default), in the registry's order."""
        return Literal[tuple(self if names is None else names)]  # type: ignore[valid-type]

    def markdown(self, fmt: str = "`{name}`") -> str:
        """A Markdown bullet list, one line per name with its description (the docs' choice lists)."""
        return "\n".join(f"* {fmt.format(name=name)}: {text}" for name, text in self.descriptions.items())
