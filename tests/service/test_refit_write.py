"""A refit's write step (issue 29, branch ``refit-io``): its estimates replace the stored ones with one
``INSERT … ON CONFLICT (frame_id) DO UPDATE`` per chunk where the database has it (SQLite ≥ 3.24, PostgreSQL), and
the frames' reasons for having no estimate are cleared for those that have one. The tables it leaves are those of a
DELETE of the chunk's frames followed by the INSERT (the path of other databases), row for row."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import illumon_service.crud.estimates as crud_estimates
import pytest
from illumon_service import crud
from illumon_service.storage import (
    Camera,
    Estimate,
    Frame,
    StoredJSON,
    make_engine,
    make_session_factory,
    upsert_dialect,
)
from sqlalchemy import insert, select, text
from svc_helpers import same_value

T0 = datetime(2025, 6, 1, tzinfo=timezone.utc)
N = 30


def _estimate(i: int, version: str) -> dict:
    """Estimate columns of frame ``i`` (1-based) by model ``version``."""
    shift = 0.0 if version == "old" else 100.0
    return {"frame_id": i, "camera_id": 1, "taken_at": T0 + timedelta(minutes=i), "cct_k": 5000.0 + i + shift,
            "duv": 0.001 * i, "xy": [0.31, 0.32 + 1e-3 * i], "white_rgb": StoredJSON(f"[0.5,1.0,{0.01 * i}]"),
            "gains_rgb": [2.0, 1.0, 1.5], "confidence": 0.5, "spectrum": [1e-3 * i] * 61,
            "intervals": None if i % 2 else {"cct_lo": 4000.0 + shift}, "source": f"refit:{version}"}


def _written(url: str, chunk: int) -> tuple[list, list]:
    """A camera of :data:`N` frames, half of them estimated by an old model and a third of them with a reason for
    having none; then :func:`crud.replace_estimates` of frames 6…25 by a new model, ``chunk`` frames per chunk.
    Returns the estimates (all columns but ``created_at``) and the frames' reasons, by id."""
    engine = make_engine(url)
    sessions = make_session_factory(engine)
    with sessions() as s, s.begin():
        s.add(Camera(name="c", token_hash="0" * 64, sensitivities=[], regions=[], response={}))
        s.flush()
        s.execute(insert(Frame), [{"camera_id": 1, "taken_at": T0 + timedelta(minutes=i), "patches": {},
                                   "not_estimated": "no_model" if i % 3 == 0 else None} for i in range(1, N + 1)])
        s.execute(insert(Estimate), [{**_estimate(i, "old"), "model": "old", "created_at": T0}
                                     for i in range(1, N + 1) if i % 2 == 0 and not 13 <= i <= 25])
    new = [_estimate(i, "new") for i in range(6, 26)]

    def chunks():  # noqa: ANN202 - the columns of ``chunk`` estimates at a time, as the refit gives them
        for start in range(0, len(new), chunk):
            part = new[start : start + chunk]
            yield {k: [r[k] for r in part] for k in part[0] if k != "camera_id"}

    with sessions() as s, s.begin():
        assert crud.replace_estimates(s, chunks(), camera_id=1, model="new") == len(new)
    with sessions() as s:
        est = [tuple(r) for r in s.execute(select(*[c for c in Estimate.__table__.columns if c.name != "created_at"])
                                           .order_by(Estimate.frame_id)).all()]
        reasons = [tuple(r) for r in s.execute(select(Frame.id, Frame.not_estimated).order_by(Frame.id)).all()]
    engine.dispose()
    return est, reasons


def _both(url_of, monkeypatch) -> None:  # noqa: ANN001 - a function of the path's name to a database URL
    """The upsert path and the DELETE + INSERT path leave the same tables; the new estimates replaced the old; a
    chunk without a stored estimate is a plain INSERT."""
    got = {}
    replaced: list[bool] = []
    insert_columns = crud_estimates.insert_columns

    def spy(*args, replace_on=None, **kwargs):  # noqa: ANN002, ANN003, ANN202 - insert_columns' own
        replaced.append(bool(replace_on))
        return insert_columns(*args, replace_on=replace_on, **kwargs)

    monkeypatch.setattr(crud_estimates, "insert_columns", spy)
    for name in ("upsert", "delete"):
        if name == "delete":
            monkeypatch.setattr(crud_estimates, "upsert_dialect", lambda _dialect: False)
        got[name] = _written(url_of(name), chunk=7)
        if name == "upsert":
            replaced = replaced[:]  # the upsert path's chunks
            monkeypatch.setattr(crud_estimates, "insert_columns", insert_columns)
    (est, reasons), (est_d, reasons_d) = got["upsert"], got["delete"]
    assert len(est) == len(est_d) == 20 + 2 + 3  # frames 6…25 new, the old ones of 2, 4 and 26, 28, 30 kept
    assert replaced == [True, False, False]  # chunks 6…12 (old estimates of 6, 8, 10, 12), 13…19, 20…25 (none)
    assert all(same_value(list(a), list(b)) for a, b in zip(est, est_d, strict=True))
    assert reasons == reasons_d
    by_id = {r[0]: r for r in est}
    assert by_id[6][-1] == "new" and by_id[4][-1] == "old" and by_id[26][-1] == "old"
    assert by_id[10][3] == 5110.0 and by_id[10][-2] == "refit:new"
    assert dict(reasons) == {i: "no_model" if i % 3 == 0 and not 6 <= i <= 25 else None for i in range(1, N + 1)}


