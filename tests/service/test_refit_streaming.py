"""A refit's history is streamed (``refit.READ_CHUNK`` rows at a time into arrays) and its estimates written a chunk
at a time (``crud.WRITE_CHUNK``, issue 29): chunks of a few rows give the same estimates, reasons and summary as one
chunk, on a history with applied gains, a second view, a view without regions, a view change and an invalid frame."""

from __future__ import annotations

import warnings
from datetime import datetime, timedelta, timezone

import illumon_service.refit as refit
import numpy as np
import pytest
from illumon.simulation import simulate_history
from illumon_service import crud
from illumon_service.storage import Camera, CameraView, Estimate, Frame, make_engine, make_session_factory
from sqlalchemy import insert, select

T0 = datetime(2025, 6, 1, tzinfo=timezone.utc)
IDS = [f"p{j:02d}" for j in range(8)]


def _store(url: str) -> int:
    rng = np.random.default_rng(3)
    wl = np.arange(400, 701, 5)
    css = np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])
    from illumon.daylight import CIEDaylight

    mired = np.linspace(110, 250, 90)
    day = CIEDaylight().spectra(np.column_stack([mired, np.zeros_like(mired)]))
    refl = np.clip(0.2 + 0.6 * rng.random((8, 1)) * np.sin(wl / rng.uniform(40, 120, (8, 1))) ** 2, 0, 1)
    hist = simulate_history(css, day, refl, rng=1, missing_fraction=0.1)
    engine = make_engine(url)
    sessions = make_session_factory(engine)
    with sessions() as s, s.begin():
        cam = Camera(name="c", token_hash="0" * 64, sensitivities=css.tolist(), response={"encoding": "linear"},
                     regions=[{"id": p, "x": 0, "y": 0, "width": 1, "height": 1} for p in IDS])
        s.add(cam)
        s.flush()
        s.add(CameraView(camera_id=cam.id, view="east", regions=cam.regions[:5]))
        rows = []
        for f, v in enumerate(hist.observations.values):
            patches = {p: None if not np.isfinite(v[j, 0]) else v[j].tolist() for j, p in enumerate(IDS)}
            row = {"camera_id": cam.id, "taken_at": T0 + timedelta(minutes=f), "patches": patches,
                   "view": "east" if f % 3 == 0 else "west" if f % 11 == 0 else None}
            if f % 4 == 0:
                row.update(applied_gains=[1.4, 1.0, 0.8], exposure=0.9)
            if f == 70:
                row["registration"] = {"state": "view_change"}
            if f == 80:
                row["patches"] = {**patches, IDS[0]: [-1.0, 0.2, 0.2]}
            rows.append(row)
        s.execute(insert(Frame), rows)
        cid = cam.id
    engine.dispose()
    return cid


def _refit(tmp_path, name: str) -> tuple[dict, list, list]:
    url = f"sqlite:///{tmp_path}/{name}.sqlite"
    cid = _store(url)
    sessions = make_session_factory(make_engine(url))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        summary = refit.refit_camera(sessions, cid, data_dir=tmp_path / name, max_frames=80)
    with sessions() as s:
        est = [tuple(getattr(e, c.name) for c in Estimate.__table__.columns if c.name not in ("created_at", "model"))
               for e in s.scalars(select(Estimate).order_by(Estimate.frame_id))]
        reasons = s.execute(select(Frame.id, Frame.not_estimated).order_by(Frame.id)).all()
    for k in ("seconds", "read_s", "fit_s", "write_s", "response_check_s", "version"):
        summary.pop(k)
    return summary, est, [tuple(r) for r in reasons]


def test_chunked_refit_equals_one_chunk(tmp_path, monkeypatch) -> None:
    whole = _refit(tmp_path, "whole")
    monkeypatch.setattr(refit, "READ_CHUNK", 7)
    monkeypatch.setattr(crud, "WRITE_CHUNK", 5)
    chunked = _refit(tmp_path, "chunked")
    assert chunked[0] == whole[0]
    assert chunked[1] == whole[1] and len(whole[1]) > 40
    assert chunked[2] == whole[2]
    reasons = dict(whole[2])
    assert reasons[81] == "invalid_values" and whole[0]["dropped_frames"] == 1
    assert any("'west' not refitted" in w for w in whole[0]["warnings"])


