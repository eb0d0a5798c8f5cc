"""Persistence: SQLAlchemy models and engine set-up.

SQLite under the data dir by default, in WAL mode with ``synchronous=FULL``: a transaction is on disk when ``commit``
returns, and routes commit before they answer, so a 2xx means committed. Any SQLAlchemy URL (PostgreSQL) works too.
Arrays are stored as JSON lists (small: 61 samples at most), written with :func:`json.dumps` (or given as JSON text,
:class:`StoredJSON`) and read with orjson (:func:`json_loads`) — but an estimate's spectrum, stored as float32 bytes
(:attr:`Estimate.spectrum_f32`, :func:`spectrum_values`). An older database is brought up to date at start-up
(:func:`make_engine`: tables, nullable columns and indexes added, obsolete indexes dropped).
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from datetime import datetime, timezone
from itertools import repeat
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import orjson
from sqlalchemy import (
    JSON,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Table,
    UniqueConstraint,
    create_engine,
    event,
    insert,
    text,
)
from sqlalchemy.engine import Dialect, Engine
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

__all__ = [
    "Base",
    "Camera",
    "Frame",
    "Estimate",
    "Job",
    "Calibration",
    "CameraView",
    "make_engine",
    "make_session_factory",
    "hash_token",
    "new_token",
    "utcnow",
    "as_utc",
    "GroupCommit",
    "IdempotencyKey",
    "LoginSession",
    "private_sqlite_file",
    "StoredJSON",
    "DateTimeTexts",
    "JSONTexts",
    "json_texts_like",
    "json_dumps",
    "json_loads",
    "orjson_loads",
    "insert_columns",
    "upsert_dialect",
    "SPECTRUM_DTYPE",
    "OBSOLETE_INDEXES",
    "drop_obsolete_indexes",
    "spectrum_bytes",
    "spectra_bytes",
    "spectrum_values",
]

T = TypeVar("T")


def utcnow() -> datetime:
    """The current time, timezone-aware UTC."""
    return datetime.now(timezone.utc)


def hash_token(token: str) -> str:
    """SHA-256 hex digest of a bearer token (tokens are random 256-bit strings, so no salt or stretching is needed)."""
    return hashlib.sha256(token.encode()).hexdigest()


def new_token() -> str:
    """A fresh random bearer token."""
    return secrets.token_urlsafe(32)


def as_utc(value: datetime | None) -> datetime | None:
    """The one UTC normaliser: naive datetimes (SQLite reads them back so; naive input means UTC) get UTC attached,
    aware ones are converted to UTC."""
    if value is None:
        return None
    return value.replace(tzinfo=timezone.utc) if value.tzinfo is None else value.astimezone(timezone.utc)


class StoredJSON(str):
    """JSON text made by the caller, which a JSON column stores as it is (:func:`json_dumps`): a refit's estimate
    rows carry their arrays so, written straight from the arrays by orjson (:func:`.estimation.batch.json_rows`),
    where :func:`json.dumps` of their lists took half of a 100k-frame write step."""

    __slots__ = ()


class JSONTexts(list):
    """A column of values for :func:`insert_columns` in which every ``str`` is JSON text made by the caller, stored
    as it is (as a :class:`StoredJSON` would be), and any other value is converted as the column's type converts it.

    The texts are plain ``str``: the ``sqlite3`` driver binds a ``str`` as it is, but looks a ``str`` subclass up in
    its adapters first (a :class:`StoredJSON` per value cost a 100k-frame refit's INSERT ~0.1 s of its five JSON
    columns, issue 29). Only :func:`insert_columns` reads the marker: elsewhere a ``str`` in a JSON column is a JSON
    string, so a column taken apart (:func:`json_texts_like`) keeps it."""

    __slots__ = ()


def json_texts_like(column: Sequence[Any], values: Iterable[Any]) -> list:
    """``values`` (some of ``column``'s) as a column of the same kind: :class:`JSONTexts` for one, a list else."""
    return JSONTexts(values) if type(column) is JSONTexts else list(values)


class DateTimeTexts(list):
    """A column of times for :func:`insert_columns` in which every ``str`` is a time as SQLite stores it, in the form
    SQLAlchemy's SQLite ``DATETIME`` writes (:func:`_datetime_text`: ``YYYY-MM-DD HH:MM:SS.ffffff``; a refit's times
    read as stored and written back), stored as it is where the column's processor writes that form, and converted as
    the time it reads as (:meth:`datetime.fromisoformat`) elsewhere; any other value is converted as the column's type
    converts it."""

    __slots__ = ()


def json_dumps(value: Any) -> str:
    """The engine's JSON serializer: :class:`StoredJSON` as it is, any other value through :func:`json.dumps` (what
    SQLAlchemy uses by default: ``NaN`` and ``Infinity`` written as such, keys converted to strings)."""
    return str(value) if type(value) is StoredJSON else json.dumps(value)


_DIGIT_RUNS = bytes(48 if 48 <= i <= 57 else 32 for i in range(256))
"""A byte table: every digit to ``0``, every other byte to a space."""
_LONG_RUN = b"0" * 20


def _long_integer(text: str | bytes) -> bool:
    """Whether ``text`` may hold an integer of 20 digits or more (any run of 20 digits; ~1 µs for 1 KB)."""
    data = text.encode() if isinstance(text, str) else bytes(text)
    return _LONG_RUN in data.translate(_DIGIT_RUNS)


def orjson_loads(text: str | bytes) -> Any:
    """:func:`orjson.loads`, or :func:`json.loads` where orjson refuses the text (``NaN`` and ``Infinity``, which
    :func:`json.dumps` writes; ``1e400``; a lone surrogate). Every value it gives equals :func:`json.loads`'s but an
    integer ≥ 2⁶⁴, which orjson reads as a float (:func:`json_loads` checks for those)."""
    try:
        return orjson.loads(text)
    except orjson.JSONDecodeError:
        return json.loads(bytes(text) if isinstance(text, memoryview) else text)


def json_loads(text: str | bytes) -> Any:
    """The engine's JSON deserializer: the values :func:`json.loads` gives, whatever was stored, read by orjson
    (:func:`orjson_loads`: every float correctly rounded, as :func:`json.loads` reads it, ~4 × faster with this
    check), by :func:`json.loads` itself where the text may hold an integer of 20 digits or more (≥ 2⁶⁴: orjson
    would read a float)."""
    if _long_integer(text):
        return json.loads(bytes(text) if isinstance(text, memoryview) else text)
    return orjson_loads(text)


class Base(DeclarativeBase):
    """Declarative base of the service tables."""


class Camera(Base):
    """A registered fixed camera: its sensitivities (61 × 3 on the grid; ``[]`` for a camera nobody measured), regions
    and output pipeline (``response``: tone curve, black and white levels, and an optional 3 × 3 ``matrix``)."""

    __tablename__ = "cameras"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True, index=True)
    sensitivities: Mapped[list] = mapped_column(JSON)
    regions: Mapped[list] = mapped_column(JSON)
    response: Mapped[dict] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    image_size: Mapped[list | None] = mapped_column(JSON, nullable=True)
    """[width, height] of its frames as declared at registration (regions are checked against it until a frame is
    stored); ``None`` when not declared."""
    models: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    """The scene models in use, by view (``default`` or ``v-<view>``): ``{"file": name under <data dir>/models,
    "version": id}``. A refit writes a new versioned file and switches to it in the transaction that stores its
    estimates, so estimates and model change together (:mod:`.refit`); ``None`` before the first refit."""


