"""The currency of the diagnosis's two stages: one extension of the base model tried, and how it scored."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Candidate"]


@dataclass
class Candidate:
    """One extension tried: its ΔBIC against the base (negative favours the extension) and fitted parameters."""

    effect: str
    score: float
    parameters: dict = field(default_factory=dict)
    patch: int | None = None
    frame: int | None = None
    residual: float | None = None