def test_upsert_leaves_the_rows_of_delete_and_insert_on_sqlite(tmp_path, monkeypatch) -> None:
    engine = make_engine(f"sqlite:///{tmp_path}/probe.sqlite")
    with engine.connect():
        assert upsert_dialect(engine.dialect)  # the path under test is taken
    engine.dispose()
    _both(lambda name: f"sqlite:///{tmp_path}/{name}.sqlite", monkeypatch)


def test_upsert_leaves_the_rows_of_delete_and_insert_on_postgresql(pg_url, monkeypatch) -> None:  # noqa: F811
    from sqlalchemy import create_engine

    reset = create_engine(pg_url)

    def fresh(_name: str) -> str:
        with reset.begin() as c:
            c.execute(text("DROP SCHEMA public CASCADE; CREATE SCHEMA public"))
        return pg_url

    try:
        _both(fresh, monkeypatch)
    finally:
        reset.dispose()


def _json_columns_written(url: str, non_finite: bool) -> dict[str, list]:
    """Estimates of frames 1…6 written by :func:`insert_columns` twice: once with their JSON columns as
    :class:`JSONTexts` (plain ``str`` texts, ``None``, a list, a dict; ``non_finite``: holding NaN and infinity, which
    PostgreSQL's JSON refuses), once as the same values one by one (:class:`StoredJSON` for a text). Returns each
    write's JSON columns as stored (text) and as read, by frame."""
    from illumon_service.storage import JSONTexts, insert_columns
    from sqlalchemy import Text, cast, delete

    engine = make_engine(url)
    sessions = make_session_factory(engine)
    with sessions() as s, s.begin():
        s.add(Camera(name="c", token_hash="0" * 64, sensitivities=[], regions=[], response={}))
        s.flush()
        s.execute(insert(Frame), [{"camera_id": 1, "taken_at": T0 + timedelta(minutes=i), "patches": {}}
                                  for i in range(1, 7)])
    odd = float("nan") if non_finite else 0.5
    texts = {"xy": ["[0.31,0.32]", "[0.3,1e-07]", [0.1, odd], "[1.0,2.5]", "[0.5,0.25]", "[0.0,-0.0]"],
             "white_rgb": ["[0.5,1.0,0.25]"] * 6, "gains_rgb": ["[2.0,1.0,1.5]"] * 6, "spectrum": ["null"] * 6,
             "intervals": ['{"cct_lo":4000.5,"gain_lo":[1.0,2.0,3.0]}', None, {"cct_lo": float("inf")},
                           '{"non_daylight":null}', None, '{"a":1}']}
    if not non_finite:
        texts["intervals"][2] = {"cct_lo": 4000.25}
    base = {"frame_id": list(range(1, 7)), "taken_at": [T0 + timedelta(minutes=i) for i in range(1, 7)],
            "cct_k": [5000.0] * 6, "duv": [0.0] * 6, "confidence": [0.5] * 6, "source": ["refit:x"] * 6}
    out = {}
    for kind in ("texts", "stored"):
        if kind == "texts":
            cols = {k: JSONTexts(v) for k, v in texts.items()}
        else:
            cols = {k: [StoredJSON(x) if type(x) is str else x for x in v] for k, v in texts.items()}
        with sessions() as s, s.begin():
            s.execute(delete(Estimate))
            insert_columns(s, Estimate.__table__, {**base, **cols},
                           {"camera_id": 1, "created_at": T0, "model": "m", "spectrum_f32": None})
        with sessions() as s:
            keys = list(texts)
            stored = s.execute(select(*[cast(Estimate.__table__.c[k], Text) for k in keys])
                               .order_by(Estimate.frame_id)).all()
            read = s.execute(select(*[Estimate.__table__.c[k] for k in keys]).order_by(Estimate.frame_id)).all()
            out[kind] = [[tuple(r) for r in stored], [tuple(r) for r in read]]
    engine.dispose()
    return out


