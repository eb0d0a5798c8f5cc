"""The engine's JSON codec (issue 29, the refit's rows): orjson reads and writes the values :mod:`json` does.

:func:`~illumon_service.storage.json_loads` gives what :func:`json.loads` gives, for the texts orjson refuses or reads
otherwise too; :class:`~illumon_service.storage.StoredJSON` is stored as it is and every other value as
:func:`json.dumps` writes it; :func:`~illumon_service.estimation.batch.json_rows` writes arrays whose texts read back as
the same floats, and leaves rows holding NaN or infinity to :func:`json.dumps` (orjson would write ``null``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from illumon_service.estimation.batch import json_rows
from illumon_service.storage import Frame, StoredJSON, json_dumps, json_loads, make_engine, make_session_factory
from sqlalchemy import insert, select, text
from svc_helpers import same_value


def _doubles(n: int) -> np.ndarray:
    """Finite doubles of every magnitude (random bit patterns), uniform ones, and awkward ones."""
    rng = np.random.default_rng(0)
    bits = rng.integers(0, 2**63, n, dtype=np.uint64).view(np.float64)
    special = [0.0, -0.0, 5e-324, 2.2250738585072014e-308, 1.7976931348623157e308, 1e16, 1e-5, 1e-7, 0.1, 1 / 3,
               123456789012345678.0, 2.0**53 + 2]
    return np.concatenate([bits[np.isfinite(bits)], rng.random(n), rng.normal(0, 1e-5, n), special])


TEXTS = ["NaN", "[1.5, NaN, Infinity, -Infinity]", '{"a": Infinity}', "1e400", "-1e400", "1" * 30, "-" + "9" * 25,
         "18446744073709551615", "18446744073709551616", "[0.1, 12345678901234567890123]", '"\\ud800"',
         '{"a": 1, "a": 2}', "-0", "-0.0", "[]", "{}", "null", "true", '"x\\u00e9"', '{"p": [0.25, null, 1, false]}']


@pytest.mark.parametrize("text", TEXTS)
def test_json_loads_gives_what_json_loads_gives(text: str) -> None:
    assert same_value(json_loads(text), json.loads(text))
    assert same_value(json_loads(text.encode()), json.loads(text))  # PostgreSQL's driver hands bytes over
    assert same_value(json_loads(memoryview(text.encode())), json.loads(text))


def test_json_loads_reads_every_float_as_json_does() -> None:
    x = _doubles(100_000).tolist()
    for written in (json.dumps(x), json_rows(np.array([x]))[0]):
        assert same_value(json_loads(written), json.loads(written)) and same_value(json_loads(written), x)


def test_json_dumps_passes_stored_json_and_writes_the_rest_as_json_dumps() -> None:
    assert json_dumps(StoredJSON("[1.0,2.5]")) == "[1.0,2.5]"
    for value in ([1.0, float("nan"), float("inf")], {"a": None, 1: [1e-5]}, "[1.0]", 10**30, None):
        assert json_dumps(value) == json.dumps(value)


def test_json_rows_read_back_as_the_floats_written() -> None:
    a = _doubles(30_000)[: 61 * 1400].reshape(-1, 61)
    a[3, 5], a[7, 0], a[7, 60] = np.nan, np.inf, -np.inf
    rows = json_rows(a)
    for i, (row, values) in enumerate(zip(rows, a.tolist(), strict=True)):
        if i in (3, 7):  # non-finite: the list, written by json.dumps as before
            assert type(row) is list and same_value(row, values) and json_dumps(row) == json.dumps(values)
        else:
            assert type(row) is StoredJSON and same_value(json.loads(row), values)
    assert json_rows(np.empty((0, 3))) == []


@pytest.mark.parametrize("width", [1, 2, 3, 8, 9])
def test_json_rows_of_narrow_rows_cut_from_one_text_equal_row_by_row(width) -> None:
    """Narrow rows (written from one text of the whole array) are the texts orjson writes row by row."""
    import orjson

    a = _doubles(12_000)[: width * (12_000 // width)].reshape(-1, width)
    a[0] = 0.0
    a[1] = -0.0
    a[2] = 5e-324
    a[3] = 1e16
    rows = json_rows(a)
    assert all(type(r) is StoredJSON for r in rows)
    assert rows == [orjson.dumps(r, option=orjson.OPT_SERIALIZE_NUMPY).decode() for r in a]
    b = a.copy()
    b[5, 0] = np.nan  # a non-finite row: its list, the others as before
    mixed = json_rows(b)
    assert type(mixed[5]) is list and mixed[:5] == rows[:5] and mixed[6:] == rows[6:]


def test_engine_stores_json_text_as_it_is_and_reads_values_as_json(tmp_path) -> None:
    """Through SQLite: a StoredJSON column holds its text, a list holds json.dumps's, and both read back."""
    engine = make_engine(f"sqlite:///{tmp_path}/db.sqlite")
    sessions = make_session_factory(engine)
    from datetime import datetime, timezone

    from illumon_service.storage import Camera

    with sessions() as s, s.begin():
        cam = Camera(name="c", token_hash="0" * 64, sensitivities=[], regions=[], response={})
        s.add(cam)
        s.flush()
        t = datetime(2025, 1, 1, tzinfo=timezone.utc)
        s.execute(insert(Frame), [{"camera_id": cam.id, "taken_at": t, "patches": StoredJSON('{"a":[0.1,0.2,1e-7]}')},
                                  {"camera_id": cam.id, "taken_at": t, "patches": {"a": [0.1, float("nan"), 1e-7]}}])
    with engine.connect() as c:
        raw = c.execute(text("SELECT patches FROM frames ORDER BY id")).scalars().all()
    assert raw == ['{"a":[0.1,0.2,1e-7]}', '{"a": [0.1, NaN, 1e-07]}']
    with sessions() as s:
        got = s.scalars(select(Frame.patches).order_by(Frame.id)).all()
    assert same_value(got[0], {"a": [0.1, 0.2, 1e-7]}) and same_value(got[1], {"a": [0.1, float("nan"), 1e-7]})
    engine.dispose()


