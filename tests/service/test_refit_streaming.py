"""A refit's history is streamed (``refit.READ_CHUNK`` rows at a time into arrays) and its estimates written a chunk
at a time (``crud.WRITE_CHUNK``, issue 29): chunks of a few rows give the same estimates, reasons and summary as one
chunk, on a history with applied gains, a second view, a view without regions, a view change and an invalid frame."""

from __future__ import annotations

import warnings
from datetime import datetime, timedelta, timezone

import illumon_service.refit as refit
import numpy as np
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