class Frame(Base):
    """One ingested frame: region means (linear 0…1, ``null`` where missing) keyed by region id, as the camera output
    them, with the white-balance gains (``applied_gains``, r g b) and relative ``exposure`` the camera says it applied
    (divided out before estimating and fitting)."""

    __tablename__ = "frames"
    __table_args__ = (
        Index("ix_frames_camera_taken", "camera_id", "taken_at", "id"),
        Index("ix_frames_camera_not_estimated", "camera_id", "not_estimated",
              sqlite_where=text("not_estimated IS NOT NULL"), postgresql_where=text("not_estimated IS NOT NULL")),
    )
    """Every "latest N frames" and time-range query of one camera is an index range scan (no sort of its rows); the
    frames with a reason for having no estimate (few) are a range of a partial index."""
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"), index=True)
    taken_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), index=True)
    patches: Mapped[dict] = mapped_column(JSON)
    width: Mapped[int | None] = mapped_column(Integer, nullable=True)
    height: Mapped[int | None] = mapped_column(Integer, nullable=True)
    image_path: Mapped[str | None] = mapped_column(String(500), nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    applied_gains: Mapped[list | None] = mapped_column(JSON, nullable=True)
    exposure: Mapped[float | None] = mapped_column(Float, nullable=True)
    view: Mapped[str | None] = mapped_column(String(64), nullable=True, index=True)
    """The camera view (PTZ preset id) the frame was taken from; ``None`` for a fixed camera's one view."""
    registration: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    """Where the frame lies relative to its view's reference frame (:mod:`.registration`): ``state``
    (``reference`` | ``ok`` | ``view_change``), ``shift`` [dx, dy] in pixels, ``response``."""
    thumb_path: Mapped[str | None] = mapped_column(String(500), nullable=True)
    """The frame's linear thumbnail (:mod:`.proposals`), while kept."""
    patch_sd: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    """Standard errors of the region means (region id → [r, g, b] or ``null``, same scale): the pixels' spread over
    √pixels, measured at ingest (or sent with client-measured means); the estimators add their square to the noise
    variance they assume. ``None`` when unknown."""
    not_estimated: Mapped[str | None] = mapped_column(String(40), nullable=True)
    """Why the frame has no estimate, while it has none: ``view_change``, ``no_regions`` (its view had none yet),
    ``too_few_regions`` (fewer than two usable), ``no_model`` (no refit yet), ``invalid_values`` (a refit left it out),
    ``estimate_failed``; ``None`` once estimated (or for rows of older versions)."""


class CameraView(Base):
    """The regions of one view (PTZ preset) of a camera other than its default view (whose regions are the camera's)."""

    __tablename__ = "camera_views"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"), index=True)
    view: Mapped[str] = mapped_column(String(64))
    regions: Mapped[list] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class Calibration(Base):
    """A calibration image's measurement: reference patches (``chart:01`` … or ``grey``) → linear mean r g b
    (``null`` where unusable), the clipped ones, the camera's own regions in the same image (``scene``: they tie the
    reference to the scene's daylight), and the camera's applied gains and exposure for that image."""

    __tablename__ = "calibrations"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(20))
    patches: Mapped[dict] = mapped_column(JSON)
    clipped: Mapped[list] = mapped_column(JSON)
    scene: Mapped[dict] = mapped_column(JSON)
    reflectance: Mapped[float | None] = mapped_column(Float, nullable=True)
    applied_gains: Mapped[list | None] = mapped_column(JSON, nullable=True)
    exposure: Mapped[float | None] = mapped_column(Float, nullable=True)
    warnings: Mapped[list] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class Estimate(Base):
    """The illuminant estimate of one frame (the latest one wins: a refit replaces older estimates)."""

    __tablename__ = "estimates"
    __table_args__ = (Index("ix_estimates_camera_taken", "camera_id", "taken_at", "frame_id"),)
    """"Latest estimate", "latest N" and ``since``/``until`` of one camera: an index range scan in time order. Every
    query of the table names its camera or its frames, and this index also serves the camera's cascade: it is the
    table's one index besides the key (older versions' ``ix_estimates_camera_id`` and ``ix_estimates_taken_at`` are
    dropped, :data:`OBSOLETE_INDEXES`; each cost a refit's write step a B-tree of 100k entries)."""
    frame_id: Mapped[int] = mapped_column(ForeignKey("frames.id", ondelete="CASCADE"), primary_key=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"))
    taken_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    cct_k: Mapped[float] = mapped_column(Float)
    duv: Mapped[float] = mapped_column(Float)
    xy: Mapped[list] = mapped_column(JSON)
    white_rgb: Mapped[list] = mapped_column(JSON)
    gains_rgb: Mapped[list] = mapped_column(JSON)
    confidence: Mapped[float] = mapped_column(Float)
    spectrum: Mapped[list | None] = mapped_column(JSON, nullable=True)
    """The illuminant's spectrum (61 values, 400–700 nm) as a JSON list, as versions before ``spectrum_f32`` stored
    it (rows they wrote keep it); JSON ``null`` in rows written since (an older database's column is ``NOT NULL``).
    Read either through :func:`spectrum_values`."""
    spectrum_f32: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    """The spectrum as little-endian float32 values (244 bytes for 61; :func:`spectrum_bytes`), for rows written
    since it exists — a JSON list of 61 floats was 1.1 KB of a row's 1.7 KB; ``None`` in older rows."""
    intervals: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    source: Mapped[str] = mapped_column(String(40))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    model: Mapped[str | None] = mapped_column(String(64), nullable=True)
    """Version of the scene model that made the estimate (:attr:`Camera.models`); ``None`` for other sources."""


SPECTRUM_DTYPE = np.dtype("<f4")
"""How :attr:`Estimate.spectrum_f32` stores a spectrum: little-endian float32, the estimator's values to 7 significant
digits (a relative error ≤ 6e-8, far below what the spectrum is known to)."""


def spectrum_bytes(values: Any) -> bytes:
    """A spectrum (a sequence of floats) as :attr:`Estimate.spectrum_f32` stores it."""
    return np.asarray(values, dtype=float).astype(SPECTRUM_DTYPE).tobytes()


def spectra_bytes(values: Any) -> list[bytes]:
    """Each row of a 2-D array of spectra as :func:`spectrum_bytes` gives it, converted at once."""
    a = np.ascontiguousarray(np.asarray(values, dtype=float).astype(SPECTRUM_DTYPE))
    if a.ndim != 2:
        raise ValueError("spectra_bytes: a 2-D array of spectra")
    if not a.shape[0]:
        return []
    width = a.shape[1] * SPECTRUM_DTYPE.itemsize
    data = a.tobytes()
    return [data[i : i + width] for i in range(0, len(data), width)] if width else [b""] * a.shape[0]


def spectrum_values(e: Any) -> list[float] | None:
    """The stored spectrum of an estimate (a row of :class:`Estimate` or a row with its columns by name): its
    ``spectrum_f32`` as floats where stored, else its JSON ``spectrum`` (rows of older versions) as it was read."""
    data = getattr(e, "spectrum_f32", None)
    if data is not None:
        return np.frombuffer(data, dtype=SPECTRUM_DTYPE).astype(float).tolist()
    return getattr(e, "spectrum", None)


class Job(Base):
    """A refit job: ``queued`` → ``running`` → ``done`` | ``failed``."""

    __tablename__ = "jobs"
    id: Mapped[str] = mapped_column(String(40), primary_key=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"), index=True)
    state: Mapped[str] = mapped_column(String(20), default="queued")
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    summary: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    """Last sign of life of the process running the job (every few seconds); a ``running`` job whose heartbeat is
    stale was orphaned by a crash (:meth:`.jobs.JobRunner.recover`)."""
    attempt: Mapped[int | None] = mapped_column(Integer, nullable=True)
    """1 for a job as submitted, 2 for its re-run after a crash (``None``: 1)."""


class IdempotencyKey(Base):
    """An ``Idempotency-Key`` a camera sent with a frame (:mod:`.idempotency`): unique per camera; the frame it
    stored, a fingerprint of the request and the answer given, returned again to a retry with the same key."""

    __tablename__ = "idempotency_keys"
    __table_args__ = (UniqueConstraint("camera_id", "key", name="uq_idempotency_camera_key"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"), index=True)
    key: Mapped[str] = mapped_column(String(255))
    fingerprint: Mapped[str] = mapped_column(String(64))
    frame_id: Mapped[int | None] = mapped_column(ForeignKey("frames.id", ondelete="CASCADE"), nullable=True, index=True)
    answer: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow, index=True)


class LoginSession(Base):
    """A status-page login (:mod:`.logins`): the SHA-256 of the random session id the cookie holds, and the hash
    of the token that logged in (a session ends when that token no longer authenticates)."""

    __tablename__ = "login_sessions"
    id_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    token_hash: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    expires_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), index=True)


def private_sqlite_file(url: str) -> Path | None:
    """For a file-backed SQLite URL: create the database file readable and writable by its owner only (0600) when
    it does not exist yet, and take group and other permissions away from an existing one and its ``-wal`` /
    ``-shm`` files (SQLite gives those the main file's mode). Returns the file, ``None`` for other URLs."""
    from sqlalchemy.engine import make_url

    u = make_url(url)
    if not u.drivername.startswith("sqlite") or not u.database or u.database == ":memory:" or u.database.startswith("file:"):
        return None
    path = Path(u.database)
    path.parent.mkdir(parents=True, exist_ok=True)
    os.close(os.open(path, os.O_RDWR | os.O_CREAT, 0o600))
    for f in (path, Path(f"{path}-wal"), Path(f"{path}-shm")):
        try:
            if f.stat().st_mode & 0o077:
                f.chmod(0o600)
        except FileNotFoundError:
            pass
    return path


def make_engine(url: str) -> Engine:
    """An engine for ``url`` with the tables created; SQLite gets WAL, ``synchronous=FULL`` and a busy timeout. JSON
    columns are written by :func:`json_dumps` and read by :func:`json_loads`."""
    codec = {"json_serializer": json_dumps, "json_deserializer": json_loads}
    if url.startswith("sqlite"):
        private_sqlite_file(url)
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30}, **codec)

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_conn, _record) -> None:  # noqa: ANN001 - DB-API connection
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=FULL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute("PRAGMA busy_timeout=30000")
            cur.close()

    else:
        engine = create_engine(url, pool_pre_ping=True, **codec)
    Base.metadata.create_all(engine)
    add_missing_columns(engine)
    add_missing_indexes(engine)
    drop_obsolete_indexes(engine)
    return engine


