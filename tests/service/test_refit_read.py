"""The refit's read step a chunk at a time (issue 29, the refit's rows): stored JSON decoded by orjson, the frames'
ranges checked at once and their arrays built at once give what reading every row with ``json.loads``, judging it
with ``frame_problem`` and building its observations through ``history_row`` gave — the same frames, reasons and
values bit for bit, whatever was stored."""

from __future__ import annotations

import json
from datetime import datetime, timedelta
from types import SimpleNamespace

import numpy as np
import pytest
from illumon_service.estimation import build_observations, history_arrays, history_row
from illumon_service.limits import frame_problem
from illumon_service.refit import _usable
from svc_helpers import same_value

T0 = datetime(2025, 6, 1)
IDS = [f"p{j}" for j in range(6)]


def _frames(n: int, seed: int) -> list[SimpleNamespace]:
    """Stored frames with missing regions, an extra region, integer values, standard errors (some missing), applied
    gains and exposures alone and together."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        patches = {}
        for p in IDS:
            if rng.random() < 0.15:
                continue  # no key
            patches[p] = None if rng.random() < 0.1 else rng.uniform(0, 2, 3).tolist()
        if i % 7 == 0:
            patches["extra"] = rng.uniform(0, 2, 3).tolist()
        if i % 11 == 0:
            patches[IDS[0]] = [0, 1, 2]
        sd = None
        if i % 2:
            sd = {p: (None if rng.random() < 0.2 else rng.uniform(0, 0.05, 3).tolist()) for p in IDS if rng.random() < 0.9}
        gains = rng.uniform(0.3, 3, 3).tolist() if i % 3 == 0 else ([2, 1, 1] if i % 13 == 1 else None)
        exposure = float(rng.uniform(0.01, 50)) if i % 5 < 2 else None
        out.append(SimpleNamespace(id=i + 1, taken_at=T0 + timedelta(minutes=i), patches=patches, applied_gains=gains,
                                   exposure=exposure, patch_sd=sd))
    return out


@pytest.mark.parametrize("matrix", [None, [[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.0, -0.5, 1.5]]])
def test_history_arrays_equal_the_observations_of_history_rows(matrix) -> None:
    frames = _frames(400, 1)
    values, sd = history_arrays(frames, IDS, matrix)
    ref = build_observations([history_row(f, matrix) for f in frames], IDS)
    assert values.dtype == ref.values.dtype and np.array_equal(values.view(np.uint64), ref.values.view(np.uint64))
    assert ref.sd is not None and np.array_equal(sd.view(np.uint64), ref.sd.view(np.uint64))
    assert np.isfinite(sd).sum() > 500 and np.isfinite(values).sum() > 1500
    values, sd = history_arrays([f for f in frames if not f.patch_sd], IDS, matrix)
    assert values.size and np.isnan(sd).all()
    assert history_arrays([], IDS, matrix)[0].shape == (0, len(IDS), 3)


def _row(i: int, patches: str, gains: str | None = None, exposure: float | None = None,
         registration: str | None = None, sd: str | None = None) -> tuple:
    """A row of ``crud.history_chunks``: id, time, patches, gains, exposure, view, registration, standard errors."""
    return (i, T0 + timedelta(minutes=i), patches, gains, exposure, None, registration, sd)


GOOD = '{"p0": [0.1, 0.2, 0.3], "p1": null, "p2": [0.5, 1.5, 2.0]}'
ODD = [  # (patches, gains, exposure, registration, standard errors)
    (GOOD, None, None, None, None),
    ('{"p0": [0, 1, 2], "p1": [0.0, 0.5, 1]}', None, None, None, None),  # integers are numbers
    ('{"p0": [0.1, 0.2, 2.5]}', None, None, None, None),
    ('{"p0": [-0.1, 0.2, 0.3]}', None, None, None, None),
    ('{"p0": [NaN, 0.2, 0.3]}', None, None, None, None),  # json.dumps's NaN: orjson refuses it
    ('{"p0": [Infinity, 0.2, 0.3]}', None, None, None, None),
    ('{"p0": [1e400, 0.2, 0.3]}', None, None, None, None),
    ('{"p0": [true, 0.2, 0.3]}', None, None, None, None),
    ('{"p0": [false, false, false]}', None, None, None, None),
    ('{"p0": ["0.1", 0.2, 0.3]}', None, None, None, None),
    ('{"p0": "abc"}', None, None, None, None),
    ('{"p0": {"a": 1, "b": 2, "c": 3}}', None, None, None, None),
    ('{"p0": [0.1, 0.2]}', None, None, None, None),
    ('{"p0": [0.1, 0.2, 0.3, 0.4]}', None, None, None, None),
    ('{"p0": 0.5}', None, None, None, None),
    ('{"p0": [0.1, null, 0.3]}', None, None, None, None),
    ('{"p0": [[0.1], [0.2], [0.3]]}', None, None, None, None),
    ('{"p0": [1, 0, 123456789012345678901234]}', None, None, None, None),  # orjson: a float; json: the integer
    ('{"p0": [1, 0, 18446744073709551615]}', None, None, None, None),
    ('{"extra": [0.1, 5.0, 0.2], "p0": [0.1, 0.2, 0.3]}', None, None, None, None),  # a region no longer defined
    ("{}", None, None, None, None),
    ("null", None, None, None, None),
    (GOOD, None, None, '{"state": "view_change"}', None),
    (GOOD, None, None, '{"state": "ok", "shift": [1, 123456789012345678901234]}', None),
    (GOOD, "[1.5, 1.0, 0.8]", 0.5, None, None),
    (GOOD, "[100, 1, 1]", None, None, None),
    (GOOD, '["1.5", "1", "1"]', None, None, None),
    (GOOD, "[true, 1, 1]", None, None, None),
    (GOOD, "[1.5, 1.0]", None, None, None),
    (GOOD, None, 0.0, None, None),
    (GOOD, None, 1e7, None, None),
    (GOOD, None, None, None, '{"p0": [0.01, 0.02, 0.03], "p2": null}'),
    (GOOD, None, None, None, '{"p0": [0.01, 3.0, 0.03]}'),
    (GOOD, None, None, None, '{"p0": [0.01, NaN, 0.03]}'),
    (GOOD, None, None, None, '{"p0": [0.01, "x", 0.03]}'),
    (GOOD, None, None, None, "{}"),
]


def _reference(rows: list[tuple]) -> tuple[list, list[dict]]:
    """The read step before issue 29's rows change: every row decoded by json.loads, filtered and judged one by one."""
    usable, dropped = [], []
    for r in rows:
        d = [None if v is None else json.loads(v) for v in (r[2], r[3], r[6], r[7])]
        if not d[0] or (d[2] or {}).get("state") == "view_change":
            continue
        problem = frame_problem(d[0], d[3], d[1], r[4])
        if problem is None:
            usable.append((r[0], r[1], d[0], d[1], r[4], r[5], d[2], d[3]))
        else:
            dropped.append({"frame_id": r[0], "reason": problem})
    return usable, dropped


