"""The estimates' spectra stored as float32 bytes (``Estimate.spectrum_f32``, issue 29): what the API answers is the
estimator's spectrum to float32 precision, for a refit's estimates and an ingest's; a database of an older version —
its ``spectrum`` a ``NOT NULL`` JSON column, no ``spectrum_f32`` — is brought up to date at start-up, its stored rows
answer their JSON spectrum as before, and new estimates are written into it; on SQLite and on PostgreSQL."""

from __future__ import annotations

import json
from datetime import timedelta

import illumon_service.estimation.batch as batch
import illumon_service.estimation.frame as frame
import numpy as np
from fastapi.testclient import TestClient
from illumon.daylight import CIEDaylight
from illumon.simulation import simulate_history
from illumon_service.app import create_app
from illumon_service.storage import SPECTRUM_DTYPE, spectra_bytes, spectrum_bytes, spectrum_values
from sqlalchemy import create_engine, inspect, text
from svc_helpers import T0, admin_headers, bearer, camera_body, grid_regions, make_settings, same_value

N_FRAMES = 60
REGIONS = grid_regions(8)
IDS = [r["id"] for r in REGIONS]

OLD_ESTIMATES = [
    """CREATE TABLE estimates (
        frame_id INTEGER NOT NULL, camera_id INTEGER NOT NULL, taken_at DATETIME NOT NULL, cct_k FLOAT NOT NULL,
        duv FLOAT NOT NULL, xy JSON NOT NULL, white_rgb JSON NOT NULL, gains_rgb JSON NOT NULL,
        confidence FLOAT NOT NULL, spectrum JSON NOT NULL, intervals JSON, source VARCHAR(40) NOT NULL,
        created_at DATETIME NOT NULL, model VARCHAR(64), PRIMARY KEY (frame_id),
        FOREIGN KEY(frame_id) REFERENCES frames (id) ON DELETE CASCADE,
        FOREIGN KEY(camera_id) REFERENCES cameras (id) ON DELETE CASCADE)""",
    "CREATE INDEX ix_estimates_taken_at ON estimates (taken_at)",
    "CREATE INDEX ix_estimates_camera_taken ON estimates (camera_id, taken_at, frame_id)",
    "CREATE INDEX ix_estimates_camera_id ON estimates (camera_id)",
]
"""The ``estimates`` table as versions before ``spectrum_f32`` created it on SQLite (``sqlite_master``)."""


def _history() -> tuple[np.ndarray, np.ndarray]:
    """(sensitivities 61 × 3, region means F × 8 × 3) of a simulated daylight history."""
    rng = np.random.default_rng(3)
    wl = np.arange(400, 701, 5)
    css = np.column_stack([np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in (600, 540, 460)])
    mired = np.linspace(110, 250, N_FRAMES + 5)
    day = CIEDaylight().spectra(np.column_stack([mired, np.zeros_like(mired)]))
    refl = np.clip(0.2 + 0.6 * rng.random((8, 1)) * np.sin(wl / rng.uniform(40, 120, (8, 1))) ** 2, 0, 1)
    return css, simulate_history(css, day, refl, rng=1, missing_fraction=0.1).observations.values


def _post(c: TestClient, cid: int, token: str, values: np.ndarray, f: int) -> dict:
    patches = {p: None if not np.isfinite(values[j, 0]) else values[j].tolist() for j, p in enumerate(IDS)}
    r = c.post(f"/v1/cameras/{cid}/observations", json={"patches": patches,
                                                        "taken_at": (T0 + timedelta(minutes=f)).isoformat()},
               headers=bearer(token))
    assert r.status_code == 201, r.text
    return r.json()


def _illuminant(c: TestClient, cid: int, token: str, f: int) -> dict:
    r = c.get(f"/v1/cameras/{cid}/illuminant", params={"at": (T0 + timedelta(minutes=f)).isoformat()},
              headers=bearer(token))
    assert r.status_code == 200, r.text
    return r.json()


def _float32_of(spectrum: np.ndarray, answered: list[float]) -> None:
    """``answered`` is ``spectrum`` rounded to float32, value for value (relative error ≤ 2⁻²⁴)."""
    want = np.asarray(spectrum, dtype=float)
    got = np.asarray(answered, dtype=float)
    assert got.shape == want.shape == (61,)
    assert got.tolist() == want.astype(np.float32).astype(float).tolist()
    assert np.all(np.abs(got - want) <= 2.0**-24 * np.abs(want))