def add_missing_columns(engine: Engine) -> list[str]:
    """Add the nullable columns a newer version defines to the tables of an older database (``create_all`` creates
    missing tables only); returns ``table.column`` of those added. Idempotent; safe when several processes race."""
    from sqlalchemy import inspect, text
    from sqlalchemy.exc import DBAPIError

    added = []
    for table in Base.metadata.sorted_tables:
        have = {c["name"] for c in inspect(engine).get_columns(table.name)}
        for col in table.columns:
            if col.name in have or not col.nullable:
                continue
            ddl = f"ALTER TABLE {table.name} ADD COLUMN {col.name} {col.type.compile(engine.dialect)}"
            try:
                with engine.begin() as conn:
                    conn.execute(text(ddl))
            except DBAPIError:  # another process added it first
                if col.name not in {c["name"] for c in inspect(engine).get_columns(table.name)}:
                    raise
            added.append(f"{table.name}.{col.name}")
    return added


def add_missing_indexes(engine: Engine) -> list[str]:
    """Create the indexes a newer version defines on the tables of an older database (``create_all`` creates the
    indexes of the tables it creates only), e.g. the (camera, time) indexes of frames and estimates; returns the
    names of those created. Idempotent; safe when several processes race. On a large history this is the one slow
    start-up (one pass over the table per index, ~1 s per million rows on SQLite).
    """
    from sqlalchemy import inspect
    from sqlalchemy.exc import DBAPIError

    added = []
    for table in Base.metadata.sorted_tables:
        have = {ix["name"] for ix in inspect(engine).get_indexes(table.name)}
        for index in sorted(table.indexes, key=lambda ix: str(ix.name)):
            if index.name in have:
                continue
            try:
                index.create(engine, checkfirst=True)
            except DBAPIError:  # another process created it first
                if index.name not in {ix["name"] for ix in inspect(engine).get_indexes(table.name)}:
                    raise
            added.append(str(index.name))
    return added