def _used(f: tuple) -> list:
    """What the refit uses of a frame it reads: region means, applied gains, exposure, view, standard errors (of its
    registration only whether it is a view change)."""
    return [f[2], f[3], f[4], f[5], f[7]]


@pytest.mark.parametrize("odd", range(len(ODD)))
def test_usable_frames_and_reasons_equal_those_of_json_loads_row_by_row(odd: int) -> None:
    """Each odd row among plain ones (one chunk): the frames used, their decoded columns and the reasons given are
    those of reading every row with json.loads and judging it with frame_problem."""
    rows = [_row(i, GOOD) for i in range(5)] + [_row(5, *ODD[odd])] + [_row(i, GOOD, "[1.2, 1, 0.9]") for i in (6, 7)]
    want_usable, want_dropped = _reference(rows)
    got_usable, got_dropped, _ = _usable(rows)
    assert got_dropped == want_dropped
    assert [f.id for f in got_usable] == [u[0] for u in want_usable]
    for f, u in zip(got_usable, want_usable, strict=True):
        assert same_value(_used(f), _used(u)) and f.taken_at == u[1]


def test_usable_frames_of_a_whole_odd_chunk() -> None:
    rows = [_row(i, *odd) for i, odd in enumerate(ODD)]
    want_usable, want_dropped = _reference(rows)
    got_usable, got_dropped, _ = _usable(rows)
    assert got_dropped == want_dropped and len(want_dropped) > 20
    assert [f.id for f in got_usable] == [u[0] for u in want_usable]
    assert all(same_value(_used(f), _used(u)) for f, u in zip(got_usable, want_usable, strict=True))


