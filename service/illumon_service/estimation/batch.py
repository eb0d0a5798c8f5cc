"""A refit's estimates kept as the estimator's arrays (:class:`RefitEstimates`), their rows built a chunk at a time
when they are written: 100k frames' estimates as row dicts took ~300 MB (61 spectrum floats each as Python objects),
as arrays ~60 MB. The spectra are written as float32 bytes (:func:`~..storage.spectra_bytes`), the other arrays as
JSON text."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import chain, repeat

import numpy as np
import orjson
from illumon.retrieval.common import RetrievalResult
from numpy.typing import NDArray

from ..storage import JSONTexts, StoredJSON, spectra_bytes
from .frame import json_safe

__all__ = ["RefitEstimates", "json_rows", "json_texts"]

_JSON_ARRAYS = ("xy", "white_rgb", "gains_rgb")
"""The estimate's columns that hold an array as JSON lists (the spectrum is float32 bytes, ``spectrum_f32``)."""

_JSON_NULL_TEXT = "null"
"""The older versions' JSON ``spectrum`` column of a row written now (JSON ``null``: the column is ``NOT NULL`` in
their databases), as the text the engine writes for ``None`` (in a :class:`~..storage.JSONTexts` column)."""


def json_rows(values: NDArray[np.float64]) -> list[StoredJSON | list[float]]:
    """Each row of a 2-D float array as the JSON text of its list (:class:`~..storage.StoredJSON`, written by orjson
    straight from the array: the shortest decimal that reads back as the same float, as :func:`json.dumps` writes
    it, ~15 × faster); a row holding NaN or ±infinity as its list instead, which the engine writes with
    :func:`json.dumps` as before (``NaN``, ``Infinity``, where orjson would write ``null``)."""
    return [StoredJSON(v) if type(v) is str else v for v in json_texts(values)]


def json_texts(values: NDArray[np.float64]) -> JSONTexts:
    """:func:`json_rows` as a column for :func:`~..storage.insert_columns`: the texts as plain ``str`` in a
    :class:`~..storage.JSONTexts` (the driver binds a ``str`` subclass more slowly), the non-finite rows' lists as
    they are."""
    a = np.ascontiguousarray(values, dtype=np.float64)
    finite = np.isfinite(a).all(axis=1)
    opt = orjson.OPT_SERIALIZE_NUMPY
    if 0 < a.shape[1] <= _WHOLE_WIDTH and a.shape[0] and finite.all():
        # narrow rows (xy, white, gains): one call for the whole array, its rows cut out of the text — orjson's
        # per-call cost was most of a 3-value row's (~0.03 s per 100k rows and column saved); the same texts
        text = orjson.dumps(a, option=opt)  # [[r0],[r1],…]: numbers hold no bracket
        return JSONTexts(text[1:-1].replace(b"],[", b"]\n[").decode().split("\n"))
    return JSONTexts(orjson.dumps(row, option=opt).decode() if ok else row.tolist()
                     for row, ok in zip(a, finite.tolist(), strict=True))


_WHOLE_WIDTH = 8
"""Rows of at most this many values are written by :func:`json_rows` from one text of the whole array (for wide
rows, the spectrum's 61 values, cutting the text apart cost more than the calls it saves)."""


def _json_dicts(rows: list[dict | None]) -> JSONTexts:
    """Each dict of ``rows`` as its orjson text (a plain ``str`` of a :class:`~..storage.JSONTexts`), ``None`` as
    ``None``. Dicts whose values hold no dict (numbers, ``None``, lists of them): cut out of one orjson text of the
    whole list where no row is ``None`` (one call instead of one a row; the same texts)."""
    if rows and all(type(v) is dict for v in rows):
        text = orjson.dumps(rows)  # [{…},{…}]: no value holds a brace
        return JSONTexts(text[1:-1].replace(b"},{", b"}\n{").decode().split("\n"))
    return JSONTexts(orjson.dumps(iv).decode() if iv is not None else None for iv in rows)


def _interval_texts(intervals: dict[str, NDArray[np.float64]], n: int) -> JSONTexts | None:
    """The JSON texts :func:`_json_dicts` writes for the rows ``{key: value of row i, …}`` of ``intervals`` (each an
    array of ``n`` numbers or of ``n`` rows of a few numbers), assembled from one orjson text of each array instead of a
    dict and an orjson call per row (~0.1 s per 100k rows); ``None`` where that does not apply: no arrays, a
    non-finite value (written ``null`` by the rows' path), a wider or higher-dimensional array. orjson writes a
    float64 of an array as it writes the same Python float (tested on random bit patterns), and a key as it writes
    it in a dict."""
    if not intervals or not n:
        return None
    parts: list = []
    for j, (key, v) in enumerate(intervals.items()):
        if len(v) != n or not (v.ndim == 1 or (v.ndim == 2 and 0 < v.shape[1] <= _WHOLE_WIDTH)) \
                or not np.isfinite(v).all():
            return None
        if v.ndim == 1:  # [a,b,…]: numbers hold no comma
            texts = orjson.dumps(np.ascontiguousarray(v), option=orjson.OPT_SERIALIZE_NUMPY)[1:-1].decode().split(",")
        else:
            texts = json_texts(v)
        parts += [repeat(("{" if j == 0 else ",") + orjson.dumps(key).decode() + ":"), texts]
    joined = "".join(chain.from_iterable(zip(*parts, repeat("}\n"))))  # no text holds a newline
    return JSONTexts(joined[:-1].split("\n"))