OBSOLETE_INDEXES = {"estimates": ("ix_estimates_camera_id", "ix_estimates_taken_at")}
"""Indexes older versions created that no query needs any more, by table (a prefix of another index, or an index no
query uses), dropped from their databases at start-up (:func:`drop_obsolete_indexes`)."""


def drop_obsolete_indexes(engine: Engine) -> list[str]:
    """Drop the :data:`OBSOLETE_INDEXES` an older database has; returns the names of those dropped. Idempotent; safe
    when several processes race (``DROP INDEX IF EXISTS``)."""
    from sqlalchemy import inspect

    dropped = []
    for table, names in OBSOLETE_INDEXES.items():
        have = {ix["name"] for ix in inspect(engine).get_indexes(table)}
        for name in names:
            if name in have:
                with engine.begin() as conn:
                    conn.execute(text(f"DROP INDEX IF EXISTS {name}"))
                dropped.append(name)
    return dropped


def upsert_dialect(dialect: Dialect) -> bool:
    """Whether :func:`insert_columns` can replace rows on ``dialect`` (``replace_on``): PostgreSQL, and SQLite from
    3.24 (``INSERT … ON CONFLICT … DO UPDATE``)."""
    if dialect.name == "postgresql":
        return True
    return dialect.name == "sqlite" and tuple(dialect.server_version_info or (0,)) >= (3, 24)