def _estimate_rows(n: int, non_finite: bool) -> tuple[list[dict], dict]:
    """Estimate rows with datetimes, -0.0, JSON text given, JSON null, NaN and infinity in JSON (``non_finite``:
    PostgreSQL refuses them, whoever writes them), binary values (``None``, empty, bytes); and constants."""
    from datetime import datetime, timedelta, timezone

    t0 = datetime(2025, 1, 1, 12, tzinfo=timezone.utc)
    rows = [{"frame_id": i + 1, "taken_at": t0 + timedelta(seconds=1.5 * i), "cct_k": 5000.0 + i,
             "duv": -0.0 if i == 2 else 0.001, "xy": [0.31, float("nan") if non_finite else 1e-5],
             "white_rgb": StoredJSON("[0.5,1.0,0.25]"), "gains_rgb": [2.0, float("inf") if non_finite else 3.0, 4.0],
             "confidence": 0.5, "spectrum": [1e-7] * 61,
             "spectrum_f32": None if i == 1 else b"" if i == 3 else bytes(range(8 * i, 8 * i + 244 % (i + 7))),
             "intervals": None if i % 2 else {"cct_lo": 4000.0, "gain_lo": [1.0, None, 2.0]}, "source": "refit:model"}
            for i in range(n)]
    return rows, {"camera_id": 1, "model": "v1", "created_at": t0}


def _stored_estimates(url: str, columns: bool, non_finite: bool = True) -> list[tuple]:
    """The rows of :func:`_estimate_rows` inserted by SQLAlchemy's executemany or by insert_columns, read back."""
    from illumon_service.storage import Camera, Estimate, insert_columns

    rows, constants = _estimate_rows(5, non_finite)
    engine = make_engine(url)
    sessions = make_session_factory(engine)
    with sessions() as s, s.begin():
        s.add(Camera(name="c", token_hash="0" * 64, sensitivities=[], regions=[], response={}))
        s.flush()
        s.execute(insert(Frame), [{"camera_id": 1, "taken_at": constants["created_at"], "patches": {}} for _ in rows])
        if columns:
            assert insert_columns(s, Estimate.__table__, {k: [r[k] for r in rows] for k in rows[0]}, constants) == 5
            with pytest.raises(ValueError):
                insert_columns(s, Estimate.__table__, {"frame_id": [9], "camera_id": [1]})  # created_at missing
        else:
            s.execute(insert(Estimate.__table__), [{**r, **constants} for r in rows])
    with sessions() as s:
        got = [tuple(r) for r in s.execute(select(Estimate.__table__).order_by(Estimate.frame_id)).all()]
    engine.dispose()
    return got


def test_insert_columns_stores_what_a_core_insert_stores(tmp_path) -> None:
    """storage.insert_columns (values converted a column at a time, the driver's executemany) stores the rows that
    SQLAlchemy's executemany INSERT of the same rows stores, text for text on SQLite."""
    import sqlite3

    stored = []
    for name in ("core", "columns"):
        got = _stored_estimates(f"sqlite:///{tmp_path}/{name}.sqlite", name == "columns")
        con = sqlite3.connect(f"{tmp_path}/{name}.sqlite")
        stored.append((con.execute("SELECT * FROM estimates ORDER BY frame_id").fetchall(), got))
        con.close()
    assert stored[0][0] == stored[1][0] and len(stored[0][0]) == 5
    assert all(same_value(list(a), list(b)) for a, b in zip(stored[0][1], stored[1][1], strict=True))