def test_utc_iso_is_as_utc_isoformat() -> None:
    """``refit._utc_iso`` (the observations' times): ``as_utc(t).isoformat()`` of naive times (SQLite's), with and
    without microseconds, and of aware ones in other zones (PostgreSQL's)."""
    from datetime import timezone

    from illumon_service.refit import _utc_iso
    from illumon_service.storage import as_utc

    naive = [T0, T0 + timedelta(microseconds=1), T0 + timedelta(seconds=59.5), datetime(1999, 12, 31, 23, 59, 59)]
    aware = [t.replace(tzinfo=timezone(timedelta(hours=h))) for t, h in zip(naive, (0, 2, -5, 14), strict=True)]
    times = naive + aware + [t.replace(tzinfo=timezone.utc) for t in naive]
    assert _utc_iso(times) == [as_utc(t).isoformat() for t in times]


def test_the_collector_is_paused_for_a_chunk_and_on_again_after_it() -> None:
    """``refit._collector_paused`` (a read chunk decoded without the collector's passes): off inside, on after, also
    when the block raises; left off after it when it was off before."""
    import gc

    from illumon_service.refit import _collector_paused

    assert gc.isenabled()
    with pytest.raises(RuntimeError), _collector_paused():
        assert not gc.isenabled()
        raise RuntimeError
    assert gc.isenabled()
    gc.disable()
    try:
        with _collector_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()


@pytest.mark.parametrize("odd", [None, *range(len(ODD))])
def test_arrays_from_the_checked_numbers_equal_history_arrays(odd: int | None, monkeypatch) -> None:
    """A view's arrays taken from the numbers the validity check converted (``_ViewRows.add`` with the chunk's
    numbers) equal ``history_arrays`` of the same frames bit for bit: plain frames in the view's region order, and
    among them frames read otherwise (another key order, a missing or extra region, integers, standard errors,
    gains, exposure, an odd row read again by json.loads)."""
    from illumon_service.refit import _usable, _ViewRows

    ids = ["p0", "p1", "p2"]
    rows = [_row(i, GOOD) for i in range(6)]
    rows += [_row(6, '{"p0": [0.0, 1, 2], "p1": [0.25, 0.5, 0.75], "p2": null}'),
             _row(7, '{"p1": [0.1, 0.2, 0.3], "p0": null, "p2": [0.5, 1.5, 2.0]}'),
             _row(8, '{"p0": [0.1, 0.2, 0.3], "p2": [0.5, 1.5, 2.0]}'),
             _row(9, '{"p0": [0.1, 0.2, 0.3], "p1": null, "p2": [0.5, 1.5, 2.0], "p3": [1.0, 1.0, 1.0]}')]
    if odd is not None:
        rows.append(_row(10, *ODD[odd]))
    rows += [_row(i, GOOD) for i in range(11, 14)]
    usable, _, plain = _usable(rows)
    for frames in (usable, [f for f in usable if f.id < 6 or f.id > 10], [f for f in usable if f.id == 6]):
        fast, slow = _ViewRows(ids), _ViewRows(ids)
        fast.add(frames, None, plain)
        slow.add(frames, None)
        a, b = fast.finish(), slow.finish()
        assert np.array_equal(a.values.view(np.uint64), b.values.view(np.uint64)) and a.values.flags.c_contiguous
        assert (a.sd is None) == (b.sd is None)
        if a.sd is not None:
            assert np.array_equal(a.sd.view(np.uint64), b.sd.view(np.uint64))
        assert np.array_equal(a.used, b.used) and a.times == b.times
    if odd is None:  # plain frames in the view's order are taken from the checked numbers, not converted again
        import illumon_service.refit as refit

        assert plain.values is not None and all(plain.start[i] >= 0 for i in (0, 6, 7))
        monkeypatch.setattr(refit, "history_arrays", None)
        _ViewRows(ids).add([f for f in usable if f.id < 7 or f.id > 10], None, plain)