def _insert_statement(table: Table, dialect: Dialect, keys: Sequence[str], replace_on: Sequence[str] | None) -> Any:
    """``insert(table)``, or with ``replace_on`` the dialect's insert whose rows replace those of the same key."""
    if not replace_on:
        return insert(table)
    if dialect.name == "postgresql":
        from sqlalchemy.dialects.postgresql import insert as dialect_insert
    elif dialect.name == "sqlite" and upsert_dialect(dialect):
        from sqlalchemy.dialects.sqlite import insert as dialect_insert
    else:
        raise ValueError(f"insert_columns: no upsert on {dialect.name}")
    stmt = dialect_insert(table)
    return stmt.on_conflict_do_update(index_elements=[table.columns[k] for k in replace_on],
                                      set_={k: stmt.excluded[k] for k in keys if k not in replace_on})


_PROBE = StoredJSON('[0.5,"x"]')


def _passes_json_text(process: Callable[[Any], Any]) -> bool:
    """Whether a bind processor turns a :class:`StoredJSON` into its own text (a JSON column on SQLite: the engine's
    serializer, :func:`json_dumps`, gives ``str(value)``), so that :func:`insert_columns` may hand the driver the
    value itself (a ``str``) without the call (~1 µs a value: 400 000 values in a 100k-frame refit). ``False``
    where the processor makes anything else of it (psycopg's JSON wrapper)."""
    out = process(_PROBE)
    return type(out) is str and out == _PROBE