class _Spectra:
    """The spectra the estimator gave, float64, by frame id (a refit's) and in order (an ingest's)."""

    def __init__(self, monkeypatch) -> None:
        self.refit: dict[str, np.ndarray] = {}
        self.ingest: list[np.ndarray] = []
        add, row = batch.RefitEstimates.add, frame.estimate_row

        def record_add(est, result, confidence, keep, source, extra=None):  # noqa: ANN001, ANN202
            for i in np.flatnonzero(keep):
                self.refit[str(result.frames[i])] = np.array(result.spectra[i], dtype=float)
            return add(est, result, confidence, keep, source, extra)

        def record_row(result, i, *args, **kwargs):  # noqa: ANN001, ANN202
            self.ingest.append(np.array(result.spectra[i], dtype=float))
            return row(result, i, *args, **kwargs)

        monkeypatch.setattr(batch.RefitEstimates, "add", record_add)
        monkeypatch.setattr(frame, "estimate_row", record_row)


def _make_old(url: str) -> None:
    """Turn the freshly created ``estimates`` table of ``url`` into an older version's (empty)."""
    engine = create_engine(url)
    with engine.begin() as conn:
        if engine.dialect.name == "sqlite":
            conn.execute(text("DROP TABLE estimates"))
            for ddl in OLD_ESTIMATES:
                conn.execute(text(ddl))
        else:
            conn.execute(text("ALTER TABLE estimates DROP COLUMN spectrum_f32"))
            conn.execute(text("ALTER TABLE estimates ALTER COLUMN spectrum SET NOT NULL"))
    assert "spectrum_f32" not in {c["name"] for c in inspect(engine).get_columns("estimates")}
    engine.dispose()


def _run(tmp_path, monkeypatch, database_url: str | None, old: bool) -> None:
    spectra = _Spectra(monkeypatch)
    settings = make_settings(tmp_path, database_url=database_url)
    css, values = _history()
    with TestClient(create_app(settings)) as c:
        r = c.post("/v1/cameras", json=camera_body(css, REGIONS, encoding="linear"), headers=admin_headers())
        assert r.status_code == 201, r.text
        cid, token = r.json()["id"], r.json()["token"]
        ids = [_post(c, cid, token, values[f], f)["frame_id"] for f in range(N_FRAMES)]
    url = settings.resolved_database_url
    stored = (np.linspace(50.0, 150.0, 61) / 3).tolist()  # 1/3 steps: no float32 value among them
    if old:  # an older version's table, holding an estimate it wrote (its spectrum as json.dumps's list)
        _make_old(url)
        engine = create_engine(url)
        with engine.begin() as conn:
            conn.execute(text(
                "INSERT INTO estimates (frame_id, camera_id, taken_at, cct_k, duv, xy, white_rgb, gains_rgb, confidence,"
                " spectrum, intervals, source, created_at, model) VALUES (:f, :c, :t, 5000.0, 0.001, '[0.34, 0.35]',"
                " '[0.8, 1.0, 0.9]', '[1.25, 1.0, 1.1]', 0.5, :s, NULL, 'model', :t, NULL)"),
                {"f": ids[0], "c": cid, "t": T0.replace(tzinfo=None), "s": json.dumps(stored)})
        engine.dispose()
    with TestClient(create_app(settings)) as c:  # start-up brings the schema up to date
        engine = create_engine(url)
        assert "spectrum_f32" in {col["name"] for col in inspect(engine).get_columns("estimates")}
        # the older version's indexes no query needs are gone, the (camera, time) one is there
        assert {ix["name"] for ix in inspect(engine).get_indexes("estimates")} == {"ix_estimates_camera_taken"}
        if old:
            got = _illuminant(c, cid, token, 0)
            assert got["frame_id"] == ids[0] and same_value(got["spectrum"]["values"], stored)
        r = c.post(f"/v1/cameras/{cid}/refit", headers=bearer(token))
        assert r.status_code == 202, r.text
        assert c.get(f"/v1/jobs/{r.json()['job_id']}", headers=bearer(token)).json()["state"] == "done"
        # a refit's estimates: the old row replaced, every spectrum the estimator's to float32 precision
        assert len(spectra.refit) > N_FRAMES // 2
        for f in range(0, N_FRAMES, 7):
            got = _illuminant(c, cid, token, f)
            _float32_of(spectra.refit[str(ids[f])], got["spectrum"]["values"])
        # an ingest's estimate with the new model
        spectra.ingest.clear()
        answer = _post(c, cid, token, values[N_FRAMES], N_FRAMES)
        assert answer["estimate"] is not None and len(spectra.ingest) == 1
        got = _illuminant(c, cid, token, N_FRAMES)
        assert got["frame_id"] == answer["frame_id"]
        _float32_of(spectra.ingest[0], got["spectrum"]["values"])
        with engine.connect() as conn:  # what is stored: the bytes, the older JSON column null
            rows = conn.execute(text("SELECT spectrum, spectrum_f32 FROM estimates")).all()
        assert len(rows) >= len(spectra.refit) and all(len(bytes(b)) == 61 * 4 for _, b in rows)
        assert {s if isinstance(s, str) else json.dumps(s) for s, _ in rows} == {"null"}
        engine.dispose()