@pytest.mark.parametrize("order", ["plain first", "errors first", "plain only"])
def test_a_view_of_plain_chunks_and_chunks_with_standard_errors(order: str) -> None:
    """A plain chunk keeps no standard errors of its own (issue 29: 38 MB of NaN at 100k frames); where another chunk
    of the view has some, its frames get NaN there, as ``history_arrays`` of every chunk gives, bit for bit; a view
    of plain chunks only has none."""
    from illumon_service.refit import _usable, _ViewRows

    ids = ["p0", "p1", "p2"]
    sd = '{"p0": [0.01, 0.02, 0.03], "p2": null}'
    plain_rows = [_row(i, GOOD) for i in range(1, 5)]
    error_rows = [_row(i, GOOD, sd=sd if i % 2 else None) for i in range(5, 9)]
    chunks = {"plain first": [plain_rows, error_rows], "errors first": [error_rows, plain_rows],
              "plain only": [plain_rows, [_row(i, GOOD) for i in range(5, 9)]]}[order]
    fast, slow = _ViewRows(ids), _ViewRows(ids)
    for rows in chunks:
        usable, _, plain = _usable(rows)
        fast.add(usable, None, plain)
        slow.add(usable, None)
    a, b = fast.finish(), slow.finish()
    assert np.array_equal(a.values.view(np.uint64), b.values.view(np.uint64))
    assert (a.sd is None) == (b.sd is None) == (order == "plain only")
    if a.sd is not None:
        assert np.array_equal(a.sd.view(np.uint64), b.sd.view(np.uint64)) and np.isfinite(a.sd).any()
        assert fast.sd[[0, 1][order == "errors first"]] is None  # the plain chunk's


PLAIN_IDS = ["p0", "p1", "p2"]
NOT_PLAIN = [  # rows of a chunk's plain frames that _plain_chunk leaves to _usable: (patches, gains, exposure,
    # registration, standard errors, view)
    ('{"p1": [0.1, 0.2, 0.3], "p0": null, "p2": [0.5, 1.5, 2.0]}', None, None, None, None, None),  # another order
    ('{"p0": [0.1, 0.2, 0.3], "p2": [0.5, 1.5, 2.0]}', None, None, None, None, None),  # a region missing
    ('{"p0": [0.1, 0.2, 0.3], "p1": null, "p2": [0.5, 1.5, 2.0], "p3": [1.0, 1.0, 1.0]}', None, None, None, None,
     None),  # an extra region
    ('{"p0": null, "p1": null, "p2": [0.5, 1.5, 2.0000000000000004]}', None, None, None, None, None),  # > MAX_VALUE
    (GOOD, None, 0.5, None, None, None),  # an exposure alone
    (GOOD, None, None, '{"state": "ok"}', None, None),
    (GOOD, None, None, None, '{"p0": [0.01, 0.02, 0.03]}', None),
    (GOOD, None, None, None, None, "preset-1"),
]


ODD_VALUES = ["[true, 0.2, 0.3]", "[false, false, false]", "[1, 0, true]", '["0.1", 0.2, 0.3]', '"abc"', '"0.5"',
              '{"0.1": 1, "0.2": 2, "0.3": 3}', "[0.1, null, 0.3]", "[null, null, null]", "[[0.1], [0.2], [0.3]]",
              "[[0.1, 0.2, 0.3]]", "[0.1, 0.2]", "[0.1, 0.2, 0.3, 0.4]", "[]", "{}", "0.5", "1", "true", "[1e400, 0.2, 0.3]",
              "[-0.1, 0.2, 0.3]", "[123456789012345678901234, 0, 1]", "[0, 1, 18446744073709551615]",
              "[-0.0, 0.5, 1]", "[0, 1, 2]", "[1.0, 1.0, 0.0]", "[2.0000000000000004, 1, 1]", "[1e-320, 0, 1]"]
"""Values of ``p0`` among plain ``p1`` and ``p2``: each of any other type, length or range than three numbers within
0…2, and plain ones (-0.0, integers, 0 and 1, a subnormal)."""
NOT_PLAIN += [(f'{{"p0": {v}, "p1": null, "p2": [0.5, 1.5, 2.0]}}', None, None, None, None, None) for v in ODD_VALUES]
NOT_PLAIN += [('{"p0": [0.1, 0.2, 0.3], "p1": null, "p2": [0.5, 1.5, 2.0], "p0": [0.1, 0.2, 0.3]}', None, None, None,
               None, None),  # a key twice
              ('{"p0": [0.1, 0.2, 0.3], "p1": null, "p2": [0.5, 1.5, 2.0]} ', None, None, None, None, None),
              ('{"p0": [0.1, 0.2, 0.3], "p1": null, "p\u0032": [0.5, 1.5, 2.0]}', None, None, None, None, None)]


def _plain_row(i: int, patches: str = GOOD, gains: str | None = None, exposure: float | None = None,
               registration: str | None = None, sd: str | None = None, view: str | None = None) -> tuple:
    return (i, T0 + timedelta(minutes=i), patches, gains, exposure, view, registration, sd)


def _read_as_usable(rows: list[tuple]) -> tuple:
    """A chunk as ``_usable`` and ``_ViewRows.add`` read it (the default view's frames, those left out)."""
    from illumon_service.refit import _ViewRows

    usable, dropped, plain = _usable(rows)
    view = _ViewRows(PLAIN_IDS)
    view.add([f for f in usable if f.view is None], None, plain)
    return view.finish(), dropped, len(usable)