_DATETIME_PROBES = (datetime(2025, 6, 1, 12, 30, 5), datetime(2025, 6, 1, 12, 30, 5, 7),
                    datetime(999, 1, 2, 3, 4, 5, 999_999), datetime(2025, 6, 1, 23, 59, 59, 120_000, timezone.utc))


def _datetime_text(value: datetime) -> str:
    """SQLite's stored text of a datetime as SQLAlchemy's SQLite ``DATETIME`` writes it by default (its fields,
    microseconds always, any time zone left out), ~5 × faster than its ``%``-formatting of a dict of the fields."""
    return value.isoformat(" ", "microseconds")[:26]


def _writes_datetime_text(process: Callable[[Any], Any]) -> bool:
    """Whether a DateTime column's bind processor writes a datetime as :func:`_datetime_text` does (checked on
    :data:`_DATETIME_PROBES`: SQLite's default storage format)."""
    return all(process(v) == _datetime_text(v) for v in _DATETIME_PROBES)


def _binds_bytes_as_buffer(dialect: Dialect, process: Callable[[Any], Any]) -> bool:
    """Whether a binary column's bind processor hands the driver a ``bytes`` value as a buffer of its bytes that
    ``sqlite3`` binds as that blob (SQLAlchemy's SQLite ``LargeBinary``: ``sqlite3.Binary``, a ``memoryview``), so
    that :func:`insert_columns` may hand it a ``bytearray`` of them instead — an exact type, which ``sqlite3`` binds
    without looking for an adapter first (a ``memoryview`` or ``bytes`` it looks up: ~0.4 µs a value, 0.04 s of the
    executemany of a 100k-frame refit's rows)."""
    return dialect.name == "sqlite" and dialect.driver == "pysqlite" and type(process(b"\x00\x01")) is memoryview