@dataclass
class _Part:
    result: RetrievalResult
    extra: dict | None
    """Per-frame 95 % intervals (:func:`~.frame.frame_intervals`); ``None``: the rows carry none."""
    confidence: NDArray[np.float64]
    index: NDArray[np.intp]
    """The frames of ``result`` that have an estimate."""
    source: str


_ROW_KEYS = ("cct_k", "duv", "xy", "white_rgb", "gains_rgb", "confidence", "spectrum", "spectrum_f32", "intervals",
             "source")
"""An estimate row's columns, in :func:`~.frame.estimate_row`'s order."""


def _part_columns(p: _Part, index: NDArray[np.intp], json_text: bool) -> dict[str, list]:
    """The estimates of the frames ``index`` of ``p`` a column at a time: ``frame_id`` (str) and the columns of
    :data:`_ROW_KEYS` (a list of one value per frame each), as :func:`~.frame.estimate_row` with
    :func:`~.frame.frame_intervals` gives them frame by frame; with ``json_text`` the JSON columns (arrays and
    intervals) as their JSON text (:func:`json_rows`; intervals hold no non-finite value: ``None`` instead)."""
    r = p.result
    conf = p.confidence[index]
    conf = np.where(np.isnan(conf), conf, np.clip(conf, 0.0, 1.0)).tolist()
    arrays = {"xy": r.xy, "white_rgb": r.white, "gains_rgb": r.gains}
    as_json = json_texts if json_text else (lambda a: a.tolist())
    columns = {"frame_id": [str(r.frames[i]) for i in index.tolist()], "cct_k": r.cct[index].tolist(),
               "duv": r.duv[index].tolist(), **{k: as_json(arrays[k][index]) for k in _JSON_ARRAYS},
               "confidence": conf,
               "spectrum": JSONTexts([_JSON_NULL_TEXT] * index.size) if json_text else [None] * index.size,
               "spectrum_f32": spectra_bytes(r.spectra[index])}
    if p.extra is None:
        columns["intervals"] = [None] * index.size
    else:
        intervals: dict[str, NDArray[np.float64]] = {k: np.asarray(v, dtype=float)[index]
                                                     for k, v in p.extra.items() if k != "confidence"}
        for k in ("gain_lo", "gain_hi"):
            if k in r.info:
                intervals[k] = np.asarray(r.info[k], dtype=float)[index]
        texts = _interval_texts(intervals, index.size) if json_text else None
        if texts is not None:
            columns["intervals"] = texts
        else:
            lists = [v.tolist() if np.isfinite(v).all() else json_safe(v.tolist()) for v in intervals.values()]
            rows = [dict(zip(intervals, values, strict=True)) or None for values in zip(*lists, strict=True)] \
                if lists else [None] * index.size
            columns["intervals"] = _json_dicts(rows) if json_text else rows
    columns["source"] = [p.source] * index.size
    return columns


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
            frames = p.result.frames
            for i in p.index.tolist():
                yield str(frames[i])

    def cct(self) -> NDArray[np.float64]:
        """The estimates' CCTs (K)."""
        return np.concatenate([p.result.cct[p.index] for p in self._parts]) if self._parts else np.array([])

    def columns(self, chunk: int, json_text: bool = False) -> Iterator[dict[str, list]]:
        """The estimates a column at a time, at most ``chunk`` frames at a time: ``frame_id`` (str) and the columns
        of the rows :func:`~.frame.estimate_row` and :func:`~.frame.frame_intervals` give, each converted from its
        array at once (frame by frame, the conversions were half a 2 000-frame refit's write step); with
        ``json_text`` the JSON columns as the JSON text the database stores, in :class:`~..storage.JSONTexts`
        columns (:func:`json_texts`; values read back equal)."""
        for p in self._parts:
            for start in range(0, p.index.size, chunk):
                yield _part_columns(p, p.index[start:start + chunk], json_text)

    def rows(self, chunk: int, json_text: bool = False) -> Iterator[list[tuple[str, dict]]]:
        """``(frame id, estimate row)`` pairs, exactly ``chunk`` at a time but the last: the rows of
        :meth:`columns` (with ``json_text`` a JSON text as a :class:`~..storage.StoredJSON`, which a row carries to
        any writer)."""
        out: list[tuple[str, dict]] = []
        for cols in self.columns(chunk, json_text):
            cols = {k: [StoredJSON(v) if type(v) is str else v for v in c] if type(c) is JSONTexts else c
                    for k, c in cols.items()}
            out += [(fid, dict(zip(_ROW_KEYS, values, strict=True)))
                    for fid, *values in zip(*(cols[k] for k in ("frame_id", *_ROW_KEYS)), strict=True)]
            while len(out) >= chunk:
                yield out[:chunk]
                out = out[chunk:]
        if out:
            yield out

    def as_dict(self) -> dict[str, dict]:
        """Every estimate row by frame id (small histories, tests)."""
        return {fid: row for part in self.rows(10_000) for fid, row in part}