def test_estimate_rows_built_column_by_column_equal_the_per_frame_rows():
    """``RefitEstimates.rows`` converts each column of a chunk at once; its rows equal :func:`estimate_row` with
    :func:`frame_intervals` frame by frame, non-finite intervals (``None``), NaN and out-of-range confidences, frames
    left out and chunk boundaries inside and across parts included."""
    from illumon.retrieval.common import RetrievalResult
    from illumon_service.estimation.batch import RefitEstimates
    from illumon_service.estimation.frame import estimate_row, frame_intervals

    rng = np.random.default_rng(0)

    def part(n: int, tag: str) -> tuple[RetrievalResult, dict, np.ndarray]:
        res = RetrievalResult(frames=[f"{tag}{i}" for i in range(n)], patches=IDS, spectra=rng.random((n, 61)),
                              xy=rng.random((n, 2)), cct=rng.uniform(3000, 9000, n), duv=rng.normal(0, 0.003, n),
                              white=rng.random((n, 3)), gains=rng.random((n, 3)), exposures=np.ones(n),
                              reflectances=np.full((8, 61), np.nan), method="model",
                              info={"gain_lo": rng.random((n, 3)), "gain_hi": rng.random((n, 3))})
        res.info["gain_hi"][1, 2] = np.inf
        extra = {"cct_lo": rng.uniform(2000, 3000, n), "cct_hi": rng.uniform(9000, 20000, n),
                 "non_daylight": rng.random(n), "confidence": rng.normal(0.5, 0.7, n)}
        extra["cct_hi"][::3] = np.inf
        extra["non_daylight"][2] = np.nan
        extra["confidence"][4] = np.nan
        return res, extra, rng.random(n) < 0.8

    est = RefitEstimates()
    parts = [part(23, "a"), part(9, "b")]
    for res, extra, keep in parts:
        est.add(res, extra["confidence"], keep, "refit:model", extra)
    est.add(parts[0][0], parts[0][1]["confidence"], parts[0][2], "refit:plain")  # no intervals
    expected = [(str(res.frames[i]), estimate_row(res, i, extra["confidence"][i], source,
                                                  frame_intervals(res, extra, i) if with_iv else None))
                for (res, extra, keep), source, with_iv in [(parts[0], "refit:model", True), (parts[1], "refit:model", True),
                                                           (parts[0], "refit:plain", False)]
                for i in np.flatnonzero(keep)]
    chunks = list(est.rows(7))
    assert [len(c) for c in chunks[:-1]] == [7] * (len(chunks) - 1) and 0 < len(chunks[-1]) <= 7
    got = [r for c in chunks for r in c]
    assert [fid for fid, _ in got] == [fid for fid, _ in expected]
    for (_, a), (_, b) in zip(got, expected, strict=True):
        assert list(a) == list(b)
        np.testing.assert_equal(a, b)  # NaN equal NaN; None where the per-frame rows have None


def test_the_objects_set_aside_return_to_the_collector_after_the_refit():
    """:func:`illumon_service.refit._objects_held_aside` (the read and write steps' containers not walked with the
    whole process's by every collection): frozen while the refit runs, unfrozen after it, also when it raises."""
    import gc

    from illumon_service.refit import _objects_held_aside

    assert gc.get_freeze_count() == 0
    with pytest.raises(RuntimeError), _objects_held_aside() as aside:
        assert gc.get_freeze_count() > 0
        kept = [[i] for i in range(1000)]
        aside()
        assert gc.get_freeze_count() >= 1000 and kept
        raise RuntimeError
    assert gc.get_freeze_count() == 0


def test_estimate_rows_as_json_text_read_back_as_the_rows():
    """``RefitEstimates.rows(…, json_text=True)`` (what a refit writes): the JSON columns as JSON text that reads back
    as the rows' values (``json.loads``), a row with a non-finite value as its list, the other columns unchanged."""
    import json

    from illumon.retrieval.common import RetrievalResult
    from illumon_service.estimation.batch import RefitEstimates
    from illumon_service.storage import StoredJSON

    rng = np.random.default_rng(1)
    n = 12
    res = RetrievalResult(frames=[f"f{i}" for i in range(n)], patches=IDS, spectra=rng.random((n, 61)),
                          xy=rng.random((n, 2)), cct=rng.uniform(3000, 9000, n), duv=rng.normal(0, 0.003, n),
                          white=rng.random((n, 3)), gains=rng.random((n, 3)), exposures=np.ones(n),
                          reflectances=np.full((8, 61), np.nan), method="model",
                          info={"gain_lo": rng.random((n, 3)), "gain_hi": rng.random((n, 3))})
    res.spectra[2, 7] = np.nan
    res.gains[5, 1] = np.inf
    extra = {"cct_lo": rng.uniform(2000, 3000, n), "cct_hi": rng.uniform(9000, 20000, n), "confidence": rng.random(n)}
    extra["cct_hi"][3] = np.inf
    est = RefitEstimates()
    est.add(res, extra["confidence"], np.ones(n, bool), "refit:model", extra)
    est.add(res, extra["confidence"], np.arange(n) % 2 == 0, "refit:plain")
    plain = [r for c in est.rows(5) for r in c]
    text = [r for c in est.rows(5, json_text=True) for r in c]
    assert [fid for fid, _ in text] == [fid for fid, _ in plain]
    assert isinstance(text[0][1]["gains_rgb"], StoredJSON) and isinstance(text[5][1]["gains_rgb"], list)
    # the spectrum as float32 bytes (its NaN kept), the older versions' JSON column null
    assert text[0][1]["spectrum"] == "null" and plain[0][1]["spectrum"] is None
    spectra = [np.frombuffer(t["spectrum_f32"], dtype="<f4") for _, t in text[:n]]
    np.testing.assert_array_equal(spectra, res.spectra.astype(np.float32))
    assert np.isnan(spectra[2][7])
    assert isinstance(text[0][1]["intervals"], StoredJSON) and text[1][1]["intervals"] is not None
    for (_, t), (_, p) in zip(text, plain, strict=True):
        assert list(t) == list(p)
        for k in ("xy", "white_rgb", "gains_rgb", "spectrum", "intervals"):
            if isinstance(t[k], StoredJSON):
                t[k] = json.loads(t[k])
            else:  # a row with NaN or infinity, or no intervals: as before
                assert t[k] is None or not np.isfinite(t[k]).all()
        np.testing.assert_equal(t, p)


