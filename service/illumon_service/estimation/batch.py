"""A refit's estimates kept as the estimator's arrays (:class:`RefitEstimates`), their rows built a chunk at a time
when they are written: 100k frames' estimates as row dicts took ~300 MB (61 spectrum floats each as Python objects),
as arrays ~60 MB."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from illumon.retrieval.common import RetrievalResult
from numpy.typing import NDArray

from .frame import json_safe

__all__ = ["RefitEstimates"]


@dataclass
class _Part:
    result: RetrievalResult
    extra: dict | None
    """Per-frame 95 % intervals (:func:`~.frame.frame_intervals`); ``None``: the rows carry none."""
    confidence: NDArray[np.float64]
    index: NDArray[np.intp]
    """The frames of ``result`` that have an estimate."""
    source: str


def _part_rows(p: _Part, index: NDArray[np.intp]) -> list[tuple[str, dict]]:
    """``(frame id, estimate row)`` of the frames ``index`` of ``p``, as :func:`~.frame.estimate_row` with
    :func:`~.frame.frame_intervals` builds them one by one."""
    r = p.result
    conf = p.confidence[index]
    conf = np.where(np.isnan(conf), conf, np.clip(conf, 0.0, 1.0)).tolist()
    columns = {"cct_k": r.cct[index].tolist(), "duv": r.duv[index].tolist(), "xy": r.xy[index].tolist(),
               "white_rgb": r.white[index].tolist(), "gains_rgb": r.gains[index].tolist(), "confidence": conf,
               "spectrum": r.spectra[index].tolist()}
    intervals: dict[str, list] = {}
    if p.extra is not None:
        for k, v in p.extra.items():
            if k != "confidence":
                intervals[k] = np.asarray(v, dtype=float)[index]
        for k in ("gain_lo", "gain_hi"):
            if k in r.info:
                intervals[k] = np.asarray(r.info[k], dtype=float)[index]
        intervals = {k: (v.tolist() if np.isfinite(v).all() else json_safe(v.tolist())) for k, v in intervals.items()}
    frames = r.frames
    keys = list(columns)
    rows = []
    for n, i in enumerate(index.tolist()):
        row = {k: columns[k][n] for k in keys}
        row["intervals"] = {k: v[n] for k, v in intervals.items()} or None if p.extra is not None else None
        row["source"] = p.source
        rows.append((str(frames[i]), row))
    return rows


@dataclass
class RefitEstimates:
    """Estimates of a refit's frames by frame id (str), as the estimator returned them; :meth:`rows` builds their
    rows (:func:`~.frame.estimate_row`) a chunk at a time."""

    _parts: list[_Part] = field(default_factory=list)

    def add(self, result: RetrievalResult, confidence: NDArray[np.float64], keep: NDArray[np.bool_], source: str,
            extra: dict | None = None) -> None:
        """The estimates of ``result``'s frames where ``keep``; ``extra``: the intervals' arrays (``None``: none)."""
        index = np.flatnonzero(keep)
        if index.size:
            self._parts.append(_Part(result, extra, np.asarray(confidence, dtype=float), index, source))

    def update(self, other: RefitEstimates) -> None:
        """Take ``other``'s estimates too (another view's)."""
        self._parts += other._parts

    def __len__(self) -> int:
        return sum(p.index.size for p in self._parts)

    def frame_ids(self) -> Iterator[str]:
        """The frame ids that have an estimate."""
        for p in self._parts:
            for i in p.index:
                yield str(p.result.frames[i])

    def cct(self) -> NDArray[np.float64]:
        """The estimates' CCTs (K)."""
        return np.concatenate([p.result.cct[p.index] for p in self._parts]) if self._parts else np.array([])

    def rows(self, chunk: int) -> Iterator[list[tuple[str, dict]]]:
        """``(frame id, estimate row)`` pairs, at most ``chunk`` at a time: the rows :func:`~.frame.estimate_row`
        and :func:`~.frame.frame_intervals` give, each column converted from its array at once (frame by frame, the
        conversions were half a 2 000-frame refit's write step)."""
        out: list[tuple[str, dict]] = []
        for p in self._parts:
            for start in range(0, p.index.size, chunk):
                out += _part_rows(p, p.index[start:start + chunk])
                while len(out) >= chunk:
                    yield out[:chunk]
                    out = out[chunk:]
        if out:
            yield out

    def as_dict(self) -> dict[str, dict]:
        """Every estimate row by frame id (small histories, tests)."""
        return {fid: row for part in self.rows(10_000) for fid, row in part}