def insert_columns(session: Session, table: Table, columns: Mapping[str, Sequence[Any]],
                   constants: Mapping[str, Any] | None = None, *, replace_on: Sequence[str] | None = None) -> int:
    """One executemany INSERT into ``table`` of rows given a column at a time, within the session's transaction, the
    rows handed to the driver as they are; returns the number of rows.

    ``columns``: each column's values, one per row (lists of one length); ``constants``: columns every row has the
    same value of. ``replace_on``: the columns of a unique key (the primary key): a row whose key is stored already
    replaces that row, every other given column set to the row's value (``INSERT … ON CONFLICT (key) DO UPDATE``,
    only where :func:`upsert_dialect`; ``ValueError`` elsewhere) — the table then holds what a DELETE of those keys
    followed by the INSERT leaves when every column is given, in one statement: on SQLite the row is rewritten where
    it lies instead of deleted and inserted again (a 100k-frame refit's write 1.7 → 1.3 s of SQLite's time).
    The statement is the one SQLAlchemy Core compiles for the dialect (``insert(table)``), every value
    converted by its column type's bind processor as SQLAlchemy converts it (datetimes as SQLite's text, JSON through
    the engine's serializer, psycopg's JSON wrapper), a column at a time and a constant once, and the rows passed to
    the driver's ``executemany`` (:meth:`~sqlalchemy.engine.Connection.exec_driver_sql`):
    ``session.execute(insert(table), rows)`` prepares every row's parameters on its own, ~10 µs a row. A
    :class:`StoredJSON` value, and a ``str`` of a :class:`JSONTexts` column (a plain ``str``, which ``sqlite3`` binds
    without an adapter lookup), is handed over as it is where its processor would give its text unchanged
    (:func:`_passes_json_text`); a datetime is formatted by :func:`_datetime_text` where that is the processor's
    text (:func:`_writes_datetime_text`: SQLite; 0.15 → 0.07 s per 100k values), and a ``str`` of a
    :class:`DateTimeTexts` column is handed over as it is there (SQLite's stored text of the time). Every column
    with a Python-side default must be given (``ValueError`` otherwise: no default is computed here).
    """
    constants = dict(constants or {})
    n = len(next(iter(columns.values()))) if columns else 0
    if not n:
        return 0
    conn = session.connection()
    dialect = conn.dialect
    keys = [*columns, *constants]
    compiled = _insert_statement(table, dialect, keys, replace_on).compile(dialect=dialect, column_keys=keys)
    if compiled.insert_prefetch:
        raise ValueError(f"insert_columns: no value for {', '.join(c.key for c in compiled.insert_prefetch)}")
    processors = {k: table.columns[k].type.dialect_impl(dialect).bind_processor(dialect) for k in keys}
    values: dict[str, Any] = {}
    for key, column in columns.items():
        process = processors[key]
        if process is None:
            values[key] = column
        elif type(column) is JSONTexts:  # its str values are the caller's JSON text (StoredJSON's)
            if _passes_json_text(process):  # texts only (a refit's usual column): the column as it is
                values[key] = column if not set(map(type, column)) - {str} else \
                    [v if type(v) is str else process(v) for v in column]
            else:
                values[key] = [process(StoredJSON(v) if type(v) is str else v) for v in column]
        elif isinstance(table.columns[key].type, JSON) and _passes_json_text(process):  # the caller's JSON text
            values[key] = [v if type(v) is StoredJSON else process(v) for v in column]
        elif isinstance(table.columns[key].type, DateTime) and _writes_datetime_text(process):  # _datetime_text
            values[key] = [v.isoformat(" ", "microseconds")[:26] if type(v) is datetime
                           else v if type(v) is str and type(column) is DateTimeTexts else process(v) for v in column]
        elif type(column) is DateTimeTexts:  # its texts as the times they are
            values[key] = [process(datetime.fromisoformat(v) if type(v) is str else v) for v in column]
        elif isinstance(table.columns[key].type, LargeBinary) and _binds_bytes_as_buffer(dialect, process):
            values[key] = [bytearray(v) if type(v) is bytes else process(v) for v in column]
        else:
            values[key] = [process(v) for v in column]
    for key, value in constants.items():
        values[key] = repeat(value if processors[key] is None else processors[key](value), n)
    if compiled.positional:
        params: list = list(zip(*(values[k] for k in compiled.positiontup or ()), strict=False))
    else:
        params = [dict(zip(keys, row, strict=True)) for row in zip(*(values[k] for k in keys), strict=False)]
    if len(params) != n or any(len(c) != n for c in columns.values()):
        raise ValueError("insert_columns: columns of different lengths")
    conn.exec_driver_sql(compiled.string, params)
    return n