def test_insert_columns_on_postgresql(pg_url) -> None:  # noqa: F811 - the fixture imported below
    """The same on PostgreSQL (psycopg's JSON wrapper, the engine's serializer, typed parameters): the rows read back
    equal, the JSON text given stored as it is."""
    from sqlalchemy import create_engine

    reset = create_engine(pg_url)
    got = []
    for columns in (False, True):
        with reset.begin() as c:
            c.execute(text("DROP SCHEMA public CASCADE; CREATE SCHEMA public"))
        got.append(_stored_estimates(pg_url, columns, non_finite=False))
        with reset.connect() as c:
            raw = c.execute(text("SELECT white_rgb::text FROM estimates ORDER BY frame_id")).scalars().all()
        assert raw == ["[0.5,1.0,0.25]"] * 5
    reset.dispose()
    assert len(got[0]) == 5 and all(same_value(list(a), list(b)) for a, b in zip(got[0], got[1], strict=True))


def test_datetime_text_is_sqlalchemy_sqlite_text() -> None:
    """``insert_columns``' datetime text (``_datetime_text``) is SQLAlchemy's SQLite ``DATETIME`` text: naive and aware
    times, microseconds or none, years before 1000; other values (``None``, a date) through the processor itself."""
    import random
    from datetime import datetime, timedelta, timezone

    from illumon_service.storage import _datetime_text, _writes_datetime_text
    from sqlalchemy import DateTime
    from sqlalchemy.dialects import sqlite

    dialect = sqlite.dialect()
    process = DateTime(timezone=True).dialect_impl(dialect).bind_processor(dialect)
    assert _writes_datetime_text(process)
    rng = random.Random(1)
    zones = [None, timezone.utc, timezone(timedelta(hours=5, minutes=30)), timezone(timedelta(hours=-8))]
    for _ in range(20_000):
        t = datetime(rng.randint(1, 9999), rng.randint(1, 12), rng.randint(1, 28), rng.randint(0, 23),
                     rng.randint(0, 59), rng.randint(0, 59), rng.choice([0, rng.randint(0, 999_999)]),
                     rng.choice(zones))
        assert _datetime_text(t) == process(t), t
    assert not _writes_datetime_text(lambda v: v.isoformat())  # another format: the processor's own text


def test_json_dicts_equal_orjson_row_by_row() -> None:
    """A refit's intervals cut out of one orjson text of the list are each row's own orjson text; a ``None`` row
    (no intervals) keeps the rows' texts one call each."""
    import orjson
    from illumon_service.estimation.batch import _json_dicts

    rng = np.random.default_rng(2)
    bits = rng.integers(0, 2**64, 400, dtype=np.uint64).view(np.float64)
    values = [float(v) for v in bits if np.isfinite(v)] + [0.0, -0.0, 5e-324, 1e300]
    rows = [{"cct_lo": values[i], "duv_hi": None, "gain_lo": values[i : i + 3], "n": 3} for i in range(len(values) - 3)]
    assert _json_dicts(rows) == [orjson.dumps(r).decode() for r in rows]
    assert _json_dicts([*rows[:2], None]) == [orjson.dumps(rows[0]).decode(), orjson.dumps(rows[1]).decode(), None]
    assert _json_dicts([]) == []



def test_interval_texts_equal_the_rows_texts() -> None:
    """A refit's intervals assembled from one orjson text of each array (issue 29) are the texts of the rows' dicts
    (``_json_dicts``), bit patterns, ±0, subnormals and huge values among them; where a value is not finite, an array
    wider than the narrow rows' or of another shape, or there is nothing to write, the rows' path is taken."""
    from illumon_service.estimation.batch import _interval_texts, _json_dicts
    from illumon_service.storage import JSONTexts

    rng = np.random.default_rng(5)
    n = 600
    bits = rng.integers(0, 2**64, 3 * n, dtype=np.uint64).view(np.float64)
    finite = np.concatenate([bits[np.isfinite(bits)], [0.0, -0.0, 5e-324, 1e300, 1e16, 0.1]])
    pick = lambda *shape: rng.choice(finite, shape)  # noqa: E731
    intervals = {"cct_lo": pick(n), "cct_hi": pick(n), "non_daylight": rng.uniform(0, 1, n),
                 "gain_lo": pick(n, 3), 'odd "key"\u00e9': pick(n, 2)}

    def rows_texts(arrays: dict) -> list:
        lists = [v.tolist() for v in arrays.values()]
        return _json_dicts([dict(zip(arrays, values, strict=True)) for values in zip(*lists, strict=True)])

    got = _interval_texts(intervals, n)
    assert type(got) is JSONTexts and got == rows_texts(intervals)
    one = {"cct_lo": intervals["cct_lo"][:1]}
    assert _interval_texts(one, 1) == rows_texts(one)
    with_nan = {**intervals, "cct_hi": np.where(np.arange(n) == 7, np.inf, intervals["cct_hi"])}
    assert _interval_texts(with_nan, n) is None
    assert _interval_texts({**intervals, "wide": pick(n, 9)}, n) is None
    assert _interval_texts({"cube": pick(n, 2, 2)}, n) is None
    assert _interval_texts({}, n) is None and _interval_texts({"cct_lo": pick(0)}, 0) is None


from test_faults import pg_url  # noqa: E402, F401 - a throwaway PostgreSQL cluster, or skip
