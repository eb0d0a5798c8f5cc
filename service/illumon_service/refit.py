"""A refit of one camera, in four steps: **read** its stored history, **fit** a scene model per view and estimate
every frame with it, **check** the declared tone response and gather the warnings, **write** the estimates and the
switch to the new models in one transaction.

:func:`refit_camera` runs the steps in order; the job runner (:mod:`.jobs`) runs it in a background thread, and
``illumon refit`` runs it for one camera or fans cameras out over Dask (:func:`.jobs.run_batch`).
"""

from __future__ import annotations

import gc
import json
import logging
import math
import operator
import re
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from itertools import chain, repeat
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import orjson
from illumon.observations import Observations
from numpy.typing import NDArray
from sqlalchemy.engine import Row
from sqlalchemy.orm import Session, sessionmaker

from . import crud
from .estimation import (
    RefitEstimates,
    RefitInputError,
    calibration_frames,
    camera_primaries,
    check_response,
    estimate_frame,
    history_arrays,
    history_row,
    refit_estimates,
    remove_old_models,
    sensitivities_array,
    versioned_model_path,
    view_model_key,
)
from .limits import MAX_VALUE, frame_problem
from .storage import DateTimeTexts, Frame, as_utc, json_texts_like, orjson_loads

__all__ = ["refit_camera", "read_history", "fit_views", "check_refit", "write_refit", "History", "ViewHistory",
           "Refitted", "MAX_DROPPED_LISTED", "READ_CHUNK"]

log = logging.getLogger("illumon_service.jobs")

MAX_DROPPED_LISTED = 100
"""Frames a refit's summary lists by id among those it left out (all are counted)."""


def refit_camera(
    sessions: sessionmaker[Session],
    camera_id: int,
    *,
    data_dir: Path,
    max_frames: int = 100_000,
    method: str = "model",
    max_fit_frames: int = 300,
    progress: Callable[[float], None] | None = None,
) -> dict:
    """Re-estimate the most recent ``max_frames`` frames of a camera and store the estimates; returns a summary.

    Frames it cannot use are left out and reported (``dropped``: frame id and reason — a value outside the ranges of
    :mod:`.limits`, stored by an older version), never a reason to fail. Each view's new scene model is written to a
    new versioned file; the estimates and the switch to the new models (:attr:`.storage.Camera.models`) are then
    committed in one transaction (:func:`write_refit`), so a crash at any point leaves either the old estimates and
    models or the new ones, never a mixture; frames stored while the fit ran are estimated with the new model in that
    same transaction.

    Parameters
    ----------
    sessions
        Session factory of the service database.
    camera_id
        The camera to refit.
    data_dir
        Service data folder (the fitted scene models go to ``models/camera-<id>[-view-<view>].<version>.json``).
    max_frames
        At most this many of the most recent frames are re-estimated.
    method
        ``model`` (scene model fit + per-frame estimates) or a retrieval method; see
        :func:`~.estimation.refit_estimates`.
    max_fit_frames
        Frames the scene model's reflectances are fitted on (spread over the illuminant range).
    progress
        Called with the fraction done (0…1).

    Returns
    -------
    dict
        Frames estimated, skipped, dropped (``dropped``: ``[{"frame_id", "reason"}]``, at most
        :data:`MAX_DROPPED_LISTED`, ``dropped_frames`` their number), method, model ``version``, timings
        (``seconds``, ``read_s``, ``fit_s``, ``write_s``), the check of the declared tone response
        (``response_check``, :func:`~.estimation.check_response`) and ``warnings``: every warning of the refit in one
        list (tone response, calibration images, views, the model's identifiability and white-balance warnings), shown
        with the camera and on the status page.

    Raises
    ------
    RefitInputError
        Too few usable frames.
    """
    t0 = time.perf_counter()
    started = time.time()
    report = progress or (lambda _p: None)
    with _objects_held_aside() as aside:
        history = read_history(sessions, camera_id, max_frames)
        t_read = time.perf_counter()
        report(0.1)
        refitted = fit_views(history, data_dir, method, max_fit_frames)
        summary = check_refit(history, refitted)
        t_fit = time.perf_counter()
        report(0.8)
        aside()  # the history and the estimates too, before the write makes its rows
        written = write_refit(sessions, data_dir, history, refitted)
    remove_old_models(data_dir, camera_id, refitted.models, started)
    t_end = time.perf_counter()
    summary.update({
        "camera_id": camera_id,
        "frames_written": written,
        "seconds": round(t_end - t0, 3),
        "read_s": round(t_read - t0, 3),
        "fit_s": round(t_fit - t_read, 3),
        "write_s": round(t_end - t_fit, 3),
    })
    report(1.0)
    return summary