def make_session_factory(engine: Engine) -> sessionmaker[Session]:
    """Session factory bound to ``engine`` (objects stay usable after commit)."""
    return sessionmaker(engine, expire_on_commit=False)


class GroupCommit:
    """Group commit: concurrent writes share one transaction and one durable commit (one fsync).

    ``submit(write)`` runs ``write(session)`` (add rows, flush, build the answer) and returns its result once the
    transaction holding it is committed, never before. Threads arriving while a commit is under way queue their
    writes; when it ends, one of them writes every queued one in one transaction and commits once (leader / followers,
    no extra thread; a leader commits one batch, then hands over). On SQLite, whose single write lock otherwise makes
    concurrent writers poll with sleeps (``busy_timeout``), this also turns that wait into a queue. A write that fails
    before the commit (its flush raises) makes the batch run again one write per transaction, so only the failing
    write fails; a commit that raises fails every write of its batch and is not retried, as it might have reached
    the disk.
    """

    def __init__(self, sessions: sessionmaker[Session], on_commit: Callable[[int], None] | None = None) -> None:
        self._sessions = sessions
        self._on_commit = on_commit  # called with the number of writes of every committed transaction
        self._cond = threading.Condition()
        self._pending: list[tuple[Callable[[Session], object], dict]] = []
        self._leading = False
        self.batches = 0
        """Transactions committed (for tests and metrics)."""

    def submit(self, write: Callable[[Session], T]) -> T:
        """Run ``write`` in a transaction shared with concurrent writes; its result after the commit (or its error).

        The thread that finds no commit under way leads: it takes every queued write (its own among them), commits
        them, and hands over; the others wait for their write's commit, or for their turn to lead.
        """
        box: dict = {}
        with self._cond:
            self._pending.append((write, box))
            while "done" not in box and self._leading:
                self._cond.wait()
            lead = "done" not in box
            if lead:
                self._leading = True
                batch, self._pending = self._pending, []
        if lead:
            try:
                self._commit(batch)
            except BaseException as exc:  # the leader's own failure (e.g. interrupted): its batch fails with it
                for _, other in batch:
                    if "result" not in other:
                        other.setdefault("error", exc)
                raise
            finally:
                with self._cond:
                    for _, other in batch:
                        other["done"] = True
                    self._leading = False
                    self._cond.notify_all()
        if "error" in box:
            raise box["error"]
        return box["result"]

    def _commit(self, batch: list[tuple[Callable[[Session], object], dict]]) -> None:
        """Write and commit ``batch``; record each write's result or error in its box."""
        with self._sessions() as session:
            try:
                results = [write(session) for write, _ in batch]
            except Exception as exc:  # noqa: BLE001 - isolated below
                session.rollback()
                if len(batch) == 1:
                    batch[0][1]["error"] = exc
                    return
                for item in batch:  # nothing of the batch is on disk: each write again, on its own
                    self._commit([item])
                return
            try:
                session.commit()
            except Exception as exc:  # noqa: BLE001 - reported to every waiting request
                for _, box in batch:
                    box["error"] = exc
                return
        self.batches += 1
        if self._on_commit is not None:
            self._on_commit(len(batch))
        for (_, box), result in zip(batch, results, strict=True):
            box["result"] = result