def test_refit_stores_values_equal_to_the_lists_json_dumps_wrote(tmp_path, monkeypatch):
    """A refit writing its estimates' arrays as orjson text reads back — raw with ``json.loads``, and as the JSON API
    and the status page give them (``estimate_out``, ``camera_history``) — equal to the refit that wrote them as lists
    through ``json.dumps`` (before issue 29's rows change); its reasons and summary are the same."""
    import json
    import sqlite3

    from illumon_service.estimation.batch import RefitEstimates

    def stored(name: str) -> tuple:
        summary, _, reasons = _refit(tmp_path, name)
        url = f"sqlite:///{tmp_path}/{name}.sqlite"
        con = sqlite3.connect(f"{tmp_path}/{name}.sqlite")
        raw = con.execute("SELECT frame_id, taken_at, cct_k, duv, xy, white_rgb, gains_rgb, confidence, spectrum, "
                          "intervals, source FROM estimates ORDER BY frame_id").fetchall()
        con.close()
        sessions = make_session_factory(make_engine(url))
        with sessions() as s:
            api = [crud.estimate_out(e) for e in crud.estimates_between(s, 1, None, None, 10_000)]
            page = crud.camera_history(s, 1, 10_000)
        return summary, reasons, raw, api, page

    new = stored("new")
    columns = RefitEstimates.columns
    monkeypatch.setattr(RefitEstimates, "columns", lambda self, chunk, json_text=False: columns(self, chunk))
    old = stored("old")
    assert new[0] == old[0] and new[1] == old[1] and len(new[2]) == len(old[2]) > 40
    # written otherwise (orjson's text, json.dumps's) but for the frames older than max_frames, estimated one by one
    assert sum(a[4] != b[4] for a, b in zip(new[2], old[2], strict=True)) > 40
    for a, b in zip(new[2], old[2], strict=True):
        parse = [json.loads(v) if j in (4, 5, 6, 8, 9) and v is not None else v for j, v in enumerate(a)]
        np.testing.assert_equal(parse, [json.loads(v) if j in (4, 5, 6, 8, 9) and v is not None else v
                                        for j, v in enumerate(b)])
    assert json.dumps(new[3]) == json.dumps(old[3]) and json.dumps(new[4]) == json.dumps(old[4])


def test_refit_writes_the_stored_times_of_its_frames(tmp_path) -> None:
    """The estimates' ``taken_at`` is their frames' stored text (carried from the read step, not formatted again),
    and frames whose time was stored in another form that SQLAlchemy reads (milliseconds, no fraction) get what
    writing the time read stores: the same rows, summary and reasons as when stored in SQLAlchemy's form."""
    import sqlite3

    def times(name: str) -> list[tuple]:
        con = sqlite3.connect(f"{tmp_path}/{name}.sqlite")
        rows = con.execute("SELECT e.frame_id, e.taken_at, f.taken_at FROM estimates e JOIN frames f "
                           "ON f.id = e.frame_id ORDER BY e.frame_id").fetchall()
        con.close()
        return rows

    plain = _refit(tmp_path, "plain")
    stored = times("plain")
    assert len(stored) > 40 and all(e == f and len(e) == 26 for _, e, f in stored)

    url = f"sqlite:///{tmp_path}/odd.sqlite"
    _store(url)
    con = sqlite3.connect(f"{tmp_path}/odd.sqlite")
    con.execute("UPDATE frames SET taken_at = substr(taken_at, 1, 23) WHERE id % 5 = 0")  # the same order
    con.execute("UPDATE frames SET taken_at = substr(taken_at, 1, 19) WHERE id % 5 = 1")
    con.commit()
    con.close()
    sessions = make_session_factory(make_engine(url))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        summary = refit.refit_camera(sessions, 1, data_dir=tmp_path / "odd", max_frames=80)
    with sessions() as s:
        est = [tuple(getattr(e, c.name) for c in Estimate.__table__.columns if c.name not in ("created_at", "model"))
               for e in s.scalars(select(Estimate).order_by(Estimate.frame_id))]
        reasons = [tuple(r) for r in s.execute(select(Frame.id, Frame.not_estimated).order_by(Frame.id)).all()]
    for k in ("seconds", "read_s", "fit_s", "write_s", "response_check_s", "version"):
        summary.pop(k)
    assert (summary, est, reasons) == plain
    odd = times("odd")
    assert [e for _, e, _ in odd] == [e for _, e, _ in stored]
    assert {len(f) for _, _, f in odd} == {19, 23, 26}