@contextmanager
def _objects_held_aside() -> Iterator[Callable[[], None]]:
    """The objects alive on entry (and whenever the yielded function is called) left out of the cyclic garbage
    collector's passes until exit (:func:`gc.freeze`, then :func:`gc.unfreeze`).

    The read and write steps make a few containers per frame (the rows' JSON dicts and lists, the estimate rows):
    every collection of the oldest generation they trigger walked every object of the process as well — the imported
    libraries', the history's — and took 35–40 % of a 100k-frame read step (9.6 → 6.0 s with the collector off, 7.0 s
    with the objects set aside). Nothing is kept longer by it than by the collector being late: objects are still
    freed when their last reference goes, a cycle among objects set aside is collected after the refit, and objects
    made by other threads meanwhile are collected as before."""
    gc.freeze()
    try:
        yield gc.freeze
    finally:
        gc.unfreeze()


@contextmanager
def _collector_paused() -> Iterator[None]:
    """The cyclic garbage collector's automatic passes off for the block (:func:`gc.disable`), on again after it
    if they were on before.

    A read chunk's rows decode into ~80 containers a frame (a dict and a list per region), alive together until the
    chunk is converted into arrays: every pass of the collector the allocations trigger meanwhile walks them all,
    and the passes took 15–25 % of a 100k-frame read step even with the older objects set aside
    (:func:`_objects_held_aside`). They make no cycles (they are freed by their counts when the chunk is let go, in
    the block), so nothing waits for the collector longer than the block (a few tens of milliseconds); other threads'
    cyclic garbage is collected after it. Two refits in two threads at once may leave the passes on for the end of
    one's block (a slower chunk, nothing else); they are never left off."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


READ_CHUNK = 2000
"""Frames the read step converts at a time (their rows are then let go)."""


@dataclass
class ViewHistory:
    """One view's usable frames, oldest first, as arrays: region means with the camera's applied gains and exposure
    divided out (:func:`~.estimation.history_row`), as :func:`~.estimation.build_observations` lays them out."""

    region_ids: list[str]
    ids: NDArray[np.int64]
    taken_at: list[datetime | str]
    """As stored (the estimate rows' ``taken_at``): the stored text where it is SQLite's form of a time
    (:func:`_stored_times`), else the time read."""
    times: list[str]
    """ISO 8601, UTC."""
    values: NDArray[np.float64]
    sd: NDArray[np.float64] | None
    used: NDArray[np.int64]
    """Regions with a value, per frame."""

    def __len__(self) -> int:
        return int(self.ids.size)

    def observations(self) -> Observations:
        """The frames as estimation's input (what ``build_observations`` makes of their history rows)."""
        return Observations(list(map(str, self.ids.tolist())), list(self.region_ids), self.values, list(self.times),
                            self.sd)


class _ViewRows:
    """A view's usable rows gathered a chunk at a time (newest first) into arrays."""

    def __init__(self, region_ids: list[str], parse: Callable[[Any], Any] | None = None) -> None:
        self.region_ids = region_ids
        self.parse = parse
        """The frames' time column's conversion of a stored value (``None``: the driver's value is the time)."""
        self.ids: list[int] = []
        self.taken_at: list[datetime | str] = []
        self.times: list[str] = []
        self.used: list[int] = []
        self.values: list[NDArray[np.float64]] = []
        self.sd: list[NDArray[np.float64] | None] = []
        """Each chunk's standard errors, ``None`` for a chunk without any (all NaN)."""

    def add(self, frames: Sequence[_Stored], matrix: list | None, plain: _PlainFrames | None = None) -> None:
        """The frames' arrays (:func:`~.estimation.history_arrays`); taken from the numbers the check converted
        (``plain``) when every frame's region means were converted there and are what ``history_arrays`` reads: no
        colour matrix, no applied gains, exposure or standard errors, and exactly the view's regions in the view's
        order (the same floats and NaN, bit for bit)."""
        p = len(self.region_ids)
        start = [-1] if plain is None or plain.values is None or matrix is not None else \
            [plain.start[f.id] if not f.patch_sd and f.applied_gains is None and f.exposure is None
             and list(f.patches) == self.region_ids else -1 for f in frames]
        if frames and min(start) >= 0:
            values = plain.values[(np.array(start)[:, None] + np.arange(p)).ravel()].reshape(len(frames), p, 3)
            sd = None  # no standard errors: NaN throughout, made only if another chunk has some (finish)
        else:
            values, sd = history_arrays(frames, self.region_ids, matrix)
        self._append([f.id for f in frames], [f.taken_at for f in frames], values, sd)

    def add_plain(self, ids: Sequence[int], taken_at: Sequence[Any], values: NDArray[np.float64]) -> None:
        """Frames of :func:`_plain_chunk` (``ids``, stored times and its F × P × 3 region means), as :meth:`add` of
        the same frames gives them: no standard errors."""
        self._append(list(ids), taken_at, values, None)

    def _append(self, ids: list[int], taken_at: Sequence[Any], values: NDArray[np.float64],
                sd: NDArray[np.float64] | None) -> None:
        stored, times = _stored_times(taken_at, self.parse)
        self.ids += ids
        self.taken_at += stored
        self.times += times  # history_row's times
        finite = np.isfinite(values)  # stored values are finite (limits): a region with a value has all three
        self.used += (finite[..., 0] | finite[..., 1] | finite[..., 2]).sum(axis=1).tolist()
        self.values.append(values)
        self.sd.append(sd)

    def finish(self) -> ViewHistory:
        """Oldest first."""
        p = len(self.region_ids)
        values = _oldest_first(self.values, p)
        sd = None
        if any(c is not None for c in self.sd):  # else every frame's are NaN: none (100k frames: 38 MB not made)
            sd = _oldest_first([np.full_like(v, np.nan) if c is None else c
                                for c, v in zip(self.sd, self.values, strict=True)], p)
            sd = sd if np.isfinite(sd).any() else None
        return ViewHistory(self.region_ids, np.array(self.ids[::-1], dtype=np.int64), self.taken_at[::-1],
                           self.times[::-1], values, sd, np.array(self.used[::-1], dtype=np.int64))


def _oldest_first(chunks: list[NDArray[np.float64]], p: int) -> NDArray[np.float64]:
    """The chunks' frames (newest first) in one contiguous F × ``p`` × 3 array, oldest first (one copy)."""
    return np.concatenate([c[::-1] for c in reversed(chunks)]) if chunks else np.empty((0, p, 3))


_SQLITE_TIMES = re.compile(r"(?:\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{6}\n)*")
"""Lines of SQLite's stored text of a time, as SQLAlchemy's SQLite ``DATETIME`` writes it (no time zone)."""


def _stored_times(stored: Sequence[Any], parse: Callable[[Any], Any] | None) -> tuple[list[datetime | str], list[str]]:
    """The frames' times for their estimate rows and as :func:`_utc_iso` gives them (the observations' times), from
    their ``taken_at`` as the driver gives it (:func:`.crud.history_chunks`) and ``parse``, the time column's
    conversion of it (``None``: none). When every one is SQLite's text of a time in the form SQLAlchemy writes
    (:data:`_SQLITE_TIMES`), the texts themselves, which are what writing the times they read as stores, and their
    ISO forms made from the text (issue 29: no datetime formatted twice a frame, ~0.06 s of a 100k-frame refit);
    the texts are still read as times (:meth:`datetime.fromisoformat`, the conversion's), so that a text that is no
    time fails the read as it does otherwise. Any other chunk: the times ``parse`` reads, and their ISO forms."""
    if stored and set(map(type, stored)) == {str}:
        lines = "\n".join(stored) + "\n"
        if len(lines) == 27 * len(stored) and _SQLITE_TIMES.fullmatch(lines):  # one 26-character line each
            for _ in map(datetime.fromisoformat, stored):  # a valid date and time
                pass
            return list(stored), [(t.replace(" ", "T") if t[20:] != "000000" else t[:19].replace(" ", "T")) + "+00:00"
                                  for t in stored]
    times = list(stored) if parse is None else [parse(v) for v in stored]
    return times, _utc_iso(times)


def _utc_iso(times: Sequence[datetime]) -> list[str]:
    """``as_utc(t).isoformat()`` of each time: a naive time (SQLite's) is UTC, whose ISO form is the naive one and
    ``+00:00`` (one call instead of three; 0.2 s of a 100k-frame read)."""
    return [t.isoformat() + "+00:00" if t.tzinfo is None else as_utc(t).isoformat() for t in times]


@dataclass
class History:
    """What the read step gives the others: the camera's usable stored frames and what it needs to fit them."""

    camera_id: int
    by_view: dict[str | None, ViewHistory]
    """Usable frames of each view that has regions (``None``: the default view, present even without)."""
    read_ids: NDArray[np.int64]
    """Every frame read, usable or not (frames stored later are estimated at the write step)."""
    dropped: list[dict]
    """Frames left out for values outside the accepted ranges: ``{"frame_id", "reason"}``."""
    views: list[str]
    """The camera's other views (PTZ presets) with usable frames."""
    view_ids: dict[str, list[str]]
    """Each of those views' region ids."""
    region_ids: list[str]
    """The default view's region ids."""
    css: np.ndarray | None
    encoding: str
    matrix: list | None
    primaries: str
    calibrations: list[tuple[str, str, dict]]
    known: dict[str, np.ndarray]
    cal_warnings: list[str]

    @property
    def frames(self) -> ViewHistory:
        """The default view's frames."""
        return self.by_view[None]


@dataclass
class Refitted:
    """What the fit step gives the others: the new model files by view, the estimates by frame id, the summary."""

    version: str
    models: dict[str | None, Path]
    estimates: RefitEstimates
    summary: dict
    view_warnings: list[str]


class _Stored(NamedTuple):
    """A stored frame as the read step uses it: the columns of :func:`.crud.history_chunks`, JSON decoded (of
    ``registration`` only whether its state is ``view_change`` is read)."""

    id: int
    taken_at: datetime | str
    """As the driver gives it (SQLite: the stored text; :func:`_stored_times`)."""
    patches: Any
    applied_gains: Any
    exposure: float | None
    view: str | None
    registration: Any
    patch_sd: Any


def _decoded(row: Row, loads: Callable[[str], Any]) -> _Stored:
    """``row`` of :func:`.crud.history_chunks` (its JSON columns as text) with its JSON decoded by ``loads``."""
    return _Stored(row[0], row[1], None if row[2] is None else loads(row[2]),
                   None if row[3] is None else loads(row[3]), row[4], row[5],
                   None if row[6] is None else loads(row[6]), None if row[7] is None else loads(row[7]))


_ZERO3 = (0.0, 0.0, 0.0)
_NAN3 = (math.nan, math.nan, math.nan)


class _Plain(NamedTuple):
    """The numbers :func:`_plain_values` converted: every plainly valid frame's region means then standard errors,
    in the order of their dicts, one row of three each (NaN for ``None``), and where each frame's means start."""

    values: NDArray[np.float64]
    start: list[int]
    """Per frame, its first row in ``values`` (-1: a frame not plainly valid)."""


def _plain_values(frames: Sequence[_Stored]) -> tuple[list[bool], _Plain | None]:
    """Which of ``frames`` :func:`~.limits.frame_problem` accepts, found for all of them at once where it is plain:
    region means and standard errors as dicts whose values are ``None`` or three numbers (``float`` or ``int``, not
    ``bool``), every number within 0…:data:`~.limits.MAX_VALUE` (NaN and ±inf are not), applied gains and exposure
    accepted by :func:`~.limits.frame_problem`. ``False`` for every other frame, and for every frame when a value of
    any is not three numbers: it is judged by :func:`~.limits.frame_problem` itself then, so a frame is never
    accepted here that it would leave out, and a reason is always the function's. With the answer, the numbers
    converted to check them (``None`` when none were)."""
    sure = [type(f.patches) is dict and (f.patch_sd is None or type(f.patch_sd) is dict)
            and ((f.applied_gains is None and f.exposure is None)
                 or frame_problem(None, None, f.applied_gains, f.exposure) is None)
            for f in frames]
    counts = [len(f.patches) + len(f.patch_sd or ()) if ok else 0 for f, ok in zip(frames, sure, strict=True)]
    stored = [v for f, ok in zip(frames, sure, strict=True) if ok for d in (f.patches, f.patch_sd or {})
              for v in d.values()]
    flat = [_ZERO3 if v is None else v for v in stored]
    try:
        if set(map(len, flat)) - {3} or set(map(type, chain.from_iterable(flat))) - {float, int}:
            return [False] * len(frames), None
        a = np.fromiter(chain.from_iterable(flat), dtype=float, count=3 * len(flat)).reshape(-1, 3)
    except (TypeError, OverflowError):  # a value without a length; an integer beyond a float's range
        return [False] * len(frames), None
    bad = ~((a >= 0.0) & (a <= MAX_VALUE)).all(axis=1)
    owner = np.repeat(np.arange(len(frames)), counts)
    bad_frames = np.bincount(owner[bad], minlength=len(frames)) > 0
    plain = [ok and not b for ok, b in zip(sure, bad_frames.tolist(), strict=True)]
    a[np.fromiter(map(operator.is_, stored, repeat(None)), dtype=bool, count=len(stored))] = math.nan
    start = (np.cumsum(counts) - counts).tolist()
    return plain, _Plain(a, [i if ok else -1 for i, ok in zip(start, plain, strict=True)])


def _plain_chunk(rows: Sequence[Row], region_ids: list[str]
                 ) -> tuple[Sequence[int], Sequence[datetime], NDArray[np.float64]] | None:
    """The frame ids, stored times and region means (F × P × 3, NaN where ``None``), in the order of ``rows``, of a
    chunk of :func:`.crud.history_chunks` rows that are all plain frames of the default view, or ``None`` for any
    other chunk (then read by :func:`_usable`): every row's region means JSON that :func:`orjson.loads` reads as a
    dict of exactly ``region_ids`` in that order, each ``None`` or three numbers (``float`` or ``int``, not ``bool``)
    within 0…:data:`~.limits.MAX_VALUE`, and no applied gains, exposure, view, registration or standard errors.
    Such a chunk is what :func:`_usable` and :meth:`_ViewRows.add` make of it without a colour matrix — every frame
    used, none left out, the numbers converted by the same calls — found from the chunk's columns instead of a
    :class:`_Stored` and a check of each frame (issue 29: the 100k-frame read step's CPU 1.3–1.7 → 0.8–0.9 s). The
    values' types are told apart without the type of each number (~0.1 s of 4.8 million at 100k frames): a string
    by the texts' quotes, ``None`` in a list by its NaN, a boolean by a look at the values that read as 0 or 1."""
    n, p = len(rows), len(region_ids)
    if not n or not p:
        return None
    columns = list(zip(*rows, strict=True))
    if any(columns[k].count(None) != n for k in (3, 4, 5, 6, 7)) or columns[2].count(None):
        return None
    try:
        decoded = list(map(orjson.loads, columns[2]))
    except orjson.JSONDecodeError:
        return None
    if set(map(type, decoded)) != {dict} or list(chain.from_iterable(decoded)) != region_ids * n:
        return None
    stored = list(chain.from_iterable(map(dict.values, decoded)))
    flat = [_NAN3 if v is None else v for v in stored]
    try:
        # no value holds a string: a text's only quotes are its keys' (exactly two each); then every value is None
        # or a list (orjson's types) of three items that float() converts: numbers, booleans, None (NaN), which the
        # checks below tell apart from numbers without a look at each number's type
        if sum(map(str.count, columns[2], repeat('"'))) != 2 * p * n or set(map(len, flat)) - {3}:
            return None
        a = np.fromiter(chain.from_iterable(flat), dtype=float, count=3 * len(flat)).reshape(-1, 3)
    except (TypeError, ValueError, OverflowError):  # not a str or a list; a list in a list; an integer beyond a float
        return None
    within = (a >= 0.0) & (a <= MAX_VALUE)  # not NaN: None in a list
    # the regions whose three numbers are within are as many as those with a value (None's three NaN never are):
    # no value holds NaN or a number out of range (counted, not marked per value: ~0.03 s of a 100k-frame read)
    if np.count_nonzero(within[:, 0] & within[:, 1] & within[:, 2]) != len(stored) - stored.count(None):
        return None
    for k in np.flatnonzero((a == 0.0) | (a == 1.0)).tolist():  # a boolean reads as 0 or 1
        if type(flat[k // 3][k % 3]) is bool:
            return None
    return columns[0], columns[1], a.reshape(n, p, 3)


def _decoded_chunk(rows: Sequence[Row]) -> list[_Stored]:
    """``_decoded(row, orjson_loads)`` of every row: :func:`orjson.loads` called directly, and the chunk decoded
    again through :func:`~.storage.orjson_loads` (whose :func:`json.loads` reads what orjson refuses) only when
    orjson refused a text of it."""
    loads = orjson.loads
    try:
        return [_Stored(r[0], r[1], None if r[2] is None else loads(r[2]), None if r[3] is None else loads(r[3]),
                        r[4], r[5], None if r[6] is None else loads(r[6]), None if r[7] is None else loads(r[7]))
                for r in rows]
    except orjson.JSONDecodeError:
        return [_decoded(r, orjson_loads) for r in rows]


def _usable(rows: Sequence[Row]) -> tuple[list[_Stored], list[dict], _PlainFrames]:
    """The frames of ``rows`` (:func:`.crud.history_chunks`) a refit can use, decoded, those it leaves out
    (``{"frame_id", "reason"}``) and the numbers already converted of the usable frames: frames of an unknown view
    (a view change) or measured before any region existed carry no region values and are passed over. JSON is read
    by orjson (:func:`~.storage.orjson_loads`); a frame not plainly valid (:func:`_plain_values`) is read again by
    :func:`json.loads` and judged by :func:`~.limits.frame_problem`, so that whatever was stored, the frames used,
    their values and the reasons given are those of the stored rows as :func:`json.loads` reads them."""
    kept = [(f, r) for f, r in zip(_decoded_chunk(rows), rows, strict=True)
            if f.patches and (f.registration or {}).get("state") != "view_change"]
    plain, numbers = _plain_values([f for f, _ in kept])
    usable, dropped, start = [], [], []
    for (f, r), ok, at in zip(kept, plain, numbers.start if numbers else repeat(-1), strict=False):
        if not ok:
            f = _decoded(r, json.loads)
            problem = frame_problem(f.patches, f.patch_sd, f.applied_gains, f.exposure)
            if problem is not None:
                dropped.append({"frame_id": f.id, "reason": problem})
                continue
        usable.append(f)
        start.append(at if ok else -1)
    return usable, dropped, _PlainFrames(None if numbers is None else numbers.values, dict(zip(
        (f.id for f in usable), start, strict=True)))


class _PlainFrames(NamedTuple):
    """A chunk's numbers converted while checking them (:class:`_Plain`), and where each usable frame's region means
    start there, by frame id (-1: read again by :func:`json.loads`)."""

    values: NDArray[np.float64] | None
    start: dict[int, int]


def read_history(sessions: sessionmaker[Session], camera_id: int, max_frames: int) -> History:
    """Read step: the camera's ``max_frames`` most recent frames, streamed :data:`READ_CHUNK` rows at a time into
    arrays (:class:`ViewHistory`), the regions of its views, its sensitivities, output pipeline and calibration
    images. ``ValueError`` for an unknown camera."""
    with sessions() as s:
        cam = crud.get_camera(s, camera_id)
        if cam is None:
            raise ValueError(f"unknown camera {camera_id}")
        regions = {v: [r["id"] for r in rs] for v, rs in crud.camera_views(s, camera_id).items()}
        matrix = (cam.response or {}).get("matrix")
        dialect = s.connection().dialect
        parse = Frame.__table__.c.taken_at.type.dialect_impl(dialect).result_processor(dialect, None)
        gathered: dict[str | None, _ViewRows] = {None: _ViewRows([r["id"] for r in cam.regions], parse)}
        read: list[NDArray[np.int64]] = []
        dropped: list[dict] = []
        views: set[str] = set()
        chunks = crud.history_chunks(s, camera_id, max_frames, READ_CHUNK)
        while True:
            with _collector_paused():  # a chunk's rows and their JSON: freed before the collector runs again
                rows = next(chunks, None)
                if rows is None:
                    break
                read.append(np.fromiter(map(operator.itemgetter(0), rows), dtype=np.int64, count=len(rows)))  # ids
                plain_chunk = None if matrix is not None else _plain_chunk(rows, gathered[None].region_ids)
                if plain_chunk is not None:  # every frame plain, of the default view
                    gathered[None].add_plain(*plain_chunk)
                    del rows, plain_chunk
                    continue
                usable, left_out, plain = _usable(rows)
                dropped += left_out
                for v in {r.view for r in usable}:
                    if v is not None:
                        views.add(v)
                    if v is None or regions.get(v):
                        gathered.setdefault(v, _ViewRows(regions.get(v, []), parse)).add([r for r in usable if r.view == v],
                                                                                 matrix, plain)
                del rows, usable, plain
        css = sensitivities_array(cam.sensitivities)
        calibrations, known, cal_warnings = calibration_frames(crud.calibrations(s, camera_id), matrix)
        history = History(
            camera_id, {v: g.finish() for v, g in gathered.items()},
            np.concatenate(read) if read else np.empty(0, np.int64), dropped, sorted(views),
            {v: regions.get(v, []) for v in views}, [r["id"] for r in cam.regions], css,
            (cam.response or {}).get("encoding", "linear"), matrix, camera_primaries(cam.response, css is not None),
            calibrations, known, cal_warnings)
    if dropped:
        log.warning("refit of camera %s: %d frame(s) left out (%s)", camera_id, len(dropped), dropped[0]["reason"])
    return history


def fit_views(h: History, data_dir: Path, method: str, max_fit_frames: int) -> Refitted:
    """Fit step: each view's scene model fitted and saved to a new versioned file, every usable frame estimated with
    it (:func:`~.estimation.refit_estimates`). A view without enough frames is reported, not fatal; a failure of the
    default view removes the files already written (nothing is committed yet) and raises."""
    version = uuid.uuid4().hex[:16]
    models: dict[str | None, Path] = {}
    view_warnings: list[str] = []
    estimates = RefitEstimates()
    for v in h.views:  # each PTZ preset: its own regions and scene model (calibration images are of the default view)
        vf = h.by_view[v].observations() if v in h.by_view else []
        path = versioned_model_path(data_dir, h.camera_id, v, version)
        try:
            est_v, summary_v = refit_estimates(vf, h.view_ids[v], h.css, method=method, model_file=path,
                                               max_fit_frames=max_fit_frames, primaries=h.primaries)
            estimates.update(est_v)
            models[v] = path
            view_warnings += [f"view {v!r}: {w}" for w in summary_v.get("identifiability_warnings") or []]
        except RefitInputError as exc:
            view_warnings.append(f"view {v!r} not refitted: {exc}")
    if not len(h.frames) and estimates:
        summary = {"frames": 0, "method": method, "views": len(h.views)}
    else:
        path = versioned_model_path(data_dir, h.camera_id, None, version)
        try:
            est_d, summary = refit_estimates(
                h.frames.observations(), h.region_ids, h.css, method=method, model_file=path, max_fit_frames=max_fit_frames,
                calibrations=h.calibrations, known_reflectances=h.known, primaries=h.primaries,
            )
        except Exception:
            for p in models.values():  # nothing committed: the new files of the other views go too
                p.unlink(missing_ok=True)
            path.unlink(missing_ok=True)
            raise
        estimates.update(est_d)
        if path.is_file():
            models[None] = path
    return Refitted(version, models, estimates, summary, view_warnings)


def check_refit(h: History, fit: Refitted) -> dict:
    """Check step: the declared tone response against the default view's history
    (:func:`~.estimation.check_response`), and every warning of the refit in one list; returns the summary."""
    t_check = time.perf_counter()
    summary = fit.summary
    check = (check_response(h.frames.observations(), h.region_ids, h.css, h.encoding) if len(h.frames)
             else {"warnings": []})
    summary["response_check"] = {k: v for k, v in check.items() if k != "warnings"}
    summary["response_check_s"] = round(time.perf_counter() - t_check, 3)  # part of fit_s
    model_warnings = [str(w) for w in summary.get("identifiability_warnings") or []]
    if isinstance(summary.get("model"), str) and summary["model"].startswith("scene model fit failed"):
        model_warnings.append(summary["model"])
    summary["warnings"] = list(dict.fromkeys(h.cal_warnings + check["warnings"] + fit.view_warnings + model_warnings))
    summary["views"] = len(h.views) + bool(h.frames)
    summary["version"] = fit.version
    summary["dropped_frames"] = len(h.dropped)
    summary["dropped"] = h.dropped[:MAX_DROPPED_LISTED]
    return summary


def write_refit(sessions: sessionmaker[Session], data_dir: Path, h: History, fit: Refitted) -> int:
    """Write step, one transaction: switch the camera's views to their new model files, replace the estimates,
    estimate with the new models the frames stored since the read step, and record why the others have none.
    Returns the number of estimates written.

    The estimates are converted :data:`~.crud.WRITE_CHUNK` frames at a time from the fit's arrays, a column at a
    time (their JSON columns written by orjson), and written in bulk (:func:`.crud.replace_estimates`: SQLAlchemy
    Core statements, one executemany INSERT per chunk). The camera row is updated
    first: on SQLite that takes the write lock before anything is read, on PostgreSQL it locks the row that every
    ingest locks (:func:`.crud.models_for_update`) before storing an estimate, so no ingest commits an estimate of
    the old model after this commit."""
    ids_of = {v: (h.view_ids[v] if v is not None else h.region_ids) for v in fit.models}
    with sessions() as s, s.begin():
        cam = crud.get_camera(s, h.camera_id, for_update=True)
        if cam is None:  # deleted while the refit ran
            for p in fit.models.values():
                p.unlink(missing_ok=True)
            return 0
        crud.use_models(s, cam, {view_model_key(v): {"file": p.name, "version": fit.version}
                                 for v, p in fit.models.items()})
        late = _late_estimates(crud.frames_not_read(s, h.camera_id, h.read_ids), data_dir, h, fit,
                               ids_of)
        ids: list[int] = []
        written = crud.replace_estimates(s, _estimate_columns(h, fit, late, ids), camera_id=h.camera_id,
                                         model=fit.version)
        # frames the refit used but could not estimate (fewer than two regions seen, a non-finite white), and those
        # it left out: no estimate of the previous model stays behind
        estimated = np.array(ids, dtype=np.int64)  # the fit's and the late frames' (ids of the rows written)
        reasons = {}
        for v in fit.models:
            if v in h.by_view:  # its frames without an estimate, in order (np.isin: one lookup table of the ids)
                vh = h.by_view[v]
                none = ~np.isin(vh.ids, estimated)
                reasons.update({i: "too_few_regions" if n < 2 else "estimate_failed"
                                for i, n in zip(vh.ids[none].tolist(), vh.used[none].tolist(), strict=True)})
        reasons.update({d["frame_id"]: "invalid_values" for d in h.dropped})
        crud.drop_estimates(s, reasons)
        if _commit_hook is not None:
            _commit_hook()
    return written


def _estimate_columns(h: History, fit: Refitted, late: dict[str, dict], ids_out: list[int]
                      ) -> Iterator[dict[str, list]]:
    """The estimates to write but their camera and model, a column at a time, :data:`~.crud.WRITE_CHUNK` frames at a
    time: the fit's (their frames' stored times; JSON columns as text, :meth:`~.estimation.RefitEstimates.columns`),
    then those of the frames stored since the read step (``late``); their frame ids are added to ``ids_out`` as they
    are given (the frames that have an estimate, without reading the fit's ids again)."""
    taken = {i: t for vh in h.by_view.values() for i, t in zip(vh.ids.tolist(), vh.taken_at, strict=True)}
    for columns in fit.estimates.columns(crud.WRITE_CHUNK, json_text=True):
        if late and any(fid in late for fid in columns["frame_id"]):
            keep = [fid not in late for fid in columns["frame_id"]]
            columns = {k: json_texts_like(c, (v for v, ok in zip(c, keep, strict=True) if ok))
                       for k, c in columns.items()}
        ids = list(map(int, columns["frame_id"]))
        ids_out += ids
        yield {**columns, "frame_id": ids, "taken_at": DateTimeTexts(map(taken.__getitem__, ids))}
    rows = list(late.values())
    for start in range(0, len(rows), crud.WRITE_CHUNK):
        part = rows[start : start + crud.WRITE_CHUNK]
        ids_out += [r["frame_id"] for r in part]
        yield {k: [r[k] for r in part] for k in part[0]}


_commit_hook: Callable[[], None] | None = None
"""Called inside a refit's transaction just before it commits (tests simulate a crash there)."""


def _late_estimates(late: Sequence[Any], data_dir: Path, h: History, fit: Refitted,
                    ids_of: dict[str | None, list[str]]) -> dict[str, dict]:
    """Estimates, with the new model of their view, of the frames stored while the refit fitted (``late``)."""
    out = {}
    for r in late:
        if r.view not in fit.models or not r.patches or frame_problem(r.patches, r.patch_sd, r.applied_gains,
                                                                      r.exposure):
            continue
        if (r.registration or {}).get("state") == "view_change":
            continue
        row = history_row(r, h.matrix)
        est = estimate_frame(data_dir, h.camera_id, row[0], row[1], row[2], ids_of[r.view], r.view, row[3],
                             model_file=fit.models[r.view])
        if est is not None:
            out[str(r.id)] = {"frame_id": r.id, "taken_at": r.taken_at, **est}
    return out