def _json_texts_as_stored_json(url: str, non_finite: bool) -> None:
    got = _json_columns_written(url, non_finite)
    assert got["texts"][0] == got["stored"][0]  # the same texts stored
    assert all(same_value(list(a), list(b)) for a, b in zip(got["texts"][1], got["stored"][1], strict=True))
    row0 = got["texts"][1][0]
    assert row0[0] == [0.31, 0.32] and row0[4] == {"cct_lo": 4000.5, "gain_lo": [1.0, 2.0, 3.0]} and row0[3] is None


def test_json_texts_columns_store_what_stored_json_values_do_on_sqlite(tmp_path) -> None:
    """A refit's JSON columns as :class:`JSONTexts` of plain ``str`` (issue 29: the driver binds a ``str`` subclass
    more slowly) store the texts, ``None`` and the lists exactly as :class:`StoredJSON` values one by one do."""
    _json_texts_as_stored_json(f"sqlite:///{tmp_path}/texts.sqlite", non_finite=True)


def test_json_texts_columns_store_what_stored_json_values_do_on_postgresql(pg_url) -> None:  # noqa: F811
    from sqlalchemy import create_engine

    reset = create_engine(pg_url)
    try:
        with reset.begin() as c:
            c.execute(text("DROP SCHEMA public CASCADE; CREATE SCHEMA public"))
        _json_texts_as_stored_json(pg_url, non_finite=False)
    finally:
        reset.dispose()


def test_a_refits_late_frames_keep_their_columns_json_texts() -> None:
    """The write step's columns without the frames estimated late (:func:`.refit._estimate_columns`) stay
    :class:`JSONTexts` where they were (a plain list of texts would be written as JSON strings)."""
    from illumon_service.storage import JSONTexts, json_texts_like

    column = JSONTexts(["[1.0]", None, "[2.0]"])
    kept = json_texts_like(column, (v for v, ok in zip(column, [True, False, True], strict=True) if ok))
    assert type(kept) is JSONTexts and kept == ["[1.0]", "[2.0]"]
    assert type(json_texts_like([1, 2], iter([2]))) is list


def test_insert_columns_refuses_an_upsert_it_cannot_compile() -> None:
    from illumon_service.storage import _insert_statement
    from sqlalchemy.dialects import mysql

    with pytest.raises(ValueError, match="no upsert"):
        _insert_statement(Estimate.__table__, mysql.dialect(), ["frame_id", "cct_k"], ("frame_id",))


from test_faults import pg_url  # noqa: E402, F401 - a throwaway PostgreSQL cluster, or skip


@pytest.mark.parametrize("sqlite_text", [True, False])
def test_datetime_texts_store_the_times_they_read_as(tmp_path, monkeypatch, sqlite_text) -> None:
    """A :class:`DateTimeTexts` column (a refit's stored times carried from its read step: SQLite's text, and
    datetimes) stores what the times themselves store, the texts as they are where the column writes that text and
    read as times where it does not (``sqlite_text`` false: the other path, as on PostgreSQL)."""
    import illumon_service.storage as storage
    from illumon_service.storage import DateTimeTexts, insert_columns
    from sqlalchemy import String, delete, type_coerce

    if not sqlite_text:
        monkeypatch.setattr(storage, "_writes_datetime_text", lambda _process: False)
    engine = make_engine(f"sqlite:///{tmp_path}/times.sqlite")
    sessions = make_session_factory(engine)
    times = [T0 + timedelta(minutes=i, microseconds=7 * (i % 2)) for i in range(1, 5)]
    with sessions() as s, s.begin():
        s.add(Camera(name="c", token_hash="0" * 64, sensitivities=[], regions=[], response={}))
        s.flush()
        s.execute(insert(Frame), [{"camera_id": 1, "taken_at": t, "patches": {}} for t in times])
    texts = [t.replace(tzinfo=None).isoformat(" ", "microseconds") for t in times]
    out = []
    for column in (times, DateTimeTexts([texts[0], times[1], texts[2], texts[3]])):
        row = {"cct_k": [5000.0] * 4, "duv": [0.0] * 4, "confidence": [0.5] * 4, "source": ["refit:x"] * 4,
               **{k: ["[1.0]"] * 4 for k in ("xy", "white_rgb", "gains_rgb")}}
        with sessions() as s, s.begin():
            s.execute(delete(Estimate))
            insert_columns(s, Estimate.__table__, {"frame_id": [1, 2, 3, 4], "taken_at": column, **row},
                           {"camera_id": 1, "created_at": T0, "model": "m"})
        with sessions() as s:
            out.append(s.execute(select(type_coerce(Estimate.taken_at, String)).order_by(Estimate.frame_id)).all())
    engine.dispose()
    assert out[1] == out[0] and [r[0] for r in out[0]] == texts