@pytest.mark.parametrize("odd", [None, *range(len(ODD) + len(NOT_PLAIN))])
def test_a_plain_chunk_reads_as_usable_reads_it(odd: int | None) -> None:
    """``refit._plain_chunk`` (a chunk whose every frame is plain, read without looking at each): its ids, times and
    region means equal what ``_usable`` and ``_ViewRows.add`` make of the chunk bit for bit — integers, ``null``, 0
    and 2 (``MAX_VALUE``) among them — and a chunk with any other row (each odd row of the tests above, another key
    order, a missing or extra region, a value above ``MAX_VALUE``, an exposure, a registration, standard errors, a
    view) is left to ``_usable``: ``None``, or where the row is plain after all, the same arrays."""
    from illumon_service.refit import _plain_chunk, _ViewRows

    rows = [_plain_row(0, '{"p0": [0, 1, 2], "p1": [0.0, 0.5, 1], "p2": null}'),
            _plain_row(1, '{"p0": [2.0, 2, 1e-300], "p1": null, "p2": [0.25, 0.1, 0.3]}'),
            _plain_row(2, '{"p0":[0.1,0.2,0.3],"p1":null,"p2":[0.5,1.5,2.0]}')]
    rows += [_plain_row(i) for i in range(3, 6)]
    if odd is not None:
        extra = ODD[odd] if odd < len(ODD) else NOT_PLAIN[odd - len(ODD)]
        rows.append(_plain_row(6, *extra))
    rows += [_plain_row(i) for i in range(7, 9)]
    want, dropped, n_usable = _read_as_usable(rows)
    got = _plain_chunk(rows, PLAIN_IDS)
    plain = _usable(rows)[2]
    every_plain = not dropped and n_usable == len(rows) and min(plain.start.values()) >= 0
    if odd is None or (odd < len(ODD) and ODD[odd][0] == GOOD and all(v is None for v in ODD[odd][1:])):
        assert got is not None and want.values.shape == (len(rows), 3, 3)
    elif not every_plain:
        assert got is None
    if got is not None:
        assert not dropped and n_usable == len(rows)
        view = _ViewRows(PLAIN_IDS)
        view.add_plain(*got)
        have = view.finish()
        assert np.array_equal(have.values.view(np.uint64), want.values.view(np.uint64))
        assert np.array_equal(have.ids, want.ids) and have.taken_at == want.taken_at and have.times == want.times
        assert np.array_equal(have.used, want.used) and have.sd is None and want.sd is None


def test_a_chunk_of_no_regions_or_no_rows_is_left_to_usable() -> None:
    from illumon_service.refit import _plain_chunk

    assert _plain_chunk([], PLAIN_IDS) is None
    assert _plain_chunk([_plain_row(0, "{}")], []) is None


def test_stored_times_carry_sqlites_text() -> None:
    """``refit._stored_times``: texts of SQLite's form are kept as stored, their ISO forms those of the times they
    read as (``_utc_iso``), a text that is no time fails as reading it does; any other chunk is read by the column's
    conversion (texts of other forms, datetimes)."""
    from illumon_service.refit import _stored_times, _utc_iso

    times = [T0, T0 + timedelta(microseconds=1), T0 + timedelta(seconds=59.5), datetime(999, 12, 31, 23, 59, 59)]
    texts = [t.isoformat(" ", "microseconds") for t in times]
    assert _stored_times(texts, None) == (texts, _utc_iso(times))
    assert _stored_times(texts[:1], datetime.fromisoformat) == (texts[:1], _utc_iso(times[:1]))
    for odd in ("2025-06-01 00:00:00", "2025-06-01T00:00:00.000000", "2025-W22-7 00:00:00.000000",
                "2025-06-01 00:00:00,000000", "2025-06-01 00:00:00.000000+00:00"):
        got, iso = _stored_times([texts[2], odd], datetime.fromisoformat)
        assert got == [times[2], datetime.fromisoformat(odd)] and iso == _utc_iso(got)
    assert _stored_times(times, None) == (times, _utc_iso(times))
    assert _stored_times([], None) == ([], [])
    for bad in ("2025-02-30 00:00:00.000000", texts[0] + "\n" + texts[1]):  # no time: read, and failing
        with pytest.raises(ValueError):
            _stored_times([texts[0], bad], datetime.fromisoformat)