def test_spectra_answered_to_float32_precision(tmp_path, monkeypatch) -> None:
    _run(tmp_path, monkeypatch, None, old=False)


def test_database_of_an_older_version(tmp_path, monkeypatch) -> None:
    _run(tmp_path, monkeypatch, None, old=True)


def test_database_of_an_older_version_on_postgresql(tmp_path, monkeypatch, pg_url) -> None:  # noqa: F811
    _run(tmp_path, monkeypatch, pg_url, old=True)


def test_spectrum_bytes() -> None:
    """Little-endian float32, the rows of an array alike, read back as floats; an older row's JSON list as stored."""
    rng = np.random.default_rng(0)
    a = rng.random((5, 61)) * 200
    a[1, 3], a[2, 0] = np.nan, np.inf
    rows = spectra_bytes(a)
    assert rows == [spectrum_bytes(r) for r in a] and all(len(b) == 244 for b in rows)
    assert rows[0] == a[0].astype("<f4").tobytes() and SPECTRUM_DTYPE.byteorder in "<="
    back = np.array([spectrum_values(type("E", (), {"spectrum_f32": b, "spectrum": None})) for b in rows])
    np.testing.assert_array_equal(back, a.astype(np.float32).astype(float))
    assert spectra_bytes(np.empty((0, 61))) == [] and spectrum_bytes([]) == b""
    old = type("E", (), {"spectrum_f32": None, "spectrum": [1.5, 2.25]})
    assert spectrum_values(old) == [1.5, 2.25]


from test_faults import pg_url  # noqa: E402, F401 - a throwaway PostgreSQL cluster, or skip


def test_estimate_queries_use_the_camera_time_index(tmp_path) -> None:
    """Without ``ix_estimates_camera_id`` and ``ix_estimates_taken_at`` every query of a camera's estimates (latest,
    nearest, a time range, the camera's frame ids, its count, its deletion) is a search of the (camera, time) index."""
    from illumon_service.storage import make_engine

    engine = make_engine(f"sqlite:///{tmp_path}/db.sqlite")
    at = "'2025-06-01 00:00:00.000000'"
    queries = [
        "SELECT * FROM estimates WHERE camera_id = 1 ORDER BY taken_at DESC, frame_id DESC LIMIT 1",
        f"SELECT * FROM estimates WHERE camera_id = 1 AND taken_at <= {at} ORDER BY taken_at DESC LIMIT 1",
        f"SELECT * FROM estimates WHERE camera_id = 1 AND taken_at > {at} ORDER BY taken_at ASC LIMIT 1",
        f"SELECT * FROM estimates WHERE camera_id = 1 AND taken_at >= {at} ORDER BY taken_at, frame_id LIMIT 10",
        "SELECT frame_id FROM estimates WHERE camera_id = 1",
        "SELECT count(*) FROM estimates WHERE camera_id = 1",
        "DELETE FROM estimates WHERE camera_id = 1",
    ]
    with engine.connect() as conn:
        for q in queries:
            plan = " ".join(str(r[-1]) for r in conn.execute(text(f"EXPLAIN QUERY PLAN {q}")))
            assert "USING" in plan and "ix_estimates_camera_taken" in plan and "TEMP B-TREE" not in plan, (q, plan)
    engine.dispose()
